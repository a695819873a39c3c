"""The realtime clock: drives a `Scheduler` against the wall clock, on its own thread.  Its turn is the one
place where the rules of a realtime run are written; the bus (bus/broker.py, bus/outbox.py) and the run
(app/realtime.py) only plug into it.

Simulation time is wall time since `start()` (times an optional speed factor), frozen while paused.  An
event runs with `sched.now` equal to its *modelled* time, so the trace and the frames carry modelled times;
how late the wall clock is when it runs is recorded in `stats()`.

**Where the simulation may run.**  One thread at a time, the one that holds the engine's lock (`_busy`):
the engine thread, except while it waits; then a thread that hands in an item through `run_here` (a
Zenoh callback: one thread wake-up less, 110-150 us of a broker round trip on the 2-core VM) runs it
itself under the lock.  Nothing else touches the network, the MACs or the port's listeners: the
simulation is single-threaded state with no locks of its own, and what leaves it is handed to outboxes
(bus/outbox.py) whose threads make the puts, so the simulation never waits on the network and a
consumer that does not read costs only its own outbox.

**The turn** (`_loop`; `run_here` does steps 1-4 for its one item and leaves 5-6 to the engine thread):

  1. inbox          every item of `call_soon` / `run_here`, each at its stamp (the simulation time it was
                     handed in), after every event due by then.  Why: input never runs before an event
                     already due, nor in the scheduler's past.
  2. due events     every event due by now (`_run_until`).  The model's own work, at its modelled times.
  3. rx hand-off    if an event woke an outbox for a received frame (`yield_to_output`), wait HANDOFF_S with
                     the interpreter free.  Why: the rx put goes out before the hooks below; it is the
                     modelled output, its wall time the delivery error.
  4. done hooks     `done_hooks`, after every pass (the broker wakes the outboxes holding statuses).  Why:
                     statuses go out next, one wake-up per outbox, not one per status.
  5. idle hooks     `idle_hooks`, only with the inbox empty and the next event at least IDLE_SLACK away (the
                     trace batch, periodic poses and clock, pose samples, the trace file).  Why: work
                     without a modelled time never makes an event late.
  6. wait           `Condition.wait` until SPIN before the next event (or `poll`, or input), then a busy
                     spin.  Why: the OS wakes a thread 50-100 us late, a spin does not (docs/benchmarks.md).

**The output port's dispatch policy** (trace/tracer.py) follows from it: the port calls its listeners at
once, in the event; the broker's endpoint puts a received frame on its modem's outbox and wakes it at once
(rx first, step 3), appends statuses and lets the done hook wake their outboxes (statuses next, step 4),
and the trace writers and the trace publisher take the port's batches at idle (trace at idle, step 5).

**Zenoh's network thread** (`_direct` in bus/broker.py): the broker's tx subscriber and queryables are
`handlers.Callback(fn, indirect=False)`, which zenoh-python marks unstable: the callback runs on Zenoh's
own network thread instead of a Python thread of its own, so with `run_here` a tx message is simulated on
that thread.  It buys one thread hop per message (~0.1 ms on a VM).  It costs: while the simulation runs
there, that network thread reads nothing else (the session's other messages wait behind the turn, at most
one item's events); a put made on the same session to a key such a callback serves runs the callback, and
so the simulation, inside that put; the callback must never block (it does not: it offers to a bounded lane
and returns, or runs one item); and an unstable API may change within zenoh-python 1.x (pyproject allows >=1.10,<2).

No I/O, no Zenoh here: the bus layer feeds the inbox and publishes from hooks that run here.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import math
import os
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any

from .scheduler import Scheduler

log = logging.getLogger("uwsimnet.engine.realtime")

_Item = tuple[float, Callable[..., Any], tuple]
sched_yield = getattr(os, "sched_yield", lambda: None)
IDLE_SLACK = 0.002
"""Idle hooks run only when the next event is at least this far (wall s): they never make one late."""
HANDOFF_S = 0.0003
"""Wall s the engine leaves the interpreter to an output thread it has just woken (`yield_to_output`)
before its done and idle hooks.  Otherwise the woken thread waits for the engine to go through them
(status wake-ups, trace, poses: 130-200 us of a zero-delay round trip on the 2-core VM, measured)."""
SPIN = 0.001
"""Wall s of busy wait before each event.  A timed wait (1 us timer slack) ends ~40-65 us after its
deadline (median/p90) on a quiet 2-core VM, but under load a sleeping thread is woken much later: a
0.3 ms spin saved ~10-15 % of a core and cost 100-200 us of delivery error median (docs/benchmarks.md)."""
TIMER_SLACK_NS = 1000
"""The engine thread's timer slack on Linux (prctl PR_SET_TIMERSLACK): a timed wait ends within ~1 us of
its deadline instead of the default 50 us, so the spin before an event can be short."""


def precise_timers(slack_ns: int = TIMER_SLACK_NS) -> bool:
    """Set the calling thread's timer slack (Linux; elsewhere, or if it fails, nothing): True if set."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        return libc.prctl(29, ctypes.c_ulong(slack_ns), 0, 0, 0) == 0      # 29: PR_SET_TIMERSLACK
    except (OSError, AttributeError):
        return False


def pin_thread(cpu: int | None) -> bool:
    """Run the calling thread on CPU `cpu` only (Linux: the thread's own affinity; None, elsewhere, or if it
    fails: nothing): True if pinned.

    For the threads that run Python in a realtime process (the engine, the outbox threads).  The GIL lets
    only one of them run at a time, so spreading them over cores buys no parallelism; it makes every
    hand-off between them (tx -> engine, engine -> outbox) wake a thread on another core, an interrupt to a
    CPU that may be idle, ~100 us on a VM.  On one core the hand-off is a context switch.  Zenoh's own
    threads stay free (docs/runtime.md, "One core for Python")."""
    if cpu is None or not hasattr(os, "sched_setaffinity"):
        return False
    try:
        os.sched_setaffinity(0, {cpu})          # pid 0: the calling thread (Linux)
    except (OSError, ValueError):
        return False
    return True


class RealtimeClock:
    """Runs `sched` in wall time on a thread of its own.

    `speed`: simulated seconds per wall second (1.0 = real time).  `spin`: wall seconds of busy wait
    before each event (0 disables it).  `until`: simulation time at which the clock stops by itself
    (`done` is set then); None runs until `stop()`.  `on_error(exc)` is called when an event or an inbox
    item raises; the clock logs it and keeps running either way.  `cpu`: the engine thread runs on that
    CPU only (`pin_thread`; None: wherever the OS puts it).
    """

    def __init__(self, sched: Scheduler, *, speed: float = 1.0, spin: float = SPIN,
                 until: float | None = None, on_error: Callable[[BaseException], None] | None = None,
                 perf_counter: Callable[[], float] = time.perf_counter, yield_cpu: bool = True,
                 cpu: int | None = None) -> None:
        if not speed > 0:
            raise ValueError(f"speed must be > 0, got {speed}")
        self.sched = sched
        self.speed = float(speed)
        self.spin = max(0.0, float(spin))
        self.until = until
        self.on_error = on_error
        self._pc = perf_counter
        self.yield_cpu = yield_cpu and hasattr(os, "sched_yield")
        self.cpu = cpu
        self._cond = threading.Condition(threading.Lock())
        self._inbox: deque[_Item] = deque()
        self._thread: threading.Thread | None = None
        self._stopping = False
        self._paused = False
        self._t0 = 0.0               # perf_counter value at which simulation time was 0 (shifted by pauses)
        self._frozen = 0.0           # simulation time while paused / before start
        self._started = False
        self.done = threading.Event()
        """Set when the engine thread has ended (`until` reached, `stop()`, or a fatal error)."""
        self.done_hooks: list[Callable[[], None]] = []
        """Called on the engine thread each time it is done with what is due (after the inbox and the due
        events, before idle hooks and before it waits), whether or not it will wait: short work that
        should not interrupt an event but must not wait for idleness either (waking output threads)."""
        self.idle_hooks: list[Callable[[], None]] = []
        """Called on the engine thread when it is about to wait and the next event is more than
        IDLE_SLACK away: deferred work (writing trace records) goes here, out of the path between an
        event and its effect.  A hook must be short and must bound its own backlog."""
        self.poll: float | None = None
        """Longest wall wait (s) between two rounds of idle hooks, None: no limit.  For input that comes
        without a wake-up (samples a hook takes from a Zenoh ring channel): it is taken within `poll`."""
        self.errors = 0
        self.first_error: BaseException | None = None
        """The first exception an event, inbox item or idle hook raised (None: none did)."""
        self.fatal: BaseException | None = None
        """What ended the engine thread abnormally (a bug in the loop itself), else None."""
        self._yield = False
        self._busy = threading.Lock()   # held by whichever thread runs the simulation (see run_here)
        self._waiting = False           # the engine thread is in its wait, until `_wake_at` (perf_counter)
        self._wake_at = math.inf
        self._kick = False              # run_here made an event due before `_wake_at`: recompute the wait
        self._here = 0                  # items run_here ran on the caller's thread
        self._late_n = 0
        self._late_sum = 0.0
        self._late_max = 0.0
        self._items = 0

    def yield_to_output(self) -> None:
        """(engine thread) A thread that carries time-critical output (an rx frame) was just woken: when
        done with what is due, leave it the interpreter (HANDOFF_S at most, less if an event is due or
        input comes) before the done and idle hooks."""
        self._yield = True

    # -- time ------------------------------------------------------------------------------------
    def now(self) -> float:
        """Current simulation time derived from the wall clock (thread-safe)."""
        if self._paused or not self._started:
            return self._frozen
        return (self._pc() - self._t0) * self.speed

    def wall_epoch(self) -> float:
        """Unix time (time.time()) at which simulation time 0 was, at the current speed; a pause moves it."""
        return time.time() - self.now() / self.speed

    @property
    def paused(self) -> bool:
        return self._paused

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    # -- control (any thread) --------------------------------------------------------------------
    def start(self) -> None:
        """Start the engine thread; simulation time continues from `sched.now`."""
        if self._thread is not None:
            raise RuntimeError("the realtime clock is already started")
        with self._cond:
            self._t0 = self._pc() - self.sched.now / self.speed
            self._frozen = self.sched.now
            self._started = True
        self._thread = threading.Thread(target=self._loop, name="uwsimnet-engine", daemon=True)
        self._thread.start()

    def call_soon(self, fn: Callable[..., Any], *args: Any) -> None:
        """Run `fn(*args)` on the engine thread, at the simulation time of this call (thread-safe)."""
        item = (self.now(), fn, args)
        with self._cond:
            self._inbox.append(item)
            self._cond.notify()

    def run_here(self, fn: Callable[..., Any], *args: Any) -> None:
        """Like `call_soon`, but when the engine thread is waiting (nothing queued, nothing due) run `fn`
        on the calling thread at once, with the events it makes due by now and the done hooks, as the
        engine thread would have: one thread wake-up less per message (110-150 us of a broker round trip
        on the 2-core VM, measured).  For a caller that only enqueues otherwise (a Zenoh callback): the
        simulation never makes it wait, its output leaves through outboxes."""
        if not (self._waiting and self._busy.acquire(blocking=False)):
            self.call_soon(fn, *args)
            return
        try:
            t = self.now()
            until = self.until
            if (self._inbox or self._paused or self._stopping or not self._waiting
                    or (until is not None and t >= until)):
                self.call_soon(fn, *args)
                return
            sched = self.sched
            self._run_until(t)
            if t > sched.now:
                sched.now = t
            self._items += 1
            self._here += 1
            try:
                fn(*args)
            except BaseException as e:  # noqa: BLE001 - a bad message never stops the engine
                self._fail(f"{getattr(fn, '__qualname__', fn)}", e)
            now = self.now()
            self._run_until(now if until is None or now < until else until)
            self._yield = False             # this thread leaves the interpreter as it returns
            for hook in self.done_hooks:
                try:
                    hook()
                except BaseException as e:  # noqa: BLE001 - the engine keeps running
                    self._fail(f"done hook {getattr(hook, '__qualname__', hook)}", e)
            nxt = sched.next_time()
            if self.poll is None and self.idle_hooks or (
                    nxt is not None and self._t0 + nxt / self.speed - self.spin < self._wake_at):
                with self._cond:
                    self._kick = True
                    self._cond.notify()
        finally:
            self._busy.release()

    def submit(self, fn: Callable[..., Any], *args: Any) -> Future:
        """Like `call_soon`, returning a Future with the result (for callers that must wait for it)."""
        fut: Future = Future()

        def run() -> None:
            if not fut.set_running_or_notify_cancel():
                return
            try:
                fut.set_result(fn(*args))
            except BaseException as e:  # noqa: BLE001 - handed to the waiting caller
                fut.set_exception(e)
        self.call_soon(run)
        return fut

    def pause(self) -> None:
        """Freeze simulation time: due events wait; inbox items still run, at the frozen time."""
        with self._cond:
            if not self._paused:
                self._frozen = self.now()
                self._paused = True
                self._cond.notify()

    def resume(self) -> None:
        with self._cond:
            if self._paused:
                self._t0 = self._pc() - self._frozen / self.speed
                self._paused = False
                self._cond.notify()

    def stop(self) -> None:
        """Ask the engine thread to end after the item or event it is running (see `join`)."""
        with self._cond:
            self._stopping = True
            self._cond.notify()

    def join(self, timeout: float | None = None) -> bool:
        """Wait for the engine thread; True if it has ended."""
        if self._thread is None:
            return True
        self._thread.join(timeout)
        return not self._thread.is_alive()

    def stats(self) -> dict[str, float]:
        """Events run, inbox items run (`items_here`: of them, on the caller's thread by `run_here`), errors,
        and how late (wall) events ran: mean and max in seconds."""
        n = self._late_n
        return {"events": n, "items": self._items, "items_here": self._here, "errors": self.errors,
                "late_mean": self._late_sum / n if n else 0.0, "late_max": self._late_max}

    # -- the engine thread -----------------------------------------------------------------------
    def _fail(self, what: str, e: BaseException) -> None:
        self.errors += 1
        if self.first_error is None:
            self.first_error = e
        log.error("%s raised %s: %s", what, type(e).__name__, e, exc_info=e)
        if self.on_error is not None:
            try:
                self.on_error(e)
            except Exception:  # noqa: BLE001 - an error handler must not stop the clock
                log.exception("on_error raised")

    def _run_until(self, t: float) -> None:
        """Run every event due at or before simulation time t (each at its modelled time)."""
        sched = self.sched
        pc = self._pc
        while True:
            nt = sched.next_time()
            if nt is None or nt > t or self._stopping:
                return
            if not self._paused:
                late = (pc() - self._t0) * self.speed - nt
                if late > 0:
                    self._late_sum += late
                    if late > self._late_max:
                        self._late_max = late
            self._late_n += 1
            try:
                sched.step()
            except BaseException as e:  # noqa: BLE001 - the engine keeps running (SystemExit of a plug-in too)
                self._fail(f"event at t={nt:.6f}", e)

    def _linger(self) -> None:
        """Wait HANDOFF_S (the interpreter is free meanwhile), cut short by input, stop or the next event."""
        nxt = self.sched.next_time()
        wait = HANDOFF_S
        if nxt is not None:
            wait = min(wait, self._t0 + nxt / self.speed - self._pc() - self.spin)
        if wait > 0:
            with self._cond:
                if not self._inbox and not self._stopping:
                    self._cond.wait(wait)

    def _wait(self, timeout: float | None, paused: bool = False) -> None:
        """(engine thread) Wait `timeout` wall s (None: until notified) unless input, stop, a kick or a
        pause change came; the simulation is free meanwhile for `run_here` on another thread."""
        self._busy.release()
        try:
            with self._cond:
                if not (self._inbox or self._stopping or self._kick or self._paused != paused):
                    self._wake_at = math.inf if timeout is None else self._pc() + timeout
                    self._waiting = True
                    self._cond.wait(timeout)
                    self._waiting = False
        finally:
            self._busy.acquire()

    def _loop(self) -> None:
        self._busy.acquire()
        precise_timers()
        pin_thread(self.cpu)
        sched = self.sched
        cond = self._cond
        inbox = self._inbox
        pc = self._pc
        yield_cpu = self.yield_cpu
        try:
            while not self._stopping:
                # 1. what came in, each at its stamp, after every event due by then - and by now: when a
                #    burst of items takes a while, events keep their wall time and the items behind
                #    them run a little later (as if they had arrived later), never the other way round
                if inbox:
                    with cond:
                        items = list(inbox)
                        inbox.clear()
                    for stamp, fn, args in items:
                        if self._stopping:
                            break
                        if self.until is not None and stamp > self.until:
                            stamp = self.until
                        due = self.now()
                        if self.until is not None and due > self.until:
                            due = self.until
                        self._run_until(due if due > stamp else stamp)
                        if stamp > sched.now:
                            sched.now = stamp
                        self._items += 1
                        try:
                            fn(*args)
                        except BaseException as e:  # noqa: BLE001 - a bad message never stops the engine
                            self._fail(f"{getattr(fn, '__qualname__', fn)}", e)
                # 2. events due now
                now = self.now()
                until = self.until
                if until is not None and now >= until:
                    self._run_until(until)
                    if sched.now < until:
                        sched.now = until
                    return
                self._run_until(now)
                if self._yield:
                    self._yield = False
                    self._linger()
                for hook in self.done_hooks:
                    try:
                        hook()
                    except BaseException as e:  # noqa: BLE001 - the engine keeps running
                        self._fail(f"done hook {getattr(hook, '__qualname__', hook)}", e)
                # 3. idle work if the next event leaves time for it, then wait for the next event, an
                #    inbox item, a pause change or stop
                nxt = sched.next_time()
                if until is not None and (nxt is None or nxt > until):
                    nxt = until
                if self.idle_hooks and not inbox and (nxt is None or (nxt - self.now()) / self.speed > IDLE_SLACK):
                    for hook in self.idle_hooks:
                        try:
                            hook()
                        except BaseException as e:  # noqa: BLE001 - the engine keeps running (SystemExit of a plug-in too)
                            self._fail(f"idle hook {getattr(hook, '__qualname__', hook)}", e)
                poll = self.poll
                if inbox or self._stopping:
                    continue
                self._kick = False
                if self._paused:
                    self._wait(None, paused=True)
                    continue
                if nxt is None:
                    self._wait(poll)
                    continue
                target = self._t0 + nxt / self.speed            # wall (perf_counter) deadline
                wait = target - pc() - self.spin
                if wait > 0:
                    if poll is not None and wait > poll:
                        self._wait(poll)                        # then the idle hooks again
                        continue
                    self._wait(wait)
                    if inbox or self._stopping or self._paused or self._kick:
                        continue
                # 4. spin the last stretch (an arriving item or stop cuts it short); sched_yield lets the
                #    threads that carry our output (Zenoh's) and input run on this core meanwhile
                while pc() < target and not inbox and not self._stopping:
                    if yield_cpu:
                        sched_yield()
        except BaseException as e:  # noqa: BLE001 - said, and kept for the caller (never a silent end)
            self.fatal = e
            log.critical("the engine thread ended: %s: %s", type(e).__name__, e, exc_info=e)
        finally:
            self._busy.release()
            self.done.set()


def run_for(clock: RealtimeClock, seconds: float) -> None:
    """Start `clock` and block the caller for `seconds` of wall time, then stop it (tests, scripts)."""
    clock.start()
    try:
        clock.done.wait(seconds)
    finally:
        clock.stop()
        clock.join(5.0)

