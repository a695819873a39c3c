"""Per-flow metrics and the conservation check, computed from trace records (docs/trace-format.md).

One pass over the events with state keyed by (transmitter dccommsId, seq), then one pass over the
frames seen: time and memory are linear in the trace.  Everything here is pure: files are only read.

    a = analyse("run.jsonl")            # one pass: a.flows (FlowMetrics per flow) + a.conservation
    assert a.conservation == [] and not a.conservation.in_flight

`flow_metrics()` and `conservation()` are the same pass, returning one half each.
"""

from __future__ import annotations

import math
from array import array
from collections import Counter
from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from ..kernel.frame import BROADCAST
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
                addr = d.get("address")
                if "tx_channel" in d:
                    self._meta_tx.setdefault((d["tx_channel"], addr), dev)
                if "rx_channel" in d:
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


# -- the pass -----------------------------------------------------------------------------------
_PENDING = 4096
"""Records `Accumulator.add` takes at a time."""


class _Frames:
    """The state of every data frame seen, one list per field, indexed by frame id (ids in the order of the
    frames' first events): what the conservation check and the delays need.  Lists, not arrays, while the
    events come (an element of a list costs a tenth of a numpy scalar); the check at the end takes them as
    arrays.  `r_*` is its receiver (unicast: at most one); `r_dev` is -2 once several receivers have had
    an outcome, and then `multi[id]` holds them all in order, each [dccommsId, rx events, drop events,
    last drop reason, n_tx at it]."""

    COLUMNS = ("flow", "dst", "n_enq", "n_tx", "n_txdrop", "txdrop", "txdrop_at", "r_dev", "r_nrx", "r_ndrop",
               "r_reason", "r_at", "t_enq", "t_tx")
    __slots__ = ("index", "keys", "ch", "multi", *COLUMNS)

    def __init__(self) -> None:
        self.index: dict[tuple[str, int], int] = {}
        self.keys: list[tuple[str, int]] = []
        self.ch: list[Any] = []
        self.multi: dict[int, dict[str, list[Any]]] = {}
        self.flow: list[int] = []
        self.dst: list[int] = []            # -1: the record had none
        self.n_enq: list[int] = []
        self.n_tx: list[int] = []
        self.n_txdrop: list[int] = []
        self.txdrop: list[str | None] = []  # reason of the last transmitter-side drop
        self.txdrop_at: list[int] = []
        self.r_dev: list[Any] = []          # None: no receiver yet; -2: several (multi)
        self.r_nrx: list[int] = []
        self.r_ndrop: list[int] = []
        self.r_reason: list[str | None] = []
        self.r_at: list[int] = []
        self.t_enq: list[float | None] = []
        self.t_tx: list[float | None] = []

    @property
    def n(self) -> int:
        return len(self.keys)

    def new(self, key: tuple[str, int], flow: int, ch: Any, dst: int) -> int:
        i = len(self.keys)
        self.index[key] = i
        self.keys.append(key)
        self.ch.append(ch)
        self.flow.append(flow)
        self.dst.append(dst)
        self.n_enq.append(0)            # (written out: a loop over the lists costs 3 % of the metrics)
        self.n_tx.append(0)
        self.n_txdrop.append(0)
        self.txdrop_at.append(0)
        self.r_nrx.append(0)
        self.r_ndrop.append(0)
        self.r_at.append(0)
        self.txdrop.append(None)
        self.r_dev.append(None)
        self.r_reason.append(None)
        self.t_enq.append(None)
        self.t_tx.append(None)
        return i

    def receivers(self, i: int) -> list[list[Any]]:
        """[[dccommsId, rx events, drop events, last drop reason, n_tx at it], ...] of frame `i`."""
        rd = self.r_dev[i]
        if rd is None:
            return []
        if rd == -2:
            return list(self.multi[i].values())
        return [[rd, self.r_nrx[i], self.r_ndrop[i], self.r_reason[i], self.r_at[i]]]

    def receiver(self, i: int, dev: str) -> list[Any] | None:
        """The record of receiver `dev` of frame `i` if the frame has several, else None: the r_* columns
        are its receiver's (set to `dev` if it had none)."""
        rd = self.r_dev[i]
        if rd is None:
            self.r_dev[i] = dev
            return None
        if rd == dev:
            return None
        if rd != -2:        # a second receiver: all of them as records from now on
            self.multi[i] = {rd: [rd, self.r_nrx[i], self.r_ndrop[i], self.r_reason[i], self.r_at[i]]}
            self.r_dev[i] = -2
        m = self.multi[i]
        r = m.get(dev)
        if r is None:
            r = m[dev] = [dev, 0, 0, None, 0]
        return r


class _Acc:
    __slots__ = ("m", "t_first", "t_first_enq", "t_last", "delays", "prev_delay", "jit_sum", "jit_n",
                 "drop_events", "intended")

    def __init__(self, m: FlowMetrics) -> None:
        self.m = m
        self.t_first: float | None = None
        self.t_first_enq: float | None = None
        self.t_last: float | None = None
        self.delays = array("d")
        self.prev_delay: float | None = None
        self.jit_sum = 0.0
        self.jit_n = 0
        self.drop_events: dict[str, int] = {}
        self.intended = 0


def _meta_flows(meta: Mapping[str, Any]) -> dict[str, Mapping[str, Any]]:
    flows = meta.get("flows") or {}
    return {k: v for k, v in flows.items() if isinstance(v, Mapping)} if isinstance(flows, Mapping) else {}


class Accumulator:
    """The metrics of a run, accumulated as the events come (`rows()`, O(1) per event): the one definition
    behind `analyse()` on a trace and the online summary of `uwsimnet run` (a batch consumer of the tracer,
    `on_batch`), so the two give the same numbers for the same run.

        acc = Accumulator(net.meta()); net.tracer.consume(acc.on_batch); net.run(); net.tracer.flush()
        a = acc.result()

    Events come in batches (the tracer's, or `add()`'s of trace records) and are taken in one flat loop,
    its state in locals and lists; the conservation check at the end is done with numpy for the frames with
    one outcome and no violation, one by one for the others.  tests/test_online_metrics.py holds it to
    the event-by-event definition it replaced (tests/metrics_reference.py) on every scene.
    """

    def __init__(self, meta: Mapping[str, Any] | None = None) -> None:
        meta = dict(meta or {})
        self.meta = meta
        self.devs = devs = DeviceMap(meta)
        self.mflows = mflows = _meta_flows(meta)
        self.accs: dict[str, _Acc] = {}
        self._flows: list[_Acc] = []        # by flow id
        self._fid: dict[str, int] = {}
        for name, f in mflows.items():
            size = f.get("size")
            fm = FlowMetrics(name=name, src=f.get("src") if isinstance(f.get("src"), str) else None,
                             dst=f.get("dst") if is_int(f.get("dst")) else None,
                             payload=size if is_int(size) else None)
            self._new_acc(name, _Acc(fm))
        self.f = _Frames()
        self.max_tx_seq: dict[str, int] = {}
        self._chan_counts: dict[tuple[Any, str, str | None], int] = {}
        self._chan_bytes: dict[Any, int] = {}
        self._chan_ctrl: dict[Any, int] = {}
        self.t_end = -math.inf
        self.ended: float | None = None     # an `end` record: the run's actual end (stopped early, realtime)
        self._header = devs.header
        self._pending: list[tuple[Any, ...]] = []     # records of `add()` not yet taken

    def _new_acc(self, name: str, a: _Acc) -> int:
        i = len(self._flows)
        self._flows.append(a)
        self._fid[name] = i
        self.accs[name] = a
        return i

    def _acc_id(self, name: str, tx_dev: str, dst: Any) -> int:
        i = self._fid.get(name)
        if i is None:
            i = self._new_acc(name, _Acc(FlowMetrics(name=name, src=tx_dev, dst=dst if is_int(dst) else None)))
        return i

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
            self.rows(pending, [r[0] for r in pending])

    def on_batch(self, b: Any) -> None:
        """A batch consumer (trace.events.Tracer.consume): the events of a `Batch`, their records' times
        shared with the trace writers."""
        self._drain()
        self.rows(b.rows, b.t9)

    def on_event(self, t: float, ev: str, ch: int, dev: str, frame: Any, reason: str | None,
                 fifo: int | None, dist: float | None, implicit: bool = False) -> None:
        """An event listener (trace.events.Tracer.listen): the event as its trace record would say it (one
        row of `rows()`; `on_batch` is the fast way)."""
        self._drain()
        self.rows([(t, ev, ch, dev, frame.src, frame.dst, frame.seq, frame.size, frame.flow, frame.kind, reason,
                    fifo, dist, implicit)], [round(t, 9)])

    def event(self, t: float, ev: str, ch: Any, dev: str, src: int, dst: int | None, seq: int, size: int,
              flow: str | None, kind: str, reason: str | None, has_dist: bool, implicit: bool = False) -> None:
        """One frame event with its record's fields (`dst` None: the record had none)."""
        self._drain()
        self.rows([(t, ev, ch, dev, src, dst, seq, size, flow, kind, reason, None, True if has_dist else None,
                    implicit)], [t])

    def rows(self, rows: Iterable[tuple[Any, ...]], t9: Iterable[float]) -> None:
        """The definition: frame events in order, each a row (t, ev, ch, dev, src, dst, seq, size, flow, kind,
        reason, fifo, dist, implicit) (trace.events.Row; `dist` only tested for None, `fifo` unused) with
        `t9` its record's time.  Both the online summary (`on_batch`) and a trace (`add`, `analyse`) come
        here.  The hot path of a run's summary: one flat loop, the state in locals and lists."""
        F = self.f
        index = F.index
        f_flow, f_dst, f_nenq, f_ntx, f_ttx, f_tenq = F.flow, F.dst, F.n_enq, F.n_tx, F.t_tx, F.t_enq
        f_rdev, f_rnrx = F.r_dev, F.r_nrx
        flows = self._flows
        fid = self._fid
        devs = self.devs
        dtx = devs.tx
        cnt = self._chan_counts
        cbytes = self._chan_bytes
        header = self._header
        max_tx_seq = self.max_tx_seq
        t_end = self.t_end
        try:
            for (_, ev, ch, dev, src, dst, seq, size, flow, kind, reason, _fifo, dist, implicit), t in zip(
                    rows, t9, strict=True):
                if t > t_end:
                    t_end = t
                if implicit and ev == "rx":
                    continue        # handed to a modem that was not the addressee (no MAC): not a delivery
                ck = (ch, ev, reason)
                cnt[ck] = cnt.get(ck, 0) + 1
                if ev == "rx":
                    at_tx = False
                    tx_dev = dtx.get((ch, src)) or devs.tx_dev(ch, src)
                elif ev == "drop":
                    known = dtx.get((ch, src))
                    if known is not None:
                        at_tx = dev == known
                    else:
                        at_tx = reason in TX_REASONS or (reason not in RX_REASONS and dist is None)
                    if at_tx:
                        if known is None:
                            dtx[(ch, src)] = dev
                        tx_dev = dev
                    else:
                        tx_dev = known if known is not None else devs.tx_dev(ch, src)
                else:
                    at_tx = True
                    tx_dev = dev
                    key = (ch, src)
                    if key not in dtx:
                        dtx[key] = dev
                    if ev == "tx":
                        cbytes[ch] = cbytes.get(ch, 0) + size
                if kind != "data":
                    if ev == "tx":      # control frames only count as bytes on air of the flow they serve
                        self._chan_ctrl[ch] = self._chan_ctrl.get(ch, 0) + 1
                        m = flows[self._acc_id(self._ctrl_flow(flow, seq, src, dst, ch, tx_dev), tx_dev, None)].m
                        m.ctrl_sent += 1
                        m.ctrl_bytes_on_air += size
                    continue

                fkey = (tx_dev, seq)
                i = index.get(fkey)
                if i is None:
                    fdst = -1 if dst is None else dst
                    name = flow if flow is not None else tx_dev
                    fl = fid.get(name)
                    if fl is None:
                        fl = self._acc_id(name, tx_dev, fdst)
                    i = F.new(fkey, fl, ch, fdst)
                else:
                    fl = f_flow[i]
                a = flows[fl]
                m = a.m
                if a.t_first is None:
                    a.t_first = t
                a.t_last = t
                if m.src is None:
                    m.src = tx_dev
                if m.dst is None:
                    fdst = f_dst[i]
                    if is_int(fdst) and fdst >= 0:
                        m.dst = fdst

                if ev == "enq":
                    f_nenq[i] += 1
                    if f_tenq[i] is None:
                        f_tenq[i] = t
                    if a.t_first_enq is None:
                        a.t_first_enq = t
                    m.enqueued += 1
                    p = m.payload
                    m.payload_offered += p if p is not None else max(0, size - header.get(tx_dev, 0))
                elif ev == "tx":
                    n_tx = f_ntx[i] = f_ntx[i] + 1
                    f_ttx[i] = t
                    if n_tx == 1:
                        m.unique_sent += 1
                        if seq > max_tx_seq.get(tx_dev, -1):
                            max_tx_seq[tx_dev] = seq
                    m.sent += 1
                    m.data_bytes_on_air += size
                elif ev == "rx":
                    rd = f_rdev[i]
                    if rd == dev:
                        f_rnrx[i] += 1
                    elif rd is None:
                        f_rdev[i] = dev
                        f_rnrx[i] += 1
                    else:
                        F.receiver(i, dev)[1] += 1  # type: ignore[index]
                    m.delivered += 1
                    p = m.payload
                    m.payload_delivered += p if p is not None else max(0, size - header.get(tx_dev, 0))
                    t_enq = f_tenq[i]
                    if t_enq is not None:
                        d = t - t_enq
                        a.delays.append(d)
                        prev = a.prev_delay
                        if prev is not None:
                            a.jit_sum += abs(d - prev)
                            a.jit_n += 1
                        a.prev_delay = d
                else:   # drop
                    de = a.drop_events
                    de[reason] = de.get(reason, 0) + 1
                    if at_tx:
                        F.n_txdrop[i] += 1
                        F.txdrop[i] = reason
                        F.txdrop_at[i] = f_ntx[i]
                    else:
                        rd = f_rdev[i]
                        if rd == dev or rd is None:
                            f_rdev[i] = dev
                            F.r_ndrop[i] += 1
                            F.r_reason[i] = reason
                            F.r_at[i] = f_ntx[i]
                        else:
                            r = F.receiver(i, dev)
                            r[2] += 1           # type: ignore[index]
                            r[3] = reason       # type: ignore[index]
                            r[4] = f_ntx[i]     # type: ignore[index]
        finally:
            self.t_end = t_end

    def _ctrl_flow(self, flow: str | None, seq: int, src: int, dst: int | None, ch: Any, tx_dev: str) -> str:
        """The flow a control frame serves: its `flow`, else the data frame it is about (an RTS names the
        data frame's (src, seq, dst); a CTS/ACK answers with src and dst swapped), else its transmitter."""
        if flow is not None:
            return flow
        F = self.f
        i = F.index.get((tx_dev, seq))
        if i is not None and F.dst[i] in (dst, BROADCAST):
            return self._flows[F.flow[i]].m.name
        if is_int(dst) and dst != BROADCAST:
            i = F.index.get((self.devs.tx_dev(ch, dst), seq))
            if i is not None and F.dst[i] in (src, BROADCAST):
                return self._flows[F.flow[i]].m.name
        return tx_dev

    # -- the end --
    def _channels(self) -> dict[Any, ChannelMetrics]:
        out: dict[Any, ChannelMetrics] = {}
        for (ch, ev, reason), n in self._chan_counts.items():
            c = out.get(ch)
            if c is None:
                c = out[ch] = ChannelMetrics(ch, bytes_on_air=self._chan_bytes.get(ch, 0),
                                             ctrl_sent=self._chan_ctrl.get(ch, 0))
            if ev == "tx":
                c.sent += n
            elif ev == "rx":
                c.delivered += n
            elif ev == "drop":
                c.drop_events[reason] = c.drop_events.get(reason, 0) + n  # type: ignore[index]
            else:
                c.enqueued += n
        for c in out.values():
            c.drop_events = dict(sorted(c.drop_events.items()))
        return {ch: out[ch] for ch in sorted(out, key=lambda c: (isinstance(c, str), c))}

    def result(self, *, horizon: float = DEFAULT_HORIZON, end: float | None = None, limit: int = 1000) -> Analysis:
        """Per-flow metrics, channel counters and the conservation check of the events so far.  Settles
        the frames: call it once, at the end."""
        self._drain()
        meta = self.meta
        if end is None and self.ended is not None:
            end = max(self.ended, self.t_end)
        if end is None:
            dur = meta.get("duration")
            end = max(dur if is_num(dur) else -math.inf, self.t_end)
            if not math.isfinite(end):
                end = 0.0
        cons = self._settle(end, horizon, limit)
        duration = meta.get("duration") if self.ended is None else self.ended
        flows = {name: _finish(a, self.mflows.get(name), duration if is_num(duration) else None)
                 for name, a in self.accs.items()}
        return Analysis(meta=meta, flows=flows, conservation=cons, channels=self._channels())

    def _settle(self, end: float, horizon: float, limit: int) -> Conservation:
        """Final outcomes per frame (into the flows' drops) and the conservation check.  The frames with one
        receiver (or none) that break no rule and have an outcome are counted with numpy; the others
        (several receivers, a violation, in flight) one by one, in order."""
        F = self.f
        n = F.n
        flows = self._flows
        violations: list[str] = []
        total = 0
        in_flight: list[InFlight] = []
        if not n:
            return Conservation(violations, in_flight, frames=0, end=end, total=0)
        i64 = np.int64
        dst_l = F.dst
        dst = np.fromiter((d if -2**62 < d < 2**62 else -1 for d in dst_l), i64, n)   # (only compared to 255)
        n_enq = np.array(F.n_enq, i64)
        n_tx = np.array(F.n_tx, i64)
        n_txdrop = np.array(F.n_txdrop, i64)
        txdrop_at = np.array(F.txdrop_at, i64)
        r_nrx = np.array(F.r_nrx, i64)
        r_ndrop = np.array(F.r_ndrop, i64)
        r_at = np.array(F.r_at, i64)
        r_dev = F.r_dev
        several = np.fromiter((x is not None and not isinstance(x, str) for x in r_dev), bool, n)
        none = np.fromiter((x is None for x in r_dev), bool, n)
        single = ~several & ~none
        odd = several | (n_enq != 1) | (n_txdrop > 1) | ((n_txdrop > 0) & (txdrop_at < n_tx))
        odd |= single & ((r_nrx > 1) | (r_nrx + r_ndrop > n_tx))
        odd |= none & (n_txdrop == 0)            # no outcome: in flight, or a violation
        uni = np.flatnonzero(single & (dst != BROADCAST) & ~odd)
        if uni.size:                             # an outcome at a modem that is not the addressee
            cache: dict[tuple[Any, Any], str | None] = {}
            chs = F.ch
            rx_dev = self.devs.rx_dev
            for i in uni.tolist():
                key = (chs[i], dst_l[i])
                if key in cache:
                    who = cache[key]
                else:
                    who = cache[key] = rx_dev(*key)
                if who is not None and r_dev[i] != who:
                    odd[i] = True
        ok = ~odd
        tx_final = (n_txdrop > 0) & (txdrop_at == n_tx)
        rx_any = single & (r_nrx > 0)
        f_flow = F.flow
        for sel, why in ((ok & single & (r_nrx == 0) & (r_ndrop > 0) & (r_at == n_tx) & ~tx_final, F.r_reason),
                         (ok & (n_txdrop > 0) & ~rx_any, F.txdrop)):
            for (f, r), c in Counter((f_flow[i], why[i]) for i in np.flatnonzero(sel).tolist()).items():
                drops = flows[f].m.drops
                drops[r] = drops.get(r, 0) + c
        sent = ok & (n_tx > 0)
        fl = np.array(f_flow, i64)
        intended = np.bincount(fl[sent], weights=np.where(dst[sent] == BROADCAST, single[sent], 1),
                               minlength=len(flows))
        for f in np.flatnonzero(intended).tolist():
            flows[f].intended += int(intended[f])

        max_tx_seq = self.max_tx_seq
        for i in np.flatnonzero(odd).tolist():
            tx_dev, seq = F.keys[i]
            a = flows[f_flow[i]]
            m = a.m
            label = f"{tx_dev} seq {seq} (flow {m.name}): "
            msgs: list[str] = []
            drops = m.drops
            rcv = F.receivers(i)
            nt = F.n_tx[i]
            ntd = F.n_txdrop[i]
            tda = F.txdrop_at[i]
            fdst = dst_l[i]
            any_rx = False
            final = ntd > 0 and tda == nt
            for rdev, n_rx, n_drop, last_reason, last_at in rcv:
                if n_rx:
                    any_rx = True
                    if n_rx > 1:
                        msgs.append(f"delivered {n_rx} times at {rdev}")
                elif n_drop and last_at == nt and not final:
                    drops[last_reason] = drops.get(last_reason, 0) + 1
                if n_rx + n_drop > nt:
                    msgs.append(f"{n_rx + n_drop} outcomes at {rdev} for {nt} transmission(s)")
            txr = F.txdrop[i]
            if ntd and not any_rx:
                drops[txr] = drops.get(txr, 0) + 1    # type: ignore[index]
            if nt:
                a.intended += len(rcv) if fdst == BROADCAST else 1
            ne = F.n_enq[i]
            if ne == 0:
                msgs.append("no enq record")
            elif ne > 1:
                msgs.append(f"enqueued {ne} times")
            if ntd > 1:
                msgs.append(f"dropped {ntd} times at the transmitter")
            if ntd and tda < nt:
                msgs.append(f"transmitted after its transmitter-side drop ({txr})")
            if fdst != BROADCAST and rcv:
                if len(rcv) > 1:
                    names = ", ".join(sorted(r[0] for r in rcv))
                    msgs.append(f"outcomes at {len(rcv)} receivers ({names}) of a unicast frame")
                else:
                    addressee = self.devs.rx_dev(F.ch[i], fdst)
                    rdev = rcv[0][0]
                    if addressee is not None and rdev != addressee:
                        msgs.append(f"outcome at {rdev}, not at its addressee {addressee}")
            if not rcv and not ntd:
                t_enq = F.t_enq[i]
                if nt == 0:
                    if max_tx_seq.get(tx_dev, -1) > seq:
                        msgs.append(f"never transmitted nor dropped, although later frames of {tx_dev} were sent")
                    else:
                        in_flight.append(InFlight(tx_dev, seq, m.name, "queued", t_enq, None))
                        m.in_flight += 1
                else:
                    t_tx = F.t_tx[i]
                    if t_tx is not None and t_tx >= end - horizon:
                        in_flight.append(InFlight(tx_dev, seq, m.name, "on air", t_enq, t_tx))
                        m.in_flight += 1
                    else:
                        msgs.append(f"transmitted at {t_tx:g} s, no outcome by the end ({end:g} s)")
            for msg in msgs:
                total += 1
                if len(violations) < limit:
                    violations.append(label + msg)
        if total > len(violations):
            violations.append(f"... {total - len(violations)} more violations")
        return Conservation(violations, in_flight, frames=n, end=end, total=total)


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
        return acc.result(horizon=horizon, end=end, limit=limit)
    meta, events = open_source(src, meta)
    acc = Accumulator(meta)
    add = acc.add
    for rec in events:
        add(rec)
    return acc.result(horizon=horizon, end=end, limit=limit)


def _finish(a: _Acc, mf: Mapping[str, Any] | None, duration: float | None) -> FlowMetrics:
    m = a.m
    m.drops = dict(sorted(m.drops.items()))
    m.superseded = {r: n - m.drops.get(r, 0) for r, n in sorted(a.drop_events.items())
                    if n - m.drops.get(r, 0) > 0}
    # active window
    w0: float | None = None
    w1: float | None = None
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
        w0 = a.t_first_enq if a.t_first_enq is not None else a.t_first
        w1 = a.t_last
    if w0 is not None and w1 is not None:
        m.window = (w0, w1)
        span = w1 - w0
        if span > 0:
            m.throughput = m.payload_delivered / span
            m.offered = m.payload_offered / span
    on_air = m.bytes_on_air
    m.efficiency = m.payload_delivered / on_air if on_air > 0 else None
    m.delivery_ratio = m.delivered / a.intended if a.intended > 0 else None
    if a.delays:
        d = np.frombuffer(a.delays, dtype=np.float64)
        m.delay_mean = float(d.mean())
        m.delay_median, m.delay_p95 = median_p95(d)
    m.jitter = a.jit_sum / a.jit_n if a.jit_n else None
    return m


def median_p95(d: np.ndarray) -> tuple[float, float]:
    """(np.median(d), np.percentile(d, 95)) of finite values, the same doubles from one sort (numpy's
    wrappers cost ~0.1 ms a call, per flow): the median is the mean of the middle one or two values, the
    95th percentile numpy's linear interpolation (virtual index (n - 1) * 0.95, `_lerp`)."""
    s = np.sort(d)
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


