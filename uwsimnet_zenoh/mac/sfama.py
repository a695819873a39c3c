"""S-FAMA: Slotted Floor Acquisition Multiple Access (Molins & Stojanovic 2006; Aqua-Sim NG's AquaSimSFama).

Time is cut into slots shared by every node (simulation time 0 is a slot start) of length

    slot = guardTime + intrinsic tx delay + tx time of the largest control frame + max propagation delay

so that a control frame sent at a slot start reaches every node within maxDistance before the slot ends.
An exchange A -> B that starts with an RTS in slot n (docs/mac.md has the full state machine):

    slot n          A: RTS (announces D = data slots)      neighbours that hear it defer to slot n+3+D
    slot n+1        B: CTS (repeats D)                     neighbours that hear it defer to slot n+3+D
    slots n+2..     A: DATA (D slots: intrinsic delay + tx time + max propagation, rounded up)
    slot n+2+D      B: ACK (at the first slot start after the DATA arrived; at the latest this one)
    end of n+2+D    A: no CTS by the end of slot n+1 or no ACK by the end of slot n+2+D = a failed attempt

Before every RTS a node waits U{0..maxBackoffSlots-1} slots (at least 4 as in the original) and
senses the channel at the slot start (busy: a new backoff, not a failure).  A node waiting for a CTS,
or about to send DATA, that overhears another node's RTS or CTS gives up this round and defers (not a
failure either: it is contention, like a busy channel).  A failed attempt (no CTS, no ACK) is retried
after a new backoff, up to maxRetries times, then the frame is dropped with reason `retry`.
Broadcast frames: RTS to 255 (so that neighbours defer), DATA in slot n+2, no CTS, no ACK.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from ..kernel.frame import Frame
from .aloha import MAC_HEADER, Dedup, ctrl_size, max_distance, next_boundary, number
from .base import MacContext, OneFrameMac
from .registry import register

if TYPE_CHECKING:
    from ..kernel.scheduler import Event

RTS_CTS_HEADER = MAC_HEADER + 2
"""RTS/CTS: the MAC header plus a 16-bit count of data slots (Aqua-Sim's SFamaHeader: 7 bytes)."""
MIN_BACKOFF_SLOTS = 4
"""The original (dccomms_ros) raises maxBackoffSlots to at least 4."""
EPS = 1e-9

# initiator states (and IDLE, from base)
BACKOFF, WAIT_CTS, WAIT_DATA_SLOT, SENDING, WAIT_ACK = "backoff", "wait_cts", "wait_data_slot", "sending", "wait_ack"


class _Responder:
    """The exchange we answered with a CTS: who, which frame, and when it ends."""

    __slots__ = ("src", "seq", "end", "rts")

    def __init__(self, rts: Frame, end: float) -> None:
        self.src = rts.src
        self.seq = rts.seq
        self.end = end
        self.rts = rts


@register("sfama", "s-fama", "slotted-fama")
class SFama(OneFrameMac):
    overhear = True

    def __init__(self, ctx: MacContext, params: dict[str, str]) -> None:
        super().__init__(ctx, params)
        self.max_backoff = max(MIN_BACKOFF_SLOTS, number(self, "maxBackoffSlots", MIN_BACKOFF_SLOTS,
                                                         minimum=1, integer=True))
        self.max_retries = number(self, "maxRetries", 7, minimum=-1, integer=True)   # -1: no limit (Aqua-Sim)
        self.rts_size = ctrl_size(self, "rtsSize", RTS_CTS_HEADER)
        self.cts_size = ctrl_size(self, "ctsSize", RTS_CTS_HEADER)
        self.ack_size = ctrl_size(self, "ackSize", MAC_HEADER)
        self.guard = number(self, "guardTime", 0.005, minimum=0.0)
        self.max_distance = max_distance(self)
        self.max_prop = ctx.max_prop_delay(self.max_distance)
        largest = max(self.rts_size, self.cts_size, self.ack_size)
        default_slot = self.guard + ctx.tx_delay + ctx.tx_time(largest) + self.max_prop
        self.slot = number(self, "slotTime", default_slot, minimum=1e-9)
        self.nav = 0.0                       # no RTS of ours, and no CTS answered, before this time
        self._n = 0                          # slot index of our current RTS
        self._d = 0                          # its data slots
        self._resp: _Responder | None = None
        self._dedup = Dedup()

    # -- slot arithmetic ----------------------------------------------------------------------
    def slot_index(self, t: float) -> int:
        """The slot that contains time t."""
        return math.floor(t / self.slot + EPS)

    def data_slots(self, frame: Frame) -> int:
        ctx = self.ctx
        need = ctx.tx_delay + ctx.tx_time(frame.size) + self.max_prop
        return max(1, math.ceil(need / self.slot - EPS))

    def _at(self, t: float, fn, *args) -> Event:
        return self.ctx.timer(max(0.0, t - self.ctx.now), self._fire, fn, args)

    def _fire(self, fn, args: tuple) -> None:
        if not self._closed:          # timers set before the modem left do nothing
            fn(*args)

    # -- the interface ------------------------------------------------------------------------
    def on_queue(self) -> None:
        if self._closed:            # offered after the modem left: nobody will ever send it
            while (frame := self.ctx.fifo_pop()) is not None:
                self.ctx.drop(frame, "removed")
            return
        self._next()

    def on_tx_done(self, frame: Frame) -> None:
        if self._closed or frame is not self.cur or self.state != SENDING:
            return
        ctx = self.ctx
        ctx.status(frame, "sent" if frame.broadcast else "transmitted")    # unicast: acked/failed follows
        end = (self._n + 3 + self._d) * self.slot
        if frame.broadcast:
            self.nav = max(self.nav, end)
            self._done()
        else:
            self.state = WAIT_ACK
            self._timer = self._at(end, self._fail)

    def on_rx(self, frame: Frame) -> None:
        ctx = self.ctx
        if frame.kind == "data":
            if not frame.broadcast:
                self._answer_data(frame)
            if self._dedup.first(frame):
                ctx.deliver(frame)
            return
        ctx.trace_rx(frame)
        info = frame.info or {}
        kind = info.get("type")
        cur = self.cur
        if frame.broadcast:
            if kind == "RTS":
                self._defer((self.slot_index(ctx.now) + 3 + int(info.get("slots", 1))) * self.slot)
        elif kind == "RTS":
            self._answer_rts(frame, int(info.get("slots", 1)))
        elif cur is None or frame.src != cur.dst or frame.seq != cur.seq:
            return                  # a late or stray answer
        elif kind == "CTS" and self.state == WAIT_CTS:
            self._cancel()
            self.state = WAIT_DATA_SLOT
            self._timer = self._at(next_boundary(ctx.now, self.slot), self._send_data)
        elif kind == "ACK" and self.state == WAIT_ACK:
            self._cancel()
            ctx.status(cur, "acked")
            self._done()

    def on_overhear(self, frame: Frame) -> None:
        now = self.ctx.now
        info = frame.info or {}
        kind = info.get("type") if frame.kind != "data" else "DATA"
        if kind == "RTS":
            end = (self.slot_index(now) + 3 + int(info.get("slots", 1))) * self.slot
        elif kind == "CTS":
            end = (self.slot_index(now) + 2 + int(info.get("slots", 1))) * self.slot
        elif kind == "DATA":
            end = next_boundary(now, self.slot) + self.slot      # its ACK slot
        else:
            return
        if kind != "DATA" and self.state in (WAIT_CTS, WAIT_DATA_SLOT):
            self._cancel()          # someone else holds the floor: give this round up (not a failure)
            self.state = BACKOFF
        self._defer(end)

    def _release(self) -> None:
        self._resp = None

    # -- initiator ----------------------------------------------------------------------------
    def _begin(self) -> None:
        self._schedule_rts()

    def _schedule_rts(self, strictly_later: bool = False) -> None:
        """RTS after U{0..maxBackoffSlots-1} slots counted from the first slot start we may use."""
        now = self.ctx.now
        t0 = max(now, self.nav)
        if self._resp is not None:
            t0 = max(t0, self._resp.end)
        first = next_boundary(t0, self.slot)
        if strictly_later and first <= now + EPS:
            first += self.slot
        k = int(self.ctx.random() * self.max_backoff)
        self._cancel()
        self.state = BACKOFF
        self._timer = self._at(first + k * self.slot, self._rts_slot)

    def _rts_slot(self) -> None:
        self._timer = None
        ctx = self.ctx
        cur = self.cur
        if cur is None or self.state != BACKOFF:
            return
        now = ctx.now
        if now < self.nav - EPS or (self._resp is not None and now < self._resp.end - EPS):
            self._schedule_rts()
            return
        if ctx.phy_busy or ctx.channel_busy():     # carrier sense at the slot start
            self._schedule_rts(strictly_later=True)
            return
        self._n = round(now / self.slot)
        self._d = self.data_slots(cur)
        ctx.transmit(ctx.ctrl_frame(cur.dst, self.rts_size, {"type": "RTS", "slots": self._d}, about=cur))
        if cur.broadcast:
            self.state = WAIT_DATA_SLOT
            self._timer = self._at((self._n + 2) * self.slot, self._send_data)
        else:
            self.state = WAIT_CTS
            self._timer = self._at((self._n + 2) * self.slot, self._fail)

    def _send_data(self) -> None:
        self._timer = None
        if self.cur is None or self.state != WAIT_DATA_SLOT:
            return
        if self.ctx.phy_busy:
            self._fail()
            return
        self._n = self.slot_index(self.ctx.now) - 2     # the exchange's RTS slot, as announced
        self.state = SENDING
        self.ctx.transmit(self.cur)

    def _fail(self) -> None:
        """No CTS or no ACK in time."""
        self._timer = None
        if self.cur is None:
            return
        if self._retry():
            self._schedule_rts(strictly_later=True)

    def _defer(self, end: float) -> None:
        """Virtual carrier sense: no RTS of ours before `end`."""
        if end <= self.nav:
            return
        self.nav = end
        if self.state == BACKOFF:
            self._schedule_rts()

    # -- responder ----------------------------------------------------------------------------
    def _answer_rts(self, rts: Frame, slots: int) -> None:
        ctx = self.ctx
        now = ctx.now
        if self.state in (WAIT_CTS, WAIT_DATA_SLOT, SENDING, WAIT_ACK):
            return                  # busy with our own exchange
        if self._resp is not None or now < self.nav - EPS:
            return                  # deferring to (or answering) another exchange
        n = self.slot_index(now)
        end = (n + 3 + slots) * self.slot
        self._resp = _Responder(rts, end)
        self._at((n + 1) * self.slot, self._send_cts, self._resp, slots)
        self._at(end, self._end_responder, self._resp)
        self._defer(end)

    def _send_cts(self, resp: _Responder, slots: int) -> None:
        if self._resp is not resp or self.ctx.phy_busy:
            return
        ctx = self.ctx
        ctx.transmit(ctx.ctrl_frame(resp.src, self.cts_size, {"type": "CTS", "slots": slots}, about=resp.rts))

    def _answer_data(self, data: Frame) -> None:
        """A unicast DATA for us: ACK at the next slot start (also a duplicate: our ACK was lost)."""
        ctx = self.ctx
        ack = ctx.ctrl_frame(data.src, self.ack_size, {"type": "ACK", "seq": data.seq}, about=data)
        self._at(next_boundary(ctx.now, self.slot), self._send_ack, ack)

    def _send_ack(self, ack: Frame) -> None:
        if not self.ctx.phy_busy:
            self.ctx.transmit(ack)

    def _end_responder(self, resp: _Responder) -> None:
        if self._resp is resp:
            self._resp = None
