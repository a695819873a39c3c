"""The metrics as main defined them before the batched Accumulator (issue #19): one event at a time, state in
Python objects; kept as the reference that tests/test_online_metrics.py holds the batched code to.

Original docstring: per-flow metrics and the conservation check, computed from trace records (docs/trace-format.md).

One pass over the events with state keyed by (transmitter dccommsId, seq), then one pass over the
frames seen: time and memory are linear in the trace.  Everything here is pure: files are only read.

    a = analyse("run.jsonl")            # one pass: a.flows (FlowMetrics per flow) + a.conservation
    assert a.conservation == [] and not a.conservation.in_flight

`flow_metrics()` and `conservation()` are the same pass, returning one half each.
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from uwsimnet_zenoh.analysis.read import (
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
from uwsimnet_zenoh.kernel.frame import BROADCAST


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
class _Frame:
    __slots__ = ("flow", "ch", "dst", "t_enq", "n_enq", "n_tx", "t_tx", "n_txdrop", "txdrop",
                 "txdrop_at", "rcv")

    def __init__(self, flow: str, ch: Any, dst: int) -> None:
        self.flow = flow
        self.ch = ch
        self.dst = dst
        self.t_enq: float | None = None
        self.n_enq = 0
        self.n_tx = 0
        self.t_tx: float | None = None
        self.n_txdrop = 0
        self.txdrop: str | None = None
        self.txdrop_at = 0          # n_tx when the transmitter dropped it
        # per receiver: [dccommsId, rx events, drop events, last drop reason, n_tx at the last drop];
        # one receiver (unicast) is kept as that list, several (broadcast) as a dict by dccommsId
        self.rcv: list[Any] | dict[str, list[Any]] | None = None

    def receiver(self, dev: str) -> list[Any]:
        rcv = self.rcv
        if rcv is None:
            r = self.rcv = [dev, 0, 0, None, 0]
            return r
        if isinstance(rcv, list):
            if rcv[0] == dev:
                return rcv
            rcv = self.rcv = {rcv[0]: rcv}
        r = rcv.get(dev)
        if r is None:
            r = rcv[dev] = [dev, 0, 0, None, 0]
        return r

    def receivers(self) -> list[list[Any]]:
        rcv = self.rcv
        if rcv is None:
            return []
        return [rcv] if isinstance(rcv, list) else list(rcv.values())


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
    """The metrics of a run, accumulated one event at a time (O(1) per event): the one definition behind
    `analyse()` on a trace and the online summary of `uwsimnet run` (a tracer listener, `on_event`), so
    the two give the same numbers for the same run.

        acc = Accumulator(net.meta()); net.tracer.listen(Callback(acc.on_event)); net.run(); a = acc.result()
    """

    def __init__(self, meta: Mapping[str, Any] | None = None) -> None:
        meta = dict(meta or {})
        self.meta = meta
        self.devs = devs = DeviceMap(meta)
        self.mflows = mflows = _meta_flows(meta)
        self.accs: dict[str, _Acc] = {}
        for name, f in mflows.items():
            size = f.get("size")
            fm = FlowMetrics(name=name, src=f.get("src") if isinstance(f.get("src"), str) else None,
                             dst=f.get("dst") if is_int(f.get("dst")) else None,
                             payload=size if is_int(size) else None)
            self.accs[name] = _Acc(fm)
        self.frames: dict[tuple[str, int], _Frame] = {}
        self.max_tx_seq: dict[str, int] = {}
        self._chan_counts: dict[tuple[Any, str, str | None], int] = {}
        self._chan_bytes: dict[Any, int] = {}
        self._chan_ctrl: dict[Any, int] = {}
        self.t_end = -math.inf
        self.ended: float | None = None     # an `end` record: the run's actual end (stopped early, realtime)
        self._header = devs.header

    def add(self, rec: Mapping[str, Any]) -> None:
        """One checked trace record (analysis.read); records of other kinds are skipped."""
        ev = rec["ev"]
        if ev not in EVENTS:
            if ev == "end" and is_num(rec.get("t")) and math.isfinite(rec["t"]):
                self.ended = float(rec["t"])
            return
        reason, flow, kind = rec.get("reason"), rec.get("flow"), rec.get("kind", "data")
        self.event(rec["t"], ev, rec["ch"], rec["dev"], rec["src"], rec.get("dst"), rec["seq"], rec["size"],
                   flow if isinstance(flow, str) else None, kind if isinstance(kind, str) else "data",
                   reason if isinstance(reason, str) else None, "dist" in rec, bool(rec.get("implicit")))

    def on_event(self, t: float, ev: str, ch: int, dev: str, frame: Any, reason: str | None,
                 fifo: int | None, dist: float | None, implicit: bool = False) -> None:
        """A tracer listener (trace.events.Tracer.listen): the event as its trace record would say it.

        The same as `event()` on the record's fields (tests/test_online_metrics.py holds them equal); the
        common cases (enq, tx and rx of a data frame of a known flow with its source, addressee and payload
        size known) are done here in one call, everything else by `event()`."""
        t = round(t, 9)
        if reason is None and not implicit and frame.kind == "data":
            a = self.accs.get(frame.flow)
            if a is not None and a.t_first is not None:
                m = a.m
                if m.src is not None and m.dst is not None and m.payload is not None:
                    frames = self.frames
                    if ev == "enq":
                        tx = self.devs.tx
                        key = (ch, frame.src)
                        if key not in tx:
                            tx[key] = dev
                        fkey = (dev, frame.seq)
                        fr = frames.get(fkey)
                        if fr is None:
                            fr = frames[fkey] = _Frame(frame.flow, ch, frame.dst)
                        if fr.flow is frame.flow or fr.flow == frame.flow:
                            if t > self.t_end:
                                self.t_end = t
                            cnt = self._chan_counts
                            ck = (ch, ev, None)
                            cnt[ck] = cnt.get(ck, 0) + 1
                            a.t_last = t
                            fr.n_enq += 1
                            if fr.t_enq is None:
                                fr.t_enq = t
                            if a.t_first_enq is None:
                                a.t_first_enq = t
                            m.enqueued += 1
                            m.payload_offered += m.payload
                            return
                    elif ev == "tx":
                        fr = frames.get((dev, frame.seq))
                        if fr is not None and fr.ch == ch and (ch, frame.src) in self.devs.tx and \
                                (fr.flow is frame.flow or fr.flow == frame.flow):
                            if t > self.t_end:
                                self.t_end = t
                            cnt = self._chan_counts
                            ck = (ch, ev, None)
                            cnt[ck] = cnt.get(ck, 0) + 1
                            size = frame.size
                            self._chan_bytes[ch] = self._chan_bytes.get(ch, 0) + size
                            a.t_last = t
                            n_tx = fr.n_tx = fr.n_tx + 1
                            fr.t_tx = t
                            if n_tx == 1:
                                m.unique_sent += 1
                                seq = frame.seq
                                mx = self.max_tx_seq
                                if seq > mx.get(dev, -1):
                                    mx[dev] = seq
                            m.sent += 1
                            m.data_bytes_on_air += size
                            return
                    elif ev == "rx":
                        tx_dev = self.devs.tx.get((ch, frame.src))
                        fr = frames.get((tx_dev, frame.seq)) if tx_dev else None
                        if fr is not None and (fr.flow is frame.flow or fr.flow == frame.flow):
                            if t > self.t_end:
                                self.t_end = t
                            cnt = self._chan_counts
                            ck = (ch, ev, None)
                            cnt[ck] = cnt.get(ck, 0) + 1
                            a.t_last = t
                            fr.receiver(dev)[1] += 1
                            m.delivered += 1
                            m.payload_delivered += m.payload
                            t_enq = fr.t_enq
                            if t_enq is not None:
                                d = t - t_enq
                                a.delays.append(d)
                                prev = a.prev_delay
                                if prev is not None:
                                    a.jit_sum += abs(d - prev)
                                    a.jit_n += 1
                                a.prev_delay = d
                            return
        self.event(t, ev, ch, dev, frame.src, frame.dst, frame.seq, frame.size, frame.flow,
                   frame.kind, reason, dist is not None, implicit)

    def _acc(self, name: str, tx_dev: str, dst: Any) -> _Acc:
        a = self.accs.get(name)
        if a is None:
            a = self.accs[name] = _Acc(FlowMetrics(name=name, src=tx_dev, dst=dst if is_int(dst) else None))
        return a

    def event(self, t: float, ev: str, ch: Any, dev: str, src: int, dst: int | None, seq: int, size: int,
              flow: str | None, kind: str, reason: str | None, has_dist: bool, implicit: bool = False) -> None:
        """One frame event (`dst` None: the record had none).  The hot path of a run's summary: kept flat."""
        if t > self.t_end:
            self.t_end = t
        if implicit and ev == "rx":
            return                  # handed to a modem that was not the addressee (no MAC): not a delivery
        cnt = self._chan_counts
        ck = (ch, ev, reason)
        cnt[ck] = cnt.get(ck, 0) + 1
        devs = self.devs
        if ev == "drop":
            at_tx, tx_dev = devs._drop(ch, src, dev, reason, has_dist)  # type: ignore[arg-type]
        elif ev == "rx":
            at_tx = False
            tx_dev = devs.tx.get((ch, src)) or devs.tx_dev(ch, src)
        else:
            at_tx = True
            tx_dev = dev
            key = (ch, src)
            if key not in devs.tx:
                devs.tx[key] = dev
            if ev == "tx":
                self._chan_bytes[ch] = self._chan_bytes.get(ch, 0) + size
        if kind != "data":
            if ev == "tx":          # control frames only count as bytes on air of the flow they serve
                self._chan_ctrl[ch] = self._chan_ctrl.get(ch, 0) + 1
                a = self._acc(_ctrl_flow(flow, seq, src, dst, ch, tx_dev, devs, self.frames), tx_dev, None)
                a.m.ctrl_sent += 1
                a.m.ctrl_bytes_on_air += size
            return

        frames = self.frames
        key = (tx_dev, seq)
        fr = frames.get(key)
        if fr is None:
            fr = frames[key] = _Frame(flow if flow is not None else tx_dev, ch, -1 if dst is None else dst)
        a = self.accs.get(fr.flow)
        if a is None:
            a = self._acc(fr.flow, tx_dev, fr.dst)
        m = a.m
        if a.t_first is None:
            a.t_first = t
        a.t_last = t
        if m.src is None:
            m.src = tx_dev
        if m.dst is None and is_int(fr.dst) and fr.dst >= 0:
            m.dst = fr.dst

        if ev == "enq":
            fr.n_enq += 1
            if fr.t_enq is None:
                fr.t_enq = t
            if a.t_first_enq is None:
                a.t_first_enq = t
            m.enqueued += 1
            p = m.payload
            m.payload_offered += p if p is not None else max(0, size - self._header.get(tx_dev, 0))
        elif ev == "tx":
            n_tx = fr.n_tx = fr.n_tx + 1
            fr.t_tx = t
            if n_tx == 1:
                m.unique_sent += 1
                if seq > self.max_tx_seq.get(tx_dev, -1):
                    self.max_tx_seq[tx_dev] = seq
            m.sent += 1
            m.data_bytes_on_air += size
        elif ev == "rx":
            fr.receiver(dev)[1] += 1
            m.delivered += 1
            p = m.payload
            m.payload_delivered += p if p is not None else max(0, size - self._header.get(tx_dev, 0))
            t_enq = fr.t_enq
            if t_enq is not None:
                d = t - t_enq
                a.delays.append(d)
                prev = a.prev_delay
                if prev is not None:
                    a.jit_sum += abs(d - prev)
                    a.jit_n += 1
                a.prev_delay = d
        else:   # drop
            a.drop_events[reason] = a.drop_events.get(reason, 0) + 1  # type: ignore[index]
            if at_tx:
                fr.n_txdrop += 1
                fr.txdrop = reason
                fr.txdrop_at = fr.n_tx
            else:
                r = fr.receiver(dev)
                r[2] += 1
                r[3] = reason
                r[4] = fr.n_tx

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
        meta = self.meta
        if end is None and self.ended is not None:
            end = max(self.ended, self.t_end)
        if end is None:
            dur = meta.get("duration")
            end = max(dur if is_num(dur) else -math.inf, self.t_end)
            if not math.isfinite(end):
                end = 0.0
        cons = _settle(self.frames, self.accs, self.devs, self.max_tx_seq, end, horizon, limit)
        duration = meta.get("duration") if self.ended is None else self.ended
        flows = {name: _finish(a, self.mflows.get(name), duration if is_num(duration) else None)
                 for name, a in self.accs.items()}
        return Analysis(meta=meta, flows=flows, conservation=cons, channels=self._channels())


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
        event = acc.event
        for t, ev, ch, dev, s, d, seq, size, flow, kind, reason, dist, imp in zip(
                *(cols[k] for k in ("t", "ev", "ch", "dev", "src", "dst", "seq", "size", "flow", "kind", "reason",
                                    "dist", "implicit")), strict=True):
            if ev in EVENTS:
                event(t, ev, ch, dev, s, d, seq, size, flow, kind, reason, dist is not None, imp)
        return acc.result(horizon=horizon, end=end, limit=limit)
    meta, events = open_source(src, meta)
    acc = Accumulator(meta)
    add = acc.add
    for rec in events:
        add(rec)
    return acc.result(horizon=horizon, end=end, limit=limit)


def _ctrl_flow(flow: str | None, seq: int, src: int, dst: int | None, ch: Any, tx_dev: str, devs: DeviceMap,
               frames: Mapping[tuple[str, int], _Frame]) -> str:
    """The flow a control frame serves: its `flow`, else the data frame it is about (an RTS names the
    data frame's (src, seq, dst); a CTS/ACK answers with src and dst swapped), else its transmitter."""
    if flow is not None:
        return flow
    fr = frames.get((tx_dev, seq))
    if fr is not None and (fr.dst == dst or fr.dst == BROADCAST):
        return fr.flow
    if is_int(dst) and dst != BROADCAST:
        fr = frames.get((devs.tx_dev(ch, dst), seq))
        if fr is not None and (fr.dst == src or fr.dst == BROADCAST):
            return fr.flow
    return tx_dev


def _settle(frames: dict[tuple[str, int], _Frame], accs: dict[str, _Acc], devs: DeviceMap,
            max_tx_seq: dict[str, int], end: float, horizon: float, limit: int) -> Conservation:
    """Final outcomes per frame (into the flows' drops) and the conservation check."""
    violations: list[str] = []
    total = 0
    in_flight: list[InFlight] = []

    def bad(fr_label: tuple[str, int, str], msg: str) -> None:
        nonlocal total
        total += 1
        if len(violations) < limit:
            tx_dev, seq, flow = fr_label
            violations.append(f"{tx_dev} seq {seq} (flow {flow}): {msg}")

    for (tx_dev, seq), fr in frames.items():
        a = accs[fr.flow]
        m = a.m
        drops = m.drops
        label = (tx_dev, seq, fr.flow)        # formatted only for a violation
        rcv = fr.receivers()
        n_tx = fr.n_tx
        any_rx = False
        tx_final = fr.n_txdrop > 0 and fr.txdrop_at == n_tx
        for rdev, n_rx, n_drop, last_reason, last_at in rcv:
            if n_rx:
                any_rx = True
                if n_rx > 1:
                    bad(label, f"delivered {n_rx} times at {rdev}")
            elif n_drop and last_at == n_tx and not tx_final:
                drops[last_reason] = drops.get(last_reason, 0) + 1
            if n_rx + n_drop > n_tx:
                bad(label, f"{n_rx + n_drop} outcomes at {rdev} for {n_tx} transmission(s)")
        if fr.n_txdrop and not any_rx:
            drops[fr.txdrop] = drops.get(fr.txdrop, 0) + 1
        if n_tx:
            a.intended += len(rcv) if fr.dst == BROADCAST else 1

        if fr.n_enq == 0:
            bad(label, "no enq record")
        elif fr.n_enq > 1:
            bad(label, f"enqueued {fr.n_enq} times")
        if fr.n_txdrop > 1:
            bad(label, f"dropped {fr.n_txdrop} times at the transmitter")
        if fr.n_txdrop and fr.txdrop_at < n_tx:
            bad(label, f"transmitted after its transmitter-side drop ({fr.txdrop})")
        if fr.dst != BROADCAST and rcv:
            if len(rcv) > 1:
                names = ", ".join(sorted(r[0] for r in rcv))
                bad(label, f"outcomes at {len(rcv)} receivers ({names}) of a unicast frame")
            else:
                addressee = devs.rx_dev(fr.ch, fr.dst)
                rdev = rcv[0][0]
                if addressee is not None and rdev != addressee:
                    bad(label, f"outcome at {rdev}, not at its addressee {addressee}")
        if not rcv and not fr.n_txdrop:
            if n_tx == 0:
                if max_tx_seq.get(tx_dev, -1) > seq:
                    bad(label, f"never transmitted nor dropped, although later frames of {tx_dev} were sent")
                else:
                    in_flight.append(InFlight(tx_dev, seq, fr.flow, "queued", fr.t_enq, None))
                    m.in_flight += 1
            elif fr.t_tx is not None and fr.t_tx >= end - horizon:
                in_flight.append(InFlight(tx_dev, seq, fr.flow, "on air", fr.t_enq, fr.t_tx))
                m.in_flight += 1
            else:
                bad(label, f"transmitted at {fr.t_tx:g} s, no outcome by the end ({end:g} s)")
    if total > len(violations):
        violations.append(f"... {total - len(violations)} more violations")
    return Conservation(violations, in_flight, frames=len(frames), end=end, total=total)


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
        m.delay_median = float(np.median(d))
        m.delay_p95 = float(np.percentile(d, 95))
    m.jitter = a.jit_sum / a.jit_n if a.jit_n else None
    return m


def flow_metrics(path_or_events: Source, meta: dict[str, Any] | None = None) -> dict[str, FlowMetrics]:
    """Per-flow metrics of a trace (path or records); flows of the meta first, in its order."""
    return analyse(path_or_events, meta).flows


def conservation(path_or_events: Source, meta: dict[str, Any] | None = None, *,
                 horizon: float = DEFAULT_HORIZON, end: float | None = None) -> Conservation:
    """Violations of the conservation law (a list: empty = OK) with `.in_flight` frames at the end."""
    return analyse(path_or_events, meta, horizon=horizon, end=end).conservation


