"""Where vehicles are: scripted trajectories and a table of latest poses.

A `PoseTable` is the one place the channel asks for positions.  Scripted vehicles are evaluated exactly
at the query time (piecewise-linear between waypoints, holding after the last); vehicles whose pose
comes from outside (HIL) keep the last sample received, extrapolated with its velocity if one was
given.  The table is plain Python floats: `points(t)` gives every position as an (x, y, z) tuple, which
is all a small channel reads, and `positions(t)` the same doubles as an (n, 3) numpy array for the
channels and tools that compute on arrays.  numpy is imported only then (its import is a third of a
small run's start-up); from that first call on, the table keeps numpy copies of its columns too, so a
large swarm's positions are one vectorised expression per read, as they always were.
"""

from __future__ import annotations

from bisect import bisect_right
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np

Point = tuple[float, float, float]
ORIGIN: Point = (0.0, 0.0, 0.0)


def _point(p: Sequence[float]) -> Point:
    x, y, z = p
    return (float(x), float(y), float(z))


class Trajectory:
    """Piecewise-linear path through (t, x, y, z) waypoints; holds the first/last point outside them."""

    __slots__ = ("t", "p")

    def __init__(self, waypoints: Sequence[Sequence[float]]) -> None:
        rows = [tuple(float(v) for v in w) for w in waypoints]
        if not rows:
            raise ValueError("a trajectory needs at least one waypoint")
        if any(len(r) != 4 for r in rows):
            raise ValueError("a waypoint is (t, x, y, z)")
        if any(not b[0] > a[0] for a, b in zip(rows, rows[1:], strict=False)):
            raise ValueError("waypoint times must increase")
        self.t: list[float] = [r[0] for r in rows]
        self.p: list[Point] = [(r[1], r[2], r[3]) for r in rows]

    def position(self, t: float) -> Point:
        ts = self.t
        if t <= ts[0]:
            return self.p[0]
        if t >= ts[-1]:
            return self.p[-1]
        i = bisect_right(ts, t) - 1
        f = (t - ts[i]) / (ts[i + 1] - ts[i])
        (x0, y0, z0), (x1, y1, z1) = self.p[i], self.p[i + 1]
        return (x0 + f * (x1 - x0), y0 + f * (y1 - y0), z0 + f * (z1 - z0))

    def velocity(self, t: float) -> Point:
        """The velocity at t, m/s: the slope of the segment t falls in (zero before the first waypoint and
        from the last one on; at a waypoint, the segment that starts there)."""
        ts = self.t
        if t < ts[0] or t >= ts[-1]:
            return ORIGIN
        i = bisect_right(ts, t) - 1
        dt = ts[i + 1] - ts[i]
        (x0, y0, z0), (x1, y1, z1) = self.p[i], self.p[i + 1]
        return ((x1 - x0) / dt, (y1 - y0) / dt, (z1 - z0) / dt)

    @property
    def end(self) -> float:
        return self.t[-1]


class PoseTable:
    """Latest pose per vehicle, by index: `points(t)` as tuples, `positions(t)` as an (n, 3) array."""

    def __init__(self, names: Sequence[str]) -> None:
        self.names = list(names)
        self.index = {n: i for i, n in enumerate(self.names)}
        n = len(self.names)
        self._pos: list[Point] = [ORIGIN] * n
        self._vel: list[Point] = [ORIGIN] * n
        self._t_sample: list[float] = [0.0] * n
        self.known: list[bool] = [True] * n
        self._scripted: dict[int, Trajectory] = {}
        self._external: set[int] = set()
        self._ext_idx: list[int] = []                   # the external vehicles' indices, sorted
        self._cache_t = float("nan")
        self._cache: list[Point] = self._pos
        self._array: tuple[int, float, np.ndarray] | None = None     # (version, t, positions(t))
        self._cols: list[np.ndarray] | None = None  # numpy copies (pos, vel, t_sample, known) once asked for
        self._ext_np: np.ndarray | None = None      # _ext_idx as a numpy index, once asked for
        self.pull: Callable[[float], None] | None = None
        """Called with t before positions at t are read: a source that applies pose samples lazily (the
        Zenoh broker keeps the newest sample per vehicle and applies it only when the geometry is needed)
        hooks in here.  It must only call `update`."""
        self.version = 0
        self.moving = False
        """Bumped on every change; with `moving` False, positions are constant until it changes."""

    def set_static(self, name: str, p: Sequence[float]) -> None:
        i = self.index[name]
        self._pos[i] = _point(p)
        if self._cols is not None:
            self._cols[0][i] = self._pos[i]
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
        self._ext_idx = sorted(self._external)
        self._ext_np = None
        self._scripted.pop(i, None)
        self.known[i] = False
        if self._cols is not None:
            self._cols[3][i] = False
        self._changed()

    def update(self, name: str, t: float, p: Sequence[float], v: Sequence[float] | None = None) -> None:
        """A pose sample (from Zenoh, a control command or a kinematic model) at simulation time t."""
        i = self.index[name]
        self._scripted.pop(i, None)
        self._pos[i] = _point(p)
        self._vel[i] = ORIGIN if v is None else _point(v)
        self._t_sample[i] = float(t)
        self.known[i] = True
        cols = self._cols
        if cols is not None:
            cols[0][i] = self._pos[i]
            cols[1][i] = self._vel[i]
            cols[2][i] = self._t_sample[i]
            cols[3][i] = True
        self._changed()

    def points(self, t: float) -> list[Point]:
        """All positions at time t (scripted ones exact, external ones p + v * max(0, t - t_sample); an
        unknown one keeps its unused stored position).  Shared: the caller must not change the list."""
        if self.pull is not None:
            self.pull(t)
        if t == self._cache_t:
            return self._cache
        if not (self._scripted or self._external):
            pos = self._pos
        else:
            pos = list(self._pos)
            for i, traj in self._scripted.items():
                pos[i] = traj.position(t)
            known = self.known
            ts = self._t_sample
            vel = self._vel
            for i in self._ext_idx:
                if known[i]:
                    dt = t - ts[i]
                    if dt < 0.0:                # max(0, t - t_sample): a sample from the future holds
                        dt = 0.0
                    p = pos[i]
                    v = vel[i]
                    pos[i] = (p[0] + v[0] * dt, p[1] + v[1] * dt, p[2] + v[2] * dt)
        self._cache, self._cache_t = pos, t
        return pos

    def positions(self, t: float) -> np.ndarray:
        """`points(t)` as an (n, 3) float64 array (the same doubles: p + v * max(0, t - t_sample) for every
        external vehicle in one expression), kept while nothing changes.  Shared: do not write to it."""
        if self.pull is not None:
            self.pull(t)
        a = self._array
        if a is not None and a[0] == self.version and (a[1] == t or not self.moving):
            return a[2]
        import numpy as np

        cols = self._columns()
        pos = cols[0].copy() if (self._scripted or self._external) else cols[0]
        for i, traj in self._scripted.items():
            pos[i] = traj.position(t)
        if self._ext_idx:
            ext = self._ext_np
            if ext is None:
                ext = self._ext_np = np.array(self._ext_idx, dtype=np.intp)
            ext = ext[cols[3][ext]]
            dt = np.maximum(t - cols[2][ext], 0.0)
            pos[ext] = cols[0][ext] + cols[1][ext] * dt[:, None]
        self._array = (self.version, t, pos)
        return pos

    def known_mask(self) -> np.ndarray:
        """`known` as a numpy bool array (the table's own: do not write to it)."""
        return self._columns()[3]

    def _columns(self) -> list[np.ndarray]:
        """The numpy copies of the columns (pos, vel, t_sample, known), made at the first call and kept
        up to date by every change from then on."""
        cols = self._cols
        if cols is None:
            import numpy as np

            n = len(self.names)
            cols = self._cols = [np.array(self._pos, dtype=np.float64).reshape(n, 3),
                                 np.array(self._vel, dtype=np.float64).reshape(n, 3),
                                 np.array(self._t_sample, dtype=np.float64), np.array(self.known, dtype=bool)]
        return cols

    def position(self, name: str, t: float) -> Point:
        return self.points(t)[self.index[name]]

    def velocity(self, i: int, t: float) -> Point:
        """Vehicle i's velocity at t, m/s: its trajectory's segment, the last external sample's, or zero."""
        traj = self._scripted.get(i)
        if traj is not None:
            return traj.velocity(t)
        return self._vel[i] if i in self._external and self.known[i] else ORIGIN
