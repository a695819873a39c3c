"""The water of a scene (docs/ocean.md): WGS-84 placement, sound-speed profiles and their presets,
bathymetry, and a moving link's arrival and Doppler factor.  Pure functions and small value classes; no I/O
but the bathymetry grid file the scene names.

Coordinates: the scene's local frame is ENU (x east, y north, z up, m) on the tangent plane at the scene's
origin; depth = -z.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from collections.abc import Sequence

__all__ = ["GSW_HOWTO", "PRESETS", "WGS84_A", "WGS84_F", "Bathymetry", "SoundSpeedProfile", "doppler_factor",
           "geodetic_to_enu", "intercept_delay", "munk_profile", "teos10_speeds"]

WGS84_A = 6_378_137.0
"""WGS-84 semi-major axis, m (NIMA TR8350.2)."""
WGS84_F = 1 / 298.257223563
"""WGS-84 flattening."""
_E2 = WGS84_F * (2 - WGS84_F)


def _ecef(lat_deg: float, lon_deg: float, h: float) -> tuple[float, float, float]:
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    n = WGS84_A / math.sqrt(1 - _E2 * math.sin(lat) ** 2)
    return ((n + h) * math.cos(lat) * math.cos(lon), (n + h) * math.cos(lat) * math.sin(lon),
            (n * (1 - _E2) + h) * math.sin(lat))


def geodetic_to_enu(lat_deg: float, lon_deg: float, depth_m: float, lat0_deg: float, lon0_deg: float
                    ) -> tuple[float, float, float]:
    """A point given in latitude, longitude (degrees, WGS-84) and depth (m below the ellipsoid) in the local
    frame at the origin (lat0, lon0): (east, north) of its surface point through ECEF, exactly, and
    z = -depth (the drop of the tangent plane, d^2 / 2R = 7.8 m at 10 km, is left out: depth stays depth)."""
    x, y, z = _ecef(lat_deg, lon_deg, 0.0)
    x0, y0, z0 = _ecef(lat0_deg, lon0_deg, 0.0)
    dx, dy, dz = x - x0, y - y0, z - z0
    la, lo = math.radians(lat0_deg), math.radians(lon0_deg)
    east = -math.sin(lo) * dx + math.cos(lo) * dy
    north = -math.sin(la) * math.cos(lo) * dx - math.sin(la) * math.sin(lo) * dy + math.cos(la) * dz
    return (east, north, -float(depth_m))


class SoundSpeedProfile:
    """c(depth), m/s: linear between the table's (depth m, speed m/s) points, held beyond its ends."""

    __slots__ = ("depths", "speeds", "name")

    def __init__(self, points: Sequence[tuple[float, float]], name: str = "table") -> None:
        pts = [(float(d), float(c)) for d, c in points]
        if len(pts) < 1:
            raise ValueError("a sound-speed profile needs at least one (depth, speed) point")
        if any(not (math.isfinite(d) and math.isfinite(c)) for d, c in pts):
            raise ValueError("sound-speed profile values must be finite numbers")
        if any(b[0] <= a[0] for a, b in zip(pts, pts[1:], strict=False)):
            raise ValueError("sound-speed profile depths must increase")
        if pts[0][0] < 0:
            raise ValueError(f"sound-speed profile depth {pts[0][0]:g} m is above the surface")
        if any(not 1300.0 <= c <= 1800.0 for _, c in pts):
            raise ValueError("sound speeds must be within 1300-1800 m/s (sea water)")
        self.depths = [d for d, _ in pts]
        self.speeds = [c for _, c in pts]
        self.name = name

    def __call__(self, depth_m: float) -> float:
        ds, cs = self.depths, self.speeds
        if depth_m <= ds[0]:
            return cs[0]
        if depth_m >= ds[-1]:
            return cs[-1]
        i = bisect_right(ds, depth_m) - 1
        f = (depth_m - ds[i]) / (ds[i + 1] - ds[i])
        return cs[i] + f * (cs[i + 1] - cs[i])

    def mean_speed(self, z1: float, z2: float) -> float:
        """Harmonic mean of c between depths z1 and z2 (the speed of a straight vertical-ish path): the
        time to cross the layers divided into the distance; c(z1) when z1 == z2."""
        a, b = sorted((float(z1), float(z2)))
        if b - a < 1e-9:
            return self(a)
        cuts = [a] + [d for d in self.depths if a < d < b] + [b]
        slowness = 0.0
        for lo, hi in zip(cuts, cuts[1:], strict=False):
            c0, c1 = self(lo), self(hi)     # linear c: integral of 1/c is ln(c1/c0)/gradient
            slowness += (hi - lo) / c0 if abs(c1 - c0) < 1e-12 else (hi - lo) * math.log(c1 / c0) / (c1 - c0)
        return (b - a) / slowness

    @classmethod
    def from_ts(cls, points: Sequence[tuple[float, float, float]], name: str = "mackenzie") -> SoundSpeedProfile:
        """From (depth m, temperature degC, salinity ppt) points through Mackenzie (1981)."""
        return cls([(d, _mackenzie(t, s, d)) for d, t, s in points], name)


GSW_HOWTO = ("TEOS-10 needs the gsw package (the Gibbs SeaWater toolbox): pip install 'uwsimnet-zenoh[teos10]'"
             " (or pip install gsw)")


def teos10_speeds(points: Sequence[tuple[float, float, float]], origin: tuple[float, float] | None
                  ) -> list[tuple[float, float]]:
    """(depth m, speed m/s) from (depth m, in-situ temperature degC ITS-90, Practical Salinity) points through
    TEOS-10 (IOC, SCOR & IAPSO 2010) with the `gsw` package: sea pressure from depth at the origin's latitude
    (gsw.p_from_z), Absolute Salinity from Practical Salinity with the atlas' anomaly at the origin
    (gsw.SA_from_SP), then the sound speed from the Gibbs function itself (gsw.sound_speed_t_exact: in-situ
    temperature, no fitted polynomial).  Without an origin: latitude 45 deg and Reference Salinity
    (gsw.SR_from_SP, the anomaly left out: at most a few hundredths of a g/kg, a few cm/s).
    ValueError(GSW_HOWTO) when gsw is not installed."""
    try:
        import gsw  # noqa: PLC0415 - optional extra, only for scenes that ask for TEOS-10
    except ImportError:
        raise ValueError(GSW_HOWTO) from None
    ds = [float(d) for d, _, _ in points]
    ts = [float(t) for _, t, _ in points]
    sp = [float(s) for _, _, s in points]
    lat, lon = origin if origin is not None else (45.0, 0.0)
    p = gsw.p_from_z([-d for d in ds], lat)
    sa = gsw.SA_from_SP(sp, p, lon, lat) if origin is not None else gsw.SR_from_SP(sp)
    cs = gsw.sound_speed_t_exact(sa, ts, p)
    return [(d, float(c)) for d, c in zip(ds, cs, strict=True)]


def _mackenzie(t: float, s: float, d: float) -> float:
    """Mackenzie (1981), JASA 70:807, nine terms (as phy.acoustic.sound_speed_mackenzie, for scalars)."""
    ds = s - 35.0
    return (1448.96 + t * (4.591 + t * (-5.304e-2 + t * 2.374e-4)) + 1.340 * ds + d * (1.630e-2 + 1.675e-7 * d)
            - 1.025e-2 * t * ds - 7.139e-13 * t * d ** 3)


def munk_profile(step_m: float = 50.0, bottom_m: float = 5000.0) -> SoundSpeedProfile:
    """Munk's canonical deep-ocean profile: c = 1500 (1 + eps (eta - 1 + exp(-eta))), eta = 2 (z - 1300)/1300,
    eps = 0.00737 (W. Munk, "Sound channel in an exponentially stratified ocean", JASA 55:220, 1974; the
    constants of Jensen, Kuperman, Porter & Schmidt, Computational Ocean Acoustics, and of Bellhop's
    MunkB examples), tabulated every `step_m` to `bottom_m`."""
    n = int(round(bottom_m / step_m))
    pts = []
    for i in range(n + 1):
        z = i * step_m
        eta = 2.0 * (z - 1300.0) / 1300.0
        pts.append((z, 1500.0 * (1.0 + 0.00737 * (eta - 1.0 + math.exp(-eta)))))
    return SoundSpeedProfile(pts, "munk")


PRESETS: dict[str, tuple[str, SoundSpeedProfile]] = {
    "isovelocity": ("1500 m/s at every depth: the straight-path model's water.",
                    SoundSpeedProfile([(0.0, 1500.0)], "isovelocity")),
    "summer-thermocline": (
        "Synthetic summer profile (not a measurement): 24 degC at the surface, 22.5 degC at 10 m, a seasonal "
        "thermocline down to 14 degC at 40 m, 13.5 degC at 300 m, salinity 37 ppt (the shape of Western "
        "Mediterranean summer profiles), speeds by Mackenzie (1981): 1534 m/s at the surface, 1507 m/s below "
        "40 m.  Downward refracting from the surface, so a shallow source leaves a shadow zone near the surface "
        "beyond about 700 m; receivers below the layer are reached (docs/ocean.md).",
        SoundSpeedProfile.from_ts([(0.0, 24.0, 37.0), (10.0, 22.5, 37.0), (40.0, 14.0, 37.0),
                                   (300.0, 13.5, 37.0)], "summer-thermocline")),
    "munk": ("Munk (1974) canonical deep-sound-channel profile, axis at 1300 m (see munk_profile).",
             munk_profile()),
}
"""Named sound-speed profiles: (source, profile)."""


class Bathymetry:
    """Water depth (m, positive down) at a horizontal position: flat, a plane slope, or a regular grid
    (bilinear, held at the edges)."""

    __slots__ = ("kind", "depth0", "gx", "gy", "xs", "ys", "table")

    def __init__(self, kind: str = "flat", depth0: float = 100.0, gradient: tuple[float, float] = (0.0, 0.0),
                 grid: tuple[Sequence[float], Sequence[float], Sequence[Sequence[float]]] | None = None) -> None:
        if not depth0 > 0 and kind != "grid":
            raise ValueError(f"bathymetry depth must be > 0 m, got {depth0:g}")
        self.kind = kind
        self.depth0 = float(depth0)
        self.gx, self.gy = (float(gradient[0]), float(gradient[1]))
        self.xs: list[float] = []
        self.ys: list[float] = []
        self.table: list[list[float]] = []
        if grid is not None:
            xs, ys, table = grid
            self.xs, self.ys = [float(x) for x in xs], [float(y) for y in ys]
            self.table = [[float(v) for v in row] for row in table]

    def depth(self, x: float, y: float) -> float:
        if self.kind == "flat":
            return self.depth0
        if self.kind == "slope":
            return max(0.0, self.depth0 + self.gx * x + self.gy * y)
        return _bilinear(self.xs, self.ys, self.table, x, y)

    @classmethod
    def read_grid(cls, path: str) -> Bathymetry:
        """A grid file: lines `x y depth` (m; `#` comments), every (x, y) of a rectilinear grid once."""
        rows: dict[tuple[float, float], float] = {}
        with open(path, encoding="utf-8") as fh:
            for n, line in enumerate(fh, start=1):
                text = line.split("#", 1)[0].split()
                if not text:
                    continue
                try:
                    x, y, d = (float(v) for v in text)
                except ValueError:
                    raise ValueError(f"{path}:{n}: expected 'x y depth', got {line.strip()!r}") from None
                if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(d) and d > 0):
                    raise ValueError(f"{path}:{n}: finite x, y and a depth > 0 expected")
                rows[(x, y)] = d
        xs, ys = sorted({x for x, _ in rows}), sorted({y for _, y in rows})
        if len(xs) < 2 or len(ys) < 2 or len(rows) != len(xs) * len(ys):
            raise ValueError(f"{path}: not a full rectilinear grid ({len(rows)} points, {len(xs)} x {len(ys)})")
        return cls("grid", grid=(xs, ys, [[rows[(x, y)] for y in ys] for x in xs]))


def _bilinear(xs: list[float], ys: list[float], t: list[list[float]], x: float, y: float) -> float:
    def locate(v: list[float], q: float) -> tuple[int, float]:
        q = min(max(q, v[0]), v[-1])
        i = min(bisect_right(v, q) - 1, len(v) - 2)
        return i, (q - v[i]) / (v[i + 1] - v[i])

    i, fx = locate(xs, x)
    j, fy = locate(ys, y)
    return ((1 - fx) * (1 - fy) * t[i][j] + fx * (1 - fy) * t[i + 1][j] + (1 - fx) * fy * t[i][j + 1]
            + fx * fy * t[i + 1][j + 1])


# --------------------------------------------------------------------------------------------------
# Motion during flight
# --------------------------------------------------------------------------------------------------
def intercept_delay(sender: Sequence[float], receiver: Sequence[float], rx_velocity: Sequence[float],
                    c: float) -> float:
    """Time tau for a wavefront leaving `sender` (its position at the first bit) at speed c to reach a
    receiver at `receiver` + rx_velocity * tau (constant velocity): the positive root of
    |D + v tau| = c tau, D = receiver - sender.  Closed form (|v| < c):
        tau = (D.v + sqrt((D.v)^2 + (c^2 - v.v) D.D)) / (c^2 - v.v)."""
    d = [float(r) - float(s) for r, s in zip(receiver, sender, strict=True)]
    v = [float(a) for a in rx_velocity]
    dv = d[0] * v[0] + d[1] * v[1] + d[2] * v[2]
    dd = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
    a = c * c - (v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    if not a > 0:
        raise ValueError("a receiver as fast as sound: no arrival")
    return (dv + math.sqrt(dv * dv + a * dd)) / a


def doppler_factor(sender: Sequence[float], receiver_at_arrival: Sequence[float], tx_velocity: Sequence[float],
                   rx_velocity: Sequence[float], c: float) -> float:
    """f_received / f_sent for a source and a receiver moving in still water (the classical formula):
        (c - v_r . u) / (c - v_s . u),  u = unit vector from the source at emission to the receiver at
    reception.  > 1 when they close in, < 1 when they part; 1 when the path is zero."""
    d = [float(r) - float(s) for r, s in zip(receiver_at_arrival, sender, strict=True)]
    n = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    if n == 0.0:
        return 1.0
    u = [x / n for x in d]
    vr = sum(a * b for a, b in zip(rx_velocity, u, strict=True))
    vs = sum(a * b for a, b in zip(tx_velocity, u, strict=True))
    return (c - vr) / (c - vs)
