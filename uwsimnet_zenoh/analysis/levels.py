"""The mean received level per link of a trace (its rx records' `level`, docs/trace-format.md): what
`uwsimnet report` shows below the flows when the trace has levels (the channel model gave them)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

from .read import is_num


@dataclass(frozen=True)
class LinkLevel:
    """One link (channel, transmitting device, receiving device): its rx records with a level, their mean
    (dB, the model's reference: re 1 uPa for the acoustic ones), min and max."""

    ch: Any
    src: str
    dev: str
    received: int
    mean_db: float
    min_db: float
    max_db: float

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


class LevelSums:
    """Sums of the levels of rx records by (ch, src address, receiving device): O(1) per record."""

    def __init__(self) -> None:
        self._by: dict[tuple[Any, int, str], list[float]] = {}     # key -> [n, sum, min, max]

    def add(self, ch: Any, src: int, dev: str, level: Any) -> None:
        """One rx record's level (anything but a finite number, as in a damaged trace, is skipped)."""
        if not is_num(level) or not math.isfinite(level):
            return
        s = self._by.get((ch, src, dev))
        if s is None:
            self._by[(ch, src, dev)] = [1.0, float(level), float(level), float(level)]
        else:
            s[0] += 1.0
            s[1] += level
            s[2] = min(s[2], level)
            s[3] = max(s[3], level)

    def result(self, tx_dev: Any) -> list[LinkLevel]:
        """The links, sorted by (channel, sender, receiver); `tx_dev(ch, src)` names the sender."""
        out = [LinkLevel(ch, tx_dev(ch, src), dev, int(n), round(total / n, 3), lo, hi)
               for (ch, src, dev), (n, total, lo, hi) in self._by.items()]
        return sorted(out, key=lambda x: (str(x.ch), x.src, x.dev))
