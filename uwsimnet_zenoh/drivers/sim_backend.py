"""Modem backends on an in-process simulation: a `Network` run by the realtime clock (or stepped).

    world = SimWorld(load_scene("scenes/examples/two-nodes.xml"))     # realtime, starts at t = 0
    a, b = world.backend("alpha-modem"), world.backend("bravo-modem")
    b.on_frame.append(print)
    world.start()
    a.send(2, b"hello", tag=1)
    ...
    world.close()

With `clock="virtual"` nothing runs by itself: the caller steps time with `world.run(until)` and calls
`send` from that same thread (deterministic tests).  `trace=PATH` and `metrics=True` give the world the
outputs of `uwsimnet run` (assembly/outputs.py, the one assembly: the same trace bytes, `.gz` and `.arrow`
too, and the online metrics, `world.analysis()`), closed whole by `close()`.  With the realtime clock
every call into the network goes through the clock's inbox and every callback runs on the engine thread.

Each received frame is decorated with what a device would measure: the distance between the two
vehicles when the frame left (the one the channel used, carried by the port's rx event), the channel's
propagation time for it, the relative radial velocity (from the pose table), the sender's bitrate.  The
world listens to the network's output port (trace/tracer.py) once for all its backends: the rx and status
events of their modems, and the addressee's outcome of each unicast frame a backend sent (its `rx`, or its
`drop` at the receiver), which the sender's backend reports as `delivered` or `lost`.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any

from ..assembly.outputs import Outputs
from ..engine.network import Network
from ..kernel.frame import BROADCAST, Frame
from ..kernel.realtime import RealtimeClock
from ..phy.modem import Modem
from ..scene.model import Scene
from ..trace.tracer import FRAME_EVENTS, Listener
from .backend import BackendFrame, BackendStatus, FrameCallback, Message, StatusCallback

log = logging.getLogger("uwsimnet.drivers.sim")
PENDING = 10000
"""Unicast frames per backend whose addressee's outcome is awaited (the oldest forgotten past it)."""


class _Output(Listener):
    """The world on its network's output port: each event of a modem with a backend to that backend,
    and the receivers' outcomes of frames sent through a backend to the sender's."""

    def __init__(self, world: SimWorld) -> None:
        self.backends = world.backends

    def event(self, t: Any, ev: str, ch: int, dev: str, frame: Frame, reason: str | None, fifo: int | None,
              dist: Any, implicit: Any) -> None:
        if ev == "rx" or ev == "drop":
            if frame.dev != dev and frame.kind == "data" and not implicit:
                sender = self.backends.get(frame.dev)     # (a frame's dev is its transmitter)
                if sender is not None:
                    sender._outcome(frame, "delivered" if ev == "rx" else "lost", reason, t, dist)
            if ev == "drop" or frame.kind != "data":
                return
        elif ev in FRAME_EVENTS:
            return
        be = self.backends.get(dev)
        if be is None:
            return
        if ev == "rx":
            be._on_rx(frame, t, dist)
        else:
            be._on_status(frame, ev, reason, t)


class SimWorld:
    def __init__(self, scene: Scene, *, clock: str = "realtime", seed: int | None = None, flows: bool = False,
                 speed: float = 1.0, trace: str | Path | None = None, metrics: bool = False) -> None:
        if clock not in ("realtime", "virtual"):
            raise ValueError(f"clock must be realtime or virtual, got {clock!r}")
        self.net = Network(scene, seed=seed, flows=flows)
        self.mode = clock
        self.clock: RealtimeClock | None = (RealtimeClock(self.net.sched, speed=speed, spin=0.0)
                                            if clock == "realtime" else None)
        self.backends: dict[str, SimBackend] = {}
        self.net.tracer.listen(_Output(self), statuses=True)
        self.outputs: Outputs | None = None
        if trace is not None or metrics:
            self.outputs = Outputs(self.net, self.net.meta(), trace, metrics=metrics).__enter__()
        self._outputs_closed = False
        self._started = False

    # -- lifecycle ----------------------------------------------------------------------------------
    def backend(self, dccomms_id: str) -> SimBackend:
        if dccomms_id not in self.net.modems:
            raise KeyError(f"no device {dccomms_id!r} in the scene (have {sorted(self.net.modems)})")
        be = self.backends.get(dccomms_id)
        if be is None:
            be = self.backends[dccomms_id] = SimBackend(self, self.net.modems[dccomms_id])
        return be

    def start(self) -> None:
        if self.clock is not None and not self._started:
            self.clock.start()
        self._started = True

    def close(self) -> None:
        if self.clock is not None and self._started:
            self.clock.stop()
            self.clock.join(5.0)
        self._started = False
        out = self.outputs
        if out is not None and not self._outputs_closed:
            self._outputs_closed = True
            try:
                out.finish(self.net.end)
            finally:
                out.__exit__(None, None, None)

    def analysis(self) -> Any:
        """The online metrics (`metrics=True`) of what ran so far (analysis.Analysis), or None."""
        return self.outputs.result() if self.outputs is not None else None

    def __enter__(self) -> SimWorld:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- time and threads ---------------------------------------------------------------------------
    def now(self) -> float:
        return self.clock.now() if self.clock is not None else self.net.sched.now

    def call(self, fn: Any, *args: Any) -> None:
        """Run fn(*args) where the network lives (the engine thread, or right here if virtual)."""
        if self.clock is not None:
            self.clock.call_soon(fn, *args)
        else:
            fn(*args)

    def run(self, until: float) -> None:
        """Virtual clock only: run every event up to simulation time `until`."""
        if self.clock is not None:
            raise RuntimeError("run() is for the virtual clock; the realtime clock runs by itself")
        self.net.run(until)

    # -- link figures for a received frame --------------------------------------------------------
    def link(self, sender_dev: str, receiver: Modem, t: float) -> tuple[float | None, float | None, float | None]:
        """Distance (m), propagation time (s) and radial velocity (m/s) between two modems at time t."""
        sender = self.net.modems.get(sender_dev)
        if sender is None:
            return None, None, None
        poses = self.net.poses
        i, j = sender.vehicle_index, receiver.vehicle_index

        def dist(at: float) -> float:
            p = poses.points(max(0.0, at))
            return float(math.dist(p[i], p[j]))

        d = dist(t)
        v = (dist(t + 0.5) - dist(t - 0.5)) if poses.moving else 0.0
        ch = receiver.rx_channel
        return d, ch.min_prop_s + ch.prop_s_per_m * d, v


class SimBackend:
    """One simulated modem as a `ModemBackend` (see drivers/backend.py)."""

    def __init__(self, world: SimWorld, modem: Modem) -> None:
        self.world = world
        self.modem = modem
        self.id = modem.id
        self.address = modem.address
        self.on_frame: list[FrameCallback] = []
        self.on_status: list[StatusCallback] = []
        self.counters = {"sent": 0, "received": 0}
        self._pending: dict[int, Frame] = {}     # id(frame) -> frame: unicast frames awaiting their outcome

    def now(self) -> float:
        return self.world.now()

    def send(self, dst: int, data: bytes, tag: Any = None, msg: Message | None = None) -> None:
        self.world.call(self._send, int(dst), bytes(data), tag, msg)

    def info(self) -> dict[str, Any]:
        m = self.modem
        return {"id": m.id, "kind": "sim", "address": m.address, "vehicle": m.vehicle, "bitrate": m.bitrate,
                "tx_channel": m.tx_channel.id, "rx_channel": m.rx_channel.id, "fifo_bytes": m.fifo_bytes,
                "max_frame_bytes": m.cfg.max_frame_bytes, "counters": dict(m.counters),
                "tx_framing": getattr(m.cfg, "tx_framing", None),
                "rx_framing": getattr(m.cfg, "rx_framing", None) or getattr(m.cfg, "tx_framing", None)}

    def close(self) -> None:
        if self.world.backends.get(self.id) is self:
            del self.world.backends[self.id]

    # -- engine thread ------------------------------------------------------------------------------
    def _send(self, dst: int, data: bytes, tag: Any, msg: Message | None) -> None:
        m = self.modem
        self.counters["sent"] += 1
        frame = m.send(dst, len(data), data=data, tag=tag, msg=None if msg is None else msg.to_wire())
        if dst != BROADCAST and frame.final is None:      # a frame refused at once has no outcome to wait for
            pending = self._pending
            pending[id(frame)] = frame
            if len(pending) > PENDING:
                del pending[next(iter(pending))]

    def _outcome(self, frame: Frame, event: str, reason: str | None, t: float, dist: float | None) -> None:
        """(the port) The addressee's outcome of a frame: reported once, if this backend sent it."""
        if self._pending.pop(id(frame), None) is not frame:
            return
        prop = None
        if dist is not None:
            ch = self.modem.tx_channel
            prop = ch.min_prop_s + ch.prop_s_per_m * float(dist)
        self._emit_status(BackendStatus(frame.tag, event, reason, t, frame.seq, prop))

    def _on_status(self, frame: Frame, event: str, reason: str | None, t: float) -> None:
        if frame.kind != "data":
            return
        if event == "dropped":
            self._pending.pop(id(frame), None)
        self._emit_status(BackendStatus(frame.tag, event, reason, t, frame.seq))

    def _emit_status(self, st: BackendStatus) -> None:
        for cb in list(self.on_status):
            try:
                cb(st)
            except Exception:  # noqa: BLE001 - a listener must not break the engine
                log.exception("%s: status listener raised", self.id)

    def _on_rx(self, frame: Frame, t: float, at: Any) -> None:
        modem = self.modem
        self.counters["received"] += 1
        dist, prop, vel = self.world.link(frame.dev, modem, frame.t_tx)
        if at is not None and math.isfinite(at):        # the distance the channel itself used (the port's rx)
            ch = modem.rx_channel
            dist, prop = float(at), ch.min_prop_s + ch.prop_s_per_m * float(at)
        sender = self.world.net.modems.get(frame.dev)
        data = frame.data if frame.data is not None else bytes(frame.payload)
        bf = BackendFrame(frame.src, frame.dst, data, frame.seq, frame.t_tx, t, frame.size,
                          sender.bitrate if sender is not None else None, dist, prop, vel,
                          Message.from_wire(frame.msg), (frame.msg or {}).get("aseq"))
        for cb in list(self.on_frame):
            try:
                cb(bf)
            except Exception:  # noqa: BLE001
                log.exception("%s: frame listener raised", self.id)
