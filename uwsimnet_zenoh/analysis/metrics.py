"""Per-flow metrics and the conservation check, computed from trace records (docs/trace-format.md).

One pass over the events with state keyed by (transmitter dccommsId, seq), then one pass over the
frames seen: time and memory are linear in the trace (a run's online summary, whose events come in time
order, lets frames settle as it goes: bounded memory, fold.Fold).  Everything here is pure: files are only read.

    a = analyse("run.jsonl")            # one pass: a.flows (FlowMetrics per flow) + a.conservation
    assert a.conservation == [] and not a.conservation.in_flight

`flow_metrics()` and `conservation()` are the same pass, returning one half each.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

from ..kernel.frame import BROADCAST
from .fold import FlowState, Fold, bin_value, counts
from .levels import LevelSums, LinkLevel
from .read import (
    DEFAULT_HORIZON,
    EVENTS,
    RX_REASONS,
    TX_REASONS,
    Source,
    is_columnar,
    is_int,
    is_num,
    open_source,
    read_columns,
)


# -- who is who ---------------------------------------------------------------------------------
class DeviceMap:
    """Resolves (channel, address) to dccommsIds and names flows.

    The transmitter of a frame is learnt from the `dev` of enq/tx events (the same address may exist
    on different channels); the meta's devices are the fallback for frames whose transmitter-side
    events are missing.
    """

    def __init__(self, meta: Mapping[str, Any] | None = None) -> None:
        self.tx: dict[tuple[Any, int], str] = {}
        self._meta_tx: dict[tuple[Any, int], str] = {}
        self._meta_rx: dict[tuple[Any, int], str] = {}
        self.header: dict[str, int] = {}
        devices = (meta or {}).get("devices") or {}
        if isinstance(devices, Mapping):
            for dev, d in devices.items():
                if not isinstance(d, Mapping):
                    continue
                addr = d.get("address")         # frames carry int addresses: any other (a damaged meta) matches none
                if "tx_channel" in d and is_int(addr):
                    self._meta_tx.setdefault((d["tx_channel"], addr), dev)
                if "rx_channel" in d and is_int(addr):
                    self._meta_rx.setdefault((d["rx_channel"], addr), dev)
                hb = d.get("header_bytes")
                self.header[dev] = hb if is_int(hb) else 0

    def learn(self, ch: Any, src: int, dev: str) -> None:
        key = (ch, src)
        if key not in self.tx:
            self.tx[key] = dev

    def tx_dev(self, ch: Any, src: int) -> str:
        """The dccommsId transmitting as `src` on channel `ch` (or `ch:src` if nobody knows)."""
        dev = self.tx.get((ch, src))
        if dev is None:
            dev = self._meta_tx.get((ch, src))
            if dev is None:
                dev = f"{ch}:{src}"
        return dev

    def rx_dev(self, ch: Any, addr: int) -> str | None:
        """The dccommsId listening as `addr` on channel `ch`, if the meta says."""
        return self._meta_rx.get((ch, addr))

    def classify_drop(self, rec: Mapping[str, Any]) -> tuple[bool, str]:
        """(at the transmitter?, transmitter dccommsId) of a drop event."""
        return self._drop(rec["ch"], rec["src"], rec["dev"], rec["reason"], "dist" in rec)

    def _drop(self, ch: Any, src: int, dev: str, reason: str, has_dist: bool) -> tuple[bool, str]:
        known = self.tx.get((ch, src))
        at_tx = (dev == known if known is not None
                 else reason in TX_REASONS or (reason not in RX_REASONS and not has_dist))
        if at_tx:
            self.learn(ch, src, dev)
            return True, dev
        return False, self.tx_dev(ch, src)

    def transmitter(self, rec: Mapping[str, Any]) -> tuple[str, bool]:
        """(transmitter dccommsId, event happened at the transmitter?) for any frame event."""
        return self.locate(rec["ev"], rec["ch"], rec["src"], rec["dev"], rec.get("reason"), "dist" in rec)

    def locate(self, ev: str, ch: Any, src: int, dev: str, reason: str | None,
               has_dist: bool) -> tuple[str, bool]:
        """`transmitter()` from the event's fields."""
        if ev == "enq" or ev == "tx":
            key = (ch, src)
            if key not in self.tx:
                self.tx[key] = dev
            return dev, True
        if ev == "drop":
            at_tx, tx_dev = self._drop(ch, src, dev, reason, has_dist)  # type: ignore[arg-type]
            return tx_dev, at_tx
        return self.tx_dev(ch, src), False


def flow_name(flow: str | None, tx_dev: str) -> str:
    """Frames of external apps (flow null) are grouped under their transmitter's dccommsId."""
    return flow if flow is not None else tx_dev


# -- results ------------------------------------------------------------------------------------
@dataclass
class FlowMetrics:
    """Metrics of one flow (definitions: docs/trace-format.md, "Report metrics")."""

    name: str
    src: str | None = None                 # transmitter dccommsId
    dst: int | None = None                 # destination address (255 = broadcast)
    payload: int | None = None             # payload bytes per frame from the meta (None: from sizes)
    window: tuple[float, float] | None = None   # active window [start, end] s
    enqueued: int = 0
    sent: int = 0                          # data tx events, retransmissions included
    unique_sent: int = 0                   # distinct data frames transmitted at least once
    delivered: int = 0                     # data rx events
    payload_delivered: int = 0             # bytes
    payload_offered: int = 0               # bytes enqueued
    data_bytes_on_air: int = 0
    ctrl_sent: int = 0                     # ctrl tx events serving this flow
    ctrl_bytes_on_air: int = 0
    throughput: float | None = None        # B/s
    offered: float | None = None           # B/s
    efficiency: float | None = None        # 0..1
    delivery_ratio: float | None = None
    delay_mean: float | None = None        # s
    delay_median: float | None = None
    delay_p95: float | None = None
    jitter: float | None = None
    drops: dict[str, int] = field(default_factory=dict)        # final outcomes, by reason
    superseded: dict[str, int] = field(default_factory=dict)   # other data drop events, by reason
    in_flight: int = 0                     # frames with no outcome at the end of the trace

    @property
    def bytes_on_air(self) -> int:
        return self.data_bytes_on_air + self.ctrl_bytes_on_air

    @property
    def broadcast(self) -> bool:
        return self.dst == BROADCAST

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["window"] = list(self.window) if self.window is not None else None
        d["bytes_on_air"] = self.bytes_on_air
        return d


@dataclass
class ChannelMetrics:
    """Counters of one channel (every frame event with that `ch`, data and control frames alike)."""

    ch: Any
    enqueued: int = 0
    sent: int = 0                          # tx events
    ctrl_sent: int = 0                     # of which control frames
    bytes_on_air: int = 0
    delivered: int = 0                     # rx events (data and control)
    drop_events: dict[str, int] = field(default_factory=dict)   # every drop event, by reason

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class InFlight:
    """A frame that had no outcome yet when the trace ended."""

    dev: str
    seq: int
    flow: str
    state: str                 # "queued" (never transmitted) | "on air" (transmitted, outcome pending)
    t_enq: float | None
    t_tx: float | None         # last transmission


class Conservation(list[str]):
    """The violations of the conservation law (a list of one-line messages: empty = OK), plus the
    frames still in flight when the trace ended (`in_flight`), which a run cut at `duration` may leave.
    """

    def __init__(self, violations: Iterable[str] = (), in_flight: Iterable[InFlight] = (),
                 frames: int = 0, end: float = 0.0, total: int | None = None) -> None:
        super().__init__(violations)
        self.in_flight: list[InFlight] = list(in_flight)
        self.frames = frames          # data frames checked
        self.end = end                # end of the run used for the in-flight horizon
        self.total = len(self) if total is None else total   # violations before truncation

    @property
    def violations(self) -> list[str]:
        return list(self)

    @property
    def ok(self) -> bool:
        return not self

    def __repr__(self) -> str:
        return (f"Conservation(violations={list(self)!r}, in_flight={len(self.in_flight)},"
                f" frames={self.frames})")


@dataclass
class Analysis:
    meta: dict[str, Any]
    flows: dict[str, FlowMetrics]
    conservation: Conservation
    channels: dict[Any, ChannelMetrics] = field(default_factory=dict)
    links: list[LinkLevel] = field(default_factory=list)
    """The mean received level per link, when the trace's rx records have a `level` (a trace read back)."""


# -- the pass -----------------------------------------------------------------------------------
_PENDING = 4096
"""Records `Accumulator.add` takes at a time."""


def _meta_flows(meta: Mapping[str, Any]) -> dict[str, Mapping[str, Any]]:
    flows = meta.get("flows") or {}
    return {k: v for k, v in flows.items() if isinstance(v, Mapping)} if isinstance(flows, Mapping) else {}


class Accumulator:
    """The metrics of a run, accumulated as the events come (O(1) per event): the one definition behind
    `analyse()` on a trace and the online summary of `uwsimnet run` (a batch consumer of the tracer,
    `on_batch`), so the two give the same numbers for the same run.

        acc = Accumulator(net.meta()); acc.follow(net.tracer); net.run()
        a = acc.result()

    The per-event work is `fold.Fold` (compiled with the engine when `make` can); this class feeds it and
    turns its state into FlowMetrics, ChannelMetrics and the Conservation.  tests/test_online_metrics.py
    holds it to the event-by-event definition it replaced (tests/metrics_reference.py) on every scene.
    """

    def __init__(self, meta: Mapping[str, Any] | None = None, *, settle_after: float = math.inf) -> None:
        """`settle_after`: a run's events (in time order) let frames settle that long after their last event
        (fold.Fold), so that its memory stays bounded; a trace read back holds every frame to the end."""
        meta = dict(meta or {})
        self.meta = meta
        self.devs = devs = DeviceMap(meta)
        self.mflows = mflows = _meta_flows(meta)
        self._fold = fold = Fold(devs._meta_tx, devs._meta_rx, devs.header, settle_after)
        for name, f in mflows.items():
            src, dst, size = f.get("src"), f.get("dst"), f.get("size")
            fold.flow(name, src if isinstance(src, str) else None, dst if is_int(dst) else None,
                      size if is_int(size) else None)
        self.ended: float | None = None     # an `end` record: the run's actual end (stopped early, realtime)
        self._pending: list[tuple[Any, ...]] = []     # records of `add()` not yet taken
        self.levels = LevelSums()           # rx records' `level` (a trace read back: `add`, `analyse`)

    # -- input --
    def add(self, rec: Mapping[str, Any]) -> None:
        """One checked trace record (analysis.read); records of other kinds are skipped.  Records are
        taken in batches (`result()` takes the rest)."""
        ev = rec["ev"]
        if ev not in EVENTS:
            if ev == "end" and is_num(rec.get("t")) and math.isfinite(rec["t"]):
                self.ended = float(rec["t"])
            return
        reason, flow, kind = rec.get("reason"), rec.get("flow"), rec.get("kind", "data")
        if ev == "rx" and "level" in rec:
            self.levels.add(rec["ch"], rec["src"], rec["dev"], rec["level"])
        pending = self._pending
        pending.append((rec["t"], ev, rec["ch"], rec["dev"], rec["src"], rec.get("dst"), rec["seq"], rec["size"],
                        flow if isinstance(flow, str) else None, kind if isinstance(kind, str) else "data",
                        reason if isinstance(reason, str) else None, None, True if "dist" in rec else None,
                        bool(rec.get("implicit"))))
        if len(pending) >= _PENDING:
            self._drain()

    def _drain(self) -> None:
        pending = self._pending
        if pending:
            self._pending = []
            self._fold.rows(pending, [r[0] for r in pending])

    def follow(self, tracer: Any) -> None:
        """Take a run's events as they happen, from the output port: from its batches if it makes them already
        (a trace writer listens: the rows and their rounded times are then shared), else each event at once
        (natively when compiled, with no row built for it).  Call it after the trace writers are added."""
        self._drain()
        if tracer.batching:
            tracer.consume(self.on_batch)
        else:
            tracer.listen(self._fold)

    def on_batch(self, b: Any) -> None:
        """A batch consumer (trace.events.Tracer.consume): the events of a `Batch`, their records' times
        shared with the trace writers."""
        self._drain()
        self._fold.rows(b.rows, b.t9)

    def on_event(self, t: float, ev: str, ch: int, dev: str, frame: Any, reason: str | None,
                 fifo: int | None, dist: float | None, implicit: bool = False) -> None:
        """An event listener (trace.events.Tracer.listen): the event as its trace record would say it (one
        row of `rows()`; `on_batch` is the fast way)."""
        self.rows([(t, ev, ch, dev, frame.src, frame.dst, frame.seq, frame.size, frame.flow, frame.kind, reason,
                    fifo, dist, implicit)], [round(t, 9)])

    def event(self, t: float, ev: str, ch: Any, dev: str, src: int, dst: int | None, seq: int, size: int,
              flow: str | None, kind: str, reason: str | None, has_dist: bool, implicit: bool = False) -> None:
        """One frame event with its record's fields (`dst` None: the record had none)."""
        self.rows([(t, ev, ch, dev, src, dst, seq, size, flow, kind, reason, None, True if has_dist else None,
                    implicit)], [t])

    def rows(self, rows: Iterable[tuple[Any, ...]], t9: Iterable[float]) -> None:
        """The definition: frame events in order, each a row (t, ev, ch, dev, src, dst, seq, size, flow, kind,
        reason, fifo, dist, implicit) (trace.events.Row; `dist` only tested for None, `fifo` unused) with
        `t9` its record's time (a `kind` that is not a string: not "data")."""
        self._drain()
        rows = list(rows)
        for k, r in enumerate(rows):
            if not isinstance(r[9], str):
                rows[k] = (*r[:9], "", *r[10:])
        self._fold.rows(rows, list(t9))

    # -- the end --
    def _channels(self) -> dict[Any, ChannelMetrics]:
        out = {ch: ChannelMetrics(ch, enqueued=c.enqueued, sent=c.sent, ctrl_sent=c.ctrl_sent,
                                  bytes_on_air=c.bytes_on_air, delivered=c.delivered,
                                  drop_events=dict(sorted(counts(c.drop_events).items())))  # type: ignore[arg-type]
               for ch, c in self._fold.channels.items()}
        return {ch: out[ch] for ch in sorted(out, key=lambda c: (isinstance(c, str), c))}

    def result(self, *, horizon: float = DEFAULT_HORIZON, end: float | None = None, limit: int = 1000) -> Analysis:
        """Per-flow metrics, channel counters and the conservation check of the events so far.  Settles
        the frames: call it once, at the end."""
        self._drain()
        meta = self.meta
        fold = self._fold
        t_end = -math.inf if fold.t_end is None else fold.t_end
        if end is None and self.ended is not None:
            end = max(self.ended, t_end)
        if end is None:
            dur = meta.get("duration")
            end = max(dur if is_num(dur) else -math.inf, t_end)
            if not math.isfinite(end):
                end = 0.0
        violations, total, flying = fold.settle(end, horizon, limit)
        cons = Conservation(violations, [InFlight(*x) for x in flying], frames=fold.n_frames, end=end,
                            total=total)
        duration = meta.get("duration") if self.ended is None else self.ended
        flows = {s.name: _finish(s, self.mflows.get(s.name), duration if is_num(duration) else None)
                 for s in fold.flows}
        return Analysis(meta=meta, flows=flows, conservation=cons, channels=self._channels(),
                        links=self.levels.result(self.devs.tx_dev))


def analyse(src: Source, meta: dict[str, Any] | None = None, *, horizon: float = DEFAULT_HORIZON,
            end: float | None = None, limit: int = 1000) -> Analysis:
    """Per-flow metrics and the conservation check in one pass over a trace (path or records).

    `horizon`: a transmitted frame with no outcome is in flight if its last tx is at or after
    `end - horizon`, a violation otherwise.  `end`: end of the run (default: the trace's `end` record
    if it has one, a run stopped early or in realtime; else the max of the meta duration and the last
    event time); rates are over that actual end too.  `limit`: at most this many violation messages are
    kept (the count of all is `conservation.total`).
    """
    if is_columnar(src):      # whole columns: no JSON, no per-record dict, no per-record checks
        m, cols = read_columns(src)  # type: ignore[arg-type]
        acc = Accumulator(m if meta is None else meta)
        rows = [r for r in zip(*(cols[k] for k in ("t", "ev", "ch", "dev", "src", "dst", "seq", "size", "flow", "kind",
                                                     "reason", "fifo", "dist", "implicit")), strict=True)
                if r[1] in EVENTS]
        for k in range(0, len(rows), _PENDING):
            part = rows[k:k + _PENDING]
            acc.rows(part, [r[0] for r in part])
        if any(v is not None for v in cols["level"]):
            add_level = acc.levels.add
            for ev, ch, src, dev, lv in zip(cols["ev"], cols["ch"], cols["src"], cols["dev"], cols["level"],
                                            strict=True):
                if ev == "rx" and lv is not None:
                    add_level(ch, src, dev, lv)
        return acc.result(horizon=horizon, end=end, limit=limit)
    meta, events = open_source(src, meta)
    acc = Accumulator(meta)
    add = acc.add
    for rec in events:
        add(rec)
    return acc.result(horizon=horizon, end=end, limit=limit)


def _finish(s: FlowState, mf: Mapping[str, Any] | None, duration: float | None) -> FlowMetrics:
    m = FlowMetrics(name=s.name, src=s.src, dst=s.dst, payload=s.payload, enqueued=s.enqueued, sent=s.sent,
                    unique_sent=s.unique_sent, delivered=s.delivered, payload_delivered=s.payload_delivered,
                    payload_offered=s.payload_offered, data_bytes_on_air=s.data_bytes_on_air,
                    ctrl_sent=s.ctrl_sent, ctrl_bytes_on_air=s.ctrl_bytes_on_air, in_flight=s.in_flight)
    m.drops = dict(sorted(counts(s.drops).items()))  # type: ignore[arg-type]
    m.superseded = {r: n - m.drops.get(r, 0) for r, n in sorted(counts(s.drop_events).items())  # type: ignore[arg-type]
                    if n - m.drops.get(r, 0) > 0}  # type: ignore[arg-type]
    # active window
    w0: Any = None
    w1: Any = None
    if mf is not None:
        start = mf.get("start")
        w0 = float(start) if is_num(start) else 0.0
        stop = mf.get("stop")
        stop = float(stop) if is_num(stop) else None
        if stop is not None and duration is not None:
            w1 = min(stop, duration)
        else:
            w1 = stop if stop is not None else duration
    if w1 is None:
        w0 = s.t_first_enq if s.t_first_enq is not None else s.t_first
        w1 = s.t_last
    if w0 is not None and w1 is not None:
        m.window = (w0, w1)
        span = w1 - w0
        if span > 0:
            m.throughput = m.payload_delivered / span
            m.offered = m.payload_offered / span
    on_air = m.bytes_on_air
    m.efficiency = m.payload_delivered / on_air if on_air > 0 else None
    m.delivery_ratio = m.delivered / s.intended if s.intended > 0 else None
    if s.bins:
        m.delay_mean = (s.sum_d + s.sum_c) / s.n_delays
        m.delay_median, m.delay_p95 = binned_median_p95({k: c.n for k, c in s.bins.items()})
    elif s.delays:
        d = [float(x) for x in s.delays]
        m.delay_mean = mean(d)
        m.delay_median, m.delay_p95 = median_p95(d)
    m.jitter = s.jit_sum / s.jit_n if s.jit_n else None
    return m


def _pairwise_sum(a: list[float], lo: int, n: int) -> float:
    """numpy's pairwise summation of a[lo:lo + n] (`pairwise_sum`, loops_utils.h): a plain loop below 8
    values, eight partial sums up to 128 (PW_BLOCKSIZE), else the two halves (cut at a multiple of 8)."""
    if n < 8:
        r = 0.0
        for i in range(lo, lo + n):
            r += a[i]
        return r
    if n <= 128:
        r0, r1, r2, r3, r4, r5, r6, r7 = a[lo:lo + 8]
        i = lo + 8
        stop = lo + n - n % 8
        while i < stop:
            r0 += a[i]
            r1 += a[i + 1]
            r2 += a[i + 2]
            r3 += a[i + 3]
            r4 += a[i + 4]
            r5 += a[i + 5]
            r6 += a[i + 6]
            r7 += a[i + 7]
            i += 8
        r = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
        for k in range(i, lo + n):
            r += a[k]
        return r
    half = n // 2
    half -= half % 8
    return _pairwise_sum(a, lo, half) + _pairwise_sum(a, lo + half, n - half)


def mean(d: list[float]) -> float:
    """np.mean(d) of a non-empty list of floats, the same double without numpy (whose import is a third of
    a small run's start-up): its pairwise sum divided by the count."""
    return _pairwise_sum(d, 0, len(d)) / len(d)


def binned_median_p95(bins: Mapping[int, int]) -> tuple[float, float]:
    """median_p95 of delays binned (fold.bin_delay: count by bin), each order statistic its bin's middle: each
    within 1/(2 fold.SUB) = 0.2 % of the exact one, and so are the median and p95 (means of two)."""
    keys = sorted(bins)
    n = sum(bins.values())

    def nth(i: int) -> float:   # the i-th smallest (0-based)
        for k in keys:
            i -= bins[k]
            if i < 0:
                return bin_value(k)
        raise IndexError(i)

    h = n // 2
    med = nth(h) if n % 2 else (nth(h - 1) + nth(h)) / 2
    v = (n - 1) * 0.95
    if v >= n - 1:
        return med, nth(n - 1)
    lo = math.floor(v)
    g = v - lo
    a, b = nth(lo), nth(lo + 1)
    diff = b - a
    return med, (b - diff * (1 - g) if g >= 0.5 else a + diff * g)


def median_p95(d: Sequence[float]) -> tuple[float, float]:
    """(np.median(d), np.percentile(d, 95)) of finite values, the same doubles from one sort (numpy's
    wrappers cost ~0.1 ms a call, per flow): the median is the mean of the middle one or two values, the
    95th percentile numpy's linear interpolation (virtual index (n - 1) * 0.95, `_lerp`)."""
    s = sorted(float(x) for x in d)
    n = len(s)
    h = n // 2
    med = float(s[h]) if n % 2 else (float(s[h - 1]) + float(s[h])) / 2
    v = (n - 1) * 0.95
    if v >= n - 1:
        return med, float(s[-1])
    lo = math.floor(v)
    g = v - lo
    a, b = float(s[lo]), float(s[lo + 1])
    diff = b - a
    return med, (b - diff * (1 - g) if g >= 0.5 else a + diff * g)


def flow_metrics(path_or_events: Source, meta: dict[str, Any] | None = None) -> dict[str, FlowMetrics]:
    """Per-flow metrics of a trace (path or records); flows of the meta first, in its order."""
    return analyse(path_or_events, meta).flows


def conservation(path_or_events: Source, meta: dict[str, Any] | None = None, *,
                 horizon: float = DEFAULT_HORIZON, end: float | None = None) -> Conservation:
    """Violations of the conservation law (a list: empty = OK) with `.in_flight` frames at the end."""
    return analyse(path_or_events, meta, horizon=horizon, end=end).conservation


