"""CS-ALOHA (carrier-sense ALOHA with ACK and retransmission) and slotted ALOHA.

CS-ALOHA, as the paper describes the Aqua-Sim protocol it used (Section 2.2) and docs/mac.md in full:

    IDLE ──frame in FIFO──▶ take it ──▶ SENSE
    SENSE: channel busy (energy heard at our receiver) ──▶ BACKOFF U[backoffMin, backoffMax] s ──▶ SENSE
           channel idle ──▶ transmit ──▶ SENDING
    SENDING ──last bit out──▶ status `sent`; broadcast (or ack=0): done
                                          unicast: WAIT_ACK for ackTimeout
    WAIT_ACK ──ACK from the addressee for this seq──▶ status `acked`, done
             ──timeout──▶ failed attempts <= maxRetries: BACKOFF ──▶ SENSE (a retransmission, same seq)
                          otherwise: drop reason `retry` + status `failed`, done

The receiver acknowledges every intact unicast data frame addressed to it at once (no carrier sense,
like an 802.11 ACK), duplicates included (its earlier ACK may have been lost), and delivers each
(src, seq) only once.  A deferral because the channel was busy is not a failed attempt.

Slotted ALOHA is the same machine on a slot grid shared by all nodes (simulation time 0 is a slot
start): every transmission starts at a slot boundary and the backoff is a whole number of slots.
Carrier sense is off by default (the textbook protocol); ACKs are on, as for CS-ALOHA.
"""

from __future__ import annotations

import math
from typing import Any

from ..kernel.frame import Frame
from .base import Mac, MacContext, OneFrameMac
from .registry import register

MAX_DISTANCE_CAP = 10_000.0
"""Default cap (m) on the distance used for timeouts and slots when `maxDistance` is not given: the
device's maxDistance defaults to 1e8 m (the original's "no limit"), which would make an acoustic ACK
timeout last 37 hours.  No underwater acoustic modem reaches farther than about 10 km."""

MAC_HEADER = 5
"""Bytes of a MAC header: source and destination address (2 B each) and a type byte (Aqua-Sim's)."""

# states
SENSE, BACKOFF, SENDING, WAIT_ACK = "sense", "backoff", "sending", "wait_ack"


def number(mac: Mac, name: str, default: float, *, minimum: float | None = None,
           integer: bool = False) -> float:
    """A numeric `<macProtocol>` parameter, checked (ValueError names the parameter)."""
    v = mac.param(name, default)
    if not math.isfinite(v):
        raise ValueError(f"macProtocol {name}: expected a finite number, got {mac.params.get(name)!r}")
    if integer and v != int(v):
        raise ValueError(f"macProtocol {name}: expected an integer, got {mac.params.get(name)!r}")
    if minimum is not None and v < minimum:
        raise ValueError(f"macProtocol {name}: must be >= {minimum:g}, got {mac.params.get(name)!r}")
    return int(v) if integer else v


def max_distance(mac: Mac) -> float:
    """`maxDistance` parameter (m), else the device's maxDistance capped at MAX_DISTANCE_CAP."""
    if "maxDistance" in mac.params:
        return number(mac, "maxDistance", 0.0, minimum=0.0)
    return min(float(getattr(mac.ctx, "max_distance", MAX_DISTANCE_CAP)), MAX_DISTANCE_CAP)


def ctrl_size(mac: Mac, name: str, mac_bytes: int) -> int:
    """Size on air of a control frame: the parameter `name` (bytes on air), else the MAC header bytes
    plus the device's headerBytes (its framing)."""
    default = mac_bytes + int(getattr(mac.ctx, "header_bytes", 0))
    return number(mac, name, default, minimum=1, integer=True)


def next_boundary(now: float, slot: float) -> float:
    """The first slot start at or after `now` (slots are k * slot from time 0)."""
    k = math.ceil(now / slot - 1e-9)
    return k * slot


class Dedup:
    """Receiver-side duplicate suppression: deliver each (src, seq) once.

    A transmitter serves one frame at a time, so a retransmission repeats the last seq delivered from
    that source; remembering the last one per source is enough."""

    def __init__(self) -> None:
        self._last: dict[int, int] = {}

    def first(self, frame: Frame) -> bool:
        if self._last.get(frame.src) == frame.seq:
            return False
        self._last[frame.src] = frame.seq
        return True


@register("aloha", "cs-aloha", "csaloha")
class CsAloha(OneFrameMac):
    """Carrier-sense ALOHA with ACK, ACK timeout, random backoff and a retry limit (docs/mac.md)."""

    def __init__(self, ctx: MacContext, params: dict[str, str]) -> None:
        super().__init__(ctx, params)
        self.max_retries = number(self, "maxRetries", 3, minimum=-1, integer=True)   # -1: no limit (Aqua-Sim)
        self.backoff_min = number(self, "backoffMin", 0.0, minimum=0.0)
        self.backoff_max = number(self, "backoffMax", 1.5, minimum=0.0)
        if self.backoff_max < self.backoff_min:
            raise ValueError(f"macProtocol backoffMax ({self.backoff_max:g} s) is smaller than backoffMin"
                             f" ({self.backoff_min:g} s)")
        self.ack_on = number(self, "ack", 1, minimum=0, integer=True) != 0
        self.carrier_sense = number(self, "carrierSense", self.default_carrier_sense, minimum=0,
                                    integer=True) != 0
        self.ack_size = ctrl_size(self, "ackSize", MAC_HEADER)
        self.guard = number(self, "guardTime", 0.005, minimum=0.0)
        self.max_distance = max_distance(self)
        self.max_prop = ctx.max_prop_delay(self.max_distance)
        # last bit of DATA out -> its last bit at the addressee (max_prop) -> the ACK is handed to the
        # addressee's PHY at once -> first bit after the intrinsic delay -> last bit back here
        default_timeout = 2 * self.max_prop + ctx.tx_delay + ctx.tx_time(self.ack_size) + self.guard
        self.ack_timeout = number(self, "ackTimeout", default_timeout, minimum=0.0)
        self._acks: list[Frame] = []        # ACKs waiting for our transmitter
        self._dedup = Dedup()
        # the original's scripts (dccomms_examples testing/mac_performance.sh:292) fill <maxBackoffSlots> in
        # every protocol's scene; its parser hands it to S-FAMA only and ALOHA runs without it: so here
        params.get("maxBackoffSlots")

    default_carrier_sense = 1

    # -- the interface ------------------------------------------------------------------------
    def on_queue(self) -> None:
        if self._closed:            # offered after the modem left: nobody will ever send it
            while (frame := self.ctx.fifo_pop()) is not None:
                self.ctx.drop(frame, "removed")
            return
        self._next()

    def on_tx_done(self, frame: Frame) -> None:
        if self._closed:
            return
        self._flush_acks()          # ACKs first: their data senders are waiting for them
        if frame is self.cur and self.state == SENDING:
            if frame.broadcast or not self.ack_on:
                self.ctx.status(frame, "sent")          # final: nothing will acknowledge it
                self._done()
            else:
                self.ctx.status(frame, "transmitted")   # this attempt is on air; acked/failed follows
                self.state = WAIT_ACK
                self._timer = self.ctx.timer(self.ack_timeout, self._ack_timeout)
        if self.state == SENSE and self._timer is None and not self.ctx.phy_busy:
            self._attempt()         # an attempt that found our transmitter sending an ACK

    def on_rx(self, frame: Frame, rx: Any) -> None:
        ctx = self.ctx
        if frame.kind != "data":
            ctx.trace_rx(frame, rx)
            info = frame.info or {}
            cur = self.cur
            if (info.get("type") == "ACK" and self.state == WAIT_ACK and cur is not None
                    and frame.src == cur.dst and frame.seq == cur.seq):
                self._cancel()
                ctx.status(cur, "acked")
                self._done()
            return
        if self.ack_on and not frame.broadcast:
            self._send_ack(frame)
        if self._dedup.first(frame):
            ctx.deliver(frame, rx)

    def _release(self) -> None:
        self._acks.clear()

    # -- the machine --------------------------------------------------------------------------
    def _begin(self) -> None:
        self._wait(self.first_delay())

    def _wait(self, delay: float) -> None:
        """Sense again after `delay` s (0: now)."""
        self.state = SENSE
        if delay > 0:
            self._timer = self.ctx.timer(delay, self._attempt)
        else:
            self._timer = None
            self._attempt()

    def _attempt(self) -> None:
        ctx = self.ctx
        self._timer = None
        if self.cur is None or self.state not in (SENSE, BACKOFF):
            return
        self.state = SENSE
        if ctx.phy_busy:            # sending an ACK: on_tx_done comes back here
            return
        if self.carrier_sense and ctx.channel_busy():
            self.state = BACKOFF    # nonpersistent: sense again after a random backoff
            self._timer = ctx.timer(self.backoff_delay(), self._attempt)
            return
        self.state = SENDING
        ctx.transmit(self.cur)

    def _ack_timeout(self) -> None:
        self._timer = None
        if self.cur is None or self.state != WAIT_ACK:
            return
        if not self._retry():
            return
        self.state = BACKOFF
        self._timer = self.ctx.timer(self.backoff_delay(), self._attempt)

    # -- acknowledgements ---------------------------------------------------------------------
    def _send_ack(self, data: Frame) -> None:
        ack = self.ctx.ctrl_frame(data.src, self.ack_size, {"type": "ACK", "seq": data.seq}, about=data)
        self._acks.append(ack)
        self._flush_acks()

    def _flush_acks(self) -> None:
        if self._acks and not self.ctx.phy_busy:
            self.ctx.transmit(self._acks.pop(0))

    # -- timing hooks (slotted ALOHA overrides them) -------------------------------------------
    def first_delay(self) -> float:
        """Delay before the first attempt of a new frame."""
        return 0.0

    def backoff_delay(self) -> float:
        """Random backoff after a busy channel or a failed attempt."""
        return self.backoff_min + (self.backoff_max - self.backoff_min) * self.ctx.random()


@register("slotted-aloha", "saloha", "s-aloha")
class SlottedAloha(CsAloha):
    """Slotted ALOHA: attempts start at slot boundaries; backoff U{0..backoffSlots-1} slots after the
    next boundary.  Slot = guardTime + intrinsic tx delay + tx time of `slotBytes` + max propagation
    delay, unless `slotTime` is given."""

    default_carrier_sense = 0

    def __init__(self, ctx: MacContext, params: dict[str, str]) -> None:
        super().__init__(ctx, params)
        self.backoff_slots = number(self, "backoffSlots", 8, minimum=1, integer=True)
        slot_bytes = number(self, "slotBytes", 64, minimum=1, integer=True)
        default_slot = self.guard + ctx.tx_delay + ctx.tx_time(slot_bytes) + self.max_prop
        self.slot = number(self, "slotTime", default_slot, minimum=1e-9)

    def first_delay(self) -> float:
        now = self.ctx.now
        return next_boundary(now, self.slot) - now

    def backoff_delay(self) -> float:
        """k = U{0..backoffSlots-1} slots after the next slot start strictly after now."""
        now = self.ctx.now
        k = int(self.ctx.random() * self.backoff_slots)
        return (math.floor(now / self.slot + 1e-9) + 1 + k) * self.slot - now
