"""What a receiver got of a frame besides the frame: the `rx` a modem hands its MAC (`MacHooks.on_rx(frame,
rx)`), the MAC hands back (`ctx.deliver(frame, rx)`) and the rx event carries (trace.tracer: its `dist`).

`rx` is a float, the distance (m) between the sender at the first bit and the receiver, whatever the channel
model.  When the model said more (phy.models.Answer: a Doppler factor, a received level) it is an `Rx`, a
float of the same value with those details as attributes; a distance-only model's reception stays a plain
float, so the built-in models' per-frame path makes no object.  Being a float, it goes wherever the distance
went (the wire, the trace's `dist`, a listener's arithmetic) unchanged.  Read the details with `doppler(rx)`
and `level_db(rx)` (None when the model gave none).  Not compiled: mypyc would unbox it to a double.
"""

from __future__ import annotations

from typing import Any


class Rx(float):
    """A reception's distance (m; its value) with the channel model's details: `doppler`, the Doppler factor
    f_received / f_sent (> 1 when the ends close in, docs/ocean.md), and `level_db`, the received level (dB),
    each None when the model did not give it.  Immutable, as a float."""

    __slots__ = ("_doppler", "_level_db")

    def __new__(cls, distance: float, doppler: float | None = None, level_db: float | None = None) -> Rx:
        self = super().__new__(cls, distance)
        object.__setattr__(self, "_doppler", doppler)
        object.__setattr__(self, "_level_db", level_db)
        return self

    @property
    def distance(self) -> float:
        return float(self)

    @property
    def doppler(self) -> float | None:
        return self._doppler

    @property
    def level_db(self) -> float | None:
        return self._level_db

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError(f"an Rx is immutable ({name})")

    def __repr__(self) -> str:
        return f"Rx({float(self)!r}, doppler={self._doppler!r}, level_db={self._level_db!r})"

    def __reduce__(self) -> tuple[Any, ...]:
        return (Rx, (float(self), self._doppler, self._level_db))


def doppler(rx: Any) -> float | None:
    """The Doppler factor of a reception (`rx` as the modem hands it), or None if the model gave none."""
    return rx._doppler if type(rx) is Rx else None


def level_db(rx: Any) -> float | None:
    """The received level (dB) of a reception, or None if the model gave none."""
    return rx._level_db if type(rx) is Rx else None


def with_details(distance: float, doppler: float | None, level_db: float | None) -> Any:
    """The reception the channel hands on: an `Rx` if the model gave a detail (not None nor nan), else the
    plain distance."""
    if doppler is not None and doppler != doppler:
        doppler = None
    if level_db is not None and level_db != level_db:
        level_db = None
    if doppler is None and level_db is None:
        return distance
    return Rx(distance, doppler, level_db)
