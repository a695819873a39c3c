"""uwsimnet-zenoh: underwater network simulation for HIL robotics, on Zenoh.

The public face, for notebooks and scripts (loaded on first use, so importing one room never imports the
others)::

    import uwsimnet_zenoh as uw
    scene = uw.load_scene("scenes/paper/phy-layer-rf.xml")
    r = uw.run(scene, seed=3, overrides={"device.*.mac": "aloha"})    # metrics per flow and channel
    net = uw.Network(scene, seed=3)                                    # or the parts themselves
    net.tracer.add(records.append)
    net.run()

Rooms and what they may import: docs/architecture.md.  MAC authors: `uwsimnet_zenoh.mac` (`Mac`,
`MacContext`, `register`) and `uwsimnet_zenoh.mac.testing`.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

from . import _native

_native.guard()         # before any engine module: a compiled build runs only if it matches its sources

_FACE = {
    "load_scene": "uwsimnet_zenoh.scene.load",
    "load_scene_text": "uwsimnet_zenoh.scene.load",
    "SceneError": "uwsimnet_zenoh.scene.xml",
    "Scene": "uwsimnet_zenoh.scene.model",
    "Network": "uwsimnet_zenoh.engine.network",
    "run": "uwsimnet_zenoh.app.api",
    "RunResult": "uwsimnet_zenoh.app.api",
    "UwsimnetError": "uwsimnet_zenoh.errors",
    "UserError": "uwsimnet_zenoh.errors",
}

__all__ = sorted(_FACE)


def __getattr__(name: str) -> Any:
    mod = _FACE.get(name)
    if mod is None:
        raise AttributeError(f"module 'uwsimnet_zenoh' has no attribute {name!r}")
    value = getattr(import_module(mod), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_FACE))
