"""Confidence intervals for results over seeds: Student's t for means, Wilson for proportions.

No scipy: the two-sided 95 % quantiles of Student's t are tabulated (df 1-30, then 40, 60, 120; 1.96 past
that), which is all a campaign of a few to a few hundred seeds needs.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

_T975 = {1: 12.706, 2: 4.303, 3: 3.182, 4: 2.776, 5: 2.571, 6: 2.447, 7: 2.365, 8: 2.306, 9: 2.262, 10: 2.228,
         11: 2.201, 12: 2.179, 13: 2.160, 14: 2.145, 15: 2.131, 16: 2.120, 17: 2.110, 18: 2.101, 19: 2.093,
         20: 2.086, 21: 2.080, 22: 2.074, 23: 2.069, 24: 2.064, 25: 2.060, 26: 2.056, 27: 2.052, 28: 2.048,
         29: 2.045, 30: 2.042, 40: 2.021, 60: 2.000, 120: 1.980}


def t975(df: int) -> float:
    """The 0.975 quantile of Student's t with `df` degrees of freedom (the next tabulated df below)."""
    if df < 1:
        raise ValueError("df must be >= 1")
    if df in _T975:
        return _T975[df]
    below = [d for d in _T975 if d <= df]
    return 1.96 if df > 120 else _T975[max(below)]


@dataclass(frozen=True)
class Interval:
    n: int
    mean: float
    half: float | None
    """Half-width of the 95 % interval (None with a single value)."""

    @property
    def low(self) -> float | None:
        return None if self.half is None else self.mean - self.half

    @property
    def high(self) -> float | None:
        return None if self.half is None else self.mean + self.half

    def text(self, digits: int = 3) -> str:
        if self.half is None:
            return f"{self.mean:.{digits}g}"
        if self.half <= 1e-9 * max(1.0, abs(self.mean)):          # identical over seeds (rounding noise)
            return f"{self.mean:.{digits}g} ± 0"
        return f"{self.mean:.{digits}g} ± {self.half:.2g}"


def mean_ci(values: Sequence[float]) -> Interval | None:
    """Mean and 95 % t interval of the finite values (None if there are none)."""
    xs = [float(v) for v in values if v is not None and math.isfinite(float(v))]
    if not xs:
        return None
    n = len(xs)
    mean = math.fsum(xs) / n
    if n == 1:
        return Interval(1, mean, None)
    var = math.fsum((x - mean) ** 2 for x in xs) / (n - 1)
    return Interval(n, mean, t975(n - 1) * math.sqrt(var / n))


def wilson(successes: int, trials: int, z: float = 1.96) -> tuple[float, float]:
    """Wilson score interval of a proportion (used for packet error rates per distance bin)."""
    if trials <= 0:
        raise ValueError("trials must be > 0")
    p = successes / trials
    den = 1 + z * z / trials
    centre = (p + z * z / (2 * trials)) / den
    half = z * math.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials)) / den
    return max(0.0, centre - half), min(1.0, centre + half)


def ratio_ci(num: Sequence[float], den: Sequence[float]) -> Interval | None:
    """The 95 % t interval of a ratio measured per seed (num[i] / den[i], paired: the same seed's runs)."""
    if len(num) != len(den):
        raise ValueError("ratio_ci: one value per seed on both sides")
    return mean_ci([a / b for a, b in zip(num, den, strict=True) if b])


def label(iv: Interval, paper: float) -> str:
    """What a measurement over seeds says of the paper's value: `reproduced` when its interval holds the value,
    `not` when it excludes it; a single run (no interval) says nothing (`one run`)."""
    if iv.half is None:
        return "one run"
    assert iv.low is not None and iv.high is not None
    return "reproduced" if iv.low <= paper <= iv.high else "not"
