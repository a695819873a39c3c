"""A small discrete-event core (SimPy-sized): a heap of events ordered by (time, seq), each a callback and
its args.

The same scheduler runs under the virtual clock (jump from event to event) and the realtime clock
(sleep until the next event); it never looks at the wall clock itself.  Ties break by insertion order,
which keeps runs deterministic.
"""

from __future__ import annotations

import heapq
from collections.abc import Callable
from typing import Any, Final

PURE: Final = __file__.endswith(".py")
"""Running from source (not compiled): heapq's C functions, faster there than `_push`/`_pop` interpreted."""


class Event:
    """A handle for a scheduled call; `cancel()` makes it a no-op (lazy deletion keeps the heap simple)."""

    __slots__ = ("t", "seq", "fn", "args", "cancelled")

    def __init__(self, t: float, seq: int, fn: Callable[..., Any], args: tuple) -> None:
        self.t = t
        self.seq = seq              # the tie-break: insertion order
        self.fn = fn
        self.args = args
        self.cancelled = False

    def __lt__(self, other: Event) -> bool:
        """The heap's order, (t, seq): compiled, one native comparison instead of a tuple's three generic
        ones, and no tuple per event."""
        return self.t < other.t or (self.t == other.t and self.seq < other.seq)

    def cancel(self) -> None:
        self.cancelled = True


def _before(a: Event, b: Event) -> bool:
    """The heap's order, (t, seq), between two events (compiled: two double and two int comparisons)."""
    return a.t < b.t or (a.t == b.t and a.seq < b.seq)


def _push(heap: list[Event], ev: Event) -> None:
    """heapq.heappush with the order compiled in: heapq's C code compares through `Event.__lt__`'s Python
    entry point (a rich comparison call per step), this compares the fields.  The keys (t, seq) are
    unique, so any heap pops the same sequence: the order of a run does not depend on this code."""
    heap.append(ev)
    pos = len(heap) - 1
    while pos > 0:
        parent = (pos - 1) >> 1
        up = heap[parent]
        if not _before(ev, up):
            break
        heap[pos] = up
        pos = parent
    heap[pos] = ev


def _pop(heap: list[Event]) -> Event:
    """heapq.heappop, compiled (`_push`): the hole at the top goes down the smaller children to a leaf, the
    last event fills it and climbs back (heapq's own way: fewer comparisons than a plain sift down)."""
    last = heap.pop()
    n = len(heap)
    if n == 0:
        return last
    top = heap[0]
    pos = 0
    child = 1
    while child < n:
        right = child + 1
        if right < n and not _before(heap[child], heap[right]):
            child = right
        heap[pos] = heap[child]
        pos = child
        child = 2 * pos + 1
    while pos > 0:
        parent = (pos - 1) >> 1
        up = heap[parent]
        if not _before(last, up):
            break
        heap[pos] = up
        pos = parent
    heap[pos] = last
    return top


class Interrupted(Exception):  # noqa: N818 - it is what happened, not an error
    """Raised out of `Scheduler.run` when `interrupt()` was called: between two events, never inside one."""


class Scheduler:
    def __init__(self) -> None:
        self.now = 0.0
        self._heap: list[Event] = []
        self._seq = 0
        self.events_run = 0
        self.interrupted = False

    def at(self, t: float, fn: Callable[..., Any], *args: Any) -> Event:
        """Schedule `fn(*args)` at absolute time `t` (never in the past)."""
        if t < self.now:
            t = self.now
        self._seq += 1
        ev = Event(t, self._seq, fn, args)
        if PURE:
            heapq.heappush(self._heap, ev)
        else:
            _push(self._heap, ev)
        return ev

    def after(self, delay: float, fn: Callable[..., Any], *args: Any) -> Event:
        return self.at(self.now + delay, fn, *args)

    def next_time(self) -> float | None:
        """Time of the next live event, dropping cancelled ones from the top (raises `Interrupted` after
        `interrupt()`)."""
        if self.interrupted:
            raise self._stop()
        heap = self._heap
        while heap and heap[0].cancelled:
            heapq.heappop(heap) if PURE else _pop(heap)
        return heap[0].t if heap else None

    def step(self) -> None:
        """Run the next event (the caller has checked there is one)."""
        if self.interrupted:
            raise self._stop()
        ev = heapq.heappop(self._heap) if PURE else _pop(self._heap)
        if ev.cancelled:
            return
        self.now = ev.t
        self.events_run += 1
        ev.fn(*ev.args)

    def interrupt(self) -> None:
        """Make `run` raise `Interrupted` before the next event.  Safe from a signal handler, which Python
        may run in the middle of a heap operation (inside `Event.__lt__` when it is not compiled): it only
        sets a flag, which the loops read between two events."""
        self.interrupted = True

    def _stop(self) -> Interrupted:
        """The interrupt is taken: once (a later `run` goes on)."""
        self.interrupted = False
        return Interrupted()

    def run(self, until: float) -> None:
        """Virtual time: run every event with t <= until, then stand at `until` (see `interrupt`)."""
        heap = self._heap
        n = 0
        try:
            while heap and heap[0].t <= until:
                if self.interrupted:
                    raise self._stop()
                ev = heapq.heappop(heap) if PURE else _pop(heap)
                if ev.cancelled:
                    continue
                self.now = ev.t
                n += 1
                ev.fn(*ev.args)
        finally:
            self.events_run += n
        if self.interrupted:        # the signal came with the last event: time stays where it was
            raise self._stop()
        self.now = max(self.now, until)

    def clear(self) -> None:
        """Forget every scheduled event (a run that has ended)."""
        self._heap.clear()

    def pending(self) -> list[Event]:
        """The live events still scheduled, in no particular order (for ending a run: what is held)."""
        return [ev for ev in self._heap if not ev.cancelled]
