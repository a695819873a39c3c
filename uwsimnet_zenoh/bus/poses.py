"""The broker's poses and periodic publications (a part of bus/broker.Broker, which mixes it in).

In: pose samples wait in a Zenoh ring channel (no Python callback: a swarm's burst of samples would take the
interpreter from the engine thread for milliseconds); the engine takes them when it reads the geometry or
idles, keeps the newest per vehicle stamped with its arrival, and applies it then.  Out: the scene-driven
vehicles' poses at their `poseRate`, and the `clock` samples, put on the misc outbox at idle.
"""

from __future__ import annotations

import logging
from collections import Counter
from typing import TYPE_CHECKING, Any

from uwsimnet_gli import wire
from uwsimnet_gli.wire import Keys, parse

from .outbox import Latest, Outbox, Throttle

if TYPE_CHECKING:
    import zenoh

    from ..engine.network import Network
    from ..kernel.realtime import RealtimeClock

log = logging.getLogger("uwsimnet.bus.broker")
KEY_CACHE = 4096
"""Key expressions whose parse is remembered (tx keys -> modem id, pose keys -> vehicle and verdict)."""
POSE_RING = 16384
"""Pose samples Zenoh holds for the engine between two takes (a ring: when full, the oldest goes)."""


class Poses:
    """Pose ingress and the periodic publications of a `Broker` (the attributes are the broker's)."""

    session: zenoh.Session
    net: Network
    clock: RealtimeClock
    keys: Keys
    channels: frozenset[int] | None
    clock_rate_hz: float
    counters: Counter[str]
    warn: Throttle
    _misc: Outbox
    _poses_in: Latest
    _pose_keys: dict[str, tuple[str | None, str | None]]
    _pose_sub: Any
    _pose_taken: float
    _pose_pubs: dict[str, Any]
    _clock_pub: Any
    _waiting_pose: set[str]
    _due_poses: list[list[str]]
    _clock_due: bool

    def _take_poses(self) -> None:
        """(engine) Move the pose samples Zenoh holds into `_poses_in`, each stamped with its arrival."""
        sub = self._pose_sub
        if sub is None:
            return
        clock = self.clock
        now = clock.now()
        epoch = clock.wall_epoch()
        n = 0
        while True:
            smp = sub.try_recv()
            if smp is None:
                break
            n += 1
            self._pose_sample(smp, now, epoch)
        self._pose_taken = now              # what comes next arrived after now
        if n >= POSE_RING:
            self.counters["pose_ring_full"] += 1
            self.warn("pose_ring_full", "%d pose samples waited for the engine: older ones may have been"
                      " lost", n)

    def _pose_sample(self, sample: Any, now: float, epoch: float) -> None:
        """One pose sample, kept as the newest of its key, stamped with its arrival in simulation time: the
        Zenoh timestamp a router gave it on arrival (bounded by the previous take and `now`: another
        machine's clock may be off), else `now`.  `epoch`: the clock's wall_epoch()."""
        raw = sample.payload.to_bytes()       # (a pose is a few dozen bytes; Zenoh's ring bounds the rest)
        if len(raw) > wire.MAX_SMALL_MESSAGE:
            raw = None
        ts = sample.timestamp
        stamp = now
        if ts is not None:
            at = (ts.get_time_as_ntp64().as_secs_f64() - epoch) * self.clock.speed
            stamp = min(now, max(self._pose_taken, at))
        self._poses_in.offer(str(sample.key_expr), stamp, raw)

    def _pull_poses_now(self) -> None:
        """(engine, idle hook) Apply the pose samples that have arrived by now."""
        self._pull_poses(self.clock.now())

    def _pull_poses(self, t: float) -> None:
        """(engine; PoseTable.pull) Apply the newest pose sample of each vehicle that arrived by
        simulation time t, as of its arrival time.  A sample superseded by a newer one of the same vehicle
        before the geometry was needed is counted (`poses_superseded`), not decoded: the newer one
        replaces it entirely (position, velocity, time)."""
        self._take_poses()
        got = self._poses_in.take(t)
        if got:
            for key, n, stamp, raw in got:
                self._apply_pose(key, n, stamp, raw)
            if self._poses_in.refused:
                self.counters["pose_refused"] = self._poses_in.refused

    def _pose_verdict(self, key: str) -> tuple[str | None, str | None]:
        """(vehicle, None) if samples on `key` position a vehicle, else (name, the counter of refusals)."""
        got = self._pose_keys.get(key)
        if got is not None:
            return got
        k = parse(key)
        if k is None or k.kind != "pose" or k.world != self.keys.world:
            got = (None, "pose_bad_key")
        else:
            v = self.net.vehicles.get(k.name)
            if v is None:
                got = (k.name, "pose_unknown")
            elif v.pose_source != "zenoh":       # another broker of this world publishes it too: expected
                got = (k.name, "pose_peer" if self.channels is not None else "pose_ignored")
            else:
                got = (k.name, None)
        if len(self._pose_keys) < KEY_CACHE:
            self._pose_keys[key] = got
        return got

    def _apply_pose(self, key: str, n: int, stamp: float, raw: bytes | None) -> None:
        name, refused = self._pose_verdict(key)
        if refused is not None:
            self.counters[refused] += n
            if refused == "pose_unknown":
                self.warn("pose_unknown", "pose for unknown vehicle %r ignored", name)
            elif refused == "pose_ignored":
                self.warn(f"pose_ignored:{name}", "pose for %s ignored: the scene drives it (poseSource scene)",
                          name)
            return                               # pose_peer: counted, no warning (two would flood)
        if n > 1:
            self.counters["poses_superseded"] += n - 1
        try:
            if raw is None:
                raise wire.CodecError("toolarge", f"pose sample over {wire.MAX_SMALL_MESSAGE} bytes")
            pose = wire.decode_pose(raw)
        except wire.CodecError as e:
            self.counters["pose_" + e.reason] += 1
            self.warn(f"pose_bad:{name}", "pose for %s ignored (%s): %s", name, e.reason, e.detail)
            return
        self.counters["poses"] += 1
        self.net.move(name, pose.p, pose.v, t=stamp)
        if name in self._waiting_pose:
            self._waiting_pose.discard(name)
            log.info("vehicle %s: first pose %s", name, list(pose.p))

    def _schedule_poses(self) -> None:
        net = self.net
        served_vehicles = {m.vehicle for m in net.modems.values()}
        by_rate: dict[float, list[str]] = {}
        for v in net.vehicles.values():
            if v.pose_source != "scene":
                continue
            if self.channels is not None and v.name not in served_vehicles:
                continue
            by_rate.setdefault(v.pose_rate_hz, []).append(v.name)
            self._pose_pubs[v.name] = self.session.declare_publisher(self.keys.pose(v.name))
        t0 = net.sched.now
        for rate, names in by_rate.items():
            net.sched.at(t0, self._pose_tick, names, 1.0 / rate, t0, 0)

    def _pose_tick(self, names: list[str], period: float, t0: float, n: int) -> None:
        """Marks the poses of `names` due; the idle hook publishes them (inline if the last batch is
        still waiting: an engine that is never idle still publishes)."""
        if self._due_poses:
            self._publish_due()
        self._due_poses.append(names)
        now = self.net.sched.now
        nxt = t0 + (n + 1) * period
        while nxt <= now:       # fell behind (paused, slow machine): skip, do not burst
            n += 1
            nxt = t0 + (n + 1) * period
        self.net.sched.at(nxt, self._pose_tick, names, period, t0, n + 1)

    def _publish_due(self) -> None:
        """Idle hook: the periodic publications that are due (poses, clock)."""
        if self._due_poses:
            net = self.net
            pos = net.poses.points(net.sched.now)      # (not `positions`: no array, no numpy import)
            idx = net.poses.index
            now = net.sched.now
            batches, self._due_poses = self._due_poses, []
            for names in batches:
                for name in names:
                    pub = self._pose_pubs.get(name)
                    if pub is not None:
                        self._misc.put(pub.put, wire.encode_pose(pos[idx[name]], t=now), "pose")
        if self._clock_due:
            self._clock_due = False
            self.publish_clock()

    def clock_sample(self) -> dict[str, Any]:
        c = self.clock
        return {"t": self.net.sched.now if c.paused else c.now(), "epoch": c.wall_epoch(), "speed": c.speed,
                "paused": c.paused}

    def publish_clock(self) -> None:
        if self._clock_pub is not None:
            self._misc.put(self._clock_pub.put, wire.pack(self.clock_sample()), "clock")

    def _clock_tick(self) -> None:
        if self._clock_due:
            self.publish_clock()
        self._clock_due = True
        self.net.sched.after(1.0 / self.clock_rate_hz, self._clock_tick)
