"""Drive a MAC with no modem, no channel and no I/O: events in, recorded effects out (as h11's ConnectionPair).

    from uwsimnet_zenoh.mac import testing
    h = testing.Harness("cs-aloha", {"maxRetries": "1"})      # a MAC by name or class, on a FakeContext
    f = h.offer(dst=2, size=20)                               # an application frame reaches the FIFO
    assert h.effects() == [("transmit", f)]                   # what the MAC did, in order
    h.tx_done()                                               # the last bit left our transmitter
    assert h.effects() == [("status", f, "transmitted")]         # not final: an ACK is awaited
    h.advance(10.0)                                           # timers fire (here: the ACK timeout)

`FakeContext` implements `MacContext` with plain numbers: a transmitter that is busy from `transmit` until
`tx_done()`, a carrier-sense flag you set (`ctx.busy`), a scheduler of its own for the MAC's timers, and a
list of effects.  Nothing here is simulated physics: the test says what the channel did.  docs/mac.md shows
how to test your own MAC with it.
"""

from __future__ import annotations

import random
from collections import deque
from typing import Any

from ..kernel.frame import BROADCAST, Frame
from ..kernel.link import MacContext
from ..kernel.scheduler import Scheduler
from .base import Mac
from .registry import resolve

Effect = tuple


class FakeContext(MacContext):
    """What a modem offers its MAC, recorded instead of done (see `kernel.link.MacContext`)."""

    def __init__(self, address: int = 1, *, half_duplex: bool = True, max_distance: float = 1500.0,
                 header_bytes: int = 0, bitrate: float = 1000.0, tx_delay: float = 0.0,
                 prop_s_per_m: float = 1 / 1500, seed: int = 1, dev: str = "m") -> None:
        self.address = address
        self.id = dev
        self.half_duplex = half_duplex
        self.max_distance = max_distance
        self.header_bytes = header_bytes
        self.bitrate = bitrate
        self.tx_delay = tx_delay
        self.prop_s_per_m = prop_s_per_m
        self.sched = Scheduler()
        self.fifo: deque[Frame] = deque()
        self.log: list[Effect] = []
        self.busy = False
        """Carrier sense: whether energy is heard at our receiver now (the test sets it)."""
        self.busy_until = 0.0
        self.on_air: Frame | None = None
        """The frame our transmitter is sending (from `transmit` until `Harness.tx_done`)."""
        self.phy_busy = False
        """Whether `on_air` holds a frame."""
        self.random = random.Random(seed).random
        self._seq = 0
        self.delivered_rx: list[Any] = []
        """The `rx` the MAC handed back with each frame it delivered (what `receive` gave it), in order."""

    # -- MacContext ---------------------------------------------------------------------------
    def fifo_peek(self) -> Frame | None:
        return self.fifo[0] if self.fifo else None

    def fifo_pop(self) -> Frame | None:
        return self.fifo.popleft() if self.fifo else None

    def transmit(self, frame: Frame, delay: float | None = None) -> None:
        if self.on_air is not None:
            raise AssertionError(f"transmit while the transmitter is busy with {self.on_air}")
        frame.tries += 1
        self.on_air = frame
        self.phy_busy = True
        self.log.append(("transmit", frame))

    def channel_busy(self) -> bool:
        return self.busy

    def channel_busy_until(self) -> float:
        return max(self.busy_until, self.now) if self.busy else self.now

    def deliver(self, frame: Frame, rx: Any) -> None:
        self.log.append(("deliver", frame))
        self.delivered_rx.append(rx)

    def drop(self, frame: Frame, reason: str, event: str = "dropped") -> None:
        self.log.append(("drop", frame, reason))
        if event != "dropped":          # the frame's final status is not `dropped` (`failed` after retries)
            self.log.append(("status", frame, event))

    def status(self, frame: Frame, event: str, reason: str | None = None) -> None:
        self.log.append(("status", frame, event))

    def tx_time(self, size: int) -> float:
        return size * 8.0 / self.bitrate

    def max_prop_delay(self, distance: float | None = None) -> float:
        return (self.max_distance if distance is None else distance) * self.prop_s_per_m

    def trace_rx(self, frame: Frame, rx: Any) -> None:
        self.log.append(("trace_rx", frame))

    def ctrl_frame(self, dst: int, size: int, info: dict, about: Frame | None = None) -> Frame:
        return Frame(self.address, dst, about.seq if about else -1, size, 0,
                     flow=about.flow if about else None, kind="ctrl", t_enq=self.now, dev=self.id, info=info)

    # -- making frames --------------------------------------------------------------------------
    def data_frame(self, dst: int, size: int, *, src: int | None = None, seq: int | None = None,
                   flow: str | None = None) -> Frame:
        """A data frame from `src` (default: us) with the next sequence number of ours unless given."""
        if seq is None:
            seq, self._seq = self._seq, self._seq + 1
        return Frame(self.address if src is None else src, dst, seq, size + self.header_bytes, size,
                     flow=flow, t_enq=self.now, dev=self.id)


class Harness:
    """One MAC on a `FakeContext`, with the events a modem and a channel would give it."""

    def __init__(self, mac: str | type[Mac], params: dict[str, str] | None = None, **ctx: Any) -> None:
        self.ctx = FakeContext(**ctx)
        cls = resolve(mac) if isinstance(mac, str) else mac
        self.mac: Mac = cls(self.ctx, dict(params or {}))
        self._seen = 0

    @property
    def now(self) -> float:
        return self.ctx.now

    def effects(self) -> list[Effect]:
        """What the MAC did since the last call, in order."""
        new = self.ctx.log[self._seen:]
        self._seen = len(self.ctx.log)
        return new

    # -- events in ----------------------------------------------------------------------------
    def offer(self, dst: int = 2, size: int = 20, **kw: Any) -> Frame:
        """The application hands a frame to the modem: it joins the FIFO and the MAC hears of it."""
        frame = self.ctx.data_frame(dst, size, **kw)
        self.ctx.fifo.append(frame)
        self.mac.on_queue()
        return frame

    def tx_done(self) -> Frame:
        """The last bit of the frame on air left our transmitter."""
        frame = self.ctx.on_air
        if frame is None:
            raise AssertionError("tx_done with nothing on air")
        self.ctx.on_air = None
        self.ctx.phy_busy = False
        self.mac.on_tx_done(frame)
        return frame

    def receive(self, frame: Frame, rx: Any = 100.0) -> None:
        """`frame` arrived intact, addressed to us or broadcast; `rx` what the receiver got with it (kernel.rx:
        the distance in m, or an `Rx` with the channel model's details)."""
        self.mac.on_rx(frame, rx)

    def overhear(self, frame: Frame, rx: Any = 100.0) -> None:
        """`frame` arrived intact, addressed to another node (only MACs with `overhear` get this)."""
        self.mac.on_overhear(frame, rx)

    def lose(self, frame: Frame, reason: str = "col") -> None:
        """A frame addressed to us was lost."""
        self.mac.on_rx_error(frame, reason)

    def advance(self, until: float) -> None:
        """Run the MAC's timers up to simulation time `until`."""
        self.ctx.sched.run(until)

    def advance_by(self, dt: float) -> None:
        self.advance(self.now + dt)

    def until_transmit(self, limit: float = 1e6) -> Frame:
        """Run timers one at a time until the MAC transmits (then time stands at the first bit)."""
        sched = self.ctx.sched
        while self.ctx.on_air is None:
            t = sched.next_time()
            if t is None or t > limit:
                raise AssertionError(f"no transmission before t={limit:g} s")
            sched.now = t
            sched.step()
        return self.ctx.on_air

    def ack_for(self, frame: Frame, size: int = 5) -> Frame:
        """The ACK the addressee of `frame` would send back (CS-ALOHA's and S-FAMA's ACK format)."""
        return Frame(frame.dst, frame.src, frame.seq, size, 0, kind="ctrl", info={"type": "ACK", "seq": frame.seq})

    def from_peer(self, src: int = 2, dst: int | None = None, size: int = 20, seq: int = 0) -> Frame:
        """A data frame a peer sent to us (or `dst`)."""
        return self.ctx.data_frame(self.ctx.address if dst is None else dst, size, src=src, seq=seq)


__all__ = ["BROADCAST", "FakeContext", "Harness"]
