"""The contracts of a modem, below it: with its MAC (phy and mac never import each other; ns-3's
UanPhyListener and UanMac play these parts), `MacHooks`, what a modem tells its MAC (mac.Mac is one), and
`MacContext`, what a modem offers its MAC (phy.Modem is one; mac.testing.FakeContext too); with its
channels, `Medium`, what a modem asks the channels it sends and listens on (phy.Channel is one: the channel
calls the modem and imports it, the modem knows the channel only as this).

They are Protocols: plain Python, no compiler rules (only the pure leaves below them are compiled,
uwsimnet_zenoh/_native.py).  `MacHooks` and `MacContext` also carry defaults (a hook that does nothing, `now`,
`timer`), which a class that names them as a base inherits; a class that does not is checked by its shape.
A reception's `rx` is typed Any: it is a float that may be a kernel.rx.Rx (a compiled `float` parameter would
unbox it to a double and lose its details)."""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:
    from .frame import Frame
    from .scheduler import Event, Scheduler


class MacHooks(Protocol):
    """What a modem tells its MAC.  The defaults do nothing: a MAC overrides what it needs (mac.Mac)."""

    def ready(self) -> bool:
        """Would take a frame offered now straight into service (it then does not count in the FIFO)?"""
        return False

    def on_queue(self) -> None:
        """A frame was added to the FIFO."""

    def on_tx_done(self, frame: Frame) -> None:
        """The last bit of `frame` left our transmitter."""

    def on_rx(self, frame: Frame, rx: Any) -> None:
        """`frame` arrived intact and is addressed to us (or broadcast); `rx` what the receiver got with it
        (kernel.rx: the distance, a float, with the channel model's details if it gave any), to hand back
        with `deliver` or `trace_rx`."""

    def on_overhear(self, frame: Frame, rx: Any) -> None:
        """`frame` arrived intact but is addressed to another node (only if the MAC's `overhear`)."""

    def on_rx_error(self, frame: Frame, reason: str) -> None:
        """A frame addressed to us was lost (prop, col, mult, range, nopose)."""

    def close(self) -> None:
        """The modem leaves the simulation: give back what you hold (drop with a reason)."""


class Medium(Protocol):
    """What a modem asks the channels it sends and listens on (phy.channel.Channel has this shape)."""

    id: int                                      # the channel id every event of the modem carries
    min_prop_s: float                            # delay = min_prop_s + prop_s_per_m * distance
    prop_s_per_m: float

    def attach(self, modem: Any) -> int:
        """Listen with `modem` (a phy.Modem) from now on: its slot."""
        raise NotImplementedError

    def detach(self, modem: Any) -> None:
        raise NotImplementedError

    def has_address(self, address: int) -> bool:
        """Does a modem listening here have `address`?"""
        raise NotImplementedError

    def max_prop_delay(self, max_distance: float) -> float:
        raise NotImplementedError

    def transmit(self, sender: Any, frame: Frame, dur: float) -> None:
        """`frame` from `sender` (a phy.Modem), its first bit on air now, `dur` s long."""
        raise NotImplementedError

    def busy(self, slot: int) -> bool:
        """Energy heard at listener `slot` now."""
        raise NotImplementedError

    def busy_until(self, slot: int) -> float:
        raise NotImplementedError


class MacContext(Protocol):
    """What a modem offers its MAC (docs/mac.md has the table).  The subclass sets the attributes and
    implements the methods; the base's own methods say what is missing."""

    address: int
    id: str
    half_duplex: bool
    max_distance: float                          # the device's maxDistance, m
    header_bytes: int                            # the device's headerBytes (framing added to every frame)
    fifo: deque[Frame]                           # the tx FIFO; read it, pop via fifo_pop
    phy_busy: bool                               # our transmitter is processing or on air
    tx_delay: float                              # intrinsic delay from transmit() to the first bit, s
    sched: Scheduler                             # the MAC's clock and timers (`now`, `timer`)
    random: Callable[[], float]                  # the MAC's own random stream, uniform on [0, 1)

    @property
    def now(self) -> float:
        return self.sched.now

    def fifo_peek(self) -> Frame | None:
        return self.fifo[0] if self.fifo else None

    def fifo_pop(self) -> Frame | None:
        raise NotImplementedError

    def transmit(self, frame: Frame, delay: float | None = None) -> None:
        """Hand a frame to the PHY (only when not phy_busy); first bit after the intrinsic delay, or
        after `delay` s."""
        raise NotImplementedError

    def channel_busy(self) -> bool:
        """Carrier sense: energy heard at our receiver now."""
        raise NotImplementedError

    def channel_busy_until(self) -> float:
        """When the energy heard at our receiver now ends (now if the channel is idle)."""
        raise NotImplementedError

    def deliver(self, frame: Frame, rx: Any) -> None:
        """Up to the application (after the rx delay); `rx` as `on_rx` gave it (the rx event carries it)."""
        raise NotImplementedError

    def drop(self, frame: Frame, reason: str, event: str = "dropped") -> None:
        """A frame we give up on: traced `drop` + its final status (`dropped`, or `failed` after retries)."""
        raise NotImplementedError

    def status(self, frame: Frame, event: str, reason: str | None = None) -> None:
        """For the application: `sent` (final, unacknowledged) | `transmitted` (an attempt on air, an
        acknowledgement expected) | `acked` (final); docs/gli-protocol.md#status-modem--app."""
        raise NotImplementedError

    def timer(self, delay: float, fn: Callable[..., Any], *args: Any) -> Event:
        return self.sched.after(delay, fn, *args)

    def tx_time(self, size: int) -> float:
        raise NotImplementedError

    def max_prop_delay(self, distance: float | None = None) -> float:
        raise NotImplementedError

    def trace_rx(self, frame: Frame, rx: Any) -> None:
        """Trace a control frame received (not delivered); `rx` as `on_rx` gave it."""
        raise NotImplementedError

    def ctrl_frame(self, dst: int, size: int, info: dict, about: Frame | None = None) -> Frame:
        raise NotImplementedError
