"""The Network wires a scene into running parts: pose table, channels, modems (with MACs), flows.

It is still sans-IO: the caller chooses the clock (run() for virtual time; engine.realtime for wall
time) and attaches trace sinks and application callbacks.  Randomness comes from independent streams
derived from (seed, purpose, name), so a run is reproducible byte for byte from (scene, seed) and adding
a flow or a device does not shift the random numbers every other part draws.
"""

from __future__ import annotations

import hashlib
from typing import Any, cast

from ..kernel.frame import Frame
from ..kernel.scheduler import Scheduler
from ..mobility.trajectory import PoseTable, Trajectory
from ..phy.channel import Channel
from ..phy.modem import Modem
from ..scene.model import Device, Scene, Vehicle
from ..trace.tracer import Tracer
from ..traffic.flow import FlowSource
from .build import build_modem, channel_options


class Network:
    # `float | int`: a duration given as an int stays one (the trace's meta says 60, not 60.0); compiled code
    # would turn a `float` annotation into a C double
    def __init__(self, scene: Scene, *, seed: int | None = None, duration: float | int | None = None,
                 flows: bool = True) -> None:
        self.scene = scene
        self.seed = scene.simulation.seed if seed is None else seed
        self.duration: float | int = duration if duration is not None else scene.end_time()
        self.sched = Scheduler()
        self.tracer = Tracer()
        self.poses = PoseTable([v.name for v in scene.vehicles])
        self.vehicles: dict[str, Vehicle] = {}
        for v in scene.vehicles:
            self._place(v)
        self.channels: dict[int, Channel] = {
            c.id: Channel(c.id, c.prop_s_per_m, c.min_prop_s, self.sched, self.poses, self.tracer,
                          **channel_options(c))
            for c in scene.channels}
        self.end: dict[str, Any] | None = None
        """The trace's `end` record once the run ended early or in realtime (see `end_record`)."""
        self.modems: dict[str, Modem] = {}
        self._gone: dict[str, Modem] = {}       # removed modems: their frames may still be on air
        for v, d in scene.devices():
            self.add_device(v.name, d)
        self.flows: list[FlowSource] = []
        if flows:
            for f in scene.flows:
                self.flows.append(FlowSource(f, self.modems[f.src], self.sched, self.seeds("flow", f.name),
                                             self.duration))

    def seeds(self, purpose: str, name: str) -> int:
        """A 64-bit seed for one random stream, stable across processes and Python versions."""
        h = hashlib.blake2b(f"{self.seed}/{purpose}/{name}".encode(), digest_size=8)
        return int.from_bytes(h.digest(), "big")

    @property
    def now(self) -> float:
        return self.sched.now

    # -- scene changes at runtime (also used by the control API) ------------------------------
    def _place(self, v: Vehicle) -> None:
        self.vehicles[v.name] = v
        if v.pose_source == "zenoh":
            self.poses.set_external(v.name)
        elif v.trajectory:
            self.poses.set_trajectory(v.name, Trajectory([(w.t, w.x, w.y, w.z) for w in v.trajectory]))
        else:
            self.poses.set_static(v.name, v.position)

    def add_device(self, vehicle: str, cfg: Device) -> Modem:
        if cfg.dccomms_id in self.modems:
            raise ValueError(f"device {cfg.dccomms_id!r} exists already")
        if vehicle not in self.poses.index:
            raise ValueError(f"no vehicle {vehicle!r}")
        for ch in (cfg.tx_channel, cfg.rx_channel):
            if ch not in self.channels:
                raise ValueError(f"device {cfg.dccomms_id!r}: no channel {ch}")
        tx_spec, rx_spec = (next(c for c in self.scene.channels if c.id == ch)
                            for ch in (cfg.tx_channel, cfg.rx_channel))
        m = build_modem(cfg, vehicle, self.poses.index[vehicle], self.sched, self.tracer,
                        self.channels[cfg.tx_channel], self.channels[cfg.rx_channel], self.seeds, tx_spec, rx_spec,
                        self.scene.environment, _known_positions(self.scene, vehicle))
        self.modems[cfg.dccomms_id] = m
        return m

    def remove_device(self, dccomms_id: str) -> None:
        m = self.modems.pop(dccomms_id, None)
        if m is None:
            raise ValueError(f"no device {dccomms_id!r}")
        self._gone[dccomms_id] = m
        m.close()
        for f in self.flows:                 # its scene flows end with it
            if f.modem is m:
                f.stop = min(f.stop, self.now)

    def move(self, vehicle: str, p: tuple[float, float, float], v: tuple[float, float, float] | None = None,
             t: float | None = None) -> None:
        """A pose from outside (HIL tracker, control command): replaces any scripted trajectory."""
        self.poses.update(vehicle, self.now if t is None else t, p, v)

    # -- running ------------------------------------------------------------------------------
    def stop(self, reason: str = "stopped") -> int:
        """End the run now (a signal, an error): every data frame that has no outcome at its transmitter
        yet ends with a drop `reason` there, so the trace accounts for every frame (docs/trace-format.md).

        Frames the transmitter still holds (its FIFO, its MAC's current frame) are dropped through the
        modem (trace record and `dropped` status to the application); frames already handed on (on air,
        in reception, waiting for delivery: found in the pending events) get the trace record only,
        since their sender has had its final status.  Nothing runs afterwards.  Returns the count."""
        held: dict[int, tuple[Modem | None, Frame]] = {}
        for m in self.modems.values():
            for f in m.fifo:
                held[id(f)] = (m, f)
            cur = getattr(m.mac, "cur", None)
            if isinstance(cur, Frame):
                held[id(cur)] = (m, cur)
        for ev in self.sched.pending():
            for a in ev.args:
                if not isinstance(a, Frame):
                    a = getattr(a, "frame", None)       # the channel's Transmission (a reception pending)
                if isinstance(a, Frame):
                    held.setdefault(id(a), (None, a))
        now = self.sched.now
        n = 0
        for holder, f in sorted(held.values(), key=lambda mf: (mf[1].dev, mf[1].seq)):
            if f.kind != "data" or f.final is not None:
                continue
            n += 1
            if holder is not None:
                holder.drop(f, reason)
                continue
            sender = self.modems.get(f.dev) or self._gone.get(f.dev)
            if sender is not None:
                f.final = reason
                self.tracer.emit(now, "drop", sender.tx_channel.id, sender.id, f, reason,
                                 fifo=sender.fifo_bytes)
        for m in self.modems.values():
            m.fifo.clear()
            m.fifo_bytes = 0
        self.sched.clear()
        return n

    def end_record(self, reason: str, t: float | None = None, **extra: Any) -> dict[str, Any]:
        """The trace's last line when a run ends before its planned duration (or in realtime): the
        actual end time, which `uwsimnet report` uses instead of the meta duration.  `t`: when the run
        ended (a realtime run: the clock's time at the stop, not its last event's), never before now."""
        end = self.sched.now if t is None else max(t, self.sched.now)
        self.end = {"ev": "end", "t": round(end, 9), "reason": reason, **extra}
        return self.end

    def run(self, until: float | None = None) -> None:
        """Virtual time: jump from event to event up to `until` (default: the scene's duration)."""
        self.sched.run(self.duration if until is None else until)

    def meta(self) -> dict[str, Any]:
        """The trace's first line: enough for `uwsimnet report` to compute rates without the scene."""
        s = self.scene
        return {
            "ev": "meta", "t": 0.0, "version": 1, "scene": s.name, "seed": self.seed,
            "duration": self.duration,
            "flows": {f.name: {"src": f.src, "dst": f.dst, "size": f.size, "interval": f.interval,
                               "arrival": f.arrival, "start": f.start, "stop": f.stop} for f in s.flows},
            "devices": {m.id: {"address": m.address, "vehicle": m.vehicle, "tx_channel": m.tx_channel.id,
                               "rx_channel": m.rx_channel.id, "bitrate": m.bitrate,
                               "header_bytes": m.header_bytes, "mac": cast(Device, m.cfg).mac.name,
                               # only when set: traces of scenes without a framing keep their bytes
                               **({"framing": m.framing.name} if m.framing is not None else {})}
                        for m in self.modems.values()},
        }


def _known_positions(scene: Any, vehicle: str) -> list[tuple[float, float, float]]:
    """Where the scene puts a vehicle: its trajectory's waypoints, else its position (none for one not in it)."""
    v = next((v for v in scene.vehicles if v.name == vehicle), None)
    if v is None:
        return []
    return [(w.x, w.y, w.z) for w in v.trajectory] or [tuple(v.position)]
