"""The output port: every fact about a frame, told once, to every listener in one shape.

A run's modems and channels tell the port (`Tracer`, `net.tracer`) each fact as it happens:

- the frame events of the trace (docs/trace-format.md): `enq`, `tx`, `rx` (with its distance: the
  receiver's outcome for the sender, as is a receiver's `drop`), `drop` (`Tracer.emit`);
- the sender's statuses, `queued`, `sent`, `transmitted`, `acked`, `failed`, `dropped` (`Tracer.status`):
  what docs/gli-protocol.md's `status` messages say.

Whatever watches the engine is a `Listener`: its `event(t, ev, ch, dev, frame, reason, fifo, dist, implicit)`
is called once per fact, at once, with the fields as the engine has them and nothing built for it (`ev` the
event or the status; a status has no fifo nor distance).  `listen(l)` takes the frame events,
`listen(l, statuses=True)` the statuses too.  The listeners of a run:

- the online metrics' fold (analysis.fold.Fold; through `Accumulator.follow`): each event at once, or the
  trace writers' batches when there are;
- the trace writers, renderings of the one record: `Batcher` (below) gathers events into `Batch`es for the
  JSONL writer and the columnar one (`consume`), which write them at `flush()` or every `batch` events;
  `Records` makes the documented dict of each event for a callable (`add`: the user's tracing class, the
  records kept in memory);
- the broker's endpoints and the simulator backend (drivers/sim_backend.py): the rx and status events of
  the modems they serve, and the receivers' outcomes of the frames their apps sent.

With no listener a run pays for a counter increment per event and nothing else.  The port's listeners are
called in the order they were added; a realtime run orders its *outputs* (rx first, statuses next, the
trace at idle: kernel/realtime.py) by where each listener puts its work, not by the port.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable, Sequence
from typing import Any, Final

from mypy_extensions import mypyc_attr

from ..kernel.frame import Frame
from ..kernel.rx import Rx
from ..kernel.rx import doppler as rx_doppler
from ..kernel.rx import level_db as rx_level

Record = dict[str, Any]

FRAME_EVENTS: Final = ("enq", "tx", "rx", "drop")
STATUSES: Final = ("queued", "sent", "transmitted", "acked", "failed", "dropped")
"""The sender's statuses (docs/gli-protocol.md#status-modem--app): `Tracer.status`."""


@mypyc_attr(allow_interpreted_subclasses=True)
class Listener:
    """What watches the engine: `event` is called once per fact (see the module's docstring).  A class
    rather than a callback so that the compiled port calls a compiled listener (the metrics' fold, the
    batcher) natively; interpreted subclasses override `event` as they like."""

    def event(self, t: Any, ev: str, ch: int, dev: str, frame: Frame, reason: str | None, fifo: int | None,
              dist: Any, implicit: Any) -> None:
        """`t` the time (a number; an int stays one), `dev` the modem where it happened, `dist` the distance
        of a reception or a receiver's drop (m, else None), `implicit` true for a frame handed up at a modem
        that is not its addressee (no MAC: the original's implicit broadcast)."""


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
    prev = math.nan                     # events come in runs at one time (enq then tx, a frame's receptions):
    r: Any = None                       # a time equal to the previous one has its rounding
    for x in xs:
        if type(x) is float:
            xf: float = x
            if xf != prev or xf <= 0.0:     # (-0.0 equals 0.0 but is another record)
                r = round_fast(xf, scale, ndigits)
                prev = xf
            out.append(r)
        else:
            out.append(round(x, ndigits))
            prev = math.nan
    return out


def round_fast(x: float, scale: float, ndigits: int) -> float:
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


def level(dist: Any) -> float | None:
    """The received level of a trace record (dB re 1 uPa, to 3 decimals as `dist`; a NaN or infinity as None,
    JSON's null): None when the reception `dist` (kernel.rx) has none."""
    lv = rx_level(dist)
    if lv is None:
        return None
    lf: float = lv
    if not math.isfinite(lf):
        return None
    return round_fast(lf, 1000.0, 3)


def lines(rows: list[Row], t9: list[Any], make: Any) -> tuple[list[Any], list[int]]:
    """The JSONL writer's lines of a batch: `make(t, ev, ch, dev, src, dst, seq, size, flow, kind, reason, fifo,
    dist, doppler, level, implicit)` per row (its msgspec struct, trace/events.py) with the time and distance its
    record says (`t9`, round(float(dist), 3)), the reception's Doppler factor and received level (kernel.rx;
    None; the level rounded as the distance) and `implicit` a bool;
    and the indices of the lines with a number msgspec would write otherwise than Python's json (`_plain`),
    which the writer writes with the reference encoder."""
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
        dop: Any = None
        lv: Any = None
        if dist is not None:
            if type(dist) is Rx:        # a reception with the channel model's details (kernel.rx)
                dop = rx_doppler(dist)
                lv = level(dist)
            d = round_fast(float(dist), 1000.0, 3)
            dist = d
            if plain:
                plain = 1e-4 <= d < 1e15 or d == 0.0
            if dop is not None and plain:
                plain = _plain(dop)
            if lv is not None and plain:
                plain = _plain(abs(lv))     # msgspec and json write a minus sign alike
        if not plain:
            odd.append(k)
        out.append(make(t, r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8], r[9], r[10], r[11], dist, dop, lv,
                        bool(r[13])))
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


BATCH: Final = 4096
"""Events per batch handed to the batch consumers."""


class Batcher(Listener):
    """The events in batches (`Batch`: one row tuple per event, its time rounded once for all of them), in
    order, at most `batch` events late, for the trace writers (`JsonlSink.write_batch`,
    `ArrowSink.write_batch`): one append per event for all of them, each writer's work per batch
    (vectorised where it can).  Whoever runs the network calls `Tracer.flush()` when the run ends."""

    def __init__(self, batch: int = BATCH) -> None:
        self.batch = batch
        self.rows: list[Row] = []
        self.consumers: list[BatchConsumer] = []
        self.t9: list[Any] = []             # the rows' record times (Batch.t9), made as they come:
        self._t_prev = math.nan             # events come in runs at one time (enq then tx, a frame's
        self._t9_prev: Any = None           # receptions), so most take the previous one's rounding

    def event(self, t: Any, ev: str, ch: int, dev: str, frame: Frame, reason: str | None, fifo: int | None,
              dist: Any, implicit: Any) -> None:
        if type(t) is float:                # (analysis.fold.Fold.event rounds the same way, for itself)
            tf: float = t
            if tf == self._t_prev:
                t9: Any = self._t9_prev
            else:
                t9 = round_fast(tf, 1e9, 9)
                if tf > 0.0:                # (never -0.0, which equals 0.0 but is another record)
                    self._t_prev = tf
                    self._t9_prev = t9
        else:
            t9 = round(t, 9)
        self.t9.append(t9)
        rows = self.rows
        rows.append((t, ev, ch, dev, frame.src, frame.dst, frame.seq, frame.size, frame.flow, frame.kind,
                     reason, fifo, dist, implicit))
        if len(rows) >= self.batch:
            self.flush()

    def flush(self) -> None:
        rows = self.rows
        if not rows:
            return
        self.rows = []
        t9 = self.t9
        self.t9 = []
        b = Batch(rows, t9)
        for fn in self.consumers:
            fn(b)


class Records(Listener):
    """`fn(record)` of every frame event, the documented dict (`record`): built per event, so for the
    few who need a dict (the user's tracing class, records kept in memory, a small realtime trace)."""

    def __init__(self, fn: Callable[[Record], None]) -> None:
        self.fn = fn

    def event(self, t: Any, ev: str, ch: int, dev: str, frame: Frame, reason: str | None, fifo: int | None,
              dist: Any, implicit: Any) -> None:
        self.fn(record(t, ev, ch, dev, frame, reason, fifo, dist, implicit))


class Callback(Listener):
    """`fn(t, ev, ch, dev, frame, reason, fifo, dist, implicit)` of every event: a function as a listener."""

    def __init__(self, fn: Callable[..., None]) -> None:
        self.fn = fn

    def event(self, t: Any, ev: str, ch: int, dev: str, frame: Frame, reason: str | None, fifo: int | None,
              dist: Any, implicit: Any) -> None:
        self.fn(t, ev, ch, dev, frame, reason, fifo, dist, implicit)


class Tracer:
    """The output port (see the module's docstring); it also counts the frame events by (ev, reason)."""

    def __init__(self, batch: int = BATCH) -> None:
        self.listeners: list[Listener] = []
        self.watchers: list[Listener] = []
        """The listeners of the statuses too (`listen(l, statuses=True)`)."""
        self.batch = batch
        self._batcher: Batcher | None = None
        self._counts: dict[str, dict[str | None, int]] = {}     # ev -> reason -> events (but the three below)
        self._n_enq = 0                         # enq, tx and rx events without a reason (nearly all of them):
        self._n_tx = 0                          # native counters, where a dict costs two lookups an event
        self._n_rx = 0

    def listen(self, listener: Listener, *, statuses: bool = False) -> None:
        """`listener.event(...)` of every frame event from now on (and of every status, `statuses`)."""
        self.listeners.append(listener)
        if statuses:
            self.watchers.append(listener)

    @property
    def batching(self) -> bool:
        """Does the port make batches (a `consume`r listens)?"""
        return self._batcher is not None

    def add(self, fn: Callable[[Record], None]) -> None:
        """`fn(record)` of every frame event (a `Records` listener)."""
        self.listen(Records(fn))

    def consume(self, fn: BatchConsumer) -> None:
        """`fn(batch)` of the frame events in `Batch`es (the port's one `Batcher`, added at the first)."""
        if self._batcher is None:
            self._batcher = Batcher(self.batch)
            self.listen(self._batcher)
        self._batcher.consumers.append(fn)

    def emit(self, t: Any, ev: str, ch: int, dev: str, frame: Frame, reason: str | None = None,
             fifo: int | None = None, dist: Any = None, implicit: Any = False) -> None:
        """A frame event at time `t` (see `Listener.event`)."""
        if reason is None:
            if ev == "tx":
                self._n_tx += 1
            elif ev == "enq":
                self._n_enq += 1
            elif ev == "rx":
                self._n_rx += 1
            else:
                self._count(ev, reason)
        else:
            self._count(ev, reason)
        for lst in self.listeners:
            lst.event(t, ev, ch, dev, frame, reason, fifo, dist, implicit)

    def status(self, t: Any, ev: str, ch: int, dev: str, frame: Frame, reason: str | None = None) -> None:
        """A status `ev` (STATUSES) of `frame` for its sender `dev`, at time `t`."""
        for lst in self.watchers:
            lst.event(t, ev, ch, dev, frame, reason, None, None, False)

    def flush(self) -> None:
        """Hand the pending events to the batch consumers (at the end of a run; at any time)."""
        if self._batcher is not None:
            self._batcher.flush()

    def _count(self, ev: str, reason: str | None) -> None:
        by = self._counts.get(ev)
        if by is None:
            by = self._counts[ev] = {}
        by[reason] = by.get(reason, 0) + 1

    def _by_reason(self) -> dict[str, dict[str | None, int]]:
        """Events so far, ev -> reason -> count (a copy)."""
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
        dop = rx_doppler(dist)
        if dop is not None:
            rec["doppler"] = dop    # the reception's Doppler factor, when the channel model gave one
        lv = level(dist)
        if lv is not None:
            rec["level"] = lv       # its received level, dB re 1 uPa, rounded as `dist` (when the model gave one)
    if implicit:
        rec["implicit"] = True      # rx of a frame addressed to another modem (no MAC: implicit broadcast)
    return rec


