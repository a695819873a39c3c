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
        self.t_last = -math.inf         # its last event, as a float (when it may be settled)
        self.retired = False            # settled before the end: its outcomes are in its flow, it takes no more

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


EXACT: Final = 8192
"""Delays the fold keeps exact, in all flows together: from one more on, every flow's delays are binned."""
SUB: Final = 256
"""Delay bins per octave: a bin's middle is within 1/(2 SUB) (0.2 %) of every value in it."""
_OFF: Final = 1100      # math.frexp's exponents are above -1075: every bin of a nonzero delay is positive


def bin_delay(bins: dict[int, Count], d: float) -> None:
    """Count delay `d` in its bin: 0 for 0, else SUB per octave (negative for a negative delay), in value order."""
    k = 0
    if d != 0.0:
        m, e = math.frexp(abs(d))
        k = (e + _OFF) * SUB + int((m - 0.5) * (2 * SUB))
        k = k if d > 0.0 else -k
    c = bins.get(k)
    if c is None:
        c = bins[k] = Count()
    c.n += 1


def bin_value(k: int) -> float:
    """The middle of bin `k` (bin_delay)."""
    if k == 0:
        return 0.0
    e, sub = divmod(abs(k), SUB)
    v = math.ldexp(0.5 + (sub + 0.5) / (2 * SUB), e - _OFF)
    return v if k > 0 else -v


SWEEP: Final = 4096
"""Frames held before the first look for settled ones (then: twice those held after the last look)."""
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
        self.seqs: list[FrameState] = []                # frames base, base + 1, ...: seq k at index k - base
        self.base = 0                                   # the frames below it are settled (Fold.settle_after)
        self.frames: dict[int, FrameState] = {}         # the others (a seq that skipped ahead, negative)
        self.max_seq = -1
        self.flow_name: object = None                   # the flow name of its last new frame, and its id
        self.flow_id = -1

    def get(self, seq: int) -> FrameState | None:
        """Its data frame `seq`, if it has one.  A modem numbers its frames 0, 1, 2, ..., so they are a
        list read by index (no int made for a key, no hash); a trace that skips goes on in the dict."""
        seqs = self.seqs
        i = seq - self.base
        if 0 <= i < len(seqs):
            return seqs[i]
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
        self.delays: list[float] = []                  # exact, while the fold keeps them (Fold.binned)
        self.bins: dict[int, Count] = {}                # then: by bin (bin_delay)
        self.n_delays = 0
        self.sum_d = 0.0                                # their sum, compensated (Neumaier): the mean once binned
        self.sum_c = 0.0
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
    meta (the fallbacks of transmitters learnt from enq/tx events); `header`: header bytes per dccommsId.

    `settle_after` (s, a run's events, which come in time order): a frame transmitted or dropped at its
    transmitter, with no event for that long and no violation, is settled at once (its outcomes into its
    flow, as `settle` would) and its state let go, so a run's memory does not grow with its frames; an
    event of such a frame later is a violation of its own.  Infinite (a trace read back, in any order):
    every frame is held to the end.  The delays are exact up to EXACT of them, then binned (bins)."""

    def __init__(self, meta_tx: dict[tuple[object, int], str], meta_rx: dict[tuple[object, int], str],
                 header: dict[str, int], settle_after: float = math.inf) -> None:
        self.meta_tx = meta_tx
        self.meta_rx = meta_rx
        self.header = header
        self.tx: dict[object, Addresses] = {}               # learnt: ch -> src -> transmitter
        self.flows: list[FlowState] = []
        self.fid: dict[str, int] = {}
        self.frames: list[FrameState] = []                  # the frames held, in the order they came
        self.n_frames = 0                                   # all of them, settled early or not
        self.settle_after = settle_after
        self._sweep_at = SWEEP
        self.late: list[str] = []                           # violations: events of frames settled early
        self.n_late = 0
        self.n_exact = 0                                    # delays kept exact, in all flows
        self.rx_channels = {ch for ch, _ in meta_rx}        # channels whose addresses the meta lists
        self.binned = False
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
        i = seq - snd.base
        if 0 <= i < n_seqs:
            f: FrameState | None = seqs[i]
        elif i == n_seqs and not snd.frames:
            f = None        # the next one, the common case: no lookup
        else:
            f = snd.frames.get(seq)
        if (f is not None and f.retired) or (f is None and 0 <= seq < snd.base):
            self._late(t, ev, tx_dev, seq)
            fl = self.flow(flow if flow is not None else tx_dev, tx_dev, -1 if dst is None else dst, None)  # type: ignore[arg-type]
            f = FrameState(tx_dev, seq, fl, ch, -1)   # counted in its flow, held by nobody
        elif f is None:
            fdst: int = -1 if dst is None else dst  # type: ignore[assignment]
            name = flow if flow is not None else tx_dev
            if name is snd.flow_name:
                fl = snd.flow_id
            else:
                fl = self.flow(name, tx_dev, fdst, None)
                snd.flow_name = name
                snd.flow_id = fl
            f = FrameState(tx_dev, seq, fl, ch, fdst)
            if i == n_seqs:
                seqs.append(f)
            else:
                snd.frames[seq] = f
            self.frames.append(f)
            self.n_frames += 1
            if len(self.frames) >= self._sweep_at and self.settle_after < math.inf:
                self._sweep()
        f.t_last = float(t)  # type: ignore[arg-type]
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
                if self.binned:
                    bin_delay(m.bins, d)
                else:
                    m.delays.append(d)
                    self.n_exact += 1
                    if self.n_exact > EXACT:
                        self._bin_all()
                m.n_delays += 1
                s0 = m.sum_d
                x = s0 + d
                m.sum_c += (s0 - x) + d if abs(s0) >= abs(d) else (d - x) + s0
                m.sum_d = x
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

    def _late(self, t: object, ev: str, dev: str, seq: int) -> None:
        """An event of a frame settled early (settle_after): a violation of its own."""
        self.n_late += 1
        if len(self.late) < 1000:
            self.late.append(f"{dev} seq {seq}: {ev} at {t} s, after its frame was settled (no event of it for "
                             f"{self.settle_after:g} s before)")

    def _bin_all(self) -> None:
        """From now on every flow's delays are binned: the exact ones so far too."""
        self.binned = True
        for m in self.flows:
            for d in m.delays:
                bin_delay(m.bins, d)
            m.delays = []

    def _sweep(self) -> None:
        """Settle the frames that can be (settle_after) and let them go."""
        t_end = self.t_end
        now = -math.inf if t_end is None else float(t_end)  # type: ignore[arg-type]
        cut = now - self.settle_after
        keep: list[FrameState] = []
        n = 0
        for f in self.frames:
            if f.t_last < cut and (f.n_tx or f.n_txdrop):
                if self._clean(f):
                    self._outcome(f)
                else:
                    msgs, fly = self._judge(f, now, self.settle_after)
                    if msgs or fly is not None:
                        keep.append(f)
                        continue
                    self._odd_outcome(f)
                f.retired = True
                n += 1
            else:
                keep.append(f)
        self.frames = keep
        for s in self.senders.values():
            if s.frames:
                for q in [q for q, f in s.frames.items() if f.retired]:
                    del s.frames[q]
                    n -= 1
            seqs = s.seqs
            k = 0
            while k < len(seqs) and seqs[k].retired:
                k += 1
            if k:
                del seqs[:k]
                s.base += k
                n -= k
        if n:                                   # some held up by a frame that does not settle (a violation):
            for s in self.senders.values():     # it and the others held go to the dict, the list starts anew
                seqs = s.seqs
                if any(f.retired for f in seqs):
                    for f in seqs:
                        if not f.retired:
                            s.frames[f.seq] = f
                    s.base += len(seqs)
                    s.seqs = []
        self._sweep_at = max(SWEEP, 2 * len(keep))

    def settle(self, end: object, horizon: float, limit: int) -> tuple[list[str], int, list[tuple[Any, ...]]]:
        """Final outcomes of every frame (into its flow's `drops`, `intended`, `in_flight`) and the conservation
        check: (violations, at most `limit` of them, the count of all, frames in flight as (dev, seq, flow,
        state, t_enq, t_tx)).  Call it once, at the end."""
        violations: list[str] = []
        total = 0
        in_flight: list[tuple[Any, ...]] = []
        for f in self.frames:
            if self._clean(f):
                self._outcome(f)
            else:
                total += self._odd(f, end, horizon, violations, in_flight, limit)
        for msg in self.late:
            if len(violations) < limit:
                violations.append(msg)
        total += self.n_late
        if total > len(violations):
            violations.append(f"... {total - len(violations)} more violations")
        return violations, total, in_flight

    def _clean(self, f: FrameState) -> bool:
        """The common case, where no violation is possible: one enq, at most one transmitter-side drop (its
        last event), an outcome, at most one receiver (the addressee if the meta knows it) and one delivery."""
        nt = f.n_tx
        ntd = f.n_txdrop
        if not (f.multi is None and f.n_enq == 1 and ntd <= 1 and not (ntd and f.txdrop_at < nt) and (
                f.r_dev is not None or ntd) and f.r_nrx <= 1 and f.r_nrx + f.r_ndrop <= nt):
            return False
        rd = f.r_dev
        if rd is not None and f.dst != _BROADCAST:
            who = self.meta_rx.get((f.ch, f.dst))
            if who is not None and rd != who:
                return False
        return True

    def _outcome(self, f: FrameState) -> None:
        """A clean frame's final outcomes into its flow."""
        m = self.flows[f.flow]
        nt = f.n_tx
        ntd = f.n_txdrop
        rd = f.r_dev
        if rd is not None and f.r_nrx == 0 and f.r_ndrop and f.r_at == nt and not (ntd > 0 and f.txdrop_at == nt):
            bump(m.drops, f.r_reason)
        if ntd and not f.r_nrx:
            bump(m.drops, f.txdrop)
        if nt:
            m.intended += 1 if (rd is not None or f.dst != _BROADCAST) else 0

    def _odd(self, f: FrameState, end: object, horizon: float, violations: list[str],
             in_flight: list[tuple[Any, ...]], limit: int) -> int:
        """A frame with several receivers, a violation or no outcome: its outcomes and messages; the number
        of its messages."""
        msgs, fly = self._judge(f, end, horizon)
        self._odd_outcome(f)
        if fly is not None:
            in_flight.append(fly)
            self.flows[f.flow].in_flight += 1
        label = f"{f.dev} seq {f.seq} (flow {self.flows[f.flow].name}): "
        for msg in msgs:
            if len(violations) < limit:
                violations.append(label + msg)
        return len(msgs)

    def _odd_outcome(self, f: FrameState) -> None:
        """A frame's final outcomes into its flow, receiver by receiver."""
        m = self.flows[f.flow]
        drops = m.drops
        rcv = f.receivers()
        nt = f.n_tx
        ntd = f.n_txdrop
        final = ntd > 0 and f.txdrop_at == nt
        any_rx = False
        for r in rcv:
            if r.n_rx:
                any_rx = True
            elif r.n_drop and r.at == nt and not final:
                bump(drops, r.reason)
        if ntd and not any_rx:
            bump(drops, f.txdrop)
        elif nt and self._nobody(f, rcv):
            bump(drops, "noaddr")
        if nt:
            m.intended += len(rcv) if f.dst == _BROADCAST else 1

    def _nobody(self, f: FrameState, rcv: list[Receiver]) -> bool:
        """A unicast frame without outcome to an address no modem on its channel has (the meta lists them): a
        channel without MAC carried it to everyone, as a broadcast (implicit rx), but nobody could receive it:
        its final outcome is `noaddr`, as for a MAC that refuses it at once."""
        fdst = f.dst
        return (not rcv and not f.n_txdrop and fdst != _BROADCAST and fdst >= 0 and f.ch in self.rx_channels
                and (f.ch, fdst) not in self.meta_rx)

    def _judge(self, f: FrameState, end: object, horizon: float) -> tuple[list[str], tuple[Any, ...] | None]:
        """A frame's violations (messages) and, if it is in flight at `end`, its (dev, seq, flow, state,
        t_enq, t_tx)."""
        name = self.flows[f.flow].name
        msgs: list[str] = []
        fly: tuple[Any, ...] | None = None
        rcv = f.receivers()
        nt = f.n_tx
        ntd = f.n_txdrop
        tda = f.txdrop_at
        fdst = f.dst
        for r in rcv:
            if r.n_rx > 1:
                msgs.append(f"delivered {r.n_rx} times at {r.dev}")
            if r.n_rx + r.n_drop > nt:
                msgs.append(f"{r.n_rx + r.n_drop} outcomes at {r.dev} for {nt} transmission(s)")
        ne = f.n_enq
        if ne == 0:
            msgs.append("no enq record")
        elif ne > 1:
            msgs.append(f"enqueued {ne} times")
        if ntd > 1:
            msgs.append(f"dropped {ntd} times at the transmitter")
        if ntd and tda < nt:
            msgs.append(f"transmitted after its transmitter-side drop ({f.txdrop})")
        if fdst != _BROADCAST and rcv:
            if len(rcv) > 1:
                names = ", ".join(sorted(r.dev for r in rcv))
                msgs.append(f"outcomes at {len(rcv)} receivers ({names}) of a unicast frame")
            else:
                addressee = self.meta_rx.get((f.ch, fdst))
                rdev = rcv[0].dev
                if addressee is not None and rdev != addressee:
                    msgs.append(f"outcome at {rdev}, not at its addressee {addressee}")
        if not rcv and not ntd and not (nt and self._nobody(f, rcv)):
            if nt == 0:
                s = self.senders.get(f.dev)
                if s is not None and s.max_seq > f.seq:
                    msgs.append(f"never transmitted nor dropped, although later frames of {f.dev} were sent")
                else:
                    fly = (f.dev, f.seq, name, "queued", f.t_enq, None)
            else:
                t_tx = f.t_tx
                if t_tx is not None and t_tx >= end - horizon:  # type: ignore[operator]
                    fly = (f.dev, f.seq, name, "on air", f.t_enq, t_tx)
                else:
                    msgs.append(f"transmitted at {t_tx:g} s, no outcome by the end ({end:g} s)")
        return msgs, fly
