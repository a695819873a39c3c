"""An example user MAC: fixed-assignment TDMA, in the style docs/mac.md teaches.

Load it from a scene without registering anything:

    <macProtocol>
      <name>uwsimnet_zenoh.mac.examples:Tdma</name>
      <slotTime>0.5</slotTime>   <!-- s -->
      <slots>4</slots>           <!-- slots per TDMA frame -->
      <slot>2</slot>             <!-- this node's slot (default: address modulo slots) -->
    </macProtocol>

Time is cut into TDMA frames of `slots` slots of `slotTime` seconds, starting at simulation time 0;
each node owns one slot and sends at most one frame per TDMA frame, at the start of its slot.  A frame
that cannot fit in a slot (intrinsic tx delay + tx time + guardTime > slotTime) is dropped with reason
`size`.  No ACK, no retransmission: collisions only happen if two nodes were given the same slot or the
guard is shorter than the propagation delay.
"""

from __future__ import annotations

import math
from typing import Any

from ..kernel.frame import Frame
from .base import Mac, MacContext


class Tdma(Mac):
    def __init__(self, ctx: MacContext, params: dict[str, str]) -> None:
        super().__init__(ctx, params)
        self.slot_time = self.param("slotTime", 1.0)
        self.slots = int(self.param("slots", 4))
        self.my_slot = int(self.param("slot", ctx.address % self.slots))
        self.guard = self.param("guardTime", 0.0)
        if self.slot_time <= 0 or self.slots < 1 or not 0 <= self.my_slot < self.slots:
            raise ValueError(f"Tdma: need slotTime > 0, slots >= 1 and 0 <= slot < slots, got {params}")
        self._wake = None          # the timer of our next slot, if one is set

    def _next_slot_start(self) -> float:
        """The start of our next slot, at or after now."""
        cycle = self.slot_time * self.slots
        now = self.ctx.now
        k = math.ceil((now - self.my_slot * self.slot_time) / cycle - 1e-9)
        return k * cycle + self.my_slot * self.slot_time

    def on_queue(self) -> None:
        if self._wake is None:
            self._wake = self.ctx.timer(self._next_slot_start() - self.ctx.now, self._my_slot)

    def _my_slot(self) -> None:
        self._wake = None
        ctx = self.ctx
        if ctx.phy_busy:
            return
        frame = ctx.fifo_pop()
        if frame is None:
            return
        if ctx.tx_delay + ctx.tx_time(frame.size) + self.guard > self.slot_time:
            ctx.drop(frame, "size")
        else:
            ctx.transmit(frame)
        if ctx.fifo:                   # more to send: come back one TDMA frame later
            self._wake = ctx.timer(self.slot_time * self.slots, self._my_slot)

    def on_tx_done(self, frame: Frame) -> None:
        self.ctx.status(frame, "sent")

    def on_rx(self, frame: Frame, rx: Any) -> None:
        if frame.kind == "data":
            self.ctx.deliver(frame, rx)
