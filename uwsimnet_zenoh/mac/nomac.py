"""NOMAC: the bare modem, as the original simulated it.

The FIFO head goes on air as soon as the transmitter is free, with no acknowledgement.  A half-duplex
modem (tx channel == rx channel) cannot start sending while its receiver hears a frame, so it waits for
the end of that reception: the original's implicit carrier sense, and what makes the paper's FIFO fill
up and its end-to-end delay rise once both ROVs transmit (docs/paper-phy-layer.md).  The decision is
taken when the modem picks the frame; the intrinsic tx delay that follows is the window in which two
modems can still collide.  A full-duplex or transmit-only modem never waits: with `txFifoSize` 0 that
is pure ALOHA.
"""

from __future__ import annotations

from ..kernel.frame import Frame
from .base import Mac
from .registry import register


@register("none", "nomac", "")
class NoMac(Mac):
    _wake = None

    def ready(self) -> bool:
        ctx = self.ctx
        return not ctx.phy_busy and not (ctx.half_duplex and ctx.channel_busy())

    def on_queue(self) -> None:
        self._pump()

    def on_tx_done(self, frame: Frame) -> None:
        if frame.kind == "data":
            self.ctx.status(frame, "sent")
        self._pump()

    def on_rx(self, frame: Frame) -> None:
        if frame.kind == "data":
            self.ctx.deliver(frame)

    def _pump(self) -> None:
        ctx = self.ctx
        if ctx.phy_busy or not ctx.fifo or self._wake is not None:
            return
        if ctx.half_duplex:
            until = ctx.channel_busy_until()
            if until > ctx.now:
                self._wake = ctx.timer(until - ctx.now, self._woken)
                return
        ctx.transmit(ctx.fifo_pop())

    def _woken(self) -> None:
        self._wake = None
        self._pump()
