"""The channel model "bellhop" (docs/ocean.md): ray-traced transmission loss and first arrivals from Bellhop
(Porter's Acoustics Toolbox; GPL-3, so it is run as a program and never imported or shipped), computed once on
a grid per (environment, frequency, source depths), cached on disk by content hash and Bellhop build
(`program_tag`), interpolated per frame.

Per receiver: horizontal range r and the two depths -> TL (incoherent, Bellhop run type 'I') and the first
significant arrival (run type 'A': the earliest arrival within 20 dB of the strongest) by trilinear
interpolation in (source depth, receiver depth, range); then, with the device's acoustic mode (its
`AcousticLink`: SL, NL, DI, B/R, modulation), Eb/N0 = SL - TL - NL + DI + 10 log10(B/R) - implementation loss,
BER by the modulation, PER = 1 - (1 - BER)^(8 L).  Delay spread as a loss, opt-in (`<isi>on</isi>`: off by
default, since the modems users run equalise or spread their symbols and would otherwise look far worse than at
sea):
the fraction f of the arrivals' energy that comes more than one bit after the first arrival is interference,
SINR = (1 - f) SNR / (1 + f SNR), and Eb/N0 = SINR B/R (less the implementation loss).  The arrival is the
delay, taken where a moving receiver is when the sound reaches it (the grid's delay field solved for the
receiver's constant velocity); the Doppler factor as the `ocean` model's, with the profile's mean speed.
A receiver with no arrival, or beyond the grid, loses the frame.  The environment is range-independent
here: the depth below the origin.
The grid's source depths are `sources` (or every `sourceStep` m); a sender far from all of them whose receiver
is nearer one swaps the two ends (reciprocity: the same TL and travel time both ways).

The grid is computed when the network is built (never per frame): the one place below the sans-IO line that
starts a program, and only when the cache has no grid for this content.
"""

from __future__ import annotations

import hashlib
import logging
import math
import os
import re
import shutil
import struct
import subprocess
import tempfile
from bisect import bisect_right
from concurrent.futures import ThreadPoolExecutor
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from .acoustic import _BER_SCALAR, MODULATIONS, AcousticLink
from .models import Answer, ChannelModel, ModelContext, Query
from .ocean import doppler_factor

log = logging.getLogger("uwsimnet.bellhop")
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
             sds: list[float], rds: list[float], rrs_m: list[float], run: str, beams: int = 0) -> str:
    """A Bellhop .env: one fluid layer (C-linear profile, vacuum surface, Thorp volume attenuation) over an
    acousto-elastic half-space (sound speed m/s, density g/cm^3, attenuation dB/wavelength); sources,
    receivers and ranges as given."""
    pts = [(d, c) for d, c in profile if d < bottom_m]
    pts.append((bottom_m, _speed_at(profile, bottom_m)))
    cp, rho, att = seabed
    lines = ["'uwsimnet'", f"{freq_hz:.6f}", "1", "'CVWT'", f"0 0.0 {bottom_m:.6f}"]
    lines += [f"{d:.6f} {c:.6f} /" for d, c in pts]
    lines += ["'A' 0.0", f"{bottom_m:.6f} {cp:.6f} 0.0 {rho:.6f} {att:.6f} /"]
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

    def lookup(self, zs: Any, zr: Any, r: Any) -> tuple[np.ndarray, np.ndarray]:
        """TL and delay at source depths zs, receiver depths zr, ranges r (arrays): nan beyond the ranges."""
        zs, zr, r = (np.atleast_1d(np.asarray(a, dtype=float)) for a in (zs, zr, r))
        out_tl = _trilinear(self.sd, self.rd, self.rr, self.tl, zs, zr, r)
        out_dl = _trilinear(self.sd, self.rd, self.rr, self.delay, zs, zr, r)
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


def run_bellhop(program: str, env: str, want: str, workdir: str, timeout: float = 3600.0) -> bytes:
    """Run Bellhop on one .env text in `workdir`; the bytes of its output file `want` ('shd' or 'arr').
    Every failure is one line (ValueError): the end of Bellhop's .prt, a timeout, a program that cannot run."""
    base = os.path.join(workdir, "run")
    Path(base + ".env").write_text(env)
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


def compute_grid(program: str, freq_hz: float, profile: list[tuple[float, float]], bottom_m: float,
                 seabed: tuple[float, float, float], sds: list[float], rds: list[float], rrs_m: list[float],
                 workers: int = 2, timeout: float = 3600.0) -> Grid:
    """The grid from Bellhop: one TL run ('I') and one arrivals run ('A') per source depth, in parallel
    (`timeout`: seconds per run)."""
    def one(sd: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        with tempfile.TemporaryDirectory(prefix="uwsimnet-bellhop-") as d1, \
                tempfile.TemporaryDirectory(prefix="uwsimnet-bellhop-") as d2:
            shd = run_bellhop(program, env_text(freq_hz, profile, bottom_m, seabed, [sd], rds, rrs_m, "I"), "shd", d1,
                              timeout)
            arr = run_bellhop(program, env_text(freq_hz, profile, bottom_m, seabed, [sd], rds, rrs_m, "A"), "arr", d2,
                              timeout)
        _, _, _, p = read_shd(shd)
        with np.errstate(divide="ignore"):
            tl = -20.0 * np.log10(np.abs(p[0]))
        first, spread, late = read_arrivals(arr.decode())
        return tl, first[0], spread[0], late[0]

    done = [0]

    def counted(sd: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        out = one(sd)
        done[0] += 1                              # progress: one line per source depth (logger uwsimnet.bellhop)
        log.info("bellhop grid: %d/%d source depths (%.1f m done)", done[0], len(sds), sd)
        return out

    log.info("bellhop grid: %d source depths x %d depths x %d ranges at %.0f Hz", len(sds), len(rds), len(rrs_m),
             freq_hz)
    with ThreadPoolExecutor(max_workers=max(1, workers)) as pool:
        parts = list(pool.map(counted, sds))
    return Grid(np.array(sds), np.array(rds), np.array(rrs_m), *(np.stack([p[n] for p in parts]) for n in range(4)))


def cache_dir() -> Path:
    return Path(os.environ.get("UWSIMNET_CACHE") or Path.home() / ".cache" / "uwsimnet") / "bellhop"


class BellhopModel(ChannelModel):
    """Ray-traced acoustics for an AcousticCommsDevice in the scene's <environment> (module docstring)."""

    family = "bellhop"
    params_known = ("program", "workers", "isi", "timeout")
    """Read only when the grid is not cached yet."""

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
        bottom = float(env.seafloor().depth(0.0, 0.0))
        self.profile = env.sound_speed()
        max_range = float(params.get("maxRange", "5000"))
        r_step = float(params.get("rangeStep", "25"))
        z_step = float(params.get("depthStep", "2"))
        z_max = min(float(params.get("maxDepth", str(bottom))), bottom)
        s_step = float(params.get("sourceStep", "5"))
        if not (max_range > 0 and r_step > 0 and z_step > 0 and s_step > 0 and z_max > 0):
            raise ValueError("maxRange, rangeStep, depthStep, maxDepth and sourceStep must be > 0")
        rrs = [float(x) for x in np.arange(r_step, max_range + r_step / 2, r_step)]
        rds = [float(x) for x in np.arange(0.0, z_max + z_step / 2, z_step)]
        rds = sorted({min(max(z, 0.5), bottom - 0.5) for z in rds})
        given = params.get("sources", "").replace(",", " ").split()
        src = [float(x) for x in given] if given else [float(x) for x in np.arange(0.0, z_max + s_step / 2, s_step)]
        sds = sorted({min(max(z, 0.5), bottom - 0.5) for z in src})
        profile = [tuple(p) for p in env.profile]
        seabed = (env.seabed_speed_mps, env.seabed_density, env.seabed_attenuation)
        key = hashlib.sha256(repr((GRID_VERSION, self.freq_hz, profile, bottom, seabed, sds, rds, rrs)).encode())
        where = Path(params.get("cache", "") or cache_dir())
        program = find_program(params.get("program"))       # the cache name is <content>-<program_tag>.npz;
        stem = key.hexdigest()[:32]                          # without the program, any Bellhop's grid serves
        found = sorted(where.glob(f"{stem}*.npz")) if program is None else []     # (untagged: before tags)
        self.path = found[-1] if found else where / f"{stem}-{program_tag(program) if program else 'none'}.npz"
        if self.path.exists():
            self.grid = _load(str(self.path), self.path.stat().st_mtime_ns)
            self._tables()
            return
        if program is None:
            raise ValueError(HOWTO)
        timeout = float(params.get("timeout", "3600"))
        if not timeout > 0:
            raise ValueError("timeout must be > 0 (seconds per Bellhop run)")
        self.grid = compute_grid(program, self.freq_hz, profile, bottom, seabed, sds, rds, rrs,
                                 workers=int(params.get("workers", str(os.cpu_count() or 1))), timeout=timeout)
        where.mkdir(parents=True, exist_ok=True)
        self.grid.save(self.path)
        self._tables()

    _memo_version = -1

    def _tables(self) -> None:
        """The grid as Python lists for the per-frame path (a few receivers: math beats numpy's call cost) and
        as one stacked array for the numpy path; shared by the models of one grid, bit rate and ISI setting."""
        self._axes, self._tl, self._dl, self._late, self._stack = _prepared(self.grid, self.bit_s, self.isi)
        self._memo: dict[tuple[int, int, tuple[int, ...]], Answer] = {}
        self._links: dict[tuple[Any, Any, int], tuple[float, float, float, float]] = {}

    def _point(self, zs: float, zr: float, r: float) -> tuple[float, float, float]:
        """TL, delay and late fraction at one geometry (trilinear, depths held at the grid's ends; nan beyond
        its ranges): the same arithmetic as `Grid.lookup`, on lists."""
        sd, rd, rr = self._axes
        if r < rr[0] or r > rr[-1]:
            return math.nan, math.nan, 0.0
        (i, i1, f), (j, j1, g), (k, k1, h) = _locate(sd, zs), _locate(rd, zr), _locate(rr, r)
        out = []
        for v in (self._tl, self._dl, self._late):
            a, b = v[i], v[i1]
            lo = (1 - g) * ((1 - h) * a[j][k] + h * a[j][k1]) + g * ((1 - h) * a[j1][k] + h * a[j1][k1])
            hi = (1 - g) * ((1 - h) * b[j][k] + h * b[j][k1]) + g * ((1 - h) * b[j1][k] + h * b[j1][k1])
            out.append((1 - f) * lo + f * hi)
        return out[0], out[1], out[2]

    def _at(self, tx: Any, p: Any, zs0: float, off_s: float) -> tuple[float, float, float]:
        """TL, delay, late fraction from the sender `tx` to a receiver at position p."""
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
        sd = self.grid.sd
        zs = np.full(len(p), -tx[2])
        zr = -p[:, 2]
        r = np.hypot(p[:, 0] - tx[0], p[:, 1] - tx[1])
        swap = off_s > np.abs(zr[:, None] - sd).min(axis=1)          # reciprocity, as `_at`
        zs, zr = np.where(swap, zr, zs), np.where(swap, zs, zr)
        v = _trilinear_stack(sd, self.grid.rd, self.grid.rr, self._stack, zs, zr, r)
        v[(r < self.grid.rr[0]) | (r > self.grid.rr[-1])] = (math.nan, math.nan, 0.0)
        return v[:, 0], v[:, 1], v[:, 2]


@lru_cache(maxsize=16)
def _load(path: str, _mtime_ns: int) -> Grid:
    """A cached grid, loaded once per process (every transmitting device of a scene builds its own model of
    the same grid: 257 loads took 1.6 s of a 256-sensor run's start); read-only once loaded."""
    return Grid.load(path)


@lru_cache(maxsize=32)
def _prepared(g: Grid, bit_s: float, isi: bool) -> tuple[Any, list, list, list, np.ndarray]:
    """`BellhopModel._tables` of a grid: axes, TL, delay and late-fraction lists, the stacked array."""
    late = g.late_fraction(np.repeat(g.sd, len(g.rd) * len(g.rr)), np.tile(np.repeat(g.rd, len(g.rr)), len(g.sd)),
                           np.tile(g.rr, len(g.sd) * len(g.rd)), bit_s).reshape(g.tl.shape)
    if not isi:
        late = np.zeros_like(late)
    return ((g.sd.tolist(), g.rd.tolist(), g.rr.tolist()), g.tl.tolist(), g.delay.tolist(), late.tolist(),
            np.stack([g.tl, g.delay, late], axis=-1))


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
                     q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """`_trilinear` of every last-axis column of v at once: (n, v.shape[-1])."""
    (i, f), (j, g), (k, h) = _axis(a0, q0), _axis(a1, q1), _axis(a2, q2)
    i1 = np.minimum(i + 1, len(a0) - 1)
    j1 = np.minimum(j + 1, len(a1) - 1)
    k1 = np.minimum(k + 1, len(a2) - 1)
    out = np.zeros((len(q0), v.shape[-1]))
    for ii, wi in ((i, 1 - f), (i1, f)):
        for jj, wj in ((j, 1 - g), (j1, g)):
            for kk, wk in ((k, 1 - h), (k1, h)):
                out += (wi * wj * wk)[:, None] * v[ii, jj, kk]
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
