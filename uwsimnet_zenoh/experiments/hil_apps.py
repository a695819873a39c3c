"""The HIL formation's applications (paper Sec. 3.3), written once and run two ways.

The logic is sans-IO: an app is told the time and its vehicle's pose when its timer fires, and the
frames its modem receives; it answers with frames to send (`Send`) and commands for its own vehicle
(`Goto`).  `experiments/hil_formation.py` drives the apps on the virtual clock in one process; the
`main()` below runs one of them as its own process on a real-time world, with the modem from
uwsimnet_gli (the same client any robot application uses) and the vehicle behind
`vehicle/<name>/cmd`:

    python -m uwsimnet_zenoh.experiments.hil_apps app leader --world hil-formation-aloha
    python -m uwsimnet_zenoh.experiments.hil_apps robot --world hil-formation-aloha

`robot` stands in for the real BlueROV of the paper and its Aruco tracker: a vehicle that obeys
`vehicle/leader/cmd` and whose *tracked* pose (with measurement noise) reaches the simulator from this
outside process on `pose/leader`, the way a real robot's localisation would.

* operator: every 4 s sends the current waypoint to the leader;
* leader: on a new waypoint, drives to it; every 2 s broadcasts its position;
* follower: on a leader position, drives to it plus its formation offset; every 5 s reports its own
  position to the operator.

Timers fire on a fixed grid of simulation time (phase + k * period), so a real-time run and the
virtual-time model send at the same instants.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import random
import signal
import struct
import sys
import threading
from dataclasses import dataclass, field
from typing import Any

from uwsimnet_gli import wire

from ..bus.kinematic import KinematicRunner
from ..kernel.frame import BROADCAST
from ..mobility.kinematic import KinematicVehicle
from .hil_spec import (
    DEPTH,
    LEADER_PERIOD,
    MAX_ACCEL,
    MAX_SPEED,
    OPERATOR,
    OPERATOR_PERIOD,
    PAYLOAD,
    TELEMETRY_PERIOD,
    VEHICLES,
    Vec,
    waypoint_at,
)

_VEC = struct.Struct("<3f")


@dataclass(frozen=True)
class Send:
    dst: int
    data: bytes


@dataclass(frozen=True)
class Goto:
    waypoint: Vec


def _frame(kind: bytes, p: Vec) -> bytes:
    b = kind + _VEC.pack(*p)
    return b + bytes(PAYLOAD - len(b))


def _parse(data: bytes, kind: bytes) -> Vec | None:
    if len(data) < 1 + _VEC.size or data[:1] != kind:
        return None
    x, y, z = _VEC.unpack_from(data, 1)
    return (x, y, z)


@dataclass
class App:
    """One robot's application: a periodic timer and a frame handler, no I/O."""

    name: str
    address: int
    period: float
    phase: float
    received: int = 0
    sent: int = 0
    goal: Vec | None = field(default=None)

    def on_timer(self, now: float, pose: Vec | None) -> list[Send]:
        return []

    def on_frame(self, src: int, data: bytes) -> list[Goto]:
        return []


class Operator(App):
    def on_timer(self, now: float, pose: Vec | None) -> list[Send]:
        self.sent += 1
        return [Send(VEHICLES["leader"][0], _frame(b"W", waypoint_at(now)))]

    def on_frame(self, src: int, data: bytes) -> list[Goto]:
        if _parse(data, b"T") is not None:
            self.received += 1
        return []


class Leader(App):
    def on_timer(self, now: float, pose: Vec | None) -> list[Send]:
        if pose is None:
            return []
        self.sent += 1
        return [Send(BROADCAST, _frame(b"P", pose))]

    def on_frame(self, src: int, data: bytes) -> list[Goto]:
        wp = _parse(data, b"W")
        if wp is None:
            return []
        self.received += 1
        if wp == self.goal:
            return []
        self.goal = wp
        return [Goto(wp)]


@dataclass
class Follower(App):
    offset: Vec = (0.0, 0.0, 0.0)

    def on_timer(self, now: float, pose: Vec | None) -> list[Send]:
        if pose is None:
            return []
        self.sent += 1
        return [Send(OPERATOR[1], _frame(b"T", pose))]

    def on_frame(self, src: int, data: bytes) -> list[Goto]:
        lp = _parse(data, b"P")
        if lp is None:
            return []
        self.received += 1
        o = self.offset
        self.goal = (lp[0] + o[0], lp[1] + o[1], lp[2] + o[2])
        return [Goto(self.goal)]


def make_app(name: str) -> App:
    """The application of vehicle `name` (or of the operator), with the experiment's periods."""
    if name == OPERATOR[0]:
        return Operator(name, OPERATOR[1], OPERATOR_PERIOD, 0.0)
    if name == "leader":
        return Leader(name, VEHICLES[name][0], LEADER_PERIOD, 0.05)
    if name not in VEHICLES:
        raise ValueError(f"no application for {name!r} (one of {', '.join([OPERATOR[0], *VEHICLES])})")
    i = [n for n in VEHICLES if n != "leader"].index(name)
    return Follower(name, VEHICLES[name][0], TELEMETRY_PERIOD, 0.3 + 0.25 * i, offset=VEHICLES[name][1])


def first_due(app: App, now: float) -> float:
    """The first timer instant of `app` at or after `now` on its grid phase + k * period."""
    return app.phase + app.period * max(0, math.ceil((now - app.phase) / app.period - 1e-9))


# -- real time: one app per process ----------------------------------------------------------------
def _stop_on_signals() -> threading.Event:
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    return stop


def run_app(name: str, world_name: str, connect: str) -> None:
    """Run the application of `name` on its modem `<name>-modem` until SIGINT/SIGTERM."""
    from uwsimnet_gli import World

    app = make_app(name)
    stop = _stop_on_signals()
    lock = threading.Lock()
    with World(world_name, connect=connect) as w:
        pose: list[Vec | None] = [None]

        def on_pose(sample: Any) -> None:
            with contextlib.suppress(wire.CodecError):
                pose[0] = wire.decode_pose(sample.payload.to_bytes()).p

        sub = w.session.declare_subscriber(w.keys.pose(name), on_pose)
        cmd = w.session.declare_publisher(w.keys.vehicle_cmd(name))
        modem = w.modem(f"{name}-modem")

        def on_frame(f) -> None:
            with lock:
                for g in app.on_frame(f.src, f.data):
                    cmd.put(wire.pack({"waypoint": list(g.waypoint)}))

        modem.on_receive(on_frame)
        if w.sim_time(timeout=10.0) is None:
            raise SystemExit(f"hil_apps: no clock from world {world_name!r}")
        due = first_due(app, w.sim_time() or 0.0)
        print(f"hil_apps: {name} ready in {w.name}", flush=True)
        while not stop.is_set():
            now = w.sim_time() or 0.0
            if now < due:
                stop.wait(min(0.2, due - now))
                continue
            with lock:
                sends = app.on_timer(due, pose[0])
            for s in sends:
                modem.send(s.dst, s.data)
            due += app.period
        sub.undeclare()
        cmd.undeclare()
    print(f"hil_apps: {name} sent {app.sent}, received {app.received}", flush=True)


class TrackedRobot(KinematicRunner):
    """The leader's stand-in: a kinematic BlueROV obeying `vehicle/leader/cmd` on the world's clock (as
    `uwsimnet vehicles` does), whose published pose is what a camera tracker would report: the true
    position plus Gaussian noise of `noise` m per axis, `rate_hz` samples per wall second."""

    def __init__(self, session: Any, world: str, *, rate_hz: float = 15.0, noise: float = 0.02,
                 seed: int = 1) -> None:
        off = VEHICLES["leader"][1]
        leader = KinematicVehicle("leader", (off[0], off[1], DEPTH), max_speed=MAX_SPEED, max_accel=MAX_ACCEL)
        super().__init__(session, world, [leader], rate_hz=rate_hz)
        self.noise = noise
        self._rng = random.Random(seed)

    def observed(self, v: KinematicVehicle) -> Vec:
        x, y, z = v.p
        g = self._rng.gauss
        return (x + g(0.0, self.noise), y + g(0.0, self.noise), z + g(0.0, self.noise))


def run_robot(world_name: str, connect: str, *, rate_hz: float = 15.0) -> None:
    """Run the TrackedRobot in this process until SIGINT/SIGTERM."""
    from uwsimnet_gli import World

    stop = _stop_on_signals()
    with World(world_name, connect=connect) as w, TrackedRobot(w.session, w.name, rate_hz=rate_hz):
        print(f"hil_apps: robot leader ready in {w.name}", flush=True)
        stop.wait()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m uwsimnet_zenoh.experiments.hil_apps")
    ap.add_argument("role", choices=["app", "robot"])
    ap.add_argument("name", nargs="?", help="app: operator, leader or followerN")
    ap.add_argument("--world", required=True)
    ap.add_argument("--connect", default="tcp/127.0.0.1:7447")
    ap.add_argument("--rate", type=float, default=15.0, help="robot: tracked poses per wall second")
    a = ap.parse_args(argv)
    if a.role == "robot":
        run_robot(a.world, a.connect, rate_hz=a.rate)
    else:
        try:
            make_app(a.name or "")
        except ValueError as e:
            print(f"hil_apps: {e}", file=sys.stderr)
            return 2
        run_app(a.name, a.world, a.connect)
    return 0


if __name__ == "__main__":
    sys.exit(main())
