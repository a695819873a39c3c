"""Table 1 read under several sustain criteria: the highest sustained rate and the monotonicity check that
the bisection of `experiments.table1.run` relies on."""

from __future__ import annotations

from uwsimnet_zenoh.experiments.table1 import CRITERIA, read_grid


def test_highest_sustained_rate_and_monotonicity():
    rows = [(20, 1.0, 2.0), (22, 0.97, 8.0), (24, 0.96, 31.0), (26, 0.96, 12.0), (28, 0.80, 50.0)]
    assert read_grid(rows, *CRITERIA["default"]) == (26, False)    # 24 fails (p95 31 s), 26 passes again
    assert read_grid(rows, *CRITERIA["loose"]) == (26, True)
    assert read_grid(rows, *CRITERIA["strict"]) == (20, True)      # >= 99 % and p95 <= 10 s
    assert read_grid([(20, 0.5, 1.0)], *CRITERIA["default"]) == (None, True)
    assert read_grid([(20, None, None)], 1.0, float("inf")) == (None, True)
