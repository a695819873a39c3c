"""The per-seed ratio interval and the label a measurement gives a paper's value (docs/paper-*.md)."""

from __future__ import annotations

import math

import pytest

from uwsimnet_zenoh.analysis.intervals import Interval, label, ratio_ci


def test_ratio_interval_is_the_t_interval_of_the_per_seed_ratios():
    num, den = [53.0, 54.2, 50.8, 53.0, 51.9], [26.5, 26.5, 27.1, 26.5, 27.1]     # Table 1, original, RF
    r = [a / b for a, b in zip(num, den, strict=True)]
    m = sum(r) / 5
    s = math.sqrt(sum((x - m) ** 2 for x in r) / 4)
    iv = ratio_ci(num, den)
    assert iv.mean == pytest.approx(m) and iv.half == pytest.approx(2.776 * s / math.sqrt(5))   # t(0.975, 4)
    assert (round(iv.mean, 2), round(iv.half, 2)) == (1.97, 0.09)
    assert label(iv, 62.5 / 27.5) == "not"                     # 2.27 is outside 1.88-2.05


def test_label_needs_an_interval():
    assert label(Interval(5, 1.05, 0.14), 30 / 27.5) == "reproduced"
    assert label(Interval(5, 1.05, 0.14), 1.5) == "not"
    assert label(Interval(1, 0.28, None), 0.0) == "one run"
    with pytest.raises(ValueError):
        ratio_ci([1.0], [1.0, 2.0])
