"""The metrics' per-event fold: frame events in, per-frame, per-flow and per-channel state out, and the
conservation check of every frame at the end.  The definition behind `analysis.metrics.Accumulator` (which
builds the results from this state), in a module of its own so that `make` compiles it with mypyc
(uwsimnet_zenoh/_native.py): the state is native objects with typed fields, the loop C.  Pure Python runs
the same code.

Times stay the numbers the records give (an int time stays an int, as in `round(3, 9)`); only the delays
are computed in floats (exact while times are below 2**53 s).
"""

from __future__ import annotations

import math
from typing import Any, Final

from mypy_extensions import mypyc_attr

from ..kernel.frame import BROADCAST, Frame
from ..trace.tracer import Listener, round_fast
from .read import RX_REASONS, TX_REASONS

_BROADCAST: Final = BROADCAST
_TX_REASONS: Final = TX_REASONS
_RX_REASONS: Final = RX_REASONS


@mypyc_attr(acyclic=True)     # holds no reference back: not tracked by the cyclic GC (compiled)
class Receiver:
    """One receiver's outcomes of a frame with several."""

    def __init__(self, dev: str, n_rx: int, n_drop: int, reason: str | None, at: int) -> None:
        self.dev = dev
        self.n_rx = n_rx
        self.n_drop = n_drop
        self.reason = reason          # of the last drop
        self.at = at                  # n_tx at the last drop

    def as_list(self) -> list[Any]:
        return [self.dev, self.n_rx, self.n_drop, self.reason, self.at]


@mypyc_attr(acyclic=True)     # holds no reference back: not tracked by the cyclic GC (compiled)
class FrameState:
    """One data frame, (transmitter dccommsId, seq): its events counted.  `r_*` is its receiver while it has
    one (unicast: at most one); from a second receiver on, `multi` holds them all in order."""

    def __init__(self, dev: str, seq: int, flow: int, ch: object, dst: int) -> None:
        self.dev = dev
        self.seq = seq
        self.flow = flow
        self.ch = ch
        self.dst = dst                  # -1: the record had none
        self.n_enq = 0
        self.n_tx = 0
        self.n_txdrop = 0
        self.txdrop: str | None = None  # reason of the last transmitter-side drop
        self.txdrop_at = 0              # n_tx at it
        self.r_dev: str | None = None
        self.r_nrx = 0
        self.r_ndrop = 0
        self.r_reason: str | None = None
        self.r_at = 0
        self.multi: dict[str, Receiver] | None = None
        self.t_enq: object = None
        self.t_tx: object = None        # last transmission

    def receiver(self, dev: str) -> Receiver | None:
        """The record of receiver `dev` if the frame has several (made one from a second receiver on),
        else None: the r_* fields are its receiver's (set to `dev` if it had none)."""
        multi = self.multi
        if multi is None:
            rd = self.r_dev
            if rd is None:
                self.r_dev = dev
                return None
            if rd == dev:
                return None
            multi = self.multi = {rd: Receiver(rd, self.r_nrx, self.r_ndrop, self.r_reason, self.r_at)}
        r = multi.get(dev)
        if r is None:
            r = multi[dev] = Receiver(dev, 0, 0, None, 0)
        return r

    def receivers(self) -> list[Receiver]:
        if self.multi is not None:
            return list(self.multi.values())
        if self.r_dev is None:
            return []
        return [Receiver(self.r_dev, self.r_nrx, self.r_ndrop, self.r_reason, self.r_at)]


@mypyc_attr(acyclic=True)     # holds no reference back: not tracked by the cyclic GC (compiled)
class Count:
    """One counter in a dict (of drop events by reason): incremented in place, where an int value would
    cost a dict store and a boxed int per event."""

    def __init__(self) -> None:
        self.n = 0


def bump(by: dict[str | None, Count], key: str | None) -> None:
    c = by.get(key)
    if c is None:
        c = by[key] = Count()
    c.n += 1


def counts(by: dict[str | None, Count]) -> dict[str | None, int]:
    """A dict of counters as plain numbers."""
    return {k: c.n for k, c in by.items()}


LOW: Final = 4096
"""Source addresses below this are found in a list (MAC addresses are small numbers), the others in a dict."""


@mypyc_attr(acyclic=True)
class Addresses:
    """A channel's transmitters learnt from its events, by source address (the fold reads `low` inline)."""

    def __init__(self) -> None:
        self.low: list[Sender | None] = []
        self.high: dict[int, Sender] = {}

    def get(self, src: int) -> Sender | None:
        low = self.low
        return low[src] if 0 <= src < len(low) else self.high.get(src)

    def set(self, src: int, s: Sender) -> None:
        if 0 <= src < LOW:
            low = self.low
            while len(low) <= src:
                low.append(None)
            low[src] = s
        else:
            self.high[src] = s


@mypyc_attr(acyclic=True)
class Sender:
    """One transmitter (dccommsId): its data frames by seq and the highest seq it transmitted.  The fold
    finds it from a channel's source address (an int key) rather than by name, once per event."""

    def __init__(self, dev: str) -> None:
        self.dev = dev
        self.seqs: list[FrameState] = []                # frames 0, 1, 2, ...: seq k at index k
        self.frames: dict[int, FrameState] = {}         # the others (a seq that skipped ahead, negative)
        self.max_seq = -1
        self.flow_name: object = None                   # the flow name of its last new frame, and its id
        self.flow_id = -1

    def get(self, seq: int) -> FrameState | None:
        """Its data frame `seq`, if it has one.  A modem numbers its frames 0, 1, 2, ..., so they are a
        list read by index (no int made for a key, no hash); a trace that skips goes on in the dict."""
        seqs = self.seqs
        if 0 <= seq < len(seqs):
            return seqs[seq]
        return self.frames.get(seq)


@mypyc_attr(acyclic=True)     # holds no reference back: not tracked by the cyclic GC (compiled)
class FlowState:
    """One flow's counters (analysis.metrics.FlowMetrics' fields that the events make)."""

    def __init__(self, name: str, src: str | None, dst: int | None, payload: int | None) -> None:
        self.name = name
        self.src = src
        self.dst = dst
        self.payload = payload
        self.enqueued = 0
        self.sent = 0
        self.unique_sent = 0
        self.delivered = 0
        self.payload_delivered = 0
        self.payload_offered = 0
        self.data_bytes_on_air = 0
        self.ctrl_sent = 0
        self.ctrl_bytes_on_air = 0
        self.t_first: object = None
        self.t_first_enq: object = None
        self.t_last: object = None
        self.delays: list[float] = []
        self.prev_delay = 0.0
        self.has_prev = False
        self.jit_sum = 0.0
        self.jit_n = 0
        self.drop_events: dict[str | None, Count] = {}  # every data drop event, by reason
        self.drops: dict[str | None, Count] = {}        # final outcomes (settle)
        self.intended = 0
        self.in_flight = 0


@mypyc_attr(acyclic=True)     # holds no reference back: not tracked by the cyclic GC (compiled)
class ChannelState:
    def __init__(self) -> None:
        self.enqueued = 0
        self.sent = 0
        self.ctrl_sent = 0
        self.bytes_on_air = 0
        self.delivered = 0
        self.drop_events: dict[str | None, Count] = {}


class Fold(Listener):
    """The state of a run's events so far.  `meta_tx`/`meta_rx`: (channel, address) -> dccommsId from the
    meta (the fallbacks of transmitters learnt from enq/tx events); `header`: header bytes per dccommsId."""

    def __init__(self, meta_tx: dict[tuple[object, int], str], meta_rx: dict[tuple[object, int], str],
                 header: dict[str, int]) -> None:
        self.meta_tx = meta_tx
        self.meta_rx = meta_rx
        self.header = header
        self.tx: dict[object, Addresses] = {}               # learnt: ch -> src -> transmitter
        self.flows: list[FlowState] = []
        self.fid: dict[str, int] = {}
        self.frames: list[FrameState] = []
        self.senders: dict[str, Sender] = {}                # transmitter dccommsId -> its frames
        self.channels: dict[object, ChannelState] = {}
        self.t_end: object = None           # None: no event yet
        self._t_end_f = -math.inf           # t_end when it is a float
        self._last_ch: object = None        # the channel of the last event, its state and its transmitters
        self._c: ChannelState | None = None
        self._ctx = Addresses()
        self._t_prev = math.nan             # the last float time `event` was given, and its record's time:
        self._t9_prev: object = None        # events come in runs at one time (enq, then tx or drop)

    def flow(self, name: str, src: str | None, dst: int | None, payload: int | None) -> int:
        """The id of flow `name`, a new one with these fields if it has none."""
        i = self.fid.get(name)
        if i is None:
            i = len(self.flows)
            self.flows.append(FlowState(name, src, dst, payload))
            self.fid[name] = i
        return i

    def tx_dev(self, ch: object, src: int) -> str:
        """The dccommsId transmitting as `src` on channel `ch` (or `ch:src` if nobody knows)."""
        a = self.tx.get(ch)
        s = a.get(src) if a is not None else None
        if s is not None:
            return s.dev
        dev = self.meta_tx.get((ch, src))
        return dev if dev is not None else f"{ch}:{src}"

    def sender(self, dev: str) -> Sender:
        s = self.senders.get(dev)
        if s is None:
            s = self.senders[dev] = Sender(dev)
        return s

    def frame(self, dev: str, seq: int) -> FrameState | None:
        s = self.senders.get(dev)
        return s.get(seq) if s is not None else None

    def _channel(self, ch: object) -> ChannelState:
        c = self.channels.get(ch)
        if c is None:
            c = self.channels[ch] = ChannelState()
        return c

    def _ctrl_flow(self, flow: str | None, seq: int, src: int, dst: object, ch: object, tx_dev: str) -> str:
        """The flow a control frame serves: its `flow`, else the data frame it is about (an RTS names the
        data frame's (src, seq, dst); a CTS/ACK answers with src and dst swapped), else its transmitter."""
        if flow is not None:
            return flow
        f = self.frame(tx_dev, seq)
        if f is not None and (f.dst == dst or f.dst == _BROADCAST):
            return self.flows[f.flow].name
        if isinstance(dst, int) and not isinstance(dst, bool) and dst != _BROADCAST:
            f = self.frame(self.tx_dev(ch, dst), seq)
            if f is not None and (f.dst == src or f.dst == _BROADCAST):
                return self.flows[f.flow].name
        return tx_dev

    def rows(self, rows: list[Any], t9: list[Any]) -> None:
        """Frame events in order, each a row (t, ev, ch, dev, src, dst, seq, size, flow, kind, reason, fifo,
        dist, implicit) (trace.events.Row; `dist` only tested for None, `fifo` unused), `t9[k]` the time
        of row k's record: `event()` of each."""
        if len(rows) != len(t9):
            raise ValueError(f"{len(rows)} rows and {len(t9)} times")
        for k in range(len(rows)):
            r: tuple[Any, ...] = rows[k]
            self.fold(t9[k], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8], r[9], r[10], r[12] is not None,
                      bool(r[13]))

    def event(self, t: Any, ev: str, ch: int, dev: str, frame: Frame, reason: str | None, fifo: int | None,
              dist: Any, implicit: Any) -> None:
        """A frame event from the output port (trace.tracer.Listener): `fold` of its record's fields, its
        time rounded as the record says it (once per run of events at one time)."""
        if type(t) is float:
            tf: float = t
            if tf == self._t_prev:
                t9: Any = self._t9_prev
            else:
                t9 = round_fast(tf, 1e9, 9)
                if tf > 0.0:        # (never -0.0, which equals 0.0 but is another record)
                    self._t_prev = tf
                    self._t9_prev = t9
        else:
            t9 = round(t, 9)
        self.fold(t9, ev, ch, dev, frame.src, frame.dst, frame.seq, frame.size, frame.flow, frame.kind, reason,
                  dist is not None, bool(implicit))

    def fold(self, t: object, ev: str, ch: object, dev: str, src: int, dst: object, seq: int, size: int,
             flow: str | None, kind: str, reason: str | None, has_dist: bool, implicit: bool) -> None:
        """One frame event, its record's fields (`t` its time as the record says it, `dst` None if the
        record had none, `has_dist` whether it had a distance): the definition of the metrics, per event.
        `event` calls it at once for a run's online summary; `rows` for a trace read back."""
        t_end = self.t_end
        t_o: object = t         # (stored as given: a float narrowed below would be boxed anew)
        if isinstance(t, float) and isinstance(t_end, float):
            if t > self._t_end_f:
                self.t_end = t_o
                self._t_end_f = t
        elif t_end is None or t > t_end:  # type: ignore[operator]
            self.t_end = t
            self._t_end_f = t if isinstance(t, float) else -math.inf
        if implicit and ev == "rx":
            return          # handed to a modem that was not the addressee (no MAC): not a delivery
        c = self._c
        ctx = self._ctx
        if ch is not self._last_ch or c is None:
            c = self._c = self.channels.get(ch) or self._channel(ch)
            got = self.tx.get(ch)
            if got is None:
                got = self.tx[ch] = Addresses()
            ctx = self._ctx = got
            self._last_ch = ch
        low = ctx.low
        got_s = low[src] if 0 <= src < len(low) else ctx.high.get(src)
        if ev == "rx":
            c.delivered += 1
            at_tx = False
            snd = got_s if got_s is not None else self.sender(self.tx_dev(ch, src))
        elif ev == "drop":
            de = c.drop_events
            cnt = de.get(reason)
            if cnt is None:
                cnt = de[reason] = Count()
            cnt.n += 1
            if got_s is not None:
                at_tx = dev == got_s.dev
                snd = got_s
            else:
                at_tx = reason in _TX_REASONS or (reason not in _RX_REASONS and not has_dist)
                if at_tx:
                    snd = self.sender(dev)
                    ctx.set(src, snd)
                else:
                    snd = self.sender(self.tx_dev(ch, src))
        else:
            at_tx = True
            if got_s is None:
                snd = self.sender(dev)
                ctx.set(src, snd)
            elif got_s.dev == dev:
                snd = got_s
            else:               # the address was another transmitter's first
                snd = self.sender(dev)
            if ev == "tx":
                c.sent += 1
                c.bytes_on_air += size
            else:
                c.enqueued += 1
        tx_dev = snd.dev
        if kind != "data":
            if ev == "tx":      # control frames only count as bytes on air of the flow they serve
                c.ctrl_sent += 1
                name = self._ctrl_flow(flow, seq, src, dst, ch, tx_dev)
                m = self.flows[self.flow(name, tx_dev, None, None)]
                m.ctrl_sent += 1
                m.ctrl_bytes_on_air += size
            return

        seqs = snd.seqs
        n_seqs = len(seqs)
        if 0 <= seq < n_seqs:
            f: FrameState | None = seqs[seq]
        elif seq == n_seqs and not snd.frames:
            f = None        # the next one, the common case: no lookup
        else:
            f = snd.frames.get(seq)
        if f is None:
            fdst: int = -1 if dst is None else dst  # type: ignore[assignment]
            name = flow if flow is not None else tx_dev
            if name is snd.flow_name:
                fl = snd.flow_id
            else:
                fl = self.flow(name, tx_dev, fdst, None)
                snd.flow_name = name
                snd.flow_id = fl
            f = FrameState(tx_dev, seq, fl, ch, fdst)
            if seq == n_seqs:
                seqs.append(f)
            else:
                snd.frames[seq] = f
            self.frames.append(f)
        m = self.flows[f.flow]
        if m.t_first is None:
            m.t_first = t
        m.t_last = t
        if m.src is None:
            m.src = tx_dev
        if m.dst is None and f.dst >= 0:
            m.dst = f.dst

        if ev == "enq":
            f.n_enq += 1
            if f.t_enq is None:
                f.t_enq = t
            if m.t_first_enq is None:
                m.t_first_enq = t
            m.enqueued += 1
            p = m.payload
            m.payload_offered += p if p is not None else max(0, size - self.header.get(tx_dev, 0))
        elif ev == "tx":
            f.n_tx += 1
            f.t_tx = t
            if f.n_tx == 1:
                m.unique_sent += 1
                if seq > snd.max_seq:
                    snd.max_seq = seq
            m.sent += 1
            m.data_bytes_on_air += size
        elif ev == "rx":
            if f.multi is None and (f.r_dev is None or f.r_dev == dev):
                f.r_dev = dev
                f.r_nrx += 1
            else:
                rc = f.receiver(dev)
                if rc is None:
                    f.r_nrx += 1
                else:
                    rc.n_rx += 1
            m.delivered += 1
            p = m.payload
            m.payload_delivered += p if p is not None else max(0, size - self.header.get(tx_dev, 0))
            t_enq = f.t_enq
            if t_enq is not None:
                d = float(t) - float(t_enq)  # type: ignore[arg-type]
                m.delays.append(d)
                if m.has_prev:
                    m.jit_sum += abs(d - m.prev_delay)
                    m.jit_n += 1
                m.prev_delay = d
                m.has_prev = True
        else:   # drop
            fde = m.drop_events
            fcnt = fde.get(reason)
            if fcnt is None:
                fcnt = fde[reason] = Count()
            fcnt.n += 1
            if at_tx:
                f.n_txdrop += 1
                f.txdrop = reason
                f.txdrop_at = f.n_tx
            elif f.multi is None and (f.r_dev is None or f.r_dev == dev):
                f.r_dev = dev
                f.r_ndrop += 1
                f.r_reason = reason
                f.r_at = f.n_tx
            else:
                rc = f.receiver(dev)
                if rc is None:
                    f.r_ndrop += 1
                    f.r_reason = reason
                    f.r_at = f.n_tx
                else:
                    rc.n_drop += 1
                    rc.reason = reason
                    rc.at = f.n_tx

    def settle(self, end: object, horizon: float, limit: int) -> tuple[list[str], int, list[tuple[Any, ...]]]:
        """Final outcomes of every frame (into its flow's `drops`, `intended`, `in_flight`) and the conservation
        check: (violations, at most `limit` of them, the count of all, frames in flight as (dev, seq, flow,
        state, t_enq, t_tx)).  Call it once, at the end."""
        violations: list[str] = []
        total = 0
        in_flight: list[tuple[Any, ...]] = []
        flows = self.flows
        meta_rx = self.meta_rx
        who_ch: object = None       # the last addressee looked up: frames of a run go to a few
        who_dst = -2
        who: str | None = None
        for f in self.frames:
            m = flows[f.flow]
            drops = m.drops
            nt = f.n_tx
            ntd = f.n_txdrop
            final = ntd > 0 and f.txdrop_at == nt
            fdst = f.dst
            multi = f.multi
            if multi is None and f.n_enq == 1 and ntd <= 1 and not (ntd and f.txdrop_at < nt) and (
                    f.r_dev is not None or ntd) and f.r_nrx <= 1 and f.r_nrx + f.r_ndrop <= nt:
                # the common case, no violation possible but a receiver that is not the addressee
                rd = f.r_dev
                if rd is not None and fdst != _BROADCAST:
                    if fdst != who_dst or f.ch is not who_ch:
                        who_ch = f.ch
                        who_dst = fdst
                        who = meta_rx.get((who_ch, fdst))
                    if who is not None and rd != who:
                        total += self._odd(f, end, horizon, violations, in_flight, limit)
                        continue
                if rd is not None and f.r_nrx == 0 and f.r_ndrop and f.r_at == nt and not final:
                    bump(drops, f.r_reason)
                if ntd and not f.r_nrx:
                    bump(drops, f.txdrop)
                if nt:
                    m.intended += 1 if (rd is not None or fdst != _BROADCAST) else 0
                continue
            total += self._odd(f, end, horizon, violations, in_flight, limit)
        if total > len(violations):
            violations.append(f"... {total - len(violations)} more violations")
        return violations, total, in_flight

    def _odd(self, f: FrameState, end: object, horizon: float, violations: list[str],
             in_flight: list[tuple[Any, ...]], limit: int) -> int:
        """A frame with several receivers, a violation or no outcome: its outcomes and messages one by one;
        the number of its messages."""
        m = self.flows[f.flow]
        drops = m.drops
        label = f"{f.dev} seq {f.seq} (flow {m.name}): "
        msgs: list[str] = []
        rcv = f.receivers()
        nt = f.n_tx
        ntd = f.n_txdrop
        tda = f.txdrop_at
        fdst = f.dst
        any_rx = False
        final = ntd > 0 and tda == nt
        for r in rcv:
            if r.n_rx:
                any_rx = True
                if r.n_rx > 1:
                    msgs.append(f"delivered {r.n_rx} times at {r.dev}")
            elif r.n_drop and r.at == nt and not final:
                bump(drops, r.reason)
            if r.n_rx + r.n_drop > nt:
                msgs.append(f"{r.n_rx + r.n_drop} outcomes at {r.dev} for {nt} transmission(s)")
        txr = f.txdrop
        if ntd and not any_rx:
            bump(drops, txr)
        if nt:
            m.intended += len(rcv) if fdst == _BROADCAST else 1
        ne = f.n_enq
        if ne == 0:
            msgs.append("no enq record")
        elif ne > 1:
            msgs.append(f"enqueued {ne} times")
        if ntd > 1:
            msgs.append(f"dropped {ntd} times at the transmitter")
        if ntd and tda < nt:
            msgs.append(f"transmitted after its transmitter-side drop ({txr})")
        if fdst != _BROADCAST and rcv:
            if len(rcv) > 1:
                names = ", ".join(sorted(r.dev for r in rcv))
                msgs.append(f"outcomes at {len(rcv)} receivers ({names}) of a unicast frame")
            else:
                addressee = self.meta_rx.get((f.ch, fdst))
                rdev = rcv[0].dev
                if addressee is not None and rdev != addressee:
                    msgs.append(f"outcome at {rdev}, not at its addressee {addressee}")
        if not rcv and not ntd:
            if nt == 0:
                s = self.senders.get(f.dev)
                if s is not None and s.max_seq > f.seq:
                    msgs.append(f"never transmitted nor dropped, although later frames of {f.dev} were sent")
                else:
                    in_flight.append((f.dev, f.seq, m.name, "queued", f.t_enq, None))
                    m.in_flight += 1
            else:
                t_tx = f.t_tx
                if t_tx is not None and t_tx >= end - horizon:  # type: ignore[operator]
                    in_flight.append((f.dev, f.seq, m.name, "on air", f.t_enq, t_tx))
                    m.in_flight += 1
                else:
                    msgs.append(f"transmitted at {t_tx:g} s, no outcome by the end ({end:g} s)")
        for msg in msgs:
            if len(violations) < limit:
                violations.append(label + msg)
        return len(msgs)
