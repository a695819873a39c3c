"""The tracer: where the core tells every frame's life (`enq`, `tx`, `rx`, `drop`; docs/trace-format.md),
and the batches its consumers take.  A module of its own, compiled with the engine when `make` can
(uwsimnet_zenoh/_native.py): the engine calls `emit` several times a frame.  The sinks that write traces
are in trace/events.py.

The tracer has four kinds of listeners:

- *event folds* (`Tracer.fold`, an `EventFold`) are called at once with each event's record fields, natively
  when both are compiled: the online metrics' fold (analysis.fold.Fold, through `Accumulator.follow`);
- *batch consumers* (`Tracer.consume`) get the events in batches (`Batch`: one row tuple per event, its
  time rounded once for all of them), in order, at most `Tracer.batch` events late: the JSONL writer
  (`JsonlSink.write_batch`) and the columnar writer (`ArrowSink.write_batch`).  The tracer appends each
  event once to the shared batch, a consumer does its work per batch (vectorised where it can), so a run
  pays one append per event for all of them.  Whoever
  runs the network calls `Tracer.flush()` when the run ends (app/virtual.py does, on an interrupt and an
  error too);
- *event listeners* (`Tracer.listen`) are called at once with the event's fields, `fn(t, ev, ch, dev,
  frame, reason, fifo, dist, implicit)`, and build nothing;
- *record sinks* (`Tracer.add`) get the event at once as a dict (the documented record); the dict is
  built only when at least one record sink listens (the realtime trace, `netTracingScript` classes).

With none, an untraced run pays for a counter increment and nothing else.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable, Sequence
from typing import Any, Final

from mypy_extensions import mypyc_attr

from ..kernel.frame import Frame

Record = dict[str, Any]
EventListener = Callable[[float, str, int, str, Frame, "str | None", "int | None", "float | None", bool], None]


Row = tuple[Any, ...]
"""One event of a batch: (t, ev, ch, dev, src, dst, seq, size, flow, kind, reason, fifo, dist, implicit) of
types (number, str, int, str, int, int, int, int, str | None, str, str | None, int | None, number | None,
bool), the frame's fields read when the event is emitted; `t` and `dist` as the engine gave them (not
rounded)."""

ROW_FIELDS = ("t", "ev", "ch", "dev", "src", "dst", "seq", "size", "flow", "kind", "reason", "fifo", "dist",
              "implicit")


_EXACT: Final = 4503599627370496.0     # 2**52: below it a double's ulp is at most 1


def rounded(xs: Sequence[Any], ndigits: int) -> list[Any]:
    """`[round(x, ndigits) for x in xs]` (a correctly rounded decimal), exactly, faster than round().

    `round(x, 9)` is the double nearest to k * 10**-9 with k the integer nearest to the exact x * 10**9
    (ties to even).  Here, for 0 < p = x * 1e9 < 2**52, k is p's nearest integer and the result the double
    `k / 1e9` (IEEE division: correctly rounded, k exact); the product p is within half an ulp of the
    exact one, so k is right unless p is within 4 ulp (p * 2**-50) of a half-integer: those values, the
    others (zero, negative, too large, not finite) and ints (round(3, 9) is 3) go to `round` itself."""
    scale = 10.0 ** ndigits
    out: list[Any] = []
    for x in xs:
        out.append(_round(x, scale, ndigits) if type(x) is float else round(x, ndigits))
    return out


def _round(x: float, scale: float, ndigits: int) -> float:
    """round(x, ndigits) of one float (`rounded`), scale = 10.0 ** ndigits."""
    p = x * scale
    if 0.0 < p < _EXACT:
        k = int(p)
        frac = p - k
        tol = p * 8.881784197001252e-16         # p * 2**-50 >= 4 ulp(p)
        if frac - 0.5 > tol:
            return (k + 1) / scale
        if 0.5 - frac > tol:
            return k / scale
    return round(x, ndigits)


def _plain(x: Any) -> bool:
    """Does msgspec write this number as Python's json does?  Both give the shortest round-tripping digits;
    they differ only in how they write exponents (`1e-05` vs `1e-5`), which Python uses below 1e-4 and from
    1e16 on (and non-finite values, which json writes as NaN)."""
    return 1e-4 <= x < 1e15 or x == 0.0


def lines(rows: list[Row], t9: list[Any], make: Any) -> tuple[list[Any], list[int]]:
    """The JSONL writer's lines of a batch: `make(t, ev, ch, dev, src, dst, seq, size, flow, kind, reason, fifo,
    dist, implicit)` per row (its msgspec struct, trace/events.py) with the time and distance its record says
    (`t9`, round(float(dist), 3)) and `implicit` a bool; and the indices of the lines with a number msgspec
    would write otherwise than Python's json (`_plain`), which the writer writes with the reference encoder."""
    if len(rows) != len(t9):
        raise ValueError(f"{len(rows)} rows and {len(t9)} times")
    out: list[Any] = []
    odd: list[int] = []
    for k, row in enumerate(rows):
        r: tuple[Any, ...] = row
        t = t9[k]
        if isinstance(t, float):        # _plain, typed: compiled, a comparison of doubles
            tf: float = t
            plain = 1e-4 <= tf < 1e15 or tf == 0.0
        else:
            plain = _plain(t)
        dist: Any = r[12]
        if dist is not None:
            d = _round(float(dist), 1000.0, 3)
            dist = d
            if plain:
                plain = 1e-4 <= d < 1e15 or d == 0.0
        if not plain:
            odd.append(k)
        out.append(make(t, r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8], r[9], r[10], r[11], dist, bool(r[13])))
    return out, odd


class Batch:
    """Events of a run in emission order (`rows`, see `Row`), with the columns consumers share computed
    once: `t9` (the times rounded to the ns, as the records say them) and `column(i)`."""

    __slots__ = ("rows", "_t9", "_cols")

    def __init__(self, rows: list[Row], t9: list[float] | None = None) -> None:
        self.rows = rows
        self._t9 = t9
        self._cols: list[tuple[Any, ...]] | None = None

    def __len__(self) -> int:
        return len(self.rows)

    def columns(self) -> list[tuple[Any, ...]]:
        """The rows as 14 columns (ROW_FIELDS order)."""
        if self._cols is None:
            self._cols = list(zip(*self.rows, strict=True)) if self.rows else [() for _ in ROW_FIELDS]
        return self._cols

    @property
    def t9(self) -> list[float]:
        """`round(t, 9)` of every row: the time of its record."""
        if self._t9 is None:
            ts = self._cols[0] if self._cols is not None else [r[0] for r in self.rows]
            self._t9 = rounded(ts, 9)
        return self._t9


BatchConsumer = Callable[[Batch], None]


@mypyc_attr(allow_interpreted_subclasses=True)
class EventFold:
    """What takes every event at once, natively (`Tracer.fold`): the online metrics' fold
    (analysis.fold.Fold) is one.  A class rather than a callback so that the compiled tracer calls the
    compiled fold directly, with the event's fields and no row built for it; the arguments are the
    record's fields (`t` rounded as the record says it, `has_dist` whether the record has a distance)."""

    def event(self, t: object, ev: str, ch: object, dev: str, src: int, dst: object, seq: int, size: int,
              flow: str | None, kind: str, reason: str | None, has_dist: bool, implicit: bool) -> None:
        raise NotImplementedError


BATCH: Final = 4096
"""Events per batch handed to the batch consumers."""


class Tracer:
    def __init__(self, batch: int = BATCH) -> None:
        self.sinks: list[Callable[[Record], None]] = []
        self.listeners: list[EventListener] = []
        self.consumers: list[BatchConsumer] = []
        self.folds: list[EventFold] = []
        self.batch = batch
        self._rows: list[Row] | None = None     # None: no batch consumer, each event counted at once
        self._t9: list[Any] = []                # the rows' record times, when the folds made them
        self._rows_only = True                  # no event listener nor record sink
        self._counts: dict[str, dict[str | None, int]] = {}     # ev -> reason -> events (but the three below)
        self._n_enq = 0                         # enq, tx and rx events without a reason (nearly all of them):
        self._n_tx = 0                          # native counters, where a dict costs two lookups an event
        self._n_rx = 0
        self._t_prev = math.nan                 # the last float time the folds were given, and its t9:
        self._t9_prev: object = None            # events come in runs at one time (enq, then tx or drop)

    def add(self, sink: Callable[[Record], None]) -> None:
        """A record sink: called with each event as a dict (docs/trace-format.md), at once."""
        self.sinks.append(sink)
        self._rows_only = False

    def listen(self, fn: EventListener) -> None:
        """An event listener: called at once with (t, ev, ch, dev, frame, reason, fifo, dist, implicit);
        nothing is built."""
        self.listeners.append(fn)
        self._rows_only = False

    def fold(self, f: EventFold) -> None:
        """An event fold: `f.event(...)` called at once with each event's record fields."""
        self.folds.append(f)

    def consume(self, fn: BatchConsumer) -> None:
        """A batch consumer: called with each `Batch` of events, in order, when `batch` events are
        pending and at `flush()`."""
        self.consumers.append(fn)
        if self._rows is None:
            self._rows = []

    def emit(self, t: Any, ev: str, ch: int, dev: str, frame: Frame, reason: str | None = None,
             fifo: int | None = None, dist: Any = None, implicit: Any = False) -> None:
        """One event at time `t` (a number: an int stays one in the record, as round() keeps it), `dist`
        the distance of a reception (m, None for the transmitter's events), `implicit` true for a frame
        handed to a modem that is not its addressee.  (`t`, `dist` and `implicit` are taken as given,
        compiled or not.)"""
        rows = self._rows
        if self.folds:
            if type(t) is float:
                tf: float = t
                if tf == self._t_prev:
                    t9: Any = self._t9_prev
                else:
                    t9 = _round(tf, 1e9, 9)
                    if tf > 0.0:        # (never -0.0, which equals 0.0 but is another record)
                        self._t_prev = tf
                        self._t9_prev = t9
            else:
                t9 = round(t, 9)
            has_dist = dist is not None
            for f in self.folds:
                f.event(t9, ev, ch, dev, frame.src, frame.dst, frame.seq, frame.size, frame.flow, frame.kind,
                        reason, has_dist, bool(implicit))
            if rows is not None:
                self._t9.append(t9)             # the batch's t9 made once (`flush`)
        if rows is None:
            self._count(ev, reason)
        else:
            rows.append((t, ev, ch, dev, frame.src, frame.dst, frame.seq, frame.size, frame.flow, frame.kind,
                         reason, fifo, dist, implicit))
            if len(rows) >= self.batch:
                self.flush()
            if self._rows_only:
                return
        for fn in self.listeners:
            fn(t, ev, ch, dev, frame, reason, fifo, dist, implicit)
        if not self.sinks:
            return
        rec = record(t, ev, ch, dev, frame, reason, fifo, dist, implicit)
        for sink in self.sinks:
            sink(rec)

    def flush(self) -> None:
        """Hand the pending events to the batch consumers (at the end of a run; at any time)."""
        rows = self._rows
        if not rows:
            return
        self._rows = []
        t9 = self._t9
        self._t9 = []
        for r in rows:
            self._count(r[1], r[10])
        b = Batch(rows, t9 if len(t9) == len(rows) else None)   # a fold added within the batch: computed
        for fn in self.consumers:
            fn(b)

    def _count(self, ev: str, reason: str | None) -> None:
        if reason is None:
            if ev == "tx":
                self._n_tx += 1
                return
            if ev == "enq":
                self._n_enq += 1
                return
            if ev == "rx":
                self._n_rx += 1
                return
        by = self._counts.get(ev)
        if by is None:
            by = self._counts[ev] = {}
        by[reason] = by.get(reason, 0) + 1

    def _by_reason(self) -> dict[str, dict[str | None, int]]:
        """Events so far, ev -> reason -> count (a copy)."""
        self.flush()
        out = {ev: dict(by) for ev, by in self._counts.items()}
        for ev, n in (("enq", self._n_enq), ("tx", self._n_tx), ("rx", self._n_rx)):
            if n:
                out.setdefault(ev, {})[None] = n
        return out

    @property
    def counts(self) -> Counter[tuple[str, str | None]]:
        """Events so far by (ev, reason) (a copy)."""
        return Counter({(ev, reason): n for ev, by in self._by_reason().items() for reason, n in by.items()})

    def count(self, ev: str, reason: str | None = None) -> int:
        by = self._by_reason().get(ev, {})
        if reason is None and ev == "drop":
            return sum(by.values())
        return by.get(reason, 0)


def record(t: Any, ev: str, ch: int, dev: str, frame: Frame, reason: str | None = None,
           fifo: int | None = None, dist: Any = None, implicit: Any = False) -> Record:
    """The documented trace record of one event (key order is part of the format)."""
    rec: Record = {"t": round(t, 9), "ev": ev, "ch": ch, "dev": dev, "src": frame.src, "dst": frame.dst,
                   "seq": frame.seq, "size": frame.size, "flow": frame.flow, "kind": frame.kind}
    if reason is not None:
        rec["reason"] = reason
    if fifo is not None:
        rec["fifo"] = fifo
    if dist is not None:
        rec["dist"] = round(float(dist), 3) if math.isfinite(dist) else None   # JSON has no inf/NaN
    if implicit:
        rec["implicit"] = True      # rx of a frame addressed to another modem (no MAC: implicit broadcast)
    return rec


