"""The edge between the engine thread and Zenoh: bounded, non-blocking hand-offs both ways.

Out (`Outbox`): the engine thread never makes a Zenoh put.  What a modem publishes (rx frames, status
events) is appended to that modem's outbox and a publisher thread of the outbox makes the puts; trace
records and the periodic publications (poses, clock) have outboxes of their own.  `put()` never waits
beyond a short lock: when an outbox is full (its consumer, or the link to it, cannot keep up: a stopped
app subscribed with BLOCK congestion control holds a put up to Zenoh's `wait_before_close`) the message
is dropped at the edge and counted (`dropped`, by kind), and the count is reported on the modem's
`info`, in the run summary and in a (rate-limited) warning: never silently.  Each outbox has its own
thread, so a stuck put costs only the modem (or trace channel) it serves.

In (`Lane`): tx messages from applications wait in a bounded FIFO per modem, and the engine takes them
round-robin, one message of a modem per inbox item: a flood on one modem fills its own lane (and its
own transmit FIFO) while the messages of the other modems keep their place.  The lane also measures
the ingress delay: wall time from the Zenoh callback to the engine handling the message.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from typing import Any

from ..kernel.realtime import pin_thread

log = logging.getLogger("uwsimnet.bus.outbox")
_sleep = time.sleep
_clock = time.monotonic

OUTBOX_CAPACITY = 1024
"""Messages an outbox holds before it drops (per modem: rx and status together)."""
LANE_CAPACITY = 1024
"""tx messages a modem's ingress lane holds before it refuses (status dropped, reason fifo)."""
INGRESS_WARN_S = 0.050
"""Ingress delay (wall s, put to engine) above which the broker warns (rate-limited)."""
LAZY_MAX = 32
"""Non-urgent messages an outbox holds before it wakes its thread anyway (see Outbox.put)."""
LOST_IDS = 1000
"""Identities of lost messages (an rx frame's (src, seq)) an outbox keeps for the trace's end record."""
STALL_S = 0.5
"""A put that takes this long (wall s) waited on a consumer that does not read: counted (`stalled`) and warned.
Zenoh says nothing of what it then gives up (a BLOCK put waits at most `wait_before_close`, 2 s on our routers:
bus/session.py, in turn with the other outboxes putting to the same stopped consumer: docs/runtime.md), so the
wait itself is what the edge reports."""


class Outbox:
    """A bounded FIFO of `(fn, arg)` calls made by a thread of its own, in order (see module docstring).

    `put(fn, arg, kind)` is for the engine thread (any thread, in fact): it appends and wakes the
    thread, or drops and counts when `capacity` calls are waiting.  `close(timeout)` lets the thread
    finish what is queued (up to `timeout` s), then ends it.  `cpu`: the thread runs on that CPU only (the
    engine's: kernel.realtime.pin_thread)."""

    def __init__(self, name: str, capacity: int = OUTBOX_CAPACITY, handoff: bool = True,
                 defer: Callable[[Outbox], None] | None = None, cpu: int | None = None,
                 on_wake: Callable[[], None] | None = None) -> None:
        self.name = name
        self.cpu = cpu
        self.handoff = handoff
        self.on_wake = on_wake
        """Called (on the putting thread) when an urgent put wakes the thread: the engine's clock then leaves
        it the interpreter before its own deferred work (RealtimeClock.yield_to_output)."""
        self.defer = defer
        """Where a non-urgent put that would wake the thread says so instead (the broker wakes every such
        outbox when its engine is done with what is due); None: it wakes the thread at once."""
        self._notified = False      # the thread has been told about what is queued (or is running)
        self.capacity = capacity
        self._q: deque[tuple[Callable[[Any], Any], Any, str, Any]] = deque()
        self._cond = threading.Condition(threading.Lock())
        self._closing = False
        self.sent = 0
        self.failed = 0
        self.dropped: Counter[str] = Counter()
        """Messages refused because the outbox was full, by kind (rx, status, trace, ...), or left at close."""
        self.lost_ids: list[Any] = []
        """The `ident` of those that had one (an rx frame's (src, seq)), the first LOST_IDS."""
        self.high_water = 0
        self.stalled: Counter[str] = Counter()
        """Puts that waited STALL_S or more (a consumer not reading; what it did not take may be lost), by kind."""
        self.stalled_max = 0.0
        self.stalled_ids: list[tuple[Any, float]] = []
        """(ident, wall s waited) of those stalled puts that had an ident, the first LOST_IDS."""
        self._thread = threading.Thread(target=self._run, name=f"uwsimnet-out-{name}", daemon=True)
        self._thread.start()

    def put(self, fn: Callable[[Any], Any], arg: Any, kind: str = "msg", urgent: bool = True,
            ident: Any = None) -> bool:
        """Queue `fn(arg)`; False (and counted, with `ident` if not None) if the outbox is full or closed.
        Never blocks.

        `urgent` (an rx frame, whose delivery time is modelled): wake the thread and hand it the
        interpreter now.  Not urgent (a status): with `defer`, the wake-up is left to the owner (a
        thread wake-up is a cross-CPU interrupt, tens of us on a VM, not worth paying in the middle of
        the engine's work), up to LAZY_MAX messages; without, the thread is woken but not handed the
        interpreter (it takes it when the caller next waits, within the switch interval)."""
        wake = False
        later = False
        with self._cond:
            q = self._q
            if self._closing or len(q) >= self.capacity:
                self._lose(kind, ident)
                return False
            q.append((fn, arg, kind, ident))
            n = len(q)
            if n > self.high_water:
                self.high_water = n
            if not self._notified:
                if urgent or self.defer is None or n >= LAZY_MAX:
                    self._notified = wake = True
                    self._cond.notify()
                elif n == 1:
                    later = True
        if later:
            self.defer(self)  # type: ignore[misc]
        elif wake and urgent and self.handoff:
            if self.on_wake is not None:
                self.on_wake()
            _sleep(0)       # let the woken thread take the interpreter now: the put leaves at once, not
            #                 when the engine next waits (measured: ~0.3 ms less per frame, bench_realtime)
        return True

    def _lose(self, kind: str, ident: Any) -> None:
        """(under the lock)"""
        self.dropped[kind] += 1
        if ident is not None and len(self.lost_ids) < LOST_IDS:
            self.lost_ids.append(ident)

    def wake(self) -> None:
        """Wake the thread for what is queued (the owner's side of `defer`)."""
        with self._cond:
            if self._q and not self._notified:
                self._notified = True
                self._cond.notify()

    def __len__(self) -> int:
        return len(self._q)

    def stats(self) -> dict[str, Any]:
        return {"queued": len(self._q), "sent": self.sent, "failed": self.failed,
                "dropped": dict(self.dropped), "high_water": self.high_water, "capacity": self.capacity,
                "stalled": dict(self.stalled), "stalled_max": self.stalled_max}

    def _run(self) -> None:
        pin_thread(self.cpu)
        q = self._q
        cond = self._cond
        while True:
            with cond:
                while not q and not self._closing:
                    self._notified = False
                    cond.wait()
                if not q:
                    return
                fn, arg, kind, ident = q.popleft()
            t0 = _clock()
            try:
                fn(arg)
                self.sent += 1
            except Exception as e:  # noqa: BLE001 - a put that fails costs only itself
                self.failed += 1
                log.debug("%s: %s put failed: %s", self.name, kind, e)
            waited = _clock() - t0
            if waited >= STALL_S:
                self.stalled[kind] += 1
                if ident is not None and len(self.stalled_ids) < LOST_IDS:
                    self.stalled_ids.append((ident, waited))
                if waited > self.stalled_max:
                    self.stalled_max = waited
                if sum(self.stalled.values()) in (1, 10, 100, 1000):
                    log.warning("%s: a %s put waited %.1f s: a subscriber does not read (what it has not taken"
                                " may be lost; %d such put(s) so far)", self.name, kind, waited,
                                sum(self.stalled.values()))

    def close(self, timeout: float = 1.0) -> bool:
        """Stop taking calls, let the queued ones go out (up to `timeout` s); True if all went."""
        with self._cond:
            self._closing = True
            self._notified = True
            self._cond.notify()
        self._thread.join(timeout)
        if self._thread.is_alive():
            with self._cond:
                left = len(self._q)
                for _, _, kind, ident in self._q:
                    self._lose(kind, ident)
                self._q.clear()
            log.warning("%s: %d message(s) not sent at close (a consumer does not read)", self.name, left)
            return False
        return True


class Lane:
    """One modem's ingress: a bounded FIFO of (wall time, item) and the delay statistics.

    The Zenoh thread calls `offer(item)`: True if the engine must be woken for this lane (it was idle),
    False if it is already scheduled; None if the lane is full (the caller refuses the message).  The
    engine calls `take()` for one item and `done_one()` to learn whether to schedule itself again."""

    __slots__ = ("name", "capacity", "_q", "_lock", "scheduled", "refused", "n", "delay_sum", "delay_max",
                 "_pc")

    def __init__(self, name: str, capacity: int = LANE_CAPACITY,
                 perf_counter: Callable[[], float] = time.perf_counter) -> None:
        self.name = name
        self.capacity = capacity
        self._q: deque[tuple[float, Any]] = deque()
        self._lock = threading.Lock()
        self.scheduled = False
        self.refused = 0
        self.n = 0
        self.delay_sum = 0.0
        self.delay_max = 0.0
        self._pc = perf_counter

    def offer(self, item: Any) -> bool | None:
        with self._lock:
            if len(self._q) >= self.capacity:
                self.refused += 1
                return None
            self._q.append((self._pc(), item))
            if self.scheduled:
                return False
            self.scheduled = True
            return True

    def take(self) -> tuple[float, Any] | None:
        """The oldest item and its ingress delay (wall s), measured now; None if empty."""
        with self._lock:
            if not self._q:
                self.scheduled = False
                return None
            t0, item = self._q.popleft()
        d = self._pc() - t0
        self.n += 1
        self.delay_sum += d
        if d > self.delay_max:
            self.delay_max = d
        return d, item

    def more(self) -> bool:
        """After a `take`: True if items remain (the lane stays scheduled), else it goes idle."""
        with self._lock:
            if self._q:
                return True
            self.scheduled = False
            return False

    def __len__(self) -> int:
        return len(self._q)

    def stats(self) -> dict[str, Any]:
        return {"n": self.n, "mean": self.delay_sum / self.n if self.n else 0.0, "max": self.delay_max,
                "queued": len(self._q), "refused": self.refused, "capacity": self.capacity}


POSE_KEYS = 4096
"""Distinct pose keys whose samples may wait for the engine at once (more: refused and counted)."""


class Latest:
    """Pose samples waiting for the engine, coalesced per key: only the newest sample of a key (and the
    one before it, for a reader at an earlier time) is kept, so a flood of poses costs the engine one
    decode per vehicle, never one per sample.

    The engine thread does both sides: `offer(key, stamp, raw)` as it takes samples from Zenoh's ring
    (stamp: simulation time of arrival), `take(t)` for what arrived by simulation time t: per key, the
    newest sample stamped at or before t, with the number of samples it stands for (itself and those it
    superseded)."""

    __slots__ = ("capacity", "_pending", "refused", "received")

    def __init__(self, capacity: int = POSE_KEYS) -> None:
        self.capacity = capacity
        self._pending: dict[str, list[Any]] = {}     # key -> [stamp, raw, prev stamp, prev raw, count]
        self.refused = 0
        self.received = 0

    def offer(self, key: str, stamp: float, raw: Any) -> bool:
        """Keep `raw` as the newest sample of `key`; False if refused (too many distinct keys waiting)."""
        self.received += 1
        e = self._pending.get(key)
        if e is None:
            if len(self._pending) >= self.capacity:
                self.refused += 1
                return False
            self._pending[key] = [stamp, raw, None, None, 1]
            return True
        e[2], e[3] = e[0], e[1]
        e[0], e[1] = stamp, raw
        e[4] += 1
        return True

    def take(self, t: float) -> list[tuple[str, int, float, Any]]:
        """(key, samples, stamp, raw) of the newest sample of each key stamped at or before `t`."""
        pending = self._pending
        if not pending:
            return []
        out = []
        for key, e in list(pending.items()):
            if e[0] <= t:
                out.append((key, e[4], e[0], e[1]))
                del pending[key]
            elif e[2] is not None and e[2] <= t:      # the newest came later: the one before it
                out.append((key, e[4] - 1, e[2], e[3]))
                e[2] = e[3] = None
                e[4] = 1
        return out

    def __len__(self) -> int:
        return len(self._pending)


class Throttle:
    """At most `burst` log lines per key, then one per `every` seconds with the count suppressed."""

    def __init__(self, burst: int = 5, every: float = 5.0, logger: logging.Logger = log) -> None:
        self.log = logger
        self.burst = burst
        self.every = every
        self._n: Counter[str] = Counter()
        self._last: dict[str, float] = {}
        self._hidden: Counter[str] = Counter()

    def __call__(self, key: str, msg: str, *args: Any) -> None:
        self._n[key] += 1
        now = time.monotonic()
        if self._n[key] <= self.burst or now - self._last.get(key, 0.0) >= self.every:
            hidden = self._hidden.pop(key, 0)
            suffix = f" ({hidden} similar messages suppressed)" if hidden else ""
            self.log.warning(msg + suffix, *args)
            self._last[key] = now
        else:
            self._hidden[key] += 1
