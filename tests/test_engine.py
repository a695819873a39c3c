"""Scheduler, trajectories, pose table, seeds and runtime scene changes."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from conftest import Recorded, device, scene, vehicle

from uwsimnet_zenoh.engine.network import Network
from uwsimnet_zenoh.kernel.scheduler import Interrupted, Scheduler
from uwsimnet_zenoh.mobility.trajectory import PoseTable, Trajectory


def test_scheduler_runs_in_time_order_and_ties_in_insertion_order():
    s = Scheduler()
    seen = []
    for t, name in ((2.0, "c"), (1.0, "a"), (1.0, "b"), (0.5, "first")):
        s.at(t, seen.append, name)
    cancelled = s.at(1.5, seen.append, "never")
    cancelled.cancel()
    s.run(10)
    assert seen == ["first", "a", "b", "c"] and s.now == 10 and s.events_run == 4


def test_the_compiled_heap_pops_events_in_time_then_insertion_order():
    """scheduler._push/_pop (the heap the compiled engine uses) against the definition: 3 000 events with
    many equal times, some cancelled, pushed in random order and interleaved with pops."""
    import random

    from uwsimnet_zenoh.kernel import scheduler as sm

    rng = random.Random(7)
    heap: list[sm.Event] = []
    popped: list[sm.Event] = []
    pushed: list[sm.Event] = []
    for seq in range(3000):
        ev = sm.Event(float(rng.randrange(200)) / 8, seq, print, ())
        pushed.append(ev)
        sm._push(heap, ev)
        if rng.random() < 0.3:
            popped.append(sm._pop(heap))
    while heap:
        popped.append(sm._pop(heap))
    assert len(popped) == len(pushed)
    # every pop is the least (t, seq) of what was in the heap at that moment: replay with heapq
    import heapq
    ref: list[tuple[float, int]] = []
    rng = random.Random(7)
    want: list[tuple[float, int]] = []
    for seq in range(3000):
        heapq.heappush(ref, (float(rng.randrange(200)) / 8, seq))
        if rng.random() < 0.3:
            want.append(heapq.heappop(ref))
    want += [heapq.heappop(ref) for _ in range(len(ref))]
    assert [(e.t, e.seq) for e in popped] == want


def test_a_scheduler_runs_its_events_by_time_then_insertion_with_cancellations():
    """Scheduler.run over its heap (compiled _push/_pop, or heapq when pure: test_native runs both) calls
    every live callback once, by (time, insertion)."""
    s = Scheduler()
    out: list[int] = []
    evs = [s.at((k * 7919) % 101 / 10, out.append, k) for k in range(500)]
    for ev in evs[::9]:
        ev.cancel()
    s.run(50.0)
    assert out == sorted((k for k in range(500) if k % 9), key=lambda k: ((k * 7919) % 101 / 10, k))


def test_scheduler_never_goes_back_in_time():
    s = Scheduler()
    s.run(5)
    times = []
    s.at(1.0, lambda: times.append(s.now))
    s.run(6)
    assert times == [5.0]


def test_an_interrupt_stops_the_run_between_two_events_once():
    s = Scheduler()
    seen = []
    s.at(1.0, seen.append, "a")
    s.at(2.0, s.interrupt)                  # as a signal handler would, during an event
    s.at(2.0, seen.append, "b")
    s.at(3.0, seen.append, "c")
    with pytest.raises(Interrupted):
        s.run(10)
    assert seen == ["a"] and s.now == 2.0 and s.events_run == 2      # time stays where the run stopped
    s.run(10)                               # taken once: a later run goes on
    assert seen == ["a", "b", "c"] and s.now == 10


def test_an_interrupt_after_the_last_event_leaves_time_there():
    s = Scheduler()
    s.at(1.0, s.interrupt)
    with pytest.raises(Interrupted):
        s.run(5)
    assert s.now == 1.0
    s.interrupt()
    with pytest.raises(Interrupted):
        s.next_time()


def test_trajectory_is_piecewise_linear_and_holds_at_the_ends():
    tr = Trajectory([(0, 0, 0, 0), (10, 10, 0, 0), (20, 10, 5, 0)])
    assert list(tr.position(-1)) == [0, 0, 0]
    assert list(tr.position(2.5)) == [2.5, 0, 0]
    assert list(tr.position(15)) == [10, 2.5, 0]
    assert list(tr.position(99)) == [10, 5, 0]
    with pytest.raises(ValueError):
        Trajectory([(0, 0, 0, 0), (0, 1, 1, 1)])


def test_external_pose_is_unknown_until_a_sample_then_extrapolated_by_velocity():
    pt = PoseTable(["a", "b"])
    pt.set_external("b")
    assert not pt.known[1]
    pt.update("b", 10.0, (1, 2, 3), (1, 0, 0))
    assert pt.known[1]
    assert np.allclose(pt.positions(12.0)[1], (3, 2, 3))


def test_seeds_are_stable_across_processes():
    code = ("from conftest import scene, vehicle, device;"
            "from uwsimnet_zenoh.engine.network import Network;"
            "print(Network(scene([vehicle('v', (0, 0, 0), device('a', 1))], seed=42)).seeds('loss', 'a'))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd="tests", env={"PYTHONHASHSEED": "123", "PATH": ""}).stdout
    here = Network(scene([vehicle("v", (0, 0, 0), device("a", 1))], seed=42)).seeds("loss", "a")
    assert int(out) == here


def test_removing_a_device_ends_its_queued_frames_with_a_reason():
    a, b = device("a", 1), device("b", 2)
    rec = Recorded(scene([vehicle("va", (0, 0, 0), a), vehicle("vb", (10, 0, 0), b)]))
    for _ in range(3):
        rec.net.modems["a"].send(2, 25)
    rec.net.sched.at(0.1, rec.net.remove_device, "a")
    rec.run()
    assert [d["reason"] for d in rec.ev("drop")] == ["removed", "removed"]
    assert len(rec.ev("rx")) == 1      # the frame on air still arrives
    with pytest.raises(ValueError, match="no device"):
        rec.net.remove_device("a")


def test_a_device_added_at_runtime_hears_what_is_sent_after():
    a = device("a", 1)
    rec = Recorded(scene([vehicle("va", (0, 0, 0), a), vehicle("vb", (10, 0, 0))]))
    rec.net.sched.at(1.0, lambda: rec.net.modems["a"].send(255, 10))
    rec.net.sched.at(2.0, lambda: rec.net.add_device("vb", device("b", 2)))
    rec.net.sched.at(3.0, lambda: rec.net.modems["a"].send(255, 10))
    rec.run()
    assert [(r["dev"], r["seq"]) for r in rec.ev("rx")] == [("b", 1)]


def test_moving_a_vehicle_changes_the_delay_of_the_next_frame():
    a, b = device("a", 1, bitrate=8000), device("b", 2, bitrate=8000)
    rec = Recorded(scene([vehicle("va", (0, 0, 0), a), vehicle("vb", (150, 0, 0), b)]))
    rec.net.sched.at(1.0, lambda: rec.net.modems["a"].send(2, 10))
    rec.net.sched.at(2.0, lambda: rec.net.move("vb", (1500, 0, 0)))
    rec.net.sched.at(3.0, lambda: rec.net.modems["a"].send(2, 10))
    rec.run()
    assert [r["t"] for r in rec.ev("rx")] == pytest.approx([1.11, 4.01])


def test_a_removed_modem_takes_no_more_flow_frames_and_refuses_apps():
    from uwsimnet_zenoh.scene.model import Flow

    a, b = device("a", 1), device("b", 2)
    rec = Recorded(scene([vehicle("va", (0, 0, 0), a), vehicle("vb", (10, 0, 0), b)],
                         [Flow(name="f", src="a", dst=2, size=10, interval=1.0)], duration=10))
    modem = rec.net.modems["a"]
    rec.net.sched.at(3.5, rec.net.remove_device, "a")
    rec.net.sched.at(4.0, lambda: modem.send(2, 10))
    rec.run()
    assert len(rec.ev("enq", flow="f")) == 4                    # 0, 1, 2, 3 s
    assert [d["reason"] for d in rec.ev("drop")] == ["removed"]  # the app's late frame


def test_unicast_to_an_address_nobody_has_is_dropped_at_once():
    only = ("none", {"delivery": "addressee"})      # without it (the original's default) the frame goes on air
    a, b = device("a", 1, mac=only), device("b", 2, mac=only)
    rec = Recorded(scene([vehicle("va", (0, 0, 0), a), vehicle("vb", (10, 0, 0), b)]))
    rec.net.sched.at(1.0, lambda: rec.net.modems["a"].send(9, 10))
    rec.run()
    assert [(d["dev"], d["reason"]) for d in rec.ev("drop")] == [("a", "noaddr")] and not rec.ev("tx")
