"""The output port (trace/tracer.py): every fact about a frame is one event, told once to every listener in one
shape; the sender's statuses go to the listeners that ask for them; the simulator backend's delivery outcomes
are the port's rx/drop at the addressee (no trace parsing), with the propagation time of the channel's law."""

from __future__ import annotations

import math
from collections import Counter

from conftest import device, scene, vehicle

from uwsimnet_zenoh.analysis import Accumulator
from uwsimnet_zenoh.drivers.sim_backend import SimWorld
from uwsimnet_zenoh.engine.network import Network
from uwsimnet_zenoh.kernel.frame import Frame
from uwsimnet_zenoh.scene.model import Channel, Flow
from uwsimnet_zenoh.trace.events import JsonlSink
from uwsimnet_zenoh.trace.tracer import FRAME_EVENTS, STATUSES, Listener, Tracer

PER_M = 1 / 1500.0
MIN_S = 0.004


class Log(Listener):
    def __init__(self) -> None:
        self.events: list[tuple] = []

    def event(self, t, ev, ch, dev, frame, reason, fifo, dist, implicit) -> None:
        self.events.append((t, ev, dev, frame.src, frame.seq, reason, dist))


def three(mac: str = "none") -> object:
    """a at the origin; b 300 m away; c 5 km away, beyond every device's 1 km range."""
    return scene([vehicle("va", (0, 0, 0), device("a", 1, max_distance=1000.0, mac=mac)),
                  vehicle("vb", (300, 0, 0), device("b", 2, max_distance=1000.0, mac=mac)),
                  vehicle("vc", (5000, 0, 0), device("c", 3, max_distance=1000.0, mac=mac))],
                 [Flow(name="ab", src="a", dst=2, size=20, interval=1.0),
                  Flow(name="ac", src="a", dst=3, size=20, interval=1.5)],
                 channels=[Channel(id=0, prop_s_per_m=PER_M, min_prop_s=MIN_S)], duration=20.0)


def test_one_event_per_fact_to_every_listener_statuses_to_those_who_ask():
    net = Network(three())
    frames, both, records = Log(), Log(), []
    net.tracer.listen(frames)
    net.tracer.listen(both, statuses=True)
    net.tracer.add(records.append)
    net.run()
    assert [e for e in both.events if e[1] in FRAME_EVENTS] == frames.events
    assert [e[1] for e in frames.events] == [r["ev"] for r in records]
    counts = Counter((e[1], e[5]) for e in frames.events)
    assert counts == net.tracer.counts                    # the port's counts are its events, one each
    statuses = [e for e in both.events if e[1] not in FRAME_EVENTS]
    assert statuses and {e[1] for e in statuses} <= set(STATUSES)
    sent = Counter(e[1] for e in statuses if e[2] == "a")
    assert sent["queued"] == sent["sent"] == counts[("enq", None)]   # NOMAC: queued, then sent, each frame
    for _t, ev, dev, _src, _seq, _reason, dist in frames.events:   # a reception carries its distance
        if ev == "rx":
            assert dist == 300.0 and dev == "b"


def test_a_listener_is_called_once_per_event_and_builds_nothing():
    tr = Tracer()
    calls = []

    class Once(Listener):
        def event(self, *a) -> None:
            calls.append(a)

    tr.listen(Once())
    f = Frame(1, 2, 0, 10, 10)
    tr.emit(0.5, "enq", 0, "a", f, None, 0)
    tr.status(0.5, "queued", 0, "a", f)                  # nobody asked for statuses
    tr.emit(0.6, "tx", 0, "a", f, None, 0)
    assert [c[1] for c in calls] == ["enq", "tx"] and calls[0][4] is f


def test_metrics_from_the_trace_batches_equal_metrics_from_each_event(tmp_path):
    def run(with_trace: bool):
        net = Network(three("aloha"))
        if with_trace:
            with open(tmp_path / "t.jsonl", "wb") as fh:
                sink = JsonlSink(fh)
                net.tracer.consume(sink.write_batch)
                acc = Accumulator(net.meta())
                assert net.tracer.batching
                acc.follow(net.tracer)                   # takes the writer's batches
                net.run()
                net.tracer.flush()
        else:
            acc = Accumulator(net.meta())
            acc.follow(net.tracer)                       # each event at once
            net.run()
        r = acc.result()
        return {n: m.to_dict() for n, m in r.flows.items()}, r.conservation.total

    assert run(True) == run(False)


def test_sim_backend_outcomes_are_the_port_events_at_the_addressee():
    w = SimWorld(three(), clock="virtual")
    a = w.backend("a")
    got = []
    a.on_status.append(got.append)
    a.send(2, b"to b", tag="b1")
    a.send(3, b"to c", tag="c1")                          # c is out of range: lost there (range)
    a.send(255, b"all", tag="bc")                         # broadcast: no addressee, no outcome
    w.run(10.0)
    by = {(s.tag, s.event): s for s in got}
    assert ("b1", "delivered") in by and ("b1", "lost") not in by
    assert by[("c1", "lost")].reason == "range"
    assert not any(s.tag == "bc" and s.event in ("delivered", "lost") for s in got)
    prop = by[("b1", "delivered")].prop_time
    assert math.isclose(prop, MIN_S + PER_M * 300.0, rel_tol=1e-12)   # the channel's law at 300 m
    assert a._pending == {}                               # every awaited outcome came: nothing held
    w.close()


def test_sim_backend_frames_carry_the_distance_the_channel_used():
    w = SimWorld(three(), clock="virtual")
    got = []
    w.backend("b").on_frame.append(got.append)
    w.backend("a").send(2, b"hello", tag=1)
    w.run(10.0)
    (f,) = got
    assert f.data == b"hello" and f.distance == 300.0
    assert math.isclose(f.prop_time, MIN_S + PER_M * 300.0, rel_tol=1e-12)
    w.close()


def test_a_realtime_run_has_the_virtual_runs_outputs_a_compressed_trace_too(tmp_path):
    """assembly/outputs.py serves both clocks: a realtime run writes a `.gz` trace, whole, meta first and the end
    record last, every frame conserved, and its summary from the same online metrics."""
    import gzip
    import json
    import subprocess

    from test_broker_e2e import free_port
    from test_run_end import ROOT, UWSIMNET
    from test_run_end import scene as run_scene

    from uwsimnet_zenoh.analysis import analyse

    port = free_port()
    sc = tmp_path / "s.xml"
    sc.write_text(run_scene(duration=2, clock="realtime", port=port))
    trace = tmp_path / "t.jsonl.gz"
    r = subprocess.run([*UWSIMNET, "run", str(sc), "--trace", str(trace), "--listen", f"tcp/127.0.0.1:{port}"],
                       cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    recs = [json.loads(line) for line in gzip.decompress(trace.read_bytes()).decode().splitlines()]
    assert recs[0]["ev"] == "meta" and recs[0]["clock"] == "realtime"
    assert recs[-1]["ev"] == "end" and recs[-1]["reason"] == "duration"
    a = analyse(trace, horizon=0.0)
    assert a.conservation.ok, a.conservation.violations[:5]
    assert "ab" in r.stdout and sum(m.delivered for m in a.flows.values()) > 0


def test_the_simulator_backend_has_the_outputs_of_uwsimnet_run(tmp_path):
    """One run assembly (assembly/outputs.py): a virtual SimWorld with `trace` and `metrics` writes the trace
    bytes `uwsimnet run` writes for the same scene and seed, and gives the same online metrics."""
    from uwsimnet_zenoh.app.virtual import simulate

    sc = three()
    ours, theirs = tmp_path / "world.jsonl", tmp_path / "run.jsonl"
    w = SimWorld(sc, clock="virtual", flows=True, seed=sc.simulation.seed, trace=ours, metrics=True)
    w.run(sc.end_time())
    w.close()
    w.close()                                             # once only
    ref = simulate(sc, seed=sc.simulation.seed, duration=sc.end_time(), trace_path=theirs, progress=False)
    assert ours.read_bytes() == theirs.read_bytes() and ours.read_bytes().count(b'"ev":"rx"') > 5
    assert w.analysis().flows == ref.analysis.flows
