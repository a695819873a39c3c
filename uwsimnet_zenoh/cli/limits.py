"""Ranges of the numbers the command line takes (one-line errors, exit 2; NaN and infinities refused)."""

from __future__ import annotations

import argparse
import math

from ..errors import UserError

DURATION_MAX = 1e9
"""s: the longest `--duration` (about 32 years of simulated time; finite, so every time in the trace is)."""
SPEED_RANGE = (1e-3, 1e4)
"""`--speed` bounds: simulated seconds per wall second."""
REALTIME_ONLY = ("listen", "connect", "zenoh_config", "channels", "external_flows", "speed", "world")


def check_numbers(args: argparse.Namespace) -> None:
    """--duration and --speed in range, one line each (NaN and infinities refused)."""
    d = args.duration
    if d is not None and not (math.isfinite(d) and 0 < d <= DURATION_MAX):
        raise UserError(f"--duration {d:g}: must be a number of seconds > 0 and <= {DURATION_MAX:g}"
                        " (omit it for the scene's duration, or Ctrl-C in real time)")
    s = args.speed
    lo, hi = SPEED_RANGE
    if s is not None and not (math.isfinite(s) and lo <= s <= hi):
        raise UserError(f"--speed {s:g}: must be a number from {lo:g} to {hi:g} (simulated seconds per wall"
                        " second)")
