"""The MAC interface (sans-IO): `Mac`, the context it acts through (`MacContext`), and `OneFrameMac`.

A MAC is a plain state machine.  The modem tells it what happened (a frame waits in the FIFO, our
transmission ended, a frame arrived intact, a reception failed) and the MAC answers through its
context: take the FIFO head, transmit, set timers, deliver to the application, report a status.  It
never sees a clock other than `ctx.now` nor any I/O, so the same MAC runs in virtual and real time.

Write your own: subclass `Mac`, then name it `module:Class` in `<macProtocol><name>` or register it
under the entry-point group `uwsimnet.mac`.  docs/mac.md walks through an example.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any, Protocol

from mypy_extensions import mypyc_attr

if TYPE_CHECKING:
    from ..kernel.frame import Frame
    from ..kernel.scheduler import Event


class MacContext(Protocol):
    """What a modem offers its MAC (`phy.modem.Modem` has it; mac never imports phy)."""

    address: int
    id: str
    half_duplex: bool
    max_distance: float                          # the device's maxDistance, m
    header_bytes: int                            # the device's headerBytes (framing added to every frame)
    fifo: Any                                    # the tx FIFO (a deque of Frame); read it, pop via fifo_pop

    @property
    def now(self) -> float: ...
    @property
    def phy_busy(self) -> bool: ...              # our transmitter is processing or on air
    def fifo_peek(self) -> Frame | None: ...
    def fifo_pop(self) -> Frame | None: ...
    def transmit(self, frame: Frame, delay: float | None = None) -> None: ...
    # hand a frame to the PHY (only when not phy_busy); first bit after the intrinsic delay, or `delay` s
    def channel_busy(self) -> bool: ...          # carrier sense: energy heard at our receiver now
    def channel_busy_until(self) -> float: ...
    def deliver(self, frame: Frame) -> None: ...   # up to the application (after the rx delay)
    def drop(self, frame: Frame, reason: str, event: str = "dropped") -> None: ...
    # a frame we give up on: traced `drop` + its final status (`dropped`, or `failed` after retries)
    def status(self, frame: Frame, event: str) -> None: ...
    # for the application: `sent` (final, unacknowledged) | `transmitted` (an attempt on air, an
    # acknowledgement expected) | `acked` (final); docs/gli-protocol.md#status-modem--app
    def timer(self, delay: float, fn: Callable[..., Any], *args: Any) -> Event: ...
    def tx_time(self, size: int) -> float: ...
    @property
    def tx_delay(self) -> float: ...             # intrinsic delay from transmit() to the first bit, s
    def max_prop_delay(self, distance: float | None = None) -> float: ...
    def trace_rx(self, frame: Frame) -> None: ...  # trace a control frame received (not delivered)
    def ctrl_frame(self, dst: int, size: int, info: dict, about: Frame | None = None) -> Frame: ...
    def random(self) -> float: ...


@mypyc_attr(allow_interpreted_subclasses=True)      # compiled (uwsimnet_zenoh._native): user MACs subclass it
class Mac:
    """Base class; the defaults make a MAC that never overhears and ignores failed receptions."""

    overhear = False
    """True if the MAC must see intact frames addressed to others (e.g. RTS/CTS for deferral)."""

    def __init__(self, ctx: MacContext, params: Mapping[str, str]) -> None:
        self.ctx = ctx
        self.params = params

    def ready(self) -> bool:
        """Would take a frame offered now straight into service (it then does not count in the FIFO)?"""
        return False

    def on_queue(self) -> None:
        """A frame was added to the FIFO."""

    def on_tx_done(self, frame: Frame) -> None:
        """The last bit of `frame` left our transmitter."""

    def on_rx(self, frame: Frame) -> None:
        """`frame` arrived intact and is addressed to us (or broadcast)."""

    def on_overhear(self, frame: Frame) -> None:
        """`frame` arrived intact but is addressed to another node (only if `overhear`)."""

    def on_rx_error(self, frame: Frame, reason: str) -> None:
        """A frame addressed to us was lost (prop, col, mult, range)."""

    def close(self) -> None:
        """The modem leaves the simulation: give back what you hold (drop with a reason)."""

    def param(self, name: str, default: float) -> float:
        """A numeric parameter of `<macProtocol>`, with a clear error if it is not a number."""
        raw = self.params.get(name)
        if raw is None:
            return default
        try:
            return float(raw)
        except ValueError:
            raise ValueError(f"macProtocol {name}: expected a number, got {raw!r}") from None


IDLE = "idle"
"""The state of a OneFrameMac with no frame in service."""


@mypyc_attr(allow_interpreted_subclasses=True)
class OneFrameMac(Mac):
    """A MAC that serves one frame at a time (`cur`, taken from the FIFO when it is idle), with one pending
    timer: CS-ALOHA and S-FAMA.  What is common to them lives here: taking the next frame, and giving
    it up when the modem leaves or after `max_retries` failed attempts.  Subclasses set `max_retries`,
    start work on `cur` in `_begin()`, and forget any state that outlives a frame in `_release()`."""

    max_retries: int

    def __init__(self, ctx: MacContext, params: Mapping[str, str]) -> None:
        super().__init__(ctx, params)
        self.state = IDLE
        self.cur: Frame | None = None
        self.fails = 0                      # failed attempts of `cur`
        self._timer: Event | None = None
        self._closed = False

    def ready(self) -> bool:
        return self.cur is None

    def close(self) -> None:
        self._closed = True
        self._cancel()
        self._release()
        if self.cur is not None:
            frame, self.cur = self.cur, None
            self.state = IDLE
            self.ctx.drop(frame, "removed")

    def _next(self) -> None:
        """Take the next frame from the FIFO, if idle and there is one."""
        if self.cur is not None:
            return
        frame = self.ctx.fifo_pop()
        if frame is None:
            self.state = IDLE
            return
        self.cur = frame
        self.fails = 0
        self._begin()

    def _done(self) -> None:
        """`cur` is finished with (sent, acknowledged or given up): take the next frame."""
        self._cancel()
        self.cur = None
        self.state = IDLE
        self._next()

    def _retry(self) -> bool:
        """Count a failed attempt of `cur`; past `max_retries` give it up (dropped `retry`, status
        `failed`) and go on with the next frame.  Whether `cur` gets another attempt.  A negative
        `max_retries` (maxRetries -1) means no limit, as in Aqua-Sim NG's ALOHA and S-FAMA."""
        self.fails += 1
        if self.max_retries < 0 or self.fails <= self.max_retries:
            return True
        frame = self.cur
        assert frame is not None            # a retry is always of the frame in service
        self.cur = None
        self.ctx.drop(frame, "retry", event="failed")      # one final status: failed (reason retry)
        self._done()
        return False

    def _begin(self) -> None:
        raise NotImplementedError

    def _release(self) -> None:
        """The modem leaves: forget what outlives a frame (queued ACKs, a responder's role)."""

    def _cancel(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
