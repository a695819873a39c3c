"""The MAC registry: names to classes.  It knows no protocol: built-ins name themselves with `@register`
(mac/__init__ imports them), users give `module:Class` or an entry point of group `uwsimnet.mac`."""

from __future__ import annotations

import importlib
from collections.abc import Callable
from importlib.metadata import entry_points

from .base import Mac

_BUILTIN: dict[str, str] = {}


def register(*names: str) -> Callable[[type[Mac]], type[Mac]]:
    """Class decorator naming a built-in MAC (case-insensitive)."""
    def deco(cls: type[Mac]) -> type[Mac]:
        for n in names:
            _BUILTIN[n.lower()] = f"{cls.__module__}:{cls.__qualname__}"
        return cls
    return deco


def builtin_names() -> list[str]:
    return sorted(_BUILTIN)


def resolve(name: str) -> type[Mac]:
    """A MAC class from a built-in name, an entry point of group `uwsimnet.mac`, or `module:Class`."""
    key = name.strip().lower()
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
