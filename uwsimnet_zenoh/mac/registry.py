"""The MAC registry: names to classes.  It knows no protocol: built-ins name themselves with `@register`
(mac/__init__ imports them, or names their modules with `defer`), users give `module:Class` or an entry
point of group `uwsimnet.mac`."""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import TYPE_CHECKING

from .base import Mac

if TYPE_CHECKING:
    from importlib.metadata import EntryPoint

_BUILTIN: dict[str, str] = {}
_DEFERRED: frozenset[str] = frozenset()
"""Modules of built-in MACs that register their names when imported, imported only when a name is not found
(or all names are listed): a run imports the MACs it uses only (start-up time)."""
_PENDING: list[str] = []
"""Those of `_DEFERRED` not imported yet by the registry."""


def defer(*modules: str) -> None:
    """Built-in MAC modules to import when their names are first needed (mac/__init__)."""
    global _DEFERRED
    _DEFERRED |= frozenset(modules)
    _PENDING.extend(modules)


def _import_deferred() -> None:
    while _PENDING:
        importlib.import_module(_PENDING.pop(0))


def entry_points(group: str) -> list[EntryPoint]:
    """importlib.metadata's, imported when a name no built-in has is looked up (~25 ms of start-up)."""
    from importlib.metadata import entry_points as eps

    return list(eps(group=group))


def register(*names: str) -> Callable[[type[Mac]], type[Mac]]:
    """Class decorator naming a built-in MAC (case-insensitive)."""
    def deco(cls: type[Mac]) -> type[Mac]:
        # a deferred built-in registers as if mac/__init__ had imported it, before every other registration:
        # it takes no name registered since
        deferred = cls.__module__ in _DEFERRED
        for n in names:
            if not (deferred and n.lower() in _BUILTIN):
                _BUILTIN[n.lower()] = f"{cls.__module__}:{cls.__qualname__}"
        return cls
    return deco


def builtin_names() -> list[str]:
    _import_deferred()
    return sorted(_BUILTIN)


def resolve(name: str) -> type[Mac]:
    """A MAC class from a built-in name, an entry point of group `uwsimnet.mac`, or `module:Class`."""
    key = name.strip().lower()
    spec = _BUILTIN.get(key)
    if spec is None and _PENDING:
        _import_deferred()
        spec = _BUILTIN.get(key)
    if spec is None:
        for ep in entry_points(group="uwsimnet.mac"):
            if ep.name.lower() == key:
                cls = ep.load()
                break
        else:
            if ":" not in name:
                raise ValueError(f"unknown MAC protocol {name!r} (built-in: {', '.join(builtin_names())};"
                                 " or give module:Class)")
            spec = name.strip()
    if spec is not None:
        mod_name, _, cls_name = spec.partition(":")
        try:
            cls = getattr(importlib.import_module(mod_name), cls_name)
        except (ImportError, AttributeError) as e:
            raise ValueError(f"cannot load MAC protocol {name!r}: {e}") from None
    if not (isinstance(cls, type) and issubclass(cls, Mac)):
        raise ValueError(f"MAC protocol {name!r} is not a subclass of uwsimnet_zenoh.mac.Mac")
    return cls
