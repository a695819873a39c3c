"""Packet loss from a distance-dependent error rate (dccomms' ``rateErrorModel``).

The scene gives an error rate ``r(m)`` of the distance in metres (see ``phy.expr``) and the unit it is a
rate of.  For a frame of ``L`` bytes on air, bit errors being independent::

    bit:    PER = 1 - (1 - r)^(8 L)
    byte:   PER = 1 - (1 - r)^L
    packet: PER = r

computed as ``-expm1(n * log1p(-r))`` so that a tiny rate still gives a loss probability (r = 1e-15,
8 L = 800 gives 8e-13 rather than the 0 that ``1 - (1 - r)**n`` rounds to).

Whatever the expression yields is made a probability first: nan -> 1 (an expression that cannot be
evaluated at this distance, e.g. ``1/(m-3)`` at 3 or ``log(m)`` at 0, loses the frame rather than
silently delivering it), +inf -> 1, -inf -> 0, then clipped to [0, 1].

Cost of ``per(d, 64)`` in microseconds (same machine and method as in ``phy.expr``)::

    model                        d = ndarray[1]   d = ndarray[256]
    "6e-13*m^13.7", bit               8.8               8.8
    "0.01*m", packet                  3.7               5.9
    "1e-4", bit  (constant)           2.0               2.0
    "0"  (constant zero)              0.5               0.6

The bit/byte path is one errstate plus seven small in-place ufunc calls after the expression.  A rate
that is a plain number (the default "0" above all) is read without `phy.expr` and without numpy: a small
run of lossless modems never imports numpy (a third of its start-up).
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from typing import TYPE_CHECKING, Literal

from .models import DistanceModel

if TYPE_CHECKING:
    import numpy as np

    from .expr import Expr

__all__ = ["NO_LOSS", "RateErrorModel", "Unit"]

Unit = Literal["bit", "byte", "packet"]
_BITS_PER_BYTE: dict[str, int] = {"bit": 8, "byte": 1, "packet": 0}
"""Exponent per byte on air; 0 marks a per-packet rate."""


_LITERAL = re.compile(r"[ \t\r\n\f\v]*((?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?)[ \t\r\n\f\v]*")
"""A rate that is one number and nothing else, as phy.expr reads a number (its _NUMBER, its spaces)."""


def _sanitise(r: float) -> float:
    return 1.0 if math.isnan(r) else min(1.0, max(0.0, r))


class RateErrorModel(DistanceModel):
    """An error rate expression of the distance ``m`` plus its unit: gives per-frame loss probabilities.

    Built once per modem and called once per transmitted frame with the distances to every receiver, so
    the per-call path stays in a handful of in-place numpy calls, and a constant rate (notably the
    default ``"0"``) never evaluates anything.  The channel model "expression" (phy.models): a device's
    `rateErrorModel`, the default of a `CustomCommsDevice`.
    """

    __slots__ = ("_expr", "_text", "unit", "lossless", "_per_byte", "_const")

    unit: Unit
    lossless: bool
    """True when the rate is the constant 0: callers may skip drawing random numbers altogether."""

    def __init__(self, expr: str | Expr, unit: Unit) -> None:
        """Compile `expr` (raises ``phy.expr.ExprError``, a ValueError, on bad text) for `unit`."""
        compiled: Expr | None = None
        if isinstance(expr, str):
            text = expr
            lit = _LITERAL.fullmatch(text) if len(text) <= 1000 else None     # phy.expr.MAX_LENGTH
            if lit is not None:
                constant: float | None = float(lit.group(1))     # what phy.expr folds the text to
            else:
                from .expr import compile_expr

                compiled = compile_expr(text)
                constant = compiled.constant
        else:
            from .expr import Expr

            if not isinstance(expr, Expr):
                raise TypeError(f"error expression must be a str or an Expr, not {type(expr).__name__}")
            compiled, text, constant = expr, expr.text, expr.constant
        if unit not in _BITS_PER_BYTE:
            raise ValueError(f"unknown error-rate unit {unit!r} (expected 'bit', 'byte' or 'packet')")
        self._expr = compiled
        self._text = text
        self.unit = unit
        self._per_byte = _BITS_PER_BYTE[unit]
        self._const = None if constant is None else _sanitise(constant)
        self.lossless = self._const == 0.0

    family = "expression"

    def losses(self, distances: Sequence[float], size: int) -> Sequence[float]:
        """The channel's per-frame call; a lossless model answers without numpy (a small run never imports it)."""
        if self.lossless:
            return [0.0] * len(distances)
        return self.per(distances, size)

    @property
    def expr(self) -> Expr:
        """The compiled expression (a plain number is compiled only when asked for)."""
        if self._expr is None:
            from .expr import compile_expr

            self._expr = compile_expr(self._text)
        return self._expr

    def __repr__(self) -> str:
        return f"RateErrorModel({self._text!r}, {self.unit!r})"

    def rate(self, distance_m: np.ndarray | float) -> np.ndarray:
        """The sanitised rate r in [0, 1] at each distance: a new float64 array of the input's shape."""
        import numpy as np

        d = np.asarray(distance_m, dtype=np.float64)
        if self._const is not None:
            return np.full(d.shape, self._const)
        with np.errstate(all="ignore"):
            return self._rate(d)

    def per(self, distance_m: np.ndarray | float, size_bytes: int) -> np.ndarray:
        """Probability that a frame of `size_bytes` bytes on air is lost, at each distance.

        Returns a new float64 array of the shape of `distance_m`, every value in [0, 1].
        """
        if not 0 <= size_bytes < math.inf:
            raise ValueError(f"frame size must be a finite number of bytes >= 0, got {size_bytes!r}")
        import numpy as np

        d = np.asarray(distance_m, dtype=np.float64)
        n = float(self._per_byte * size_bytes)  # a float multiplies an array faster than an int
        c = self._const
        if c is not None:
            if c == 0.0:
                return np.zeros(d.shape)
            if self._per_byte:
                c = 0.0 if n == 0 else 1.0 if c == 1.0 else -math.expm1(n * math.log1p(-c))
            return np.full(d.shape, c)
        with np.errstate(all="ignore"):
            s = self._rate(d)
            if not self._per_byte:
                return s
            if n == 0:  # nothing on air to corrupt (and 0 * log1p(-1) would be nan)
                return np.zeros(d.shape)
            # s <- -expm1(n * log1p(-s)), in place: s is our own fresh array.
            np.negative(s, out=s)
            np.log1p(s, out=s)
            np.multiply(s, n, out=s)
            np.expm1(s, out=s)
            return np.negative(s, out=s)

    def _rate(self, d: np.ndarray) -> np.ndarray:
        """Sanitised rate for a non-constant expression; the caller holds np.errstate(all="ignore")."""
        import numpy as np

        if d.ndim == 0:
            return self._rate(d.reshape(1)).reshape(())
        r = self.expr.unguarded(d)
        # fmin/fmax ignore nan in favour of the other operand: nan -> 1, +inf -> 1, -inf -> 0.
        s = np.fmin(r, 1.0)
        return np.fmax(s, 0.0, out=s)


NO_LOSS = RateErrorModel("0", "packet")
"""Never loses a frame."""
