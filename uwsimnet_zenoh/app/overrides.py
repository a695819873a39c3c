"""Scene overrides addressed by paths (docs/campaigns.md): change a parameter without editing the XML.

    apply(scene, {"device.*.mac": "sfama", "flow.f1.rate": 2.5, "channel.0.prop_s_per_m": 1/1500})

Paths (`<id>` may be `*` for every device or flow):

    simulation.duration                          s
    channel.<id>.<field>                         prop_s_per_m, min_prop_s
    device.<id>.<field>                          bitrate, tx_fifo_bytes, intrinsic_tx_s, intrinsic_rx_s,
                                                 jitter_tx_s, jitter_rx_s, max_distance, min_distance,
                                                 header_bytes, max_frame_bytes
    device.<id>.mac                              a MAC name (built-in or entry point; module:Class is refused)
    device.<id>.mac.<param>                      a <macProtocol> parameter (text, as in the XML)
    device.<id>.error.expr | error.unit          the rateErrorModel
    vehicle.<name>.position                      "x y z" (m) or a list of three numbers
    flow.<name>.<field>                          size, interval (s), rate (frames/s: interval = 1/rate),
                                                 arrival, start, stop, dst

Values come as text from the command line: they are converted by the scene model's own types and checked by
its own validators, so an override is refused exactly as the same value in a scene file would be.  Every
refusal is one line naming the path (`UserError`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from pydantic import ValidationError

from ..errors import UserError
from ..mac import resolve
from ..scene.model import Channel, Device, Flow, Scene

DEVICE_FIELDS = ("bitrate", "tx_fifo_bytes", "intrinsic_tx_s", "intrinsic_rx_s", "jitter_tx_s", "jitter_rx_s",
                 "max_distance", "min_distance", "header_bytes", "max_frame_bytes")
CHANNEL_FIELDS = ("prop_s_per_m", "min_prop_s")
FLOW_FIELDS = ("size", "interval", "rate", "arrival", "start", "stop", "dst")


def _refuse(path: str, msg: str) -> UserError:
    return UserError(f"override {path}: {msg}")


def _revalidate(cls: type, obj: Any, changes: dict[str, Any], path: str) -> Any:
    data = obj.model_dump()
    data.update(changes)
    try:
        return cls.model_validate(data)
    except ValidationError as e:
        err = e.errors()[0]
        where = ".".join(str(x) for x in err["loc"])
        raise _refuse(path, f"{where}: {err['msg']}" if where else err["msg"]) from None


def _pick(items: tuple, key: str, name: str, path: str, what: str) -> list[int]:
    if name == "*":
        return list(range(len(items)))
    idx = [i for i, x in enumerate(items) if str(getattr(x, key)) == name]
    if not idx:
        known = ", ".join(str(getattr(x, key)) for x in items) or "none"
        raise _refuse(path, f"no {what} {name!r} (the scene has: {known})")
    return idx


def _number_list(value: Any, path: str) -> tuple[float, float, float]:
    parts = value.replace(",", " ").split() if isinstance(value, str) else list(value)
    try:
        xyz = tuple(float(x) for x in parts)
    except (TypeError, ValueError):
        xyz = ()
    if len(xyz) != 3:
        raise _refuse(path, f"expected three numbers x y z, got {value!r}")
    return xyz  # type: ignore[return-value]


def _device(dev: Device, rest: list[str], value: Any, path: str) -> Device:
    if rest == ["mac"]:
        name = str(value).strip() or "none"
        if ":" in name:     # an override names what is installed, never a module to import (campaign files travel)
            raise _refuse(path, f"{name!r}: a MAC given as module:Class belongs in a scene you wrote; here name a"
                                " built-in or an installed plug-in (entry point group uwsimnet.mac)")
        try:
            resolve(name)
        except ValueError as e:
            raise _refuse(path, str(e)) from None
        return dev.model_copy(update={"mac": dev.mac.model_copy(update={"name": name})})
    if len(rest) == 2 and rest[0] == "mac":
        params = {**dev.mac.params, rest[1]: str(value)}
        return dev.model_copy(update={"mac": dev.mac.model_copy(update={"params": params})})
    if len(rest) == 2 and rest[0] == "error" and rest[1] in ("expr", "unit"):
        from ..phy.expr import compile_expr  # noqa: PLC0415 - only when an error model is overridden

        if rest[1] == "expr":
            try:
                compile_expr(str(value))
            except ValueError as e:
                raise _refuse(path, str(e)) from None
        err = _revalidate(type(dev.error), dev.error, {rest[1]: str(value)}, path)
        return dev.model_copy(update={"error": err})
    if len(rest) == 1 and rest[0] in DEVICE_FIELDS:
        return _revalidate(Device, dev, {rest[0]: value}, path)
    raise _refuse(path, f"unknown device field {'.'.join(rest)!r} (one of {', '.join(DEVICE_FIELDS)},"
                        " mac, mac.<param>, error.expr, error.unit)")


def _flow(flow: Flow, field: str, value: Any, path: str) -> Flow:
    if field not in FLOW_FIELDS:
        raise _refuse(path, f"unknown flow field {field!r} (one of {', '.join(FLOW_FIELDS)})")
    if field == "rate":
        try:
            rate = float(value)
        except (TypeError, ValueError):
            raise _refuse(path, f"expected a number of frames/s, got {value!r}") from None
        if not rate > 0 or rate == float("inf"):
            raise _refuse(path, f"rate must be a finite number > 0, got {value!r}")
        field, value = "interval", 1.0 / rate
    if field == "stop" and str(value).lower() in ("", "none", "null"):
        value = None
    return _revalidate(Flow, flow, {field: value}, path)


def apply_one(scene: Scene, path: str, value: Any) -> Scene:
    parts = path.split(".")
    head = parts[0]
    if head == "simulation" and parts[1:] == ["duration"]:
        return scene.model_copy(update={"simulation": _revalidate(type(scene.simulation), scene.simulation,
                                                                  {"duration": value}, path)})
    if head == "channel" and len(parts) == 3:
        if parts[2] not in CHANNEL_FIELDS:
            raise _refuse(path, f"unknown channel field {parts[2]!r} (one of {', '.join(CHANNEL_FIELDS)})")
        chans = list(scene.channels)
        for i in _pick(scene.channels, "id", parts[1], path, "channel"):
            chans[i] = _revalidate(Channel, chans[i], {parts[2]: value}, path)
        return scene.model_copy(update={"channels": tuple(chans)})
    if head == "device" and len(parts) >= 3:
        found = False
        vehicles = []
        for v in scene.vehicles:
            devs = list(v.devices)
            for i, d in enumerate(devs):
                if parts[1] in ("*", d.dccomms_id):
                    devs[i] = _device(d, parts[2:], value, path)
                    found = True
            vehicles.append(v.model_copy(update={"devices": tuple(devs)}))
        if not found:
            known = ", ".join(d.dccomms_id for _, d in scene.devices()) or "none"
            raise _refuse(path, f"no device {parts[1]!r} (the scene has: {known})")
        return scene.model_copy(update={"vehicles": tuple(vehicles)})
    if head == "vehicle" and len(parts) == 3 and parts[2] == "position":
        vehicles = list(scene.vehicles)
        for i in _pick(scene.vehicles, "name", parts[1], path, "vehicle"):
            vehicles[i] = vehicles[i].model_copy(update={"position": _number_list(value, path)})
        return scene.model_copy(update={"vehicles": tuple(vehicles)})
    if head == "flow" and len(parts) == 3:
        flows = list(scene.flows)
        for i in _pick(scene.flows, "name", parts[1], path, "flow"):
            flows[i] = _flow(flows[i], parts[2], value, path)
        return scene.model_copy(update={"flows": tuple(flows)})
    raise _refuse(path, "unknown path (simulation.duration, channel.<id>.<field>, device.<id>.<field>,"
                        " vehicle.<name>.position, flow.<name>.<field>; docs/campaigns.md)")


def apply(scene: Scene, overrides: Mapping[str, Any] | None) -> Scene:
    """`scene` with every override applied in order; the result is checked as a whole again."""
    for path, value in (overrides or {}).items():
        scene = apply_one(scene, path, value)
    if overrides:
        try:
            scene = Scene.model_validate(scene.model_dump())
        except ValidationError as e:
            err = e.errors()[0]
            raise UserError(f"overrides {', '.join(overrides)}: {err['msg']}") from None
    return scene
