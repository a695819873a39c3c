"""The water vocabulary: `<environment>` (origin, sound speed, bathymetry, seabed) and a vehicle's
`<geoPosition>` (docs/ocean.md, docs/scene-format.md)."""

from __future__ import annotations

import math
import os
import re
from typing import TYPE_CHECKING

from .model import Environment
from .xml import XmlReader, _El, _Fields

if TYPE_CHECKING:
    from ..phy.ocean import SoundSpeedProfile

_PAIRS = re.compile(r"[;,\n]")


def _held(table: list[tuple[float, float]], x: float) -> float:
    """A (x, value) table at x: linear between its points, held beyond its ends."""
    if x <= table[0][0]:
        return table[0][1]
    for (x0, v0), (x1, v1) in zip(table, table[1:], strict=False):
        if x <= x1:
            return v0 + (x - x0) / (x1 - x0) * (v1 - v0)
    return table[-1][1]


class EnvironmentVocabulary(XmlReader):
    """Mixin: the environment; sets `self.origin` for the vehicles read after it."""

    origin: tuple[float, float] | None = None

    def environment(self, el: _El) -> Environment:
        from ..phy.ocean import PRESETS, Bathymetry, SoundSpeedProfile

        k = self.kids(el, single=("origin", "preset", "profile", "temperature", "salinity", "equation",
                                  "bathymetry", "seabed"))
        f = _Fields()
        if (e := k.get("origin")) is not None:
            lat, lon = self._numbers(e, 2, "origin", "'latitude longitude' (degrees)")
            if not (-90 < lat < 90 and -180 <= lon <= 180):
                self.fail(e, f"origin: latitude must be within (-90, 90) and longitude within [-180, 180],"
                             f" got {lat:g} {lon:g}")
            f.set("origin", (lat, lon), "origin", e)
            self.origin = (lat, lon)
        given = [t for t in ("preset", "profile", "temperature") if k.get(t) is not None]
        if len(given) > 1:
            self.fail(k.get(given[1]), f"{given[1]}: give one of <preset>, <profile> or <temperature>")
        for tag in ("salinity", "equation"):
            if (e := k.get(tag)) is not None and k.get("temperature") is None:
                self.fail(e, f"{tag}: needs <temperature> (the profile from temperature and salinity)")
        try:
            if (e := k.get("preset")) is not None:
                name = self.choice(e, tuple(PRESETS))
                prof = PRESETS[name][1]
            elif (e := k.get("profile")) is not None:
                prof = SoundSpeedProfile(self._table(e, "profile", "'depth speed' pairs (m, m/s)"), "table")
            elif (e := k.get("temperature")) is not None:
                prof = self._from_ts(e, k.get("salinity"), k.get("equation"), SoundSpeedProfile)
            else:
                prof = PRESETS["isovelocity"][1]
        except ValueError as err:
            self.fail(e, f"{e.tag}: {err}")
        f.values["profile"] = tuple(zip(prof.depths, prof.speeds, strict=True))
        f.values["profile_name"] = prof.name
        if (e := k.get("bathymetry")) is not None:
            self._bathymetry(e, f, Bathymetry)
        if (e := k.get("seabed")) is not None:
            sk = self.kids(e, single=("soundSpeed", "density", "attenuation"))
            for tag, field in (("soundSpeed", "seabed_speed_mps"), ("density", "seabed_density"),
                               ("attenuation", "seabed_attenuation")):
                if (x := sk.get(tag)) is not None:
                    v, raw = self.number(x, f"seabed/{tag}")
                    f.set(field, v, f"seabed/{tag}", x, raw)
        return self.build(Environment, el, f)

    def _from_ts(self, e: _El, s_el: _El | None, eq_el: _El | None, profile: type) -> SoundSpeedProfile:
        """The profile from <temperature> and <salinity> (one value, or 'depth salinity' pairs taken at the
        temperature's depths, linear between and held beyond) through <equation>: Mackenzie (1981) or TEOS-10."""
        from ..phy.ocean import teos10_speeds

        temps = self._table(e, "temperature", "'depth temperature' pairs (m, degC)")
        if any(not -2 <= t <= 40 for _, t in temps):
            self.fail(e, "temperature: expected -2 to 40 degC (Mackenzie's domain is -2 to 30)")
        sal = [(0.0, 35.0)]
        if s_el is not None:
            one = self.text(s_el).split()
            sal = [(0.0, self.number(s_el)[0])] if len(one) == 1 else self._table(
                s_el, "salinity", "one salinity or 'depth salinity' pairs (m, practical salinity)")
            if any(b[0] <= a[0] for a, b in zip(sal, sal[1:], strict=False)):
                self.fail(s_el, "salinity: depths must increase")
            if (bad := [v for _, v in sal if not 0 <= v <= 45]):
                self.fail(s_el, f"salinity: expected 0-45 (practical salinity, ~ppt), got {bad[0]:g}")
        equation = self.choice(eq_el, ("mackenzie", "teos10")) if eq_el is not None else "mackenzie"
        pts = [(d, t, _held(sal, d)) for d, t in temps]
        if equation == "mackenzie":
            return profile.from_ts(pts)
        try:
            return profile(teos10_speeds(pts, self.origin), "teos10")
        except ValueError as err:
            self.fail(eq_el, f"equation: {err}")

    def _bathymetry(self, e: _El, f: _Fields, bathymetry: type) -> None:
        words = self.text(e).split()
        kind = words[0] if words else ""
        if kind == "flat" and len(words) == 2:
            f.set("depth_m", self.number(e, "bathymetry", words[1])[0], "bathymetry", e, words[1])
        elif kind == "slope" and len(words) == 4:
            d0, gx, gy = (self.number(e, "bathymetry", w)[0] for w in words[1:])
            f.set("depth_m", d0, "bathymetry", e, words[1])
            f.values["gradient"] = (gx, gy)
        elif kind == "grid" and len(words) == 2:
            path = words[1]
            if not os.path.isabs(path) and self.source not in ("", "<memory>", "<string>"):
                path = os.path.join(os.path.dirname(os.path.abspath(self.source)), path)
            try:
                bathymetry.read_grid(path)
            except (OSError, ValueError) as err:
                self.fail(e, f"bathymetry: {err}")
            f.values["grid_file"] = path
        else:
            self.fail(e, f"bathymetry: expected 'flat DEPTH', 'slope DEPTH DX DY' or 'grid FILE', got"
                         f" {self.text(e)!r}")
        f.values["bathymetry"] = kind

    def geo_position(self, el: _El) -> tuple[float, float, float]:
        """`<geoPosition>latitude longitude depth</geoPosition>` in the local frame of the origin."""
        from ..phy.ocean import geodetic_to_enu

        lat, lon, depth = self._numbers(el, 3, "geoPosition", "'latitude longitude depth' (degrees, m)")
        if self.origin is None:
            self.fail(el, "geoPosition: needs <environment><origin>")
        if not (-90 < lat < 90 and -180 <= lon <= 180 and depth >= 0):
            self.fail(el, f"geoPosition: latitude within (-90, 90), longitude within [-180, 180] and depth >= 0"
                          f" expected, got {lat:g} {lon:g} {depth:g}")
        return geodetic_to_enu(lat, lon, depth, *self.origin)

    def _numbers(self, el: _El, n: int, label: str, what: str) -> list[float]:
        parts = self.text(el).replace(",", " ").split()
        if len(parts) != n:
            self.fail(el, f"{label}: expected {what}, got {self.text(el)!r}")
        return [self.number(el, label, p)[0] for p in parts]

    def _table(self, el: _El, label: str, what: str) -> list[tuple[float, float]]:
        rows = []
        for chunk in _PAIRS.split(self.text(el)):
            if not chunk.strip():
                continue
            a, b = self._pair(el, chunk, label, what)
            rows.append((a, b))
        if not rows:
            self.fail(el, f"{label}: expected {what}")
        return rows

    def _pair(self, el: _El, chunk: str, label: str, what: str) -> tuple[float, float]:
        parts = chunk.split()
        if len(parts) != 2:
            self.fail(el, f"{label}: expected {what} separated by ',' ';' or new lines, got {chunk.strip()!r}")
        a, b = (self.number(el, label, p)[0] for p in parts)
        if not (math.isfinite(a) and math.isfinite(b)):
            self.fail(el, f"{label}: finite numbers expected")
        return a, b
