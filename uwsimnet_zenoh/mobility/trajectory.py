"""Where vehicles are: scripted trajectories and a table of latest poses.

A `PoseTable` is the one place the channel asks for positions.  Scripted vehicles are evaluated exactly
at the query time (piecewise-linear between waypoints, holding after the last); vehicles whose pose
comes from outside (HIL) keep the last sample received, extrapolated with its velocity if one was
given.  Positions of all vehicles come back as one (n, 3) array so the channel can compute distances to
every receiver in a single numpy expression.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np


class Trajectory:
    """Piecewise-linear path through (t, x, y, z) waypoints; holds the first/last point outside them."""

    __slots__ = ("t", "p")

    def __init__(self, waypoints: Sequence[tuple[float, float, float, float]]) -> None:
        arr = np.asarray(waypoints, dtype=float).reshape(-1, 4)
        if len(arr) == 0:
            raise ValueError("a trajectory needs at least one waypoint")
        if np.any(np.diff(arr[:, 0]) <= 0):
            raise ValueError("waypoint times must increase")
        self.t = arr[:, 0].copy()
        self.p = arr[:, 1:].copy()

    def position(self, t: float) -> np.ndarray:
        ts = self.t
        if t <= ts[0]:
            return self.p[0]
        if t >= ts[-1]:
            return self.p[-1]
        i = int(np.searchsorted(ts, t, side="right")) - 1
        f = (t - ts[i]) / (ts[i + 1] - ts[i])
        return self.p[i] + f * (self.p[i + 1] - self.p[i])

    @property
    def end(self) -> float:
        return float(self.t[-1])


class PoseTable:
    """Latest pose per vehicle, by index; `positions(t)` is the (n, 3) array at time t."""

    def __init__(self, names: Sequence[str]) -> None:
        self.names = list(names)
        self.index = {n: i for i, n in enumerate(self.names)}
        n = len(self.names)
        self._pos = np.zeros((n, 3))
        self._vel = np.zeros((n, 3))
        self._t_sample = np.zeros(n)
        self.known = np.ones(n, dtype=bool)
        self._scripted: dict[int, Trajectory] = {}
        self._external: set[int] = set()
        self._ext_idx = np.zeros(0, dtype=np.intp)      # the external vehicles' indices, sorted (numpy)
        self._cache_t = float("nan")
        self.pull: Callable[[float], None] | None = None
        """Called with t before positions at t are read: a source that applies pose samples lazily (the
        Zenoh broker keeps the newest sample per vehicle and applies it only when the geometry is needed)
        hooks in here.  It must only call `update`."""
        self.version = 0
        self.moving = False
        """Bumped on every change; with `moving` False, positions are constant until it changes."""

    def set_static(self, name: str, p: Sequence[float]) -> None:
        i = self.index[name]
        self._pos[i] = p
        self._changed()

    def _changed(self) -> None:
        self._cache_t = float("nan")
        self.version += 1
        self.moving = bool(self._scripted or self._external)

    def set_trajectory(self, name: str, traj: Trajectory) -> None:
        self._scripted[self.index[name]] = traj
        self._changed()

    def set_external(self, name: str) -> None:
        """The vehicle is positioned only by samples from outside; unknown until the first one."""
        i = self.index[name]
        self._external.add(i)
        self._ext_idx = np.array(sorted(self._external), dtype=np.intp)
        self._scripted.pop(i, None)
        self.known[i] = False
        self._changed()

    def update(self, name: str, t: float, p: Sequence[float], v: Sequence[float] | None = None) -> None:
        """A pose sample (from Zenoh, a control command or a kinematic model) at simulation time t."""
        i = self.index[name]
        self._scripted.pop(i, None)
        self._pos[i] = p
        self._vel[i] = v if v is not None else (0.0, 0.0, 0.0)
        self._t_sample[i] = t
        self.known[i] = True
        self._changed()

    def positions(self, t: float) -> np.ndarray:
        """All positions at time t (scripted ones exact, external ones extrapolated by velocity)."""
        if self.pull is not None:
            self.pull(t)
        if t == self._cache_t:
            return self._cache
        pos = self._pos.copy() if (self._scripted or self._external) else self._pos
        for i, traj in self._scripted.items():
            pos[i] = traj.position(t)
        ext = self._ext_idx
        if len(ext):
            # one numpy expression for every external vehicle (the same doubles as one at a time:
            # p + v * max(0, t - t_sample)); an unknown one keeps its (unused) stored position
            ext = ext[self.known[ext]]
            dt = np.maximum(t - self._t_sample[ext], 0.0)
            pos[ext] = self._pos[ext] + self._vel[ext] * dt[:, None]
        self._cache, self._cache_t = pos, t
        return pos

    def position(self, name: str, t: float) -> np.ndarray:
        return self.positions(t)[self.index[name]]
