"""The realtime clock (kernel/realtime.py): wall-time events, the thread-safe inbox, pause, speed, stop.

Bounds on timing are generous (tens of ms) so a loaded CI machine does not fail them; the precise
figures are in bench/bench_realtime.py and docs/benchmarks.md."""

from __future__ import annotations

import threading
import time

import pytest
from conftest import device, scene, vehicle

from uwsimnet_zenoh.engine.network import Network
from uwsimnet_zenoh.kernel.realtime import HANDOFF_S, RealtimeClock, run_for
from uwsimnet_zenoh.kernel.scheduler import Scheduler
from uwsimnet_zenoh.trace.tracer import Callback

SLACK = 0.25     # s: what a loaded machine may add (60-80 ms seen with the suite's two workers and other jobs);
#                   the modelled times below are long enough that a wrong clock misses by more than that


@pytest.fixture
def clock():
    clocks = []

    def make(sched=None, **kw):
        c = RealtimeClock(sched or Scheduler(), **kw)
        clocks.append(c)
        return c
    yield make
    for c in clocks:
        c.stop()
        assert c.join(5.0), "engine thread did not stop"


def test_events_run_at_their_wall_time_with_modelled_now(clock):
    c = clock()
    s = c.sched
    seen = []
    t0 = time.perf_counter()
    for t in (0.1, 0.25, 0.25, 0.55, 1.0):
        s.at(t, lambda t=t: seen.append((t, s.now, time.perf_counter() - t0, threading.current_thread().name)))
    c.start()
    deadline = time.monotonic() + 5
    while len(seen) < 5 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert [x[0] for x in seen] == [0.1, 0.25, 0.25, 0.55, 1.0]
    for t, now, wall, thread in seen:
        assert now == t                         # sched.now is the modelled time, exactly
        assert t - 0.002 <= wall <= t + SLACK   # and it ran when the wall clock got there
        assert thread == "uwsimnet-engine"
    assert c.stats()["events"] == 5


def test_call_soon_runs_on_the_engine_thread_at_the_time_of_the_call(clock):
    c = clock()
    c.start()
    time.sleep(0.05)
    done = threading.Event()
    got = {}

    def item(x):
        got.update(x=x, now=c.sched.now, thread=threading.current_thread().name)
        done.set()
    before = c.now()
    c.call_soon(item, 42)
    after = c.now()
    assert done.wait(2)
    assert got["x"] == 42 and got["thread"] == "uwsimnet-engine"
    assert before <= got["now"] <= after


def test_call_soon_from_many_threads_keeps_each_threads_order(clock):
    c = clock()
    out = []
    c.start()

    def producer(k):
        for i in range(200):
            c.call_soon(out.append, (k, i))
    ths = [threading.Thread(target=producer, args=(k,)) for k in range(4)]
    for t in ths:
        t.start()
    for t in ths:
        t.join()
    assert c.submit(lambda: None).result(2) is None
    assert len(out) == 800
    for k in range(4):
        assert [i for kk, i in out if kk == k] == list(range(200))


def test_submit_returns_result_and_exception(clock):
    c = clock()
    c.start()
    assert c.submit(lambda a, b: a + b, 2, 3).result(2) == 5
    with pytest.raises(ZeroDivisionError):
        c.submit(lambda: 1 / 0).result(2)


def test_an_event_that_raises_does_not_stop_the_clock(clock):
    errors = []
    c = clock(on_error=errors.append)
    fired = threading.Event()
    c.sched.at(0.01, lambda: 1 / 0)
    c.sched.at(0.03, fired.set)
    c.call_soon(lambda: [][1])
    c.start()
    assert fired.wait(2)
    assert c.errors == 2 and len(errors) == 2
    assert c.running


def test_pause_freezes_simulation_time(clock):
    c = clock()
    fired = []
    c.sched.at(0.75, lambda: fired.append(time.perf_counter()))
    c.start()
    time.sleep(0.05)
    c.pause()
    t_paused = c.now()
    time.sleep(1.0)
    assert c.paused and c.now() == t_paused
    assert not fired                          # due at 0.75 sim, but sim time stands at ~0.05
    ran = c.submit(lambda: c.sched.now).result(2)
    assert ran == pytest.approx(t_paused, abs=1e-9)     # the inbox still runs, at the frozen time
    t_resume = time.perf_counter()
    c.resume()
    deadline = time.monotonic() + 2
    while not fired and time.monotonic() < deadline:
        time.sleep(0.005)
    assert fired
    assert fired[0] - t_resume == pytest.approx(0.75 - t_paused, abs=SLACK)


def test_speed_factor(clock):
    c = clock(speed=4.0)
    fired = threading.Event()
    c.sched.at(2.0, fired.set)
    t0 = time.perf_counter()
    c.start()
    assert fired.wait(5)
    assert time.perf_counter() - t0 == pytest.approx(0.5, abs=SLACK)
    assert c.wall_epoch() == pytest.approx(time.time() - c.now() / 4.0, abs=0.01)


def test_until_ends_the_run_there(clock):
    c = clock(until=0.5)
    late = []
    c.sched.at(0.25, lambda: None)
    c.sched.at(2.5, late.append, 1)
    t0 = time.perf_counter()
    c.start()
    assert c.done.wait(5)
    assert time.perf_counter() - t0 == pytest.approx(0.5, abs=SLACK)
    assert c.sched.now == 0.5 and not late


def test_stop_wakes_an_idle_clock_at_once(clock):
    c = clock()
    c.start()
    _until_waiting(c)                           # idle: the engine thread waits for work
    t0 = time.perf_counter()
    c.stop()
    assert c.join(1.0)
    assert time.perf_counter() - t0 < 0.5


@pytest.mark.parametrize("far", [None, 3600.0])
def test_poll_runs_the_idle_hooks_while_the_clock_waits(clock, far):
    """With `poll`, a clock with nothing due for an hour (or nothing at all) still runs its idle hooks, each
    `poll` s: input that arrives without a wake-up (a ring of samples) is taken meanwhile.  Without it, once."""
    for poll, more in ((0.01, True), (None, False)):
        c = clock(Scheduler())
        if far is not None:
            c.sched.at(far, lambda: None)
        calls = []
        c.idle_hooks.append(lambda calls=calls: calls.append(time.perf_counter()))
        c.poll = poll
        c.start()
        deadline = time.monotonic() + (5.0 if more else 0.3)
        while len(calls) < 5 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert len(calls) >= 5 if more else len(calls) == 1
        c.stop()
        assert c.join(5.0)


def test_after_yield_to_output_the_hooks_wait_with_the_interpreter_free(clock):
    """An event that woke an output thread (`yield_to_output`) has the engine wait HANDOFF_S, in a
    Condition wait (the interpreter free for that thread), before its done and idle hooks; without it, no
    wait.  (A lower bound only: a loaded machine can make the wait longer, never shorter.)"""
    c = clock(Scheduler())
    seen: dict[str, float] = {}
    c.sched.at(0.05, lambda: (seen.setdefault("event", time.perf_counter()), c.yield_to_output()))
    c.done_hooks.append(lambda: seen.setdefault("done", time.perf_counter()) if "event" in seen else None)
    c.idle_hooks.append(lambda: seen.setdefault("idle", time.perf_counter()) if "event" in seen else None)
    c.start()
    deadline = time.monotonic() + 5.0
    while "idle" not in seen and time.monotonic() < deadline:
        time.sleep(0.01)
    assert seen["done"] - seen["event"] >= 0.9 * HANDOFF_S
    assert seen["idle"] >= seen["done"]


def _until_waiting(c: RealtimeClock) -> None:
    deadline = time.monotonic() + 5.0
    while not c._waiting and time.monotonic() < deadline:     # the engine thread has reached its wait
        time.sleep(0.001)
    assert c._waiting


def test_run_here_runs_on_the_calling_thread_when_the_engine_waits(clock):
    """An idle engine: `run_here` runs the item on the caller's thread, at the time of the call, with what
    it makes due at once (a zero-delay delivery) and the done hooks, before it returns."""
    c = clock(Scheduler())
    c.sched.at(3600.0, lambda: None)
    ran: dict[str, object] = {}
    c.done_hooks.append(lambda: ran.setdefault("done", threading.get_ident()) if "item" in ran else None)

    def item() -> None:
        ran["item"] = (threading.get_ident(), c.sched.now)
        c.sched.after(0.0, lambda: ran.setdefault("event", threading.get_ident()))
    c.start()
    time.sleep(0.2)
    _until_waiting(c)
    me = threading.get_ident()
    c.run_here(item)
    assert ran["item"][0] == me and ran["event"] == me and ran["done"] == me
    assert 0.2 <= ran["item"][1] < 0.2 + SLACK * 4


def test_run_here_wakes_the_engine_for_an_earlier_event(clock):
    """What the item schedules before the engine's wake-up (it waits an hour) runs at its own time."""
    c = clock(Scheduler())
    c.sched.at(3600.0, lambda: None)
    got = []
    c.start()
    _until_waiting(c)
    c.run_here(lambda: c.sched.after(0.3, lambda: got.append((c.sched.now, c.now()))))
    deadline = time.monotonic() + 5.0
    while not got and time.monotonic() < deadline:
        time.sleep(0.01)
    assert got, "the event made by run_here did not run"
    modelled, wall = got[0]
    assert 0.0 <= wall - modelled < SLACK        # at its time, not at the engine's old wake-up


def test_run_here_queues_when_the_engine_is_busy(clock):
    """While the engine runs an event, `run_here` does what `call_soon` does: the item runs on the engine
    thread, after the event."""
    c = clock(Scheduler())
    inside, release = threading.Event(), threading.Event()
    order = []
    c.sched.at(0.01, lambda: (inside.set(), release.wait(5.0), order.append("event")))
    c.start()
    assert inside.wait(5.0)
    c.run_here(lambda: order.append(("item", threading.current_thread().name)))
    assert order == []
    release.set()
    deadline = time.monotonic() + 5.0
    while len(order) < 2 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert order == ["event", ("item", "uwsimnet-engine")]


def test_run_for_helper():
    c = RealtimeClock(Scheduler())
    t0 = time.perf_counter()
    run_for(c, 0.05)
    assert not c.running and time.perf_counter() - t0 < 1.0


def test_bad_speed():
    with pytest.raises(ValueError):
        RealtimeClock(Scheduler(), speed=0)


def test_a_network_in_realtime_delivers_after_the_modelled_delay(clock):
    """Frames handed over from another thread arrive at their modelled time, in wall time too."""
    sc = scene([vehicle("a", (0, 0, 0), device("a-m", 1, bitrate=10_000)),
                vehicle("b", (900, 0, 0), device("b-m", 2, bitrate=10_000))], duration=8)
    net = Network(sc, flows=False)
    got = []
    net.tracer.listen(Callback(lambda t, ev, ch, dev, f, *_: got.append((f.t_enq, t, time.perf_counter()))
                               if ev == "rx" and dev == "b-m" else None))
    c = clock(net.sched)
    c.start()
    sent = []
    for _ in range(3):
        sent.append(time.perf_counter())
        c.call_soon(lambda: net.modems["a-m"].send(2, 40, data=b"x" * 40))
        time.sleep(0.15)
    deadline = time.monotonic() + 5
    while len(got) < 3 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert len(got) == 3
    modelled = 900 / 1500 + 40 * 8 / 10_000               # propagation + transmission: 0.632 s
    for (t_enq, t_rx, wall), w_sent in zip(got, sent, strict=True):
        assert t_rx - t_enq == pytest.approx(modelled, abs=1e-9)
        assert wall - w_sent == pytest.approx(modelled, abs=SLACK)


def test_cpu_pins_the_engine_thread_and_only_it(clock):
    """RealtimeClock(cpu=c): the engine thread runs on CPU c only; the thread that made it keeps its CPUs
    (kernel.realtime.pin_thread: the threads that run Python share one core, Zenoh's stay free)."""
    import os

    allowed = os.sched_getaffinity(0)
    cpu = max(allowed)
    c = clock(cpu=cpu)
    c.start()
    assert c.submit(os.sched_getaffinity, 0).result(5.0) == {cpu}
    assert os.sched_getaffinity(0) == allowed
    free = clock()
    free.start()
    assert free.submit(os.sched_getaffinity, 0).result(5.0) == allowed     # cpu=None: not pinned


def test_pin_thread_refuses_a_cpu_the_process_may_not_use():
    import os

    from uwsimnet_zenoh.kernel.realtime import pin_thread

    allowed = os.sched_getaffinity(0)
    got = []
    t = threading.Thread(target=lambda: got.append((pin_thread(max(allowed) + 4096), pin_thread(None),
                                                    os.sched_getaffinity(0))))
    t.start()
    t.join(5.0)
    assert got == [(False, False, allowed)]


@pytest.mark.parametrize(("allowed", "env", "want"), [
    ({0, 1, 2, 3}, None, None),         # default: not pinned
    ({0, 1, 2, 3}, "auto", 3),          # the last CPU the process may use
    ({5}, "auto", None),                # one CPU: nothing to choose
    ({0, 1, 2, 3}, "1", 1),
    ({0, 1, 2, 3}, "any", None),
    ({0, 1, 2, 3}, " ANY ", None),
])
def test_python_cpu_choice(monkeypatch, allowed, env, want):
    import os

    from uwsimnet_zenoh.app.realtime import python_cpu

    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: set(allowed))
    if env is None:
        monkeypatch.delenv("UWSIMNET_PYTHON_CPU", raising=False)
    else:
        monkeypatch.setenv("UWSIMNET_PYTHON_CPU", env)
    assert python_cpu() == want


@pytest.mark.parametrize("env", ["7", "-1", "two"])
def test_python_cpu_says_why_it_ignores_a_bad_setting(monkeypatch, caplog, env):
    import os

    from uwsimnet_zenoh.app.realtime import python_cpu

    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1})
    monkeypatch.setenv("UWSIMNET_PYTHON_CPU", env)
    with caplog.at_level("WARNING", logger="uwsimnet"):
        assert python_cpu() is None
    assert f"UWSIMNET_PYTHON_CPU={env} ignored: this process may use CPUs 0,1 (or say auto, any)" in caplog.text
