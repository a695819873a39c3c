"""The MAC room: the sans-IO interface (base.py), the registry (registry.py) and the built-in protocols
(NOMAC, CS-ALOHA, slotted ALOHA, S-FAMA).  Beside phy/ and never importing it: a MAC acts only through its
`MacContext`.  Imports kernel/ only.  Write your own: docs/mac.md, and test it with `mac.testing`."""

from . import aloha, nomac, sfama  # noqa: F401 - the built-ins register their names
from .base import Mac, MacContext, OneFrameMac
from .registry import builtin_names, register, resolve

__all__ = ["Mac", "MacContext", "OneFrameMac", "builtin_names", "register", "resolve"]
