"""Traffic sources that behave like applications: they hand frames to a modem, periodically or as a
Poisson process, between `start` and `stop`.  Each flow draws from its own random stream, so two runs
that differ only in the MAC see exactly the same offered traffic (common random numbers)."""

from __future__ import annotations

import math
import random
from collections.abc import Callable
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ..kernel.scheduler import Scheduler
    from ..phy.modem import Modem
    from ..scene.model import Flow


class FlowSource:
    def __init__(self, spec: Flow, modem: Modem, sched: Scheduler, seed: int, end: float) -> None:
        self.spec = spec
        self.modem = modem
        self.sched = sched
        self.stop = min(end, spec.stop) if spec.stop is not None else end
        self._dst, self._size, self._name = spec.dst, spec.size, spec.name     # read per frame
        self._periodic = spec.arrival == "periodic"
        self._random = random.Random(seed).random
        self._fire_at: Callable[[], None] = self._fire          # bound once (not a lookup per frame)
        self._rate = 1.0 / spec.interval if spec.arrival == "poisson" else 0.0
        first = spec.start + self._gap() if self._rate else spec.start
        self.sent = 0
        if first < self.stop:
            sched.at(first, self._fire_at)

    def _gap(self) -> float:
        """The next Poisson gap: `random.expovariate(rate)`'s own formula (the same doubles), computed
        here rather than through the stdlib's Python method."""
        return -math.log(1.0 - self._random()) / self._rate

    def _fire(self) -> None:
        if self.sched.now >= self.stop:      # stopped early (its modem was removed)
            return
        self.modem.send(self._dst, self._size, flow=self._name)
        self.sent += 1
        if self._periodic:                      # no drift from repeated float additions
            spec = self.spec
            nxt = spec.start + self.sent * spec.interval
        else:                                   # poisson
            nxt = self.sched.now + self._gap()
        if nxt < self.stop:
            self.sched.at(nxt, self._fire_at)
