"""Kinematic vehicles (sans-IO): a point that follows velocity or waypoint commands under speed and
acceleration limits.  No I/O, no clock of its own: the caller calls `step(dt)` (bus/kinematic.py on wall
time, experiments on virtual time).

Commands (the payload of `uwsimnet/<world>/vehicle/<name>/cmd`, a msgpack map; docs/runtime.md):

    {"v": [vx, vy, vz]}                          hold this velocity (m/s), clipped to max_speed
    {"waypoint": [x, y, z], "speed": s?}         go there (at most s, default max_speed) and stop
    {"waypoints": [[x, y, z], ...], "speed": s?} go through them in order, stop at the last
    {"stop": true}                               velocity 0 (decelerating if max_accel is set)
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from typing import Any

from ..errors import UwsimnetError

Vec = tuple[float, float, float]


class CommandError(UwsimnetError, ValueError):
    pass


def _vec(x: Any, what: str) -> Vec:
    if not isinstance(x, list | tuple) or len(x) != 3:
        raise CommandError(f"{what} must be 3 numbers")
    out = []
    for c in x:
        if isinstance(c, bool) or not isinstance(c, int | float) or not math.isfinite(c):
            raise CommandError(f"{what} must be 3 finite numbers")
        out.append(float(c))
    return (out[0], out[1], out[2])


def _norm(v: Sequence[float]) -> float:
    return math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])


class KinematicVehicle:
    def __init__(self, name: str, p: Sequence[float] = (0.0, 0.0, 0.0), *, max_speed: float = 1.0,
                 max_accel: float | None = None, arrive_radius: float = 0.02) -> None:
        if max_speed <= 0:
            raise ValueError("max_speed must be > 0")
        self.name = name
        self.p: Vec = (float(p[0]), float(p[1]), float(p[2]))
        self.v: Vec = (0.0, 0.0, 0.0)
        self.max_speed = float(max_speed)
        self.max_accel = None if max_accel is None else float(max_accel)
        self.arrive_radius = arrive_radius
        self.mode = "idle"               # idle | velocity | waypoint
        self.cmd_v: Vec = (0.0, 0.0, 0.0)
        self.targets: deque[Vec] = deque()
        self.speed = self.max_speed
        self.t = 0.0

    # -- commands ----------------------------------------------------------------------------------
    def command(self, cmd: Any) -> None:
        if not isinstance(cmd, dict):
            raise CommandError("a command is a map")
        speed = cmd.get("speed")
        if speed is not None and (isinstance(speed, bool) or not isinstance(speed, int | float) or not speed > 0):
            raise CommandError("speed must be a number > 0")
        if "v" in cmd:
            self.velocity(_vec(cmd["v"], "v"))
        elif "waypoint" in cmd:
            self.go([_vec(cmd["waypoint"], "waypoint")], speed)
        elif "waypoints" in cmd:
            wps = cmd["waypoints"]
            if not isinstance(wps, list | tuple) or not wps:
                raise CommandError("waypoints must be a non-empty list")
            self.go([_vec(w, "waypoint") for w in wps], speed)
        elif cmd.get("stop"):
            self.velocity((0.0, 0.0, 0.0))
        else:
            raise CommandError("expected one of v, waypoint, waypoints, stop")

    def velocity(self, v: Sequence[float]) -> None:
        n = _norm(v)
        k = min(1.0, self.max_speed / n) if n > 0 else 0.0
        self.cmd_v = (v[0] * k, v[1] * k, v[2] * k)
        self.targets.clear()
        self.mode = "velocity"

    def go(self, waypoints: Sequence[Sequence[float]], speed: float | None = None) -> None:
        self.targets = deque((float(w[0]), float(w[1]), float(w[2])) for w in waypoints)
        self.speed = min(self.max_speed, float(speed)) if speed else self.max_speed
        self.mode = "waypoint"

    @property
    def target(self) -> Vec | None:
        return self.targets[0] if self.targets else None

    # -- time --------------------------------------------------------------------------------------
    def step(self, dt: float) -> Vec:
        """Advance `dt` seconds; returns the new position."""
        if dt <= 0:
            return self.p
        want = self._wanted(dt)
        v = want
        if self.max_accel is not None:
            dv = (want[0] - self.v[0], want[1] - self.v[1], want[2] - self.v[2])
            n = _norm(dv)
            lim = self.max_accel * dt
            if n > lim:
                k = lim / n
                v = (self.v[0] + dv[0] * k, self.v[1] + dv[1] * k, self.v[2] + dv[2] * k)
        self.v = v
        self.p = (self.p[0] + v[0] * dt, self.p[1] + v[1] * dt, self.p[2] + v[2] * dt)
        self.t += dt
        if self.mode == "waypoint":
            while self.targets and _norm(self._to(self.targets[0])) <= self.arrive_radius:
                self.targets.popleft()
            if not self.targets:
                self.mode = "idle"
                if self.max_accel is None:
                    self.v = (0.0, 0.0, 0.0)
        return self.p

    def _to(self, q: Vec) -> Vec:
        return (q[0] - self.p[0], q[1] - self.p[1], q[2] - self.p[2])

    def _wanted(self, dt: float) -> Vec:
        if self.mode == "velocity":
            return self.cmd_v
        if self.mode == "waypoint" and self.targets:
            d = self._to(self.targets[0])
            n = _norm(d)
            if n == 0:
                return (0.0, 0.0, 0.0)
            s = min(self.speed, n / dt)               # do not overshoot in one step
            if self.max_accel is not None and len(self.targets) == 1:
                s = min(s, math.sqrt(2 * self.max_accel * n))   # brake in time for the last one
            return (d[0] / n * s, d[1] / n * s, d[2] / n * s)
        return (0.0, 0.0, 0.0)

    def state(self) -> dict[str, Any]:
        return {"name": self.name, "p": list(self.p), "v": list(self.v), "mode": self.mode,
                "target": None if self.target is None else list(self.target)}
