"""Kinematic vehicles on Zenoh: `mobility.kinematic.KinematicVehicle`s stepped on the world's simulation
time (its `clock` samples: they stand still while the world is paused and follow `uwsimnet run
--speed`), their poses published `rate_hz` times per wall second on `uwsimnet/<world>/pose/<name>`
(with velocity, so the broker extrapolates between samples, and `t`, the simulation time), commands
read from `uwsimnet/<world>/vehicle/<name>/cmd` (msgpack maps, see mobility/kinematic.py).

    uwsimnet vehicles --vehicle leader=0,0,-5 --vehicle f1=-1.5,0,-5 --max-speed 0.5 --world W

The vehicles of the scene that these drive must have `<poseSource>zenoh</poseSource>`.  A bad command is
logged and counted, never fatal.  Threading: the Zenoh callback only enqueues; one thread steps and
publishes.
"""

from __future__ import annotations

import contextlib
import logging
import queue
import threading
import time
from collections import Counter
from collections.abc import Iterable
from typing import Any

import zenoh
from uwsimnet_gli import wire
from uwsimnet_gli.wire import Keys, check_chunk

from ..mobility.kinematic import CommandError, KinematicVehicle
from .clock import WorldClock

log = logging.getLogger("uwsimnet.bus.kinematic")


class KinematicRunner:
    def __init__(self, session: zenoh.Session, world: str, vehicles: Iterable[KinematicVehicle], *,
                 rate_hz: float = 10.0) -> None:
        self.session = session
        self.keys = Keys(world)
        self.world = world
        self.vehicles = {check_chunk(v.name, "vehicle name"): v for v in vehicles}
        self.period = 1.0 / rate_hz
        self.counters: Counter[str] = Counter()
        self._inbox: queue.SimpleQueue[tuple[str, bytes]] = queue.SimpleQueue()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.clock = WorldClock(session, self.keys)
        self._pubs = {n: session.declare_publisher(self.keys.pose(n)) for n in self.vehicles}
        # one subscriber per vehicle (not vehicle/*/cmd): an identity limited to its vehicles may run it
        self._subs = [session.declare_subscriber(self.keys.vehicle_cmd(n), self._on_cmd) for n in self.vehicles]
        self._lock = threading.Lock()

    def start(self) -> KinematicRunner:
        self._publish(self.clock.now())
        self._thread = threading.Thread(target=self._loop, name="uwsimnet-kinematic", daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5)
        self.clock.close()
        for e in (*self._subs, *self._pubs.values()):
            with contextlib.suppress(Exception):
                e.undeclare()

    def __enter__(self) -> KinematicRunner:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def state(self) -> dict[str, dict[str, Any]]:
        with self._lock:
            return {n: v.state() for n, v in self.vehicles.items()}

    def _on_cmd(self, sample: zenoh.Sample) -> None:
        self._inbox.put((str(sample.key_expr), sample.payload.to_bytes()))

    def _apply(self, key: str, raw: bytes) -> None:
        parts = key.split("/")
        name = parts[3] if len(parts) == 5 else ""
        v = self.vehicles.get(name)
        if v is None:
            self.counters["cmd_unknown"] += 1
            return
        try:
            v.command(wire.unpack(raw, wire.MAX_SMALL_MESSAGE))
            self.counters["cmd"] += 1
        except (wire.CodecError, CommandError) as e:
            self.counters["cmd_bad"] += 1
            log.warning("%s: command ignored: %s", name, e)

    def _loop(self) -> None:
        last = self.clock.now()                          # simulation time of the last step (None: no clock yet)
        nxt = time.monotonic() + self.period
        while not self._stop.wait(max(0.0, nxt - time.monotonic())):
            now = self.clock.now()
            with self._lock:
                while True:
                    try:
                        key, raw = self._inbox.get_nowait()
                    except queue.Empty:
                        break
                    self._apply(key, raw)
                if now is not None and last is not None and now > last:
                    for v in self.vehicles.values():
                        v.step(now - last)
            if now is not None:
                last = now
            self._publish(now)
            nxt += self.period
            if nxt < time.monotonic():
                nxt = time.monotonic() + self.period

    def observed(self, v: KinematicVehicle) -> tuple[float, float, float]:
        """The position published for `v`: its true one (a subclass may model a tracker's error)."""
        return v.p

    def _publish(self, now: float | None) -> None:
        with self._lock:
            out = [(n, self.observed(v), v.v) for n, v in self.vehicles.items()]
        for n, p, vel in out:
            with contextlib.suppress(Exception):
                self._pubs[n].put(wire.encode_pose(p, v=vel, t=now))
                self.counters["poses"] += 1
