"""Bellhop's side of the channel model "bellhop" (docs/ocean.md): the program found and tagged, its .env and
.bty files written, its .shd and .arr files read, and the grids computed: one job per (grid, source depth),
in parallel when more than one is missing (Bellhop processes from worker threads, or a campaign's process
pool or Dask cluster: `grid_executor`), with a progress line on stderr per job.  The one place below the
sans-IO line that starts a program; it runs when the network is built, never per frame.  Bellhop is GPL-3:
run as a program, never imported or shipped."""

from __future__ import annotations

import hashlib
import math
import os
import re
import shutil
import struct
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from concurrent.futures import BrokenExecutor, Executor, ThreadPoolExecutor, as_completed
from contextlib import contextmanager
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

GRID_VERSION = "uwsimnet-bellhop-grid-4"
LATE_S = (1e-4, 2e-4, 5e-4, 1e-3, 2e-3, 5e-3, 1e-2, 2e-2, 5e-2, 1e-1)
"""Delays after the first arrival (s) at which the grid keeps the fraction of arrival energy still to come."""
HOWTO = ("Bellhop not found: run `make bellhop` (installs the aubellhop wheel's binary into .tools/bellhop),"
         " or name the program in <program> or in UWSIMNET_BELLHOP")


def find_program(explicit: str | None = None) -> str | None:
    """The Bellhop binary: `explicit`, $UWSIMNET_BELLHOP, `bellhop.exe`/`bellhop` on PATH, or `make bellhop`'s."""
    for cand in (explicit, os.environ.get("UWSIMNET_BELLHOP")):
        if cand:
            return cand if os.access(cand, os.X_OK) else None
    for name in ("bellhop.exe", "bellhop"):
        if (p := shutil.which(name)) is not None:
            return p
    root = Path(__file__).resolve().parents[2] / ".tools" / "bellhop"
    found = sorted(root.glob("lib/python3*/site-packages/aubellhop/bin/bellhop.exe"))
    return str(found[0]) if found else None


def program_tag(program: str) -> str:
    """The Bellhop build in a grid's cache name: the first 12 hex digits of the SHA-256 of the program's bytes
    (a new Bellhop, even of the same version number, computes its own grids); kept per (path, size, mtime)."""
    st = os.stat(program)
    return _tag(os.path.realpath(program), st.st_size, st.st_mtime_ns)


@lru_cache(maxsize=8)
def _tag(path: str, _size: int, _mtime_ns: int) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(1 << 20):
            h.update(chunk)
    return h.hexdigest()[:12]


def env_text(freq_hz: float, profile: list[tuple[float, float]], bottom_m: float, seabed: tuple[float, float, float],
             sds: list[float], rds: list[float], rrs_m: list[float], run: str, beams: int = 0,
             bty: bool = False) -> str:
    """A Bellhop .env: one fluid layer (C-linear profile, vacuum surface, Thorp volume attenuation) over an
    acousto-elastic half-space (sound speed m/s, density g/cm^3, attenuation dB/wavelength); sources,
    receivers and ranges as given.  `bty`: the bottom follows the run's .bty file (bottom option 'A*'), and
    `bottom_m` is its deepest point (the profile must reach it)."""
    pts = [(d, c) for d, c in profile if d < bottom_m]
    pts.append((bottom_m, _speed_at(profile, bottom_m)))
    cp, rho, att = seabed
    lines = ["'uwsimnet'", f"{freq_hz:.6f}", "1", "'CVWT'", f"0 0.0 {bottom_m:.6f}"]
    lines += [f"{d:.6f} {c:.6f} /" for d, c in pts]
    lines += ["'A*' 0.0" if bty else "'A' 0.0", f"{bottom_m:.6f} {cp:.6f} 0.0 {rho:.6f} {att:.6f} /"]
    for vals, scale in ((sds, 1.0), (rds, 1.0), (rrs_m, 1e-3)):
        lines += [str(len(vals)), " ".join(f"{v * scale:.6f}" for v in vals) + " /"]
    lines += [f"'{run}'", str(beams), "-89.0 89.0 /", f"0.0 {bottom_m * 1.01:.6f} {rrs_m[-1] * 1.01e-3:.6f}"]
    return "\n".join(lines) + "\n"


def _speed_at(profile: list[tuple[float, float]], z: float) -> float:
    ds, cs = [d for d, _ in profile], [c for _, c in profile]
    return float(np.interp(z, ds, cs))


def read_shd(data: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A Bellhop .shd (the Acoustics Toolbox's binary shade file): records of 4*recl bytes; record 2 holds
    the counts, 7-9 the source depths, receiver depths and ranges, 10 on the pressure per (source, depth)."""
    recl = struct.unpack_from("<i", data, 0)[0]
    rec = 4 * recl
    _nfreq, ntheta, _nsx, _nsy, nsd, nrd, nrr = struct.unpack_from("<7i", data, 2 * rec)
    if ntheta != 1:
        raise ValueError("a .shd with more than one bearing")
    sd = np.frombuffer(data, "<f4", nsd, 7 * rec).astype(float)
    rd = np.frombuffer(data, "<f4", nrd, 8 * rec).astype(float)
    rr = np.frombuffer(data, "<f8" if _rr_is_double(data, rec, nrr) else "<f4", nrr, 9 * rec).astype(float)
    p = np.empty((nsd, nrd, nrr), dtype=complex)
    for i in range(nsd):
        for j in range(nrd):
            v = np.frombuffer(data, "<f4", 2 * nrr, (10 + i * nrd + j) * rec).astype(float)
            p[i, j] = v[0::2] + 1j * v[1::2]
    return sd, rd, rr, p


def _rr_is_double(data: bytes, rec: int, nrr: int) -> bool:
    """Ranges are written as doubles by recent Bellhop and singles by old ones: doubles read as increasing."""
    if nrr < 2 or 9 * rec + 8 * nrr > len(data):
        return False
    v = np.frombuffer(data, "<f8", nrr, 9 * rec)
    return bool(np.all(np.isfinite(v)) and np.all(np.diff(v) > 0) and v[-1] < 1e8)


def read_arrivals(text: str, window_db: float = 20.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per (source depth, receiver depth, range) of a Bellhop ascii .arr file ('2D'): the first significant
    arrival (earliest within `window_db` of the strongest; nan: none), the rms delay spread (s), and the
    fraction of the arrivals' energy (sum |A|^2) that comes later than first + each of LATE_S.
    Each arrival's amplitude is |A| exp(omega Im(tau)): Bellhop leaves the volume attenuation (top option 'T')
    out of the amplitude column and writes it as the delay's imaginary part (aubellhop's readers.py builds
    the complex amplitude A exp(-i(phase + omega tau)) from the same columns)."""
    head = re.finditer(r"\S+", text)
    tok = [m.group() for _, m in zip(range(2), head, strict=False)]    # range first: zip stops before head
    if len(tok) < 2 or "2D" not in tok[0]:
        raise ValueError("not a 2D Bellhop arrivals file")
    omega = 2.0 * math.pi * float(tok[1])
    counts = []
    for _ in range(3):                            # the source depths, receiver depths, ranges: a count, values
        m = next(head, None)
        if m is None:
            raise ValueError("a Bellhop .arr cut short in its header")
        n, end = int(m.group()), m.end()
        counts.append(n)
        for _, m in zip(range(n), head, strict=False):
            end = m.end()
    nsd, nrd, nrr = counts
    data = np.fromstring(text[end:], sep=" ")    # the rest is numbers: counts and 8-column arrival rows
    first = np.full((nsd, nrd, nrr), np.nan)
    spread = np.full((nsd, nrd, nrr), np.nan)
    late = np.zeros((nsd, nrd, nrr, len(LATE_S)))
    rows, cells = [], []                          # where each cell's rows start in `data`, and its index
    pos = 0
    counts_at = data.tolist()
    for i in range(nsd):
        pos += 1                                  # the source's largest count
        for j in range(nrd):
            for k in range(nrr):
                n = int(counts_at[pos]) if pos < len(counts_at) else -1
                pos += 1
                if n:
                    rows.append((pos, n))
                    cells.append((i, j, k))
                    pos += 8 * n
    if pos != len(data):
        raise ValueError(f"a Bellhop .arr whose counts do not match its {len(data)} numbers")
    if not rows:
        return first, spread, late
    starts = np.array([r for r, _ in rows])
    ns = np.array([n for _, n in rows])
    idx = np.repeat(starts, ns) + 8 * (np.arange(ns.sum()) - np.repeat(np.cumsum(ns) - ns, ns))
    a = data[idx[:, None] + np.arange(8)]         # every arrival row, cell after cell
    cell = np.repeat(np.arange(len(rows)), ns)
    seg = np.cumsum(ns) - ns                      # each cell's first row in `a`
    amp, delay = np.abs(a[:, 0]) * np.exp(omega * a[:, 3]), a[:, 2]
    top = np.maximum.reduceat(amp, seg)
    some = top > 0.0                              # every path attenuated to nothing: no arrival
    strong = amp >= (top * 10 ** (-window_db / 20))[cell]
    f = np.minimum.reduceat(np.where(strong, delay, np.inf), seg)
    w = amp ** 2
    with np.errstate(invalid="ignore", divide="ignore"):
        total = np.add.reduceat(w, seg)
        mean = np.add.reduceat(w * delay, seg) / total
        sp = np.sqrt(np.maximum(0.0, np.add.reduceat(w * (delay - mean[cell]) ** 2, seg) / total))
        lt = np.stack([np.add.reduceat(w * (delay > f[cell] + off), seg) / total for off in LATE_S], axis=-1)
    ci, cj, ck = (np.array(x)[some] for x in zip(*cells, strict=True))
    first[ci, cj, ck] = f[some]
    spread[ci, cj, ck] = sp[some]
    late[ci, cj, ck] = lt[some]
    return first, spread, late


class Grid:
    """TL (dB) and first-arrival delay (s) on (source depth, receiver depth, range) axes; trilinear lookup."""

    def __init__(self, sd: np.ndarray, rd: np.ndarray, rr: np.ndarray, tl: np.ndarray, delay: np.ndarray,
                 spread: np.ndarray, late: np.ndarray) -> None:
        self.sd, self.rd, self.rr = (np.asarray(a, dtype=float) for a in (sd, rd, rr))
        self.tl, self.delay, self.spread, self.late = (np.asarray(a, dtype=float) for a in (tl, delay, spread, late))
        self._changes: np.ndarray | None = None
        self._paths: Paths | None = None

    def save(self, path: str | Path) -> None:
        tmp = f"{path}.tmp{os.getpid()}.npz"
        np.savez_compressed(tmp, sd=self.sd, rd=self.rd, rr=self.rr, tl=self.tl, delay=self.delay,
                            spread=self.spread, late=self.late)
        os.replace(tmp, path)

    @classmethod
    def load(cls, path: str | Path) -> Grid:
        with np.load(path) as z:
            return cls(z["sd"], z["rd"], z["rr"], z["tl"], z["delay"], z["spread"], z["late"])

    def late_fraction(self, zs: Any, zr: Any, r: Any, after_s: float) -> np.ndarray:
        """The fraction of the arrivals' energy later than first + after_s (log-linear between LATE_S)."""
        zs, zr, r = (np.atleast_1d(np.asarray(a, dtype=float)) for a in (zs, zr, r))
        x = math.log(min(max(after_s, LATE_S[0]), LATE_S[-1]))
        xs = [math.log(v) for v in LATE_S]
        m = min(max(int(np.searchsorted(xs, x, side="right")) - 1, 0), len(xs) - 2)
        w = (x - xs[m]) / (xs[m + 1] - xs[m])
        a = _trilinear(self.sd, self.rd, self.rr, self.late[..., m], zs, zr, r)
        b = _trilinear(self.sd, self.rd, self.rr, self.late[..., m + 1], zs, zr, r)
        return (1 - w) * a + w * b

    def path_changes(self) -> np.ndarray:
        """Per grid cell (source-depth, receiver-depth and range interval; one along an axis of one point):
        whether its 8 corners' first arrivals differ by more than one path's travel time can across the cell
        (`path_bound`), i.e. whether the first arrival changes path in it (a shadow's edge: the direct path at
        one corner, the bottom bounce a second later at the next)."""
        if self._changes is None:
            d = self.delay
            lo, hi = d, d
            for ax in range(3):
                if d.shape[ax] > 1:
                    a, b = np.take(lo, range(d.shape[ax] - 1), ax), np.take(lo, range(1, d.shape[ax]), ax)
                    c, e = np.take(hi, range(d.shape[ax] - 1), ax), np.take(hi, range(1, d.shape[ax]), ax)
                    lo, hi = np.minimum(a, b), np.maximum(c, e)
            steps = [np.diff(a) if len(a) > 1 else np.zeros(1) for a in (self.sd, self.rd, self.rr)]
            bound = path_bound(steps[0][:, None, None], steps[1][None, :, None], steps[2][None, None, :])
            with np.errstate(invalid="ignore"):
                self._changes = hi - lo > bound
        return self._changes

    def paths(self) -> Paths:
        """`Paths.of` this grid, computed once."""
        if self._paths is None:
            self._paths = Paths.of(self)
        return self._paths

    def lookup(self, zs: Any, zr: Any, r: Any) -> tuple[np.ndarray, np.ndarray]:
        """TL and delay at source depths zs, receiver depths zr, ranges r (arrays): nan beyond the ranges; the
        delay within one path (`same_path`)."""
        zs, zr, r = (np.atleast_1d(np.asarray(a, dtype=float)) for a in (zs, zr, r))
        out_tl = _trilinear(self.sd, self.rd, self.rr, self.tl, zs, zr, r)
        out_dl = same_path(self.sd, self.rd, self.rr, self.delay, self.paths(), zs, zr, r,
                           _trilinear(self.sd, self.rd, self.rr, self.delay, zs, zr, r))
        beyond = (r > self.rr[-1]) | (r < self.rr[0])
        out_tl[beyond] = np.nan
        out_dl[beyond] = np.nan
        return out_tl, out_dl


def _axis(ax: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    if len(ax) == 1:
        return np.zeros(len(q), dtype=int), np.zeros(len(q))
    q = np.clip(q, ax[0], ax[-1])
    i = np.clip(np.searchsorted(ax, q, side="right") - 1, 0, len(ax) - 2)
    return i, (q - ax[i]) / (ax[i + 1] - ax[i])


SLOWEST_C = 1400.0
"""m/s, below any sea water's sound speed: along one path, the travel time changes by at most the distance
an end moves over the sound speed there (the eikonal's gradient is 1/c)."""

PATH_SLACK_S = 1e-3
"""s added to that bound: Bellhop's arrival times along one path scatter by its beams' sampling, far less."""


def path_bound(d_sd: Any, d_rd: Any, d_rr: Any) -> Any:
    """The most one path's first arrival can change across a grid cell of these steps (m), twice over: moving
    the source by d_sd, the receiver by (d_rd, d_rr)."""
    return 2.0 * (d_sd + np.hypot(d_rd, d_rr)) / SLOWEST_C + PATH_SLACK_S


class Paths:
    """Where a grid's first arrival changes path, and what to interpolate there (`same_path`): per grid cell
    (`Grid.path_changes`) its row in `along`, else -1; per such cell, its bound (`path_bound`) and, for each
    of its 8 corners taken as the reference, the 8 corners' times on the reference's path: a corner on
    another path replaced by the reference's time extrapolated along its path (per axis, the slope toward a
    neighbour on the same path: the cell's other end, else the far side; else none).  Corners are numbered
    4 a + 2 b + c (a, b, c: 0 at the cell's low end, 1 at its high end of source depth, receiver depth,
    range).  Computed once per grid; `stack` joins the grids of one cell's bearing sectors."""

    def __init__(self, row: np.ndarray, bound: np.ndarray, along: np.ndarray) -> None:
        self.row, self.bound, self.along = row, bound, along
        self.row_list, self.bound_list, self.along_list = row.tolist(), bound.tolist(), along.tolist()

    @classmethod
    def of(cls, g: Grid) -> Paths:
        changes = g.path_changes()
        cells = np.argwhere(changes)
        row = np.full(changes.shape, -1, dtype=int)
        row[tuple(cells.T)] = np.arange(len(cells))
        axes = (g.sd, g.rd, g.rr)
        lo = [cells[:, a] for a in range(3)]
        hi = [np.minimum(x + 1, len(ax) - 1) for x, ax in zip(lo, axes, strict=True)]
        ends = [[lo[a], hi[a]] for a in range(3)]
        corner = [tuple(ends[a][(m >> (2 - a)) & 1] for a in range(3)) for m in range(8)]
        val = np.stack([g.delay[c] for c in corner], axis=1)                      # (cells, 8)
        bound = path_bound(*(axes[a][hi[a]] - axes[a][lo[a]] for a in range(3)))
        along = np.empty((len(cells), 8, 8))
        for ref in range(8):
            near = corner[ref]
            dn = val[:, ref]
            slope = []
            for a, ax in enumerate(axes):
                n = near[a]
                toward = np.where(n == lo[a], hi[a], lo[a])
                got, done = np.zeros(len(cells)), np.zeros(len(cells), dtype=bool)
                for nb in (toward, 2 * n - toward):                 # the cell's other end, else the far side
                    ok = (nb != n) & (nb >= 0) & (nb < len(ax)) & ~done
                    nb = np.clip(nb, 0, len(ax) - 1)
                    d = g.delay[tuple(nb if b == a else near[b] for b in range(3))]
                    step = np.where(ok, ax[nb] - ax[n], 1.0)
                    with np.errstate(invalid="ignore"):
                        same = ok & (np.abs(d - dn) <= path_bound(*(np.abs(step) if b == a else 0.0
                                                                    for b in range(3))))
                    got = np.where(same, (d - dn) / step, got)
                    done |= same
                slope.append(got)
            for m, c in enumerate(corner):
                extrapolated = dn + sum(slope[b] * (axes[b][c[b]] - axes[b][near[b]]) for b in range(3))
                with np.errstate(invalid="ignore"):
                    along[:, ref, m] = np.where(np.abs(val[:, m] - dn) > bound, extrapolated, val[:, m])
        return cls(row, bound, along)

    @classmethod
    def stack(cls, paths: list[Paths]) -> Paths:
        """The paths of grids on the same axes, as one: `row` gains a leading axis (the grid), rows offset."""
        offsets = np.cumsum([0] + [len(p.along) for p in paths[:-1]])
        rows = np.stack([np.where(p.row >= 0, p.row + o, -1) for p, o in zip(paths, offsets, strict=True)])
        return cls(rows, np.concatenate([p.bound for p in paths]), np.concatenate([p.along for p in paths]))


def reference(val: list[float], wt: list[float], bound: float) -> int:
    """The corner whose path a query follows: the nearest (the largest weight), unless the corners on other
    paths weigh more together; then the nearest of those."""
    ref = max(range(8), key=wt.__getitem__)
    same = [abs(x - val[ref]) <= bound for x in val]
    if sum(w for w, s in zip(wt, same, strict=True) if s) < 0.5:
        ref = max((m for m in range(8) if not same[m]), key=wt.__getitem__)
    return ref


def same_path(a0: np.ndarray, a1: np.ndarray, a2: np.ndarray, delay: np.ndarray, paths: Paths,
              q0: np.ndarray, q1: np.ndarray, q2: np.ndarray, plain: np.ndarray,
              lead: np.ndarray | None = None) -> np.ndarray:
    """The first arrival at each query: `plain` (the trilinear interpolation), except in a cell where the path
    changes: there, the trilinear interpolation of the corners' times on one path (`reference`, `Paths`), so
    the time is one a ray takes, never a mix of the direct path's and a bounce's a second later.  A corner
    with no arrival (nan) still makes the answer nan, as in `plain`.  `lead`: each query's grid in a stack of
    grids on the same axes (delay and paths stacked)."""
    (i, f), (j, g), (k, h) = _axis(a0, q0), _axis(a1, q1), _axis(a2, q2)
    row = paths.row[i, j, k] if lead is None else paths.row[lead, i, j, k]
    at = np.flatnonzero(row >= 0)
    if not len(at):
        return plain
    row, f, g, h = row[at], f[at], g[at], h[at]
    i, j, k = i[at], j[at], k[at]
    hi = [np.minimum(x + 1, len(a) - 1) for x, a in ((i, a0), (j, a1), (k, a2))]
    ends = [[i, hi[0]], [j, hi[1]], [k, hi[2]]]
    w = [[1 - f, f], [1 - g, g], [1 - h, h]]
    v = delay if lead is None else delay[lead[at]]
    n = np.arange(len(at))
    val = np.stack([v[tuple(ends[a][(m >> (2 - a)) & 1] for a in range(3)) if lead is None
                      else (n,) + tuple(ends[a][(m >> (2 - a)) & 1] for a in range(3))] for m in range(8)], axis=1)
    wt = np.stack([w[0][(m >> 2) & 1] * w[1][(m >> 1) & 1] * w[2][m & 1] for m in range(8)], axis=1)
    bound = paths.bound[row]
    ref = np.argmax(wt, axis=1)
    with np.errstate(invalid="ignore"):
        same = np.abs(val - val[n, ref][:, None]) <= bound[:, None]
    ref = np.where((wt * same).sum(axis=1) < 0.5, np.argmax(np.where(same, -1.0, wt), axis=1), ref)
    out = plain.copy()
    out[at] = (wt * paths.along[row, ref]).sum(axis=1)
    return out


def _trilinear(a0: np.ndarray, a1: np.ndarray, a2: np.ndarray, v: np.ndarray, q0: np.ndarray, q1: np.ndarray,
               q2: np.ndarray) -> np.ndarray:
    (i, f), (j, g), (k, h) = _axis(a0, q0), _axis(a1, q1), _axis(a2, q2)
    i1 = np.minimum(i + 1, len(a0) - 1)
    j1 = np.minimum(j + 1, len(a1) - 1)
    k1 = np.minimum(k + 1, len(a2) - 1)
    out = np.zeros(len(q0))
    for ii, wi in ((i, 1 - f), (i1, f)):
        for jj, wj in ((j, 1 - g), (j1, g)):
            for kk, wk in ((k, 1 - h), (k1, h)):
                out += wi * wj * wk * v[ii, jj, kk]
    return out


def bty_text(points: list[tuple[float, float]]) -> str:
    """A Bellhop .bty: linear ('L') bottom depth (m) at ranges (m; written in km) along one bearing."""
    return "\n".join(["'L'", str(len(points))] + [f"{r * 1e-3:.6f} {z:.6f}" for r, z in points]) + "\n"


def run_bellhop(program: str, env: str, want: str, workdir: str, timeout: float = 3600.0,
                bty: str | None = None) -> bytes:
    """Run Bellhop on one .env text (and its .bty, if any) in `workdir`; the bytes of its output file `want`
    ('shd' or 'arr').  Every failure is one line (ValueError): the end of Bellhop's .prt, a timeout, a program
    that cannot run."""
    base = os.path.join(workdir, "run")
    Path(base + ".env").write_text(env)
    if bty is not None:
        Path(base + ".bty").write_text(bty)
    try:
        done = subprocess.run([program, base], cwd=workdir, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        raise ValueError(f"Bellhop ({program}) ran over its timeout of {timeout:g} s (parameter <timeout>)") from None
    except OSError as e:
        raise ValueError(f"Bellhop ({program}) cannot run: {e.strerror or e}") from None
    out = Path(f"{base}.{want}")
    if done.returncode != 0 or not out.exists():
        prt = Path(base + ".prt")
        tail = prt.read_text(errors="replace").strip().splitlines()[-3:] if prt.exists() else [done.stderr.strip()]
        if not any(tail):
            tail = [f"exit status {done.returncode}, no .{want} and no .prt written"]
        raise ValueError(f"Bellhop failed ({program}): {' | '.join(tail)}")
    return out.read_bytes()


class GridSpec:
    """One grid to compute or load: Bellhop's input for one (environment, frequency, source depths) and, for a
    range-dependent bottom, the bottom's profile along one bearing (`bty`: (range m, depth m) points, the
    .bty file).  Its cache name is the SHA-256 of this content (`key`)."""

    def __init__(self, freq_hz: float, profile: list[tuple[float, float]], bottom_m: float,
                 seabed: tuple[float, float, float], sds: list[float], rds: list[float], rrs: list[float],
                 bty: list[tuple[float, float]] | None = None, label: str = "") -> None:
        self.freq_hz, self.profile, self.bottom_m, self.seabed = freq_hz, profile, bottom_m, seabed
        self.sds, self.rds, self.rrs, self.bty, self.label = sds, rds, rrs, bty, label

    def key(self) -> str:
        content: tuple[Any, ...] = (GRID_VERSION, self.freq_hz, self.profile, self.bottom_m, self.seabed, self.sds,
                                    self.rds, self.rrs)
        if self.bty is not None:                 # a flat bottom's key is the one grids had before .bty files
            content += (self.bty,)
        return hashlib.sha256(repr(content).encode()).hexdigest()[:32]


def depth_job(program: str, spec: GridSpec, sd: float, timeout: float
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """One source depth of a grid (a worker's job, in any process): Bellhop's TL run ('I') and arrivals run
    ('A'); TL, first arrival, delay spread, late fractions over (receiver depth, range), and its seconds."""
    t0 = time.perf_counter()
    if not os.access(program, os.X_OK):          # a cluster worker on another machine: its own Bellhop
        program = find_program() or program
    bty = bty_text(spec.bty) if spec.bty is not None else None
    out = []
    for run, want in (("I", "shd"), ("A", "arr")):
        with tempfile.TemporaryDirectory(prefix="uwsimnet-bellhop-") as d:
            env = env_text(spec.freq_hz, spec.profile, spec.bottom_m, spec.seabed, [sd], spec.rds, spec.rrs, run,
                           bty=bty is not None)
            out.append(run_bellhop(program, env, want, d, timeout, bty))
    _, _, _, p = read_shd(out[0])
    with np.errstate(divide="ignore"):
        tl = -20.0 * np.log10(np.abs(p[0]))
    first, spread, late = read_arrivals(out[1].decode())
    return tl, first[0], spread[0], late[0], time.perf_counter() - t0


_EXECUTOR: list[Executor] = []


@contextmanager
def grid_executor(executor: Executor) -> Iterator[None]:
    """Grids computed inside this block run their source depths on `executor` (a campaign's process pool, or a
    Dask client's `get_executor()`), not on a pool of their own."""
    _EXECUTOR.append(executor)
    try:
        yield
    finally:
        _EXECUTOR.pop()


def compute_grids(program: str, specs: list[GridSpec], workers: int = 2, timeout: float = 3600.0) -> list[Grid]:
    """The grids of `specs` from Bellhop, one job per (grid, source depth): on the executor of `grid_executor`
    if one is set (processes, a Dask cluster), else on `workers` threads when there is more than one job, each
    running its Bellhop as a process, else here.  A line on stderr
    per job done (`bellhop: grid 3/8 source depth 20 m at 26 kHz ... 1.3 s`); the result does not depend on
    where or in what order the jobs ran."""
    tasks = [(g, s) for g, spec in enumerate(specs) for s in range(len(spec.sds))]
    parts: dict[tuple[int, int], tuple[np.ndarray, ...]] = {}

    def done(n: int, key: tuple[int, int], part: tuple[Any, ...]) -> None:
        parts[key] = part[:4]
        spec = specs[key[0]]
        sys.stderr.write(f"bellhop: grid {n}/{len(tasks)} source depth {spec.sds[key[1]]:g} m at"
                         f" {spec.freq_hz / 1e3:g} kHz{spec.label} ... {part[4]:.1f} s\n")
        sys.stderr.flush()

    executor = _EXECUTOR[-1] if _EXECUTOR else None
    own = None
    if executor is None and len(tasks) > 1 and workers > 1:
        # threads, each running its job's Bellhop as a process: a process pool would re-import the caller's
        # main module (spawn: a script without the __main__ guard runs again) or fork a process that holds
        # Zenoh's threads; only the reading of the output (~15 % of a job) holds the GIL
        own = executor = ThreadPoolExecutor(max_workers=min(workers, len(tasks)))
    try:
        if executor is None:
            for n, (g, s) in enumerate(tasks, 1):
                done(n, (g, s), depth_job(program, specs[g], specs[g].sds[s], timeout))
        else:
            futs = {executor.submit(depth_job, program, specs[g], specs[g].sds[s], timeout): (g, s)
                    for g, s in tasks}
            try:
                for n, f in enumerate(as_completed(futs), 1):
                    done(n, futs[f], f.result())
            except BrokenExecutor as e:
                raise ValueError(f"a Bellhop worker died ({e})") from None
            finally:
                for f in futs:
                    f.cancel()
    finally:
        if own is not None:
            own.shutdown(wait=True, cancel_futures=True)
    return [Grid(np.array(spec.sds), np.array(spec.rds), np.array(spec.rrs),
                 *(np.stack([parts[(g, s)][n] for s in range(len(spec.sds))]) for n in range(4)))
            for g, spec in enumerate(specs)]


def compute_grid(program: str, freq_hz: float, profile: list[tuple[float, float]], bottom_m: float,
                 seabed: tuple[float, float, float], sds: list[float], rds: list[float], rrs_m: list[float],
                 workers: int = 2, timeout: float = 3600.0) -> Grid:
    """One range-independent grid (`compute_grids` of one spec)."""
    return compute_grids(program, [GridSpec(freq_hz, profile, bottom_m, seabed, sds, rds, rrs_m)], workers,
                         timeout)[0]


def cache_dir() -> Path:
    return Path(os.environ.get("UWSIMNET_CACHE") or Path.home() / ".cache" / "uwsimnet") / "bellhop"


