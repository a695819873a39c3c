"""The channel model "bellhop" (docs/ocean.md): ray-traced transmission loss and first arrivals from Bellhop
(Porter's Acoustics Toolbox; GPL-3, so it is run as a program and never imported or shipped), computed once on
a grid per (environment, frequency, source depths), cached on disk by content hash and Bellhop build
(`program_tag`), interpolated per frame.

Per receiver: horizontal range r and the two depths -> TL (incoherent, Bellhop run type 'I') and the first
significant arrival (run type 'A': the earliest arrival within 20 dB of the strongest) by trilinear
interpolation in (source depth, receiver depth, range), the arrival along one path where the cell's corners'
are different paths (`same_path`); then, with the device's acoustic mode (its
`AcousticLink`: SL, NL, DI, B/R, modulation), Eb/N0 = SL - TL - NL + DI + 10 log10(B/R) - implementation loss,
BER by the modulation, PER = 1 - (1 - BER)^(8 L).  Delay spread as a loss, opt-in (`<isi>on</isi>`: off by
default, since the modems users run equalise or spread their symbols and would otherwise look far worse than at
sea):
the fraction f of the arrivals' energy that comes more than one bit after the first arrival is interference,
SINR = (1 - f) SNR / (1 + f SNR), and Eb/N0 = SINR B/R (less the implementation loss).  The arrival is the
delay, taken where a moving receiver is when the sound reaches it (the grid's delay field solved for the
receiver's constant velocity); the Doppler factor as the `ocean` model's, with the profile's mean speed.
A receiver with no arrival, or beyond the grid, loses the frame.  A flat bottom is range-independent; a
sloping or gridded one gives a grid per (source cell, bearing sector), each with the bottom along the
sector's centre line (`range_dependent`; docs/ocean.md states the approximation).
The grid's source depths are `sources` (or every `sourceStep` m); a sender far from all of them whose receiver
is nearer one swaps the two ends (reciprocity: the same TL and travel time both ways).

The grids are computed when the network is built (never per frame), by phy/bellhop_grid.py, and only when the
cache has none for this content.
"""

from __future__ import annotations

import math
import os
from bisect import bisect_right
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from .acoustic import _BER_SCALAR, MODULATIONS, AcousticLink
from .bellhop_grid import (
    GRID_VERSION,
    HOWTO,
    LATE_S,
    Grid,
    GridSpec,
    Paths,
    _axis,
    bty_text,
    cache_dir,
    compute_grid,
    compute_grids,
    env_text,
    find_program,
    grid_executor,
    program_tag,
    read_arrivals,
    read_shd,
    reference,
    run_bellhop,
    same_path,
)
from .models import Answer, ChannelModel, ModelContext, Query
from .ocean import doppler_factor

__all__ = ["GRID_VERSION", "HOWTO", "LATE_S", "MANY", "BellhopModel", "Grid", "GridSpec", "bty_text", "cache_dir",
           "compute_grid", "compute_grids", "env_text", "find_program", "grid_executor", "mean_speeds",
           "program_tag", "range_dependent", "read_arrivals", "read_shd", "run_bellhop", "sector_of"]


class BellhopModel(ChannelModel):
    """Ray-traced acoustics for an AcousticCommsDevice in the scene's <environment> (module docstring)."""

    family = "bellhop"
    params_known = ("program", "workers", "isi", "timeout", "sectors", "positionStep")
    """Read only when the grid is not cached yet, or only with a sloping or gridded bottom."""

    def __init__(self, params: Any, ctx: ModelContext) -> None:
        env = ctx.environment
        if env is None:
            raise ValueError("needs an <environment> (sound speed, bathymetry, seabed)")
        base = ctx.builtin("acoustic")
        self.link = base if isinstance(base, AcousticLink) else base.link     # a FixedBerLink's physics
        m = self.link.modem
        self.freq_hz = float(m.carrier_khz) * 1e3
        self.snr_const = self.link.sl_db - self.link.nl_db + self.link.di_db      # SNR = this - TL, dB
        self.to_ebn0 = 10 ** (0.1 * (self.link.bw_gain_db - m.implementation_loss_db))   # B/R / impl. loss
        self.bit_s = 1.0 / float(m.bitrate_bps)
        dev = ctx.device
        self.reach = (float(getattr(dev, "min_distance", 0.0)), float(getattr(dev, "max_distance", math.inf)))
        """The sender's min/maxDistance: the channel drops a receiver outside them (`range`) unasked."""
        isi = params.get("isi", "off")
        if isi not in ("on", "off"):
            raise ValueError(f"isi must be on or off, not {isi!r}")
        self.isi = isi == "on"
        self.ber = _BER_SCALAR[m.modulation]         # BER of linear Eb/N0, on floats
        self.profile = env.sound_speed()
        max_range = float(params.get("maxRange", "5000"))
        r_step = float(params.get("rangeStep", "25"))
        z_step = float(params.get("depthStep", "2"))
        max_depth = params.get("maxDepth")
        s_step = float(params.get("sourceStep", "5"))
        given = [float(x) for x in params.get("sources", "").replace(",", " ").split()]
        if not (max_range > 0 and r_step > 0 and z_step > 0 and s_step > 0 and
                (max_depth is None or float(max_depth) > 0)):
            raise ValueError("maxRange, rangeStep, depthStep, maxDepth and sourceStep must be > 0")
        rrs = [float(x) for x in np.arange(r_step, max_range + r_step / 2, r_step)]
        profile = [tuple(p) for p in env.profile]
        seabed = (env.seabed_speed_mps, env.seabed_density, env.seabed_attenuation)

        def spec(bottom: float, local: float, bty: list[tuple[float, float]] | None = None,
                 label: str = "") -> GridSpec:
            z_max = min(float(max_depth) if max_depth is not None else bottom, bottom)
            rds = sorted({min(max(float(z), 0.5), bottom - 0.5) for z in np.arange(0.0, z_max + z_step / 2, z_step)})
            src = given or [float(x) for x in np.arange(0.0, min(z_max, local) + s_step / 2, s_step)]
            sds = sorted({min(max(z, 0.5), local - 0.5) for z in src})
            return GridSpec(self.freq_hz, profile, bottom, seabed, sds, rds, rrs, bty, label)

        floor = env.seafloor()
        self.cells: list[tuple[float, float]] = []
        self.sectors = 0
        if env.bathymetry == "flat":
            bottom = float(floor.depth(0.0, 0.0))
            specs = [spec(bottom, bottom)]
        else:
            self.sectors, self.cells, specs = range_dependent(params, ctx, floor, max_range, r_step, spec)
        where = Path(params.get("cache", "") or cache_dir())
        program = find_program(params.get("program"))
        paths = [_cached(where, s.key(), program) for s in specs]
        missing = [i for i, p in enumerate(paths) if not p.exists() and p not in paths[:i]]   # each file once
        if missing:
            if program is None:
                raise ValueError(HOWTO)
            timeout = float(params.get("timeout", "3600"))
            if not timeout > 0:
                raise ValueError("timeout must be > 0 (seconds per Bellhop run)")
            grids = compute_grids(program, [specs[i] for i in missing],
                                  workers=int(params.get("workers", str(os.cpu_count() or 1))), timeout=timeout)
            where.mkdir(parents=True, exist_ok=True)
            for i, g in zip(missing, grids, strict=True):
                g.save(paths[i])
        self.paths = paths
        self.path = paths[0]
        self.grid = _load(str(self.path), self.path.stat().st_mtime_ns)
        self._tables()
        self.grids = [_load(str(p), p.stat().st_mtime_ns) for p in paths]
        self._by_sector = [_prepared(g, self.bit_s, self.isi)[:5] for g in self.grids] if self.sectors else []
        cells = [self.grids[c * self.sectors:(c + 1) * self.sectors] for c in range(len(self.cells))]
        self._by_cell = [np.stack([_prepared(g, self.bit_s, self.isi)[5] for g in gs]) for gs in cells]
        self._by_cell_paths = [(np.stack([g.delay for g in gs]), Paths.stack([g.paths() for g in gs]))
                               for gs in cells]

    def grid_for(self, tx: Any, rx: Any) -> Grid:
        """The grid a frame from position tx to position rx reads: the grid of a flat bottom, else that of the
        sender's nearest cell and the receiver's bearing sector."""
        return self.grids[self._which(tx, rx)] if self.sectors else self.grid

    def _which(self, s: Any, p: Any) -> int:
        """Index of the (cell, sector) grid for a sender at s and a receiver at p (range-dependent only)."""
        c = self.cells
        cell = 0 if len(c) == 1 else min(range(len(c)), key=lambda i: (c[i][0] - s[0]) ** 2 + (c[i][1] - s[1]) ** 2)
        return cell * self.sectors + sector_of(p[0] - s[0], p[1] - s[1], self.sectors)

    _memo_version = -1

    def _tables(self) -> None:
        """The grid as Python lists for the per-frame path (a few receivers: math beats numpy's call cost) and
        as one stacked array for the numpy path; shared by the models of one grid, bit rate and ISI setting."""
        self._axes, self._tl, self._dl, self._late, self._paths, self._stack = _prepared(self.grid, self.bit_s,
                                                                                          self.isi)
        self._memo: dict[tuple[int, int, tuple[int, ...]], Answer] = {}
        self._links: dict[tuple[Any, Any, int], tuple[float, float, float, float]] = {}

    def _point(self, zs: float, zr: float, r: float, tables: Any = None) -> tuple[float, float, float]:
        """TL, delay and late fraction at one geometry (trilinear, depths held at the grid's ends; nan beyond
        its ranges; the delay within one path): the same arithmetic as `Grid.lookup`, on lists (`tables`: a
        sector's, else the grid's)."""
        (sd, rd, rr), tl, dl, late, paths = tables or (self._axes, self._tl, self._dl, self._late, self._paths)
        if r < rr[0] or r > rr[-1]:
            return math.nan, math.nan, 0.0
        (i, i1, f), (j, j1, g), (k, k1, h) = _locate(sd, zs), _locate(rd, zr), _locate(rr, r)
        out = []
        for v in (tl, dl, late):
            a, b = v[i], v[i1]
            lo = (1 - g) * ((1 - h) * a[j][k] + h * a[j][k1]) + g * ((1 - h) * a[j1][k] + h * a[j1][k1])
            hi = (1 - g) * ((1 - h) * b[j][k] + h * b[j][k1]) + g * ((1 - h) * b[j1][k] + h * b[j1][k1])
            out.append((1 - f) * lo + f * hi)
        row = paths.row_list[i][j][k]
        if row >= 0:                                            # the first arrival changes path in this cell:
            val = [dl[c0][c1][c2] for c0 in (i, i1) for c1 in (j, j1) for c2 in (k, k1)]    # follow one path
            wt = [w0 * w1 * w2 for w0 in (1 - f, f) for w1 in (1 - g, g) for w2 in (1 - h, h)]
            along = paths.along_list[row][reference(val, wt, paths.bound_list[row])]
            out[1] = sum(w * x for w, x in zip(wt, along, strict=True))
        return out[0], out[1], out[2]

    def _at(self, tx: Any, p: Any, zs0: float, off_s: float) -> tuple[float, float, float]:
        """TL, delay, late fraction from the sender `tx` to a receiver at position p."""
        if self.sectors:                                        # range-dependent: the grid of the sender's
            s = tx.position                                     # nearest cell and the receiver's bearing
            return self._point(zs0, -p[2], math.hypot(p[0] - s[0], p[1] - s[1]), self._by_sector[self._which(s, p)])
        zs, zr = zs0, -p[2]
        if off_s > min(abs(zr - s) for s in self._axes[0]):    # reciprocity: a sender off the grid's source
            zs, zr = zr, zs                                     # depths, to a receiver on one, swaps the ends
        return self._point(zs, zr, math.hypot(p[0] - tx.position[0], p[1] - tx.position[1]))

    def answer(self, q: Query) -> Answer:
        """The grid's answer, kept per transmission's geometry: while no pose changes (a pose table that is
        not `moving`, at the same `version`: the channel has just read it at this frame's time), the same
        sender, frame size and receivers get the same answer, so a still network pays the interpolation once
        per link (bench/bench_user_path.py `--modes half-bellhop`)."""
        poses = q._poses
        if poses is None or poses.moving:
            return self._answer_links(q) if len(q.slots) <= MANY else self._answer_many(q)
        if self._memo_version != poses.version:
            self._memo.clear()
            self._memo_version = poses.version
        key = (q._sender, q.size, tuple(q.slots))
        got = self._memo.get(key)
        if got is None:
            if len(self._memo) >= MEMO:
                self._memo.clear()
            got = self._memo[key] = self._answer_links(q) if len(q.slots) <= MANY else self._answer_many(q)
        return got

    def _answer_links(self, q: Query) -> Answer:
        """A few receivers, on Python floats; a link whose two ends are where (and as fast as) they were at an
        earlier frame of the same size reuses that frame's answer (realtime: still vehicles whose poses keep
        arriving, so the table is `moving` and its version changes at every sample)."""
        links = self._links
        tx = q.sender
        size = q.size
        lo, hi = self.reach                  # out of the sender's reach: the channel drops the receiver
        dist, veh = q.distances, q._vehicles  # (`range`) without reading its answer: no state, no lookup
        rxs = [q._state(veh[s]) if lo <= dist[n] <= hi else None for n, s in enumerate(q.slots)]
        got = [FAR if rx is None else links.get((tx, rx, size)) for rx in rxs]
        if None not in got:
            return Answer(*(list(c) for c in zip(*got, strict=True)))
        ans = self._answer_few(tx, rxs, size)
        if len(links) + len(rxs) > MEMO:
            links.clear()
        for n, rx in enumerate(rxs):
            if rx is not None:
                links[(tx, rx, size)] = (ans.per[n], ans.delay[n], ans.level_db[n], ans.doppler[n])  # type: ignore
        return ans

    def _answer_few(self, tx: Any, rxs: list[Any], size: int) -> Answer:
        """`answer` on Python floats; a receiver None (out of reach) is lost, unread."""
        zs0 = -tx.position[2]
        off_s = min(abs(zs0 - s) for s in self._axes[0])
        tx_moving = tx.velocity != (0.0, 0.0, 0.0)
        rr = self._axes[2]
        r_lo, r_hi = rr[0], rr[-1]
        x0, y0 = tx.position[0], tx.position[1]
        per: list[float] = []
        delays: list[float] = []
        levels: list[float] = []
        dopplers: list[float] = []
        for rx in rxs:
            moving = rx is not None and rx.velocity != (0.0, 0.0, 0.0)
            if rx is None or not (moving or tx_moving) and not r_lo <= math.hypot(
                    rx.position[0] - x0, rx.position[1] - y0) <= r_hi:
                per.append(FAR[0])                    # out of reach, or still ends off the grid's ranges:
                delays.append(FAR[1])                 # lost, what the lookup gives, without it
                levels.append(FAR[2])
                dopplers.append(FAR[3])
                continue
            t, d, f = self._at(tx, rx.position, zs0, off_s)
            at = rx.position
            if moving and math.isfinite(d):           # motion during flight: the arrival where the receiver
                for _ in range(3):                    # is then (fixed point; contraction |v| / c ~ 1e-3)
                    at = tuple(p + v * d for p, v in zip(rx.position, rx.velocity, strict=True))
                    t, d2, f = self._at(tx, at, zs0, off_s)
                    if not math.isfinite(d2) or abs(d2 - d) < 1e-12:
                        d = d2
                        break
                    d = d2
            if moving or tx_moving:
                c = self.profile.mean_speed(max(0.0, zs0), max(0.0, -at[2]))
                dopplers.append(doppler_factor(tx.position, at, tx.velocity, rx.velocity, c))
            else:
                dopplers.append(1.0)                  # both ends still: the formula's value, exactly
            delays.append(d)
            levels.append(self.link.sl_db - t)
            if not math.isfinite(t) or not math.isfinite(d):
                per.append(1.0)
                continue
            snr = 10.0 ** (0.1 * min(self.snr_const - t, 3000.0))
            f = min(max(f, 0.0), 1.0)
            ebn0 = (1.0 - f) * snr / (1.0 + f * snr) * self.to_ebn0     # ISI: energy a bit late is interference
            b = self.ber(ebn0)
            per.append(1.0 if b >= 1.0 else -math.expm1(8.0 * size * math.log1p(-b)))
        return Answer(per, delays, levels, dopplers)

    def _answer_many(self, q: Query) -> Answer:
        """`answer` for many receivers: the same arithmetic on numpy arrays, one trilinear gather of the
        stacked (TL, delay, late fraction) table per pass (numpy's call cost is paid per frame, not per
        receiver); the moving receivers' fixed point and the Doppler factors as in `answer`."""
        sender, rxs = q.sender, q.receivers
        tx, txv = np.array(sender.position, dtype=float), np.array(sender.velocity, dtype=float)
        p = np.array([r.position for r in rxs], dtype=float)
        vel = np.array([r.velocity for r in rxs], dtype=float)
        off_s = float(np.abs(-tx[2] - self.grid.sd).min())
        tl, delay, f = self._at_many(tx, p, off_s)
        at = p.copy()
        active = vel.any(axis=1) & np.isfinite(delay)        # motion during flight, as `answer` (3 passes)
        for _ in range(3):
            idx = np.flatnonzero(active)
            if not len(idx):
                break
            at[idx] = p[idx] + vel[idx] * delay[idx, None]
            tl[idx], d2, f[idx] = self._at_many(tx, at[idx], off_s)
            active[idx[~np.isfinite(d2) | (np.abs(d2 - delay[idx]) < 1e-12)]] = False
            delay[idx] = d2
        if txv.any() or vel.any():
            zs0 = max(0.0, -float(tx[2]))
            c = mean_speeds(self.profile, zs0, np.maximum(0.0, -at[:, 2]))
            d = at - tx
            n = np.sqrt((d * d).sum(axis=1))
            u = d / np.where(n == 0.0, 1.0, n)[:, None]
            doppler = np.where(n == 0.0, 1.0, (c - (vel * u).sum(axis=1)) / (c - (txv * u).sum(axis=1))).tolist()
        else:
            doppler = [1.0] * len(rxs)                        # still water, still ends: exactly 1
        f = np.clip(f, 0.0, 1.0)
        ok = np.isfinite(tl) & np.isfinite(delay)
        with np.errstate(invalid="ignore", over="ignore"):
            snr = 10.0 ** (0.1 * np.minimum(self.snr_const - np.where(ok, tl, 0.0), 3000.0))
            ebn0 = (1.0 - f) * snr / (1.0 + f * snr) * self.to_ebn0     # ISI: energy a bit late is interference
            b = np.minimum(np.asarray(MODULATIONS[self.link.modem.modulation](ebn0), dtype=float), 1.0)
            per = np.where(ok & (b < 1.0), -np.expm1(8.0 * q.size * np.log1p(-np.where(b < 1.0, b, 0.0))), 1.0)
        return Answer(per.tolist(), delay.tolist(), (self.link.sl_db - tl).tolist(), doppler)

    def _at_many(self, tx: np.ndarray, p: np.ndarray, off_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """`_at` for receivers at positions p (n, 3): TL, delay, late fraction (nan, nan, 0 beyond the ranges)."""
        if self.sectors:                # range-dependent: the sender's cell's sectors, stacked: one gather
            r = np.hypot(p[:, 0] - tx[0], p[:, 1] - tx[1])
            c = np.array(self.cells)
            cell = int(np.argmin(((c - tx[:2]) ** 2).sum(axis=1)))      # the first nearest, as `_which`
            step = 2 * math.pi / self.sectors
            k = np.round(np.arctan2(p[:, 1] - tx[1], p[:, 0] - tx[0]) / step).astype(int) % self.sectors
            g = self.grids[cell * self.sectors]
            with np.errstate(invalid="ignore"):          # below the bottom: TL inf, 0 * inf is nan (lost)
                zs = np.full(len(p), -tx[2])
                v = _trilinear_stack(g.sd, g.rd, g.rr, self._by_cell[cell], zs, -p[:, 2], r, lead=k)
                v[:, 1] = same_path(g.sd, g.rd, g.rr, *self._by_cell_paths[cell], zs, -p[:, 2], r, v[:, 1], lead=k)
            v[(r < g.rr[0]) | (r > g.rr[-1])] = (math.nan, math.nan, 0.0)
            return v[:, 0], v[:, 1], v[:, 2]
        sd = self.grid.sd
        zs = np.full(len(p), -tx[2])
        zr = -p[:, 2]
        r = np.hypot(p[:, 0] - tx[0], p[:, 1] - tx[1])
        swap = off_s > np.abs(zr[:, None] - sd).min(axis=1)          # reciprocity, as `_at`
        zs, zr = np.where(swap, zr, zs), np.where(swap, zs, zr)
        v = _trilinear_stack(sd, self.grid.rd, self.grid.rr, self._stack, zs, zr, r)
        v[:, 1] = same_path(sd, self.grid.rd, self.grid.rr, self.grid.delay, self.grid.paths(), zs, zr, r, v[:, 1])
        v[(r < self.grid.rr[0]) | (r > self.grid.rr[-1])] = (math.nan, math.nan, 0.0)
        return v[:, 0], v[:, 1], v[:, 2]


def _cached(where: Path, stem: str, program: str | None) -> Path:
    """The cache file of a grid: <content>-<program_tag>.npz; without the program, any Bellhop's grid serves
    (and an untagged one, from before the tags)."""
    found = sorted(where.glob(f"{stem}*.npz")) if program is None else []
    return found[-1] if found else where / f"{stem}-{program_tag(program) if program else 'none'}.npz"


def sector_of(dx: float, dy: float, sectors: int) -> int:
    """The bearing sector of a horizontal offset (east, north): sector k is centred on the azimuth 360 k / N
    degrees counter-clockwise from east (k = 0: east, N = 8: k = 2 is north)."""
    return round(math.atan2(dy, dx) / (2 * math.pi / sectors)) % sectors


def range_dependent(params: Any, ctx: ModelContext, floor: Any, max_range: float, r_step: float,
                    spec: Any) -> tuple[int, list[tuple[float, float]], list[GridSpec]]:
    """The grids of a sloping or gridded bottom: per source cell (the sender's known positions, its start and
    waypoints, on a `positionStep` m lattice) and bearing sector (`sectors` around it), the bottom along the
    sector's centre line from the cell's centre every rangeStep to past maxRange (a .bty), depths held >= 1 m.
    A cell's grids share their axes (the .env's depth is the deepest point of all its sectors), so that one
    gather answers a frame's receivers in every sector."""
    sectors = int(params.get("sectors", "8"))
    step = float(params.get("positionStep", "250"))
    if not (sectors >= 1 and step > 0):
        raise ValueError("sectors must be >= 1 and positionStep > 0")
    known = getattr(ctx, "positions", ()) or ((0.0, 0.0, 0.0),)
    cells = sorted({(round(p[0] / step) * step, round(p[1] / step) * step) for p in known})
    specs = []
    for cx, cy in cells:
        lines = []
        for k in range(sectors):
            phi = 2 * math.pi * k / sectors
            lines.append([(round(float(r), 6), round(max(1.0, float(floor.depth(cx + r * math.cos(phi),
                                                                                 cy + r * math.sin(phi)))), 6))
                          for r in np.arange(0.0, max_range + 2.5 * r_step, r_step)])   # as the .bty has them
        deepest = max(z for line in lines for _, z in line)     # one depth axis for the cell's sectors
        specs += [spec(deepest, line[0][1], line, f" bearing {360 * k / sectors:g} deg from ({cx:g}, {cy:g})")
                  for k, line in enumerate(lines)]
    return sectors, cells, specs


@lru_cache(maxsize=16)
def _load(path: str, _mtime_ns: int) -> Grid:
    """A cached grid, loaded once per process (every transmitting device of a scene builds its own model of
    the same grid: 257 loads took 1.6 s of a 256-sensor run's start); read-only once loaded."""
    return Grid.load(path)


@lru_cache(maxsize=32)
def _prepared(g: Grid, bit_s: float, isi: bool) -> tuple[Any, list, list, list, Paths, np.ndarray]:
    """`BellhopModel._tables` of a grid: axes, TL, delay and late-fraction lists, where its first arrival
    changes path, the stacked array."""
    late = g.late_fraction(np.repeat(g.sd, len(g.rd) * len(g.rr)), np.tile(np.repeat(g.rd, len(g.rr)), len(g.sd)),
                           np.tile(g.rr, len(g.sd) * len(g.rd)), bit_s).reshape(g.tl.shape)
    if not isi:
        late = np.zeros_like(late)
    return ((g.sd.tolist(), g.rd.tolist(), g.rr.tolist()), g.tl.tolist(), g.delay.tolist(), late.tolist(),
            g.paths(), np.stack([g.tl, g.delay, late], axis=-1))


def mean_speeds(profile: Any, z0: float, z: np.ndarray) -> np.ndarray:
    """`SoundSpeedProfile.mean_speed(z0, z)` for an array of depths z: the harmonic mean of c between z0 and
    each z, (b - a) / (S(b) - S(a)) with S the travel time down from the profile's first depth (c linear
    between the points, held beyond them: the integral of 1/c over a linear piece is ln(c1/c0) / gradient)."""
    ds, cs = np.array(profile.depths, dtype=float), np.array(profile.speeds, dtype=float)
    z = np.asarray(z, dtype=float)
    if len(ds) == 1:
        return np.full(len(z), cs[0])

    def slowness(x: np.ndarray) -> np.ndarray:
        dd, dc = np.diff(ds), np.diff(cs)
        flat = np.abs(dc) < 1e-12
        seg = np.where(flat, dd / cs[:-1], dd * np.log(cs[1:] / cs[:-1]) / np.where(flat, 1.0, dc))
        cum = np.concatenate([[0.0], np.cumsum(seg)])
        xc = np.clip(x, ds[0], ds[-1])
        i = np.clip(np.searchsorted(ds, xc, side="right") - 1, 0, len(ds) - 2)
        c0 = cs[i]
        c1 = c0 + (xc - ds[i]) / dd[i] * dc[i]
        h = xc - ds[i]
        piece = np.where(np.abs(c1 - c0) < 1e-12, h / c0, h * np.log(c1 / c0) / np.where(np.abs(c1 - c0) < 1e-12,
                                                                                         1.0, c1 - c0))
        return cum[i] + piece + np.maximum(x - ds[-1], 0.0) / cs[-1] - np.maximum(ds[0] - x, 0.0) / cs[0]

    a, b = np.minimum(z0, z), np.maximum(z0, z)
    same = b - a < 1e-9
    with np.errstate(invalid="ignore", divide="ignore"):
        out = (b - a) / (slowness(b) - slowness(a))
    return np.where(same, np.interp(a, ds, cs), out)


FAR = (1.0, math.nan, math.nan, 1.0)
"""(PER, delay, level, Doppler) of a receiver out of the sender's reach: lost, never read by the channel."""

MEMO = 4096
"""Answers (and links) a model keeps before it starts again: bounds the memory of a long run whose
vehicles move (each new geometry is a new key)."""

MANY = 24
"""Receivers above which `answer` goes to numpy (bench/bench_bellhop.py: below it, Python floats are faster)."""


def _trilinear_stack(a0: np.ndarray, a1: np.ndarray, a2: np.ndarray, v: np.ndarray, q0: np.ndarray,
                     q1: np.ndarray, q2: np.ndarray, lead: np.ndarray | None = None) -> np.ndarray:
    """`_trilinear` of every last-axis column of v at once: (n, v.shape[-1]); `lead`: each query's index on
    v's first axis (a stack of grids on the same axes)."""
    (i, f), (j, g), (k, h) = _axis(a0, q0), _axis(a1, q1), _axis(a2, q2)
    i1 = np.minimum(i + 1, len(a0) - 1)
    j1 = np.minimum(j + 1, len(a1) - 1)
    k1 = np.minimum(k + 1, len(a2) - 1)
    out = np.zeros((len(q0), v.shape[-1]))
    for ii, wi in ((i, 1 - f), (i1, f)):
        for jj, wj in ((j, 1 - g), (j1, g)):
            for kk, wk in ((k, 1 - h), (k1, h)):
                out += (wi * wj * wk)[:, None] * (v[ii, jj, kk] if lead is None else v[lead, ii, jj, kk])
    return out


def _locate(ax: list[float], q: float) -> tuple[int, int, float]:
    """Cell (i, i + 1) and weight of q on an increasing axis, q held at its ends."""
    n = len(ax)
    if n == 1 or q <= ax[0]:
        return 0, min(1, n - 1), 0.0
    if q >= ax[-1]:
        return n - 2, n - 1, 1.0
    i = bisect_right(ax, q) - 1
    return i, i + 1, (q - ax[i]) / (ax[i + 1] - ax[i])
