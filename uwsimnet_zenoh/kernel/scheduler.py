"""A small discrete-event core (SimPy-sized): a heap of (time, seq, callback, args).

The same scheduler runs under the virtual clock (jump from event to event) and the realtime clock
(sleep until the next event); it never looks at the wall clock itself.  Ties break by insertion order,
which keeps runs deterministic.
"""

from __future__ import annotations

import heapq
from collections.abc import Callable
from typing import Any


class Event:
    """A handle for a scheduled call; `cancel()` makes it a no-op (lazy deletion keeps the heap simple)."""

    __slots__ = ("t", "fn", "args", "cancelled")

    def __init__(self, t: float, fn: Callable[..., Any], args: tuple) -> None:
        self.t = t
        self.fn = fn
        self.args = args
        self.cancelled = False

    def cancel(self) -> None:
        self.cancelled = True


class Interrupted(Exception):  # noqa: N818 - it is what happened, not an error
    """Raised out of `Scheduler.run` when `interrupt()` was called: between two events, never inside one."""


class _Interrupt(Event):
    """The event `interrupt()` pushes: born cancelled, so the loops that skip cancelled events look at it
    only on that rare path (`_skip`), where it raises Interrupted: an interrupt costs the other events
    nothing and time never goes back, even when the signal came between a pop and the event's `now`."""

    __slots__ = ()

    def __init__(self, t: float) -> None:
        super().__init__(t, _never, ())
        self.cancelled = True


def _never() -> None:
    raise Interrupted


def _skip(ev: Event) -> None:
    """A cancelled event was popped or found on top: an interrupt raises, any other is dropped."""
    if type(ev) is _Interrupt:
        raise Interrupted


class Scheduler:
    def __init__(self) -> None:
        self.now = 0.0
        self._heap: list[tuple[float, int, Event]] = []
        self._seq = 0
        self.events_run = 0

    def at(self, t: float, fn: Callable[..., Any], *args: Any) -> Event:
        """Schedule `fn(*args)` at absolute time `t` (never in the past)."""
        if t < self.now:
            t = self.now
        ev = Event(t, fn, args)
        self._seq += 1
        heapq.heappush(self._heap, (t, self._seq, ev))
        return ev

    def after(self, delay: float, fn: Callable[..., Any], *args: Any) -> Event:
        return self.at(self.now + delay, fn, *args)

    def next_time(self) -> float | None:
        """Time of the next live event, dropping cancelled ones from the top."""
        heap = self._heap
        while heap and heap[0][2].cancelled:
            _skip(heap[0][2])
            heapq.heappop(heap)
        return heap[0][0] if heap else None

    def step(self) -> None:
        """Run the next event (the caller has checked there is one)."""
        t, _, ev = heapq.heappop(self._heap)
        if ev.cancelled:
            _skip(ev)
            return
        self.now = t
        self.events_run += 1
        ev.fn(*ev.args)

    def interrupt(self) -> None:
        """Make `run` raise `Interrupted` before the next event (safe from a signal handler: one heap
        push, ordered before every event due at `now`, with a sequence number no `at` uses)."""
        heapq.heappush(self._heap, (self.now, -1, _Interrupt(self.now)))

    def run(self, until: float) -> None:
        """Virtual time: run every event with t <= until, then stand at `until` (see `interrupt`)."""
        heap = self._heap
        pop = heapq.heappop
        n = 0
        try:
            while heap and heap[0][0] <= until:
                t, _, ev = pop(heap)
                if ev.cancelled:
                    _skip(ev)
                    continue
                self.now = t
                n += 1
                ev.fn(*ev.args)
        except Interrupted:
            self.events_run += n
            raise
        self.events_run += n
        self.now = max(self.now, until)

    def clear(self) -> None:
        """Forget every scheduled event (a run that has ended)."""
        self._heap.clear()

    def pending(self) -> list[Event]:
        """The live events still scheduled, in no particular order (for ending a run: what is held)."""
        return [ev for _, _, ev in self._heap if not isinstance(ev, _Interrupt) and not ev.cancelled]
