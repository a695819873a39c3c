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

Aqua-Sim NG's AquaSimSFama (rmartin5/aqua-sim-ng, model/aqua-sim-mac-sfama.cc at 0653634, the last change
before the paper's runs) differs in four rules; each is a parameter (docs/mac.md, "Aqua-Sim's rules"),
off by default, and the `original` profile of the TWINBOT experiments turns all four on:

    broadcast=aquasim        a broadcast goes out as an RTS to 255 that nobody answers: every attempt
                             fails like an unanswered unicast one (retried per maxRetries; -1: for ever,
                             holding up the queue).  broadcast=drop: refused at once (drop `broadcast`)
    answerRtsInBackoff=0     after a failed attempt the node first backs off U{0..maxBackoffSlots-1}
                             slots in which it answers no RTS, then draws the usual backoff before its RTS
    overhearEndsRound=1      an overheard RTS, CTS or DATA (or a CTS for us we are not waiting for) ends
                             the round in any state: waiting for a CTS, for the data slot or for the ACK
                             (sent again after the deferral, not a failed attempt), and as responder: the
                             CTS or ACK not yet sent is not sent; a unicast DATA for us is accepted
                             (ACK, delivery) only within a round we answered
    carrierSense=0           no physical carrier sense at the RTS slot

and a fifth, off in every profile unless asked (`twinbot --ack-wait aquasim`):

    ackWaitAquasim=1         the ACK wait ends one slot after the first slot start at or after the DATA's
                             last bit left (aqua-sim-mac-sfama.cc@0653634 DataSendTimerProcess :898-941 ->
                             SlotInitHandler :1052 -> StatusProcess :777-836, slotnum 1), not at the end of
                             slot n+2+D: when the DATA's end reaches the receiver past the next slot start,
                             its ACK starts just as the wait ends, and every attempt fails
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

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
RETRY_BACKOFF = "retry_backoff"
"""answerRtsInBackoff=0: the backoff after a failed attempt, in which no RTS is answered (Aqua-Sim's BACKOFF)."""
BROADCAST_MODES = ("rts", "aquasim", "drop")


def flag(mac: SFama, name: str, default: int) -> bool:
    """A 0/1 `<macProtocol>` parameter."""
    v = number(mac, name, default, minimum=0, integer=True)
    if v > 1:
        raise ValueError(f"macProtocol {name}: expected 0 or 1, got {mac.params.get(name)!r}")
    return v == 1


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
        # Aqua-Sim NG's rules where they differ from ours (module docstring); the defaults are ours
        self.broadcast_mode = str(params.get("broadcast", "rts")).strip().lower()
        if self.broadcast_mode not in BROADCAST_MODES:
            raise ValueError(f"macProtocol broadcast: expected one of {', '.join(BROADCAST_MODES)},"
                             f" got {params.get('broadcast')!r}")
        self.answer_rts_in_backoff = flag(self, "answerRtsInBackoff", 1)
        self.overhear_ends_round = flag(self, "overhearEndsRound", 0)
        self.carrier_sense = flag(self, "carrierSense", 1)
        self.ack_wait_aquasim = flag(self, "ackWaitAquasim", 0)
        self._ack_timer: Event | None = None   # our ACK waiting for its slot (overhearEndsRound cancels it)
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
            if self.ack_wait_aquasim:       # StatusProcess: 1 slot after the coming slot start (module docstring)
                end = (math.ceil(ctx.now / self.slot - EPS) + 1) * self.slot
            self._timer = self._at(end, self._fail)

    def on_rx(self, frame: Frame, rx: Any) -> None:
        ctx = self.ctx
        if frame.kind == "data":
            if not frame.broadcast:
                if self.overhear_ends_round and not self._in_round(frame):
                    self.on_overhear(frame, rx)     # Aqua-Sim: not expected, so neither ACKed nor delivered
                    return
                self._answer_data(frame)
            if self._dedup.first(frame):
                ctx.deliver(frame, rx)
            return
        ctx.trace_rx(frame, rx)
        info = frame.info or {}
        kind = info.get("type")
        cur = self.cur
        if self.overhear_ends_round and ((frame.broadcast and kind == "RTS") or (kind == "CTS" and not (
                self.state == WAIT_CTS and cur is not None and frame.src == cur.dst and frame.seq == cur.seq))):
            self.on_overhear(frame, rx)     # Aqua-Sim: an RTS not to our address, a CTS we do not wait for
            return
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

    def on_overhear(self, frame: Frame, rx: Any) -> None:
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
        if self.overhear_ends_round:
            self._end_round()       # Aqua-Sim: whatever the state, this round is over
        elif kind != "DATA" and self.state in (WAIT_CTS, WAIT_DATA_SLOT):
            self._cancel()          # someone else holds the floor: give this round up (not a failure)
            self.state = BACKOFF
        self._defer(end)

    def _end_round(self) -> None:
        """overhearEndsRound: give up our round as initiator (a DATA already sent goes again after the
        deferral, not counted as a failed attempt) and as responder (no CTS or ACK not yet sent)."""
        if self.state in (WAIT_CTS, WAIT_DATA_SLOT, WAIT_ACK):
            self._cancel()
            self.state = BACKOFF
        if self._resp is not None:
            self._resp = None       # _send_cts checks it; data of that round is no longer accepted
        if self._ack_timer is not None:
            self._ack_timer.cancel()
            self._ack_timer = None

    def _in_round(self, data: Frame) -> bool:
        """A unicast DATA for us belongs to the round we answered with a CTS."""
        r = self._resp
        return r is not None and r.src == data.src and r.seq == data.seq

    def _release(self) -> None:
        self._resp = None

    # -- initiator ----------------------------------------------------------------------------
    def _begin(self) -> None:
        cur = self.cur
        if cur is not None and cur.broadcast and self.broadcast_mode == "drop":
            self.cur = None
            self.ctx.drop(cur, "broadcast")      # broadcast=drop: this S-FAMA sends no broadcast data
            self._done()
            return
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
        if ctx.phy_busy or (self.carrier_sense and ctx.channel_busy()):     # carrier sense at the slot start
            self._schedule_rts(strictly_later=True)
            return
        self._n = round(now / self.slot)
        self._d = self.data_slots(cur)
        ctx.transmit(ctx.ctrl_frame(cur.dst, self.rts_size, {"type": "RTS", "slots": self._d}, about=cur))
        if cur.broadcast and self.broadcast_mode == "rts":
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
        if not self._retry():
            return
        if self.answer_rts_in_backoff:
            self._schedule_rts(strictly_later=True)
            return
        # Aqua-Sim: a backoff in which no RTS is answered, then the usual one before the RTS
        k = int(self.ctx.random() * self.max_backoff)
        self.state = RETRY_BACKOFF
        self._timer = self._at(next_boundary(self.ctx.now, self.slot) + k * self.slot, self._retry_backoff_done)

    def _retry_backoff_done(self) -> None:
        self._timer = None
        if self.cur is not None and self.state == RETRY_BACKOFF:
            self._schedule_rts()

    def _defer(self, end: float) -> None:
        """Virtual carrier sense: no RTS of ours before `end`."""
        if end <= self.nav:
            return
        self.nav = end
        if self.state in (BACKOFF, RETRY_BACKOFF):      # RETRY_BACKOFF: the deferral replaces it
            self._schedule_rts()

    # -- responder ----------------------------------------------------------------------------
    def _answer_rts(self, rts: Frame, slots: int) -> None:
        ctx = self.ctx
        now = ctx.now
        if self.state in (WAIT_CTS, WAIT_DATA_SLOT, SENDING, WAIT_ACK):
            return                  # busy with our own exchange
        if self._resp is not None or now < self.nav - EPS:
            return                  # deferring to (or answering) another exchange
        if self.state == RETRY_BACKOFF:
            return                  # answerRtsInBackoff=0: backing off after a failed attempt
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
        self._ack_timer = self._at(next_boundary(ctx.now, self.slot), self._send_ack, ack)

    def _send_ack(self, ack: Frame) -> None:
        self._ack_timer = None
        if not self.ctx.phy_busy:
            self.ctx.transmit(ack)

    def _end_responder(self, resp: _Responder) -> None:
        if self._resp is resp:
            self._resp = None
