"""The MAC interface (sans-IO): `Mac`, the context it acts through (`MacContext`), and `OneFrameMac`.

A MAC is a plain state machine.  The modem tells it what happened (a frame waits in the FIFO, our
transmission ended, a frame arrived intact, a reception failed) and the MAC answers through its
context: take the FIFO head, transmit, set timers, deliver to the application, report a status.  It
never sees a clock other than `ctx.now` nor any I/O, so the same MAC runs in virtual and real time.

Write your own: subclass `Mac`, then name it `module:Class` in `<macProtocol><name>` or register it
under the entry-point group `uwsimnet.mac`.  docs/mac.md walks through an example.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Final

from ..kernel.link import MacContext, MacHooks

if TYPE_CHECKING:
    from ..kernel.frame import Frame
    from ..kernel.scheduler import Event


class Mac(MacHooks):
    """Base class; the defaults make a MAC that never overhears and ignores failed receptions.  The modem
    calls it through `kernel.link.MacHooks` and offers it a `MacContext` (docs/mac.md)."""

    overhear = False
    """True if the MAC must see intact frames addressed to others (e.g. RTS/CTS for deferral)."""

    def __init__(self, ctx: MacContext, params: Mapping[str, str]) -> None:
        self.ctx = ctx
        self.params = params

    def param(self, name: str, default: float) -> float:
        """A numeric parameter of `<macProtocol>`, with a clear error if it is not a number."""
        raw = self.params.get(name)
        if raw is None:
            return default
        try:
            return float(raw)
        except ValueError:
            raise ValueError(f"macProtocol {name}: expected a number, got {raw!r}") from None


IDLE: Final = "idle"
"""The state of a OneFrameMac with no frame in service."""


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
