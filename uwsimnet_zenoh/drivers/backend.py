"""The modem backend: what an emulator or a bridge sits on.

An emulator makes a simulated modem look like a real device (EvoLogics AT over TCP, a framed serial
pty); a bridge lets an application that cannot link Zenoh use a modem (socket, POSIX queues).  Both
need the same thing underneath: a modem they can `send(dst, data, tag)` to, that reports what became
of each frame and hands up what it received.  That is `ModemBackend`.  Two implementations:

* `sim_backend.SimBackend`: a modem of an in-process `Network` (this part; used by the tests and by
  `uwsimnet emulate` when the emulator runs the scene itself);
* `zenoh_backend.ZenohBackend`: a modem served by a broker, through the client library's
  `uwsimnet_gli.Modem` (delivery outcomes from the `trace/<ch>` records of the addressee's events).

Callbacks run on the backend's thread (the engine thread, a Zenoh thread): they must not block.

`BackendStatus.event` is the simulator's vocabulary (queued, sent, dropped, acked, failed) plus two
outcomes seen at the addressee, which a device would learn from its link-layer acknowledgement:
`delivered` (the frame reached the addressee's application) and `lost` (it did not: reason prop, col,
mult, range, nopose).  Emulators turn those into DELIVEREDIM / FAILEDIM after the time an
acknowledgement would take to come back.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

MESSAGE_KINDS = ("burst", "im", "ims", "pbm")
IM_FLAGS = ("ack", "noack", "force")


@dataclass(frozen=True)
class Message:
    """The kind of message the sender's modem sent, as the receiver's modem reports it: burst data, an
    instant message with its flag, a synchronous instant message with its requested time, a piggy-back
    message; `pid` the protocol id of the sender's interface.  It crosses Zenoh in the wire's tx and rx
    messages (fields `kind`, `flag`, `ts`, `pid`: docs/gli-protocol.md)."""

    kind: str = "burst"            # burst | im | ims | pbm
    flag: str | None = None        # im: ack | noack | force
    ts: int | None = None          # ims: requested transmission time, µs of the sender's clock (None: at once)
    pid: int | None = None         # 0..7

    def __post_init__(self) -> None:
        if self.kind not in MESSAGE_KINDS:
            raise ValueError(f"kind must be one of {MESSAGE_KINDS}, got {self.kind!r}")
        if self.flag is not None and (self.kind != "im" or self.flag not in IM_FLAGS):
            raise ValueError(f"flag {self.flag!r} is for kind im only, one of {IM_FLAGS}")
        if self.ts is not None and (self.kind != "ims" or not 0 <= self.ts < 1 << 32):
            raise ValueError(f"ts {self.ts!r} is for kind ims only, 0 .. 2^32-1 µs")
        if self.pid is not None and not 0 <= self.pid <= 7:
            raise ValueError(f"pid must be 0..7, got {self.pid!r}")

    def to_wire(self) -> dict[str, Any]:
        """The wire's tx/rx fields (uwsimnet_gli.wire.check_msg)."""
        return {k: v for k, v in (("kind", self.kind), ("flag", self.flag), ("ts", self.ts), ("pid", self.pid))
                if v is not None}

    @classmethod
    def from_wire(cls, m: dict[str, Any] | None) -> Message | None:
        """From checked wire fields (None: the sender did not say)."""
        if not m or m.get("kind") is None:
            return None
        return cls(m["kind"], m.get("flag"), m.get("ts"), m.get("pid"))


@dataclass(frozen=True)
class BackendFrame:
    """A frame the modem received.  Times are simulation seconds.  `size` is bytes on air, `distance`
    (m), `prop_time` (s) and `velocity` (m/s, positive = moving apart) the link at transmission time,
    when the backend knows them.  `msg` is the kind of message the sender chose (None: the sender did not
    say, e.g. an application on the bus)."""

    src: int
    dst: int
    data: bytes
    seq: int = -1
    t_tx: float | None = None
    t_rx: float | None = None
    size: int | None = None
    bitrate: float | None = None
    distance: float | None = None
    prop_time: float | None = None
    velocity: float | None = None
    msg: Message | None = None
    aseq: int | None = None
    """The sending application's own sequence number (the wire's `aseq`), None if it set none."""


@dataclass(frozen=True)
class BackendStatus:
    tag: Any
    event: str                    # queued | sent | dropped | acked | failed | delivered | lost
    reason: str | None
    t: float
    seq: int = -1
    prop_time: float | None = None
    """delivered/lost: the one-way propagation time to the addressee, s (None if unknown)."""


FrameCallback = Callable[[BackendFrame], None]
StatusCallback = Callable[[BackendStatus], None]


class ModemBackend(Protocol):
    id: str
    address: int
    on_frame: list[FrameCallback]
    on_status: list[StatusCallback]

    def send(self, dst: int, data: bytes, tag: Any = None, msg: Message | None = None) -> None:
        """Hand a frame to the modem (thread-safe, never blocks).  Its fate comes through on_status."""

    def now(self) -> float:
        """Current simulation time, s."""

    def info(self) -> dict[str, Any]: ...

    def close(self) -> None: ...


def detach(backend: ModemBackend, frame_cb: FrameCallback | None = None,
           status_cb: StatusCallback | None = None) -> None:
    """Take a front-end's callbacks off its backend (a no-op for those already gone)."""
    for lst, fn in ((backend.on_frame, frame_cb), (backend.on_status, status_cb)):
        if fn is not None and fn in lst:
            lst.remove(fn)


# -- what a device would measure ----------------------------------------------------------------------
@dataclass(frozen=True)
class LinkMetrics:
    """What a modem reports about a reception, derived from a simulated frame (emulators)."""

    rssi: int                 # dB (EvoLogics reports negative values, about -20 close to -110 far)
    integrity: int            # 0..255, > 100 decodes well
    prop_time: float          # s
    duration: float           # s, the frame's time on air
    velocity: float           # m/s
    bitrate: int              # bps
    distance: float           # m


def link_metrics(f: BackendFrame, bitrate: float | None = None, sound_speed: float = 1500.0) -> LinkMetrics:
    """Plausible device figures for a received frame.

    Propagation time and distance come from the backend when it knows them, else from t_rx - t_tx
    minus the time on air; RSSI follows spherical spreading plus ~4 dB/km absorption below a source
    level giving -30 dB at 1 m; integrity falls slowly with distance.  These are a device's *kind* of
    numbers, not a model of any receiver; applications that only threshold on them behave sensibly."""
    br = f.bitrate or bitrate or 1000.0
    size = f.size if f.size is not None else len(f.data)
    duration = size * 8.0 / br
    prop = f.prop_time
    if prop is None and f.distance is not None:
        prop = f.distance / sound_speed
    if prop is None and f.t_tx is not None and f.t_rx is not None:
        prop = max(0.0, f.t_rx - f.t_tx - duration)
    prop = prop or 0.0
    dist = f.distance if f.distance is not None else prop * sound_speed
    rssi = -30.0 - 20.0 * math.log10(max(dist, 1.0)) - 0.004 * dist
    integrity = 240.0 - dist / 25.0
    return LinkMetrics(rssi=int(round(max(-120.0, min(-20.0, rssi)))),
                       integrity=int(round(max(101.0, min(255.0, integrity)))),
                       prop_time=prop, duration=duration, velocity=f.velocity or 0.0, bitrate=int(round(br)),
                       distance=dist)
