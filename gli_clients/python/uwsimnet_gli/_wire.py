"""Keys and msgpack payloads of the GLI protocol (docs/gli-protocol.md), standalone: no simulator import."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import msgpack

PREFIX = "uwsimnet"
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
BROADCAST = 255
_BAD = set("/*$?#")


def check_chunk(name: str, what: str) -> str:
    if not isinstance(name, str) or not name or any(c in _BAD or c.isspace() for c in name):
        raise ValueError(f"{what} {name!r} is not one Zenoh key chunk (no '/', '*', '$', '?', '#', spaces)")
    return name


class Keys:
    def __init__(self, world: str) -> None:
        self.world = world
        self.base = f"{PREFIX}/{world}"

    def modem(self, dev: str, leaf: str) -> str:
        return f"{self.base}/modem/{dev}/{leaf}"

    def pose(self, vehicle: str) -> str:
        return f"{self.base}/pose/{vehicle}"

    def control(self, op: str) -> str:
        return f"{self.base}/control/{op}"

    @property
    def clock(self) -> str:
        return f"{self.base}/clock"


def pack(obj: Any) -> bytes:
    return msgpack.packb(obj, use_bin_type=True)


def unpack(raw: bytes) -> Any:
    return msgpack.unpackb(raw, raw=False, strict_map_key=False)


@dataclass(frozen=True)
class Frame:
    """A frame delivered by a modem: addresses, payload, sequence number of the sender, and the
    simulation times of its first bit on air (`t_tx`) and of its delivery (`t_rx`).  `modem` is the
    dccommsId that received it; `wall` the time.time() at which this process got it.  `dist` is the
    distance (m) between transmitter and receiver when the frame left, as the simulator's channel had it
    (None from a broker that does not send it)."""

    src: int
    dst: int
    data: bytes
    seq: int
    t_tx: float
    t_rx: float
    modem: str = ""
    wall: float = field(default=0.0, compare=False)
    dist: float | None = None


@dataclass(frozen=True)
class Status:
    """What became of a frame you sent: `event` queued | sent | dropped | acked | failed, `reason` for
    dropped/failed (fifo, size, nopose, malformed, invalid, toolarge, unknown, ...), `t` simulation time."""

    tag: int | None
    event: str
    reason: str | None
    t: float
    modem: str = ""
    seq: int | None = None
    """the modem's sequence number of the frame (the `seq` its receivers see in `rx`), when known"""


def _num(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)


def _int(x: Any) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def encode_tx(dst: int, data: bytes, tag: int | None = None, flow: str | None = None) -> bytes:
    if not _int(dst) or not 0 <= dst <= 65535:
        raise ValueError(f"dst must be an address 0..65535, got {dst!r}")
    m: dict[str, Any] = {"dst": dst, "data": bytes(data)}
    if tag is not None:
        m["tag"] = int(tag)
    if flow is not None:
        m["flow"] = str(flow)
    return pack(m)


def decode_rx(raw: bytes, modem: str = "", wall: float = 0.0) -> Frame | None:
    """The frame, or None if the message is not a valid rx payload."""
    try:
        m = unpack(raw)
    except Exception:  # noqa: BLE001
        return None
    if (not isinstance(m, dict) or not all(_int(m.get(k)) for k in ("src", "dst", "seq"))
            or not isinstance(m.get("data"), bytes) or not _num(m.get("t_tx")) or not _num(m.get("t_rx"))):
        return None
    dist = m.get("dist")
    if dist is not None and not (_num(dist) and dist >= 0):
        return None
    return Frame(m["src"], m["dst"], m["data"], m["seq"], float(m["t_tx"]), float(m["t_rx"]), modem, wall,
                 None if dist is None else float(dist))


def decode_status(raw: bytes, modem: str = "") -> Status | None:
    try:
        m = unpack(raw)
    except Exception:  # noqa: BLE001
        return None
    if not isinstance(m, dict) or not isinstance(m.get("event"), str) or not _num(m.get("t")):
        return None
    tag = m.get("tag")
    reason = m.get("reason")
    seq = m.get("seq")
    return Status(tag if _int(tag) else None, m["event"], reason if isinstance(reason, str) else None,
                  float(m["t"]), modem, seq if _int(seq) else None)


def encode_pose(p, *, v=None, q=None, t: float | None = None) -> bytes:
    m: dict[str, Any] = {}
    if t is not None:
        m["t"] = float(t)
    m["p"] = [float(x) for x in p]
    if len(m["p"]) != 3:
        raise ValueError("p must have 3 coordinates")
    if v is not None:
        m["v"] = [float(x) for x in v]
        if len(m["v"]) != 3:
            raise ValueError("v must have 3 components")
    if q is not None:
        m["q"] = [float(x) for x in q]
        if len(m["q"]) != 4:
            raise ValueError("q must have 4 components (x, y, z, w)")
    return pack(m)
