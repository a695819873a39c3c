"""The MAC room: the sans-IO interface (base.py), the registry (registry.py) and the built-in protocols
(NOMAC, CS-ALOHA, slotted ALOHA, S-FAMA, DcMac).  Beside phy/ and never importing it: a MAC acts only through its
`MacContext`.  Imports kernel/ only.  Write your own: docs/mac.md, and test it with `mac.testing`."""

from importlib import import_module
from typing import Any

from . import nomac  # noqa: F401 - the built-ins register their names (NOMAC at once)
from .base import Mac, MacContext, OneFrameMac
from .registry import builtin_names, defer, register, resolve

_LATER = ("aloha", "sfama", "dcmac")
defer(*(f"{__name__}.{m}" for m in _LATER))     # imported when their names are first resolved (start-up time)

__all__ = ["Mac", "MacContext", "OneFrameMac", "builtin_names", "register", "resolve"]


def __getattr__(name: str) -> Any:
    if name in _LATER:                          # `mac.aloha` as when mac/__init__ imported it
        return import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
