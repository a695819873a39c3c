"""Interference arithmetic for the channel's SINR mode (capture): pure functions, no state.

The rule (docs/acoustic.md, "Interference and capture"), as ns-3 UanPhyGen's `m_minRxSinrDb`: a frame is
judged by its *minimum* SINR over its reception interval [a, e) at a receiver,

    SINR_min = S / (N + max over t in [a, e) of sum of the powers of the receptions overlapping t)

with S its received power and N the noise power (linear).  The summed interference is piecewise constant
and only rises where an interferer starts, so its maximum is found by evaluating it at each interferer's
start (clipped to a): O(k^2) for k overlapping frames, and k is small.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

__all__ = ["classify", "max_interference", "min_sinr_db"]

Span = tuple[float, float, float]
"""(start, end, power) of one interfering reception at the receiver: times in s, power linear."""


def max_interference(spans: Sequence[Span], a: float) -> float:
    """The largest total power of the intervals in `spans` that overlap at any one instant t >= a.

    Intervals are half-open [start, end): one that ends exactly where another starts does not add to it.
    `spans` must all overlap the reception [a, e) (the caller selects them)."""
    worst = 0.0
    for s0, _, _ in spans:
        t = s0 if s0 > a else a
        tot = 0.0
        for s1, e1, p1 in spans:
            if s1 <= t < e1:
                tot += p1
        if tot > worst:
            worst = tot
    return worst


def min_sinr_db(signal: float, noise: float, spans: Sequence[Span], a: float) -> float:
    """Minimum SINR (dB) over a reception starting at `a` of power `signal`, with `noise` and `spans`."""
    return 10.0 * math.log10(signal / (noise + max_interference(spans, a)))


def classify(u: float, per_snr: float, per_sinr: float, overlap: bool) -> str | None:
    """The fate of a frame from one uniform draw `u` in [0, 1) (one draw per frame and receiver).

    u < PER(SNR)             -> "prop" (noise alone loses it), or "mult" if it overlapped other frames
    PER(SNR) <= u < PER(SINR) -> "col"  (the interference lost it)
    otherwise                -> None   (received; "captured" if it overlapped)
    With no overlap PER(SINR) is PER(SNR), so the outcome is the binary rule's.
    """
    if u < per_snr:
        return "mult" if overlap else "prop"
    if u < per_sinr:
        return "col"
    return None
