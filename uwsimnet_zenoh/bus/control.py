"""Runtime control (what the original offered as ROS services): queryables under `control/<op>`.

A request is a Zenoh query on `uwsimnet/<world>/control/<op>` whose payload is a msgpack map (or
nothing); the reply is a msgpack map with `ok` (bool) and either the result fields or `error` (a
one-line message).  Every operation runs on the engine thread, at the simulation time the query arrived.

    op             request                                     reply (besides ok)
    state          {}                                          world, t, paused, speed, epoch, channels,
                                                               modems {id: {...}}, vehicles {name: {...}},
                                                               counters
    pause          {}                                          t, paused
    resume         {}                                          t, paused
    move           {vehicle, p: [x,y,z], v?: [vx,vy,vz]}       t
    add_device     {vehicle, device: {dccomms_id, address,     id, info
                    tx_channel, rx_channel, ...}}
    remove_device  {id}                                        id, t

`device` takes the fields of `scene.model.Device` in SI units (docs/runtime.md lists them):
`bitrate` bps, `intrinsic_tx_s`, `max_distance` m, `error: {unit, expr}`, `mac: {name, params}`, ...
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, Protocol

from pydantic import ValidationError
from uwsimnet_gli.wire import KeyNameError, Keys, check_chunk

from ..errors import UwsimnetError
from ..scene.model import Device

Reply = dict[str, Any]


class Served(Protocol):
    """What the control operations act on: the broker's network, clock and served modems (bus/broker.py
    implements it; this module never imports the broker)."""

    net: Any
    clock: Any
    keys: Keys
    counters: Any
    endpoints: dict[str, Any]
    real: set[str]
    foreign: set[str]
    swapped: dict[str, tuple[str, Any]]

    def serves(self, channel: int) -> bool: ...
    def attach(self, modem: Any) -> None: ...
    def detach(self, dev: str) -> None: ...
    def info(self, dev: str) -> dict[str, Any]: ...
    def clock_sample(self) -> dict[str, Any]: ...
    def publish_clock(self) -> None: ...


class ControlError(UwsimnetError, ValueError):
    """A refused control request (the message becomes the reply's `error`)."""


def _vec3(req: dict, key: str, required: bool) -> tuple[float, float, float] | None:
    v = req.get(key)
    if v is None:
        if required:
            raise ControlError(f"missing {key!r}")
        return None
    if (not isinstance(v, list | tuple) or len(v) != 3
            or not all(isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x) for x in v)):
        raise ControlError(f"{key!r} must be an array of 3 finite numbers")
    return (float(v[0]), float(v[1]), float(v[2]))


def _str(req: dict, key: str) -> str:
    v = req.get(key)
    if not isinstance(v, str) or not v:
        raise ControlError(f"{key!r} must be a non-empty string")
    return v


class Control:
    def __init__(self, broker: Served) -> None:
        self.b = broker
        self.ops: dict[str, Callable[[dict], Reply]] = {
            "state": self.state, "pause": self.pause, "resume": self.resume, "move": self.move,
            "add_device": self.add_device, "remove_device": self.remove_device,
        }

    def handle(self, op: str, req: dict) -> Reply:
        fn = self.ops.get(op)
        if fn is None:
            return {"ok": False, "error": f"unknown operation {op!r} (one of {', '.join(sorted(self.ops))})"}
        try:
            out = fn(req)
        except ControlError as e:
            return {"ok": False, "error": str(e)}
        except (ValueError, KeyError) as e:
            return {"ok": False, "error": " ".join(str(e).split())}
        return {"ok": True, **out}

    # -- operations ------------------------------------------------------------------------------
    def state(self, req: dict) -> Reply:
        b = self.b
        net = b.net
        now = net.sched.now
        pos = net.poses.points(now)
        modems = {dev: {"vehicle": ep.modem.vehicle, "address": ep.modem.address,
                        "tx_channel": ep.modem.tx_channel.id, "rx_channel": ep.modem.rx_channel.id,
                        "kind": "real" if dev in b.real else "sim"}
                  for dev, ep in b.endpoints.items()}
        for dev, (vehicle, cfg) in b.swapped.items():          # handed to a real driver (HIL swap)
            modems[dev] = {"vehicle": vehicle, "address": cfg.address, "tx_channel": cfg.tx_channel,
                           "rx_channel": cfg.rx_channel, "kind": "real"}
        vehicles = {}
        for name, v in net.vehicles.items():
            i = net.poses.index[name]
            known = bool(net.poses.known[i])
            vehicles[name] = {"source": v.pose_source,
                              "p": [float(x) for x in pos[i]] if known else None}
        c = b.clock_sample()
        return {"world": b.keys.world, "t": now, "paused": c["paused"], "speed": c["speed"], "epoch": c["epoch"],
                "channels": sorted(net.channels), "modems": modems, "vehicles": vehicles,
                "counters": dict(b.counters)}

    def pause(self, req: dict) -> Reply:
        self.b.clock.pause()
        self.b.publish_clock()
        return {"t": self.b.clock.now(), "paused": True}       # the frozen simulation time

    def resume(self, req: dict) -> Reply:
        self.b.clock.resume()
        self.b.publish_clock()
        return {"t": self.b.net.sched.now, "paused": False}

    def move(self, req: dict) -> Reply:
        net = self.b.net
        name = _str(req, "vehicle")
        if name not in net.vehicles:
            raise ControlError(f"no vehicle {name!r}")
        p = _vec3(req, "p", True)
        v = _vec3(req, "v", False)
        net.move(name, p, v)
        return {"t": net.sched.now}

    def add_device(self, req: dict) -> Reply:
        b = self.b
        net = b.net
        vehicle = _str(req, "vehicle")
        if vehicle not in net.vehicles:
            raise ControlError(f"no vehicle {vehicle!r}")
        spec = req.get("device")
        if not isinstance(spec, dict):
            raise ControlError("'device' must be a map of device fields")
        try:
            cfg = Device.model_validate(spec)
        except ValidationError as e:
            errs = "; ".join(f"{'.'.join(str(x) for x in err['loc'])}: {err['msg']}" for err in e.errors())
            raise ControlError(f"device: {errs}") from None
        try:
            check_chunk(cfg.dccomms_id, "dccomms_id")
        except KeyNameError as e:
            raise ControlError(str(e)) from None
        for ch in (cfg.tx_channel, cfg.rx_channel):
            if not b.serves(ch) or ch not in net.channels:
                raise ControlError(f"channel {ch} is not served by this broker (channels {sorted(net.channels)})")
        if cfg.dccomms_id in b.foreign:
            raise ControlError(f"{cfg.dccomms_id!r} is served by another broker")
        if cfg.dccomms_id in b.real:
            raise ControlError(f"{cfg.dccomms_id!r} is served by a real driver")
        for m in net.modems.values():
            if m.rx_channel.id == cfg.rx_channel and m.address == cfg.address:
                raise ControlError(f"address {cfg.address} is already used on rx channel {cfg.rx_channel}"
                                   f" by {m.id!r}")
        m = net.add_device(vehicle, cfg)
        b.attach(m)
        return {"id": m.id, "info": b.info(m.id)}

    def remove_device(self, req: dict) -> Reply:
        b = self.b
        dev = _str(req, "id")
        if dev not in b.endpoints:
            raise ControlError(f"no device {dev!r} on this broker")
        b.net.remove_device(dev)          # frames it still held end as drop `removed` (statuses go out)
        b.detach(dev)
        return {"id": dev, "t": b.net.sched.now}
