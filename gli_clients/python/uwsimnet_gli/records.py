"""What an application gets back from a modem: received frames and status events, read leniently.

The wire (uwsimnet_gli.wire) validates and raises; an application's receive loop would rather skip a
sample it cannot read, so these readers return None instead.  `modem` and `wall` are the client's own
additions: which modem delivered the frame and when this process got it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from . import wire


@dataclass(frozen=True)
class Frame:
    """A frame delivered by a modem: addresses, payload, sequence number of the sender, and the
    simulation times of its first bit on air (`t_tx`) and of its delivery (`t_rx`).  `modem` is the
    dccommsId that received it; `wall` the time.time() at which this process got it.  `dist` is the
    distance (m) between transmitter and receiver when the frame left, as the simulator's channel had it
    (None from a broker that does not send it).  `msg` is the kind of message the sender chose (`kind`,
    `flag`, `ts`, `pid`; None if it did not say)."""

    src: int
    dst: int
    data: bytes
    seq: int
    t_tx: float
    t_rx: float
    modem: str = ""
    wall: float = field(default=0.0, compare=False)
    dist: float | None = None
    msg: dict | None = field(default=None, compare=False)


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


def read_rx(raw: bytes, modem: str = "", wall: float = 0.0) -> Frame | None:
    """The frame, or None if the message is not a valid rx payload."""
    try:
        f = wire.decode_rx(raw)
    except wire.CodecError:
        return None
    return Frame(f.src, f.dst, f.data, f.seq, f.t_tx, f.t_rx, modem, wall, f.dist, f.msg)


def read_status(raw: bytes, modem: str = "") -> Status | None:
    """The status event, or None if the message is not a valid status payload."""
    try:
        s = wire.decode_status(raw)
    except wire.CodecError:
        return None
    return Status(s.tag, s.event, s.reason, s.t, modem, s.seq)


def read_map(raw: bytes) -> Any:
    """A msgpack reply (info, control answers), or None if it is not one."""
    try:
        return wire.unpack(raw, wire.MAX_REPLY_MESSAGE)
    except wire.CodecError:
        return None
