"""The channel-model registry: names to classes, as mac.registry does for MACs.

Built-in names are listed here (their modules are imported only when named: numpy and the acoustic
physics stay out of a run that does not use them); users give `module:Class` or an entry point of group
`uwsimnet.channel_models`.  Built-in names win over entry points; names are case-insensitive."""

from __future__ import annotations

import importlib

from .models import ChannelModel

GROUP = "uwsimnet.channel_models"
"""The entry-point group of installed channel models."""

_BUILTIN: dict[str, str] = {
    "expression": "uwsimnet_zenoh.phy.error:RateErrorModel",
    "acoustic": "uwsimnet_zenoh.phy.acoustic:AcousticLink",
    "ocean": "uwsimnet_zenoh.phy.ocean_model:OceanModel",
    "bellhop": "uwsimnet_zenoh.phy.bellhop:BellhopModel",
}


def builtin_names() -> list[str]:
    return sorted(_BUILTIN)


def resolve(name: str) -> type[ChannelModel]:
    """A channel-model class from a built-in name, an entry point of `GROUP`, or `module:Class`."""
    key = name.strip().lower()
    spec = _BUILTIN.get(key)
    cls: object = None
    if spec is None:
        from importlib.metadata import entry_points

        for ep in entry_points(group=GROUP):
            if ep.name.lower() == key:
                try:
                    cls = ep.load()
                except Exception as e:  # noqa: BLE001 - an installed plug-in that does not import: one line
                    raise ValueError(f"cannot load channel model {name!r} (entry point {ep.value}):"
                                     f" {type(e).__name__}: {e}") from None
                break
        else:
            if ":" not in name:
                raise ValueError(f"unknown channel model {name!r} (built-in: {', '.join(builtin_names())};"
                                 f" an entry point of group {GROUP}; or module:Class)")
            spec = name.strip()
    if spec is not None:
        mod_name, _, cls_name = spec.partition(":")
        try:
            cls = getattr(importlib.import_module(mod_name), cls_name)
        except Exception as e:  # noqa: BLE001 - the user's module: one line, not a traceback
            raise ValueError(f"cannot load channel model {name!r}: {type(e).__name__}: {e}") from None
    if not (isinstance(cls, type) and issubclass(cls, ChannelModel)):
        raise ValueError(f"channel model {name!r} is not a subclass of uwsimnet_zenoh.phy.models.ChannelModel")
    return cls
