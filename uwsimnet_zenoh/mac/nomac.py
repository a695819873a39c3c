"""NOMAC: the bare modem, as the original simulated it (dccomms_ros `CustomROSCommsDevice` without a MAC).

The FIFO head goes on air as soon as the transmitter is free, with no acknowledgement.  A half-duplex
modem (tx channel == rx channel) cannot start sending while its receiver hears a frame, so it waits for
the end of that reception: the original's implicit carrier sense, and what makes the paper's FIFO fill
up and its end-to-end delay rise once both ROVs transmit (docs/paper-phy-layer.md).  The decision is
taken when the modem picks the frame; the intrinsic tx delay that follows is the window in which two
modems can still collide.  A full-duplex or transmit-only modem never waits: with `txFifoSize` 0 that
is pure ALOHA.

As in the original (`PhySend`, `TransmitEnqueuedPacket`, `_fixedIPGmicros = 100`): only a frame that finds
the modem idle waits the intrinsic delay; a frame that had to wait (behind another frame, or for a
reception to end) leaves `IPG` = 100 us after that event, without paying the intrinsic delay again.

Delivery (`<macProtocol><name>none</name><delivery>...</delivery>`): `all` (the default, the original's
implicit broadcast: there is no destination filtering without a MAC, every modem in range on the channel
hands the frame to its application, which filters; traced `rx` with `implicit: true` at the others) or
`addressee` (only the addressee and broadcast).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, Final

from ..kernel.frame import Frame
from .base import Mac, MacContext
from .registry import register

if TYPE_CHECKING:
    from ..kernel.scheduler import Event

IPG: Final = 100e-6
"""dccomms_ros CustomROSCommsDevice::_fixedIPGmicros: the gap before a queued frame, s."""
DELIVERY = ("all", "addressee")


@register("none", "nomac", "")
class NoMac(Mac):
    def __init__(self, ctx: MacContext, params: Mapping[str, str]) -> None:
        super().__init__(ctx, params)
        self._wake: Event | None = None
        delivery = params.get("delivery", "all").strip().lower()
        if delivery not in DELIVERY:
            raise ValueError(f"macProtocol delivery: expected all or addressee, got {params['delivery']!r}")
        self.implicit_broadcast = delivery == "all"
        self.overhear = self.implicit_broadcast

    def ready(self) -> bool:
        ctx = self.ctx
        return not ctx.phy_busy and not (ctx.half_duplex and ctx.channel_busy())

    def on_queue(self) -> None:
        self._pump(queued=False)

    def on_tx_done(self, frame: Frame) -> None:
        if frame.kind == "data":
            self.ctx.status(frame, "sent")
        self._pump(queued=True)

    def on_rx(self, frame: Frame, rx: Any) -> None:
        if frame.kind == "data":
            self.ctx.deliver(frame, rx)

    def on_overhear(self, frame: Frame, rx: Any) -> None:
        if self.implicit_broadcast and frame.kind == "data":
            self.ctx.deliver(frame, rx)

    def _pump(self, queued: bool) -> None:
        ctx = self.ctx
        if ctx.phy_busy or not ctx.fifo or self._wake is not None:
            return
        if ctx.half_duplex:
            until = ctx.channel_busy_until()
            if until > ctx.now:
                self._wake = ctx.timer(until - ctx.now, self._woken)
                return
        frame = ctx.fifo_pop()
        assert frame is not None            # the FIFO is not empty (checked above)
        ctx.transmit(frame, IPG if queued else None)

    def _woken(self) -> None:
        self._wake = None
        self._pump(queued=True)

