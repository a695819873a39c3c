"""Issue #19: the summary of `uwsimnet run` is computed online and equals `uwsimnet report` on the trace;
the trace costs nothing when nobody listens and is written fast, byte for byte as Python's json writes it.

The golden traces (test_golden_traces.py) pin the JSONL bytes of every scene; here: the metrics computed
during the run against the same metrics computed from its trace (JSONL, gzip and the columnar trace), on
every scene under scenes/ and on the ALOHA reference scenario with a MAC that retransmits."""

from __future__ import annotations

import gzip
import io
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from uwsimnet_zenoh.analysis import analyse, read_trace, report_json
from uwsimnet_zenoh.app.virtual import load_scene_file, simulate
from uwsimnet_zenoh.cli.main import main
from uwsimnet_zenoh.engine.network import Network
from uwsimnet_zenoh.kernel.frame import Frame
from uwsimnet_zenoh.trace import events
from uwsimnet_zenoh.trace.events import Callback, JsonlSink, Tracer

ROOT = Path(__file__).resolve().parent.parent
SCENES = sorted(str(p.relative_to(ROOT)) for p in (ROOT / "scenes").rglob("*.xml"))


def same_analysis(a, b) -> None:
    assert report_json(a.flows) == report_json(b.flows)
    assert {k: c.to_dict() for k, c in a.channels.items()} == {k: c.to_dict() for k, c in b.channels.items()}
    assert list(a.conservation) == list(b.conservation)
    assert a.conservation.in_flight == b.conservation.in_flight
    assert a.conservation.frames == b.conservation.frames


@pytest.mark.parametrize("scene", SCENES)
def test_online_summary_equals_the_report_of_the_trace(scene, tmp_path):
    sc = load_scene_file(str(ROOT / scene))
    duration = min(sc.simulation.duration or 40.0, 40.0)
    run = simulate(sc, seed=3, duration=duration, trace_path=tmp_path / "t.jsonl", progress=False)
    assert run.analysis is not None       # (scenes whose traffic comes from external apps have no flow)
    same_analysis(run.analysis, analyse(tmp_path / "t.jsonl"))
    sent = sum(f.sent for f in run.analysis.flows.values()) + sum(f.ctrl_sent for f in run.analysis.flows.values())
    assert sum(c.sent for c in run.analysis.channels.values()) == sent == run.net.tracer.count("tx")


def test_online_summary_with_retransmissions_and_control_frames(tmp_path):
    """S-FAMA-like exchanges (ctrl frames, retries, receiver-side drops of earlier attempts) on a busy channel."""
    from test_aloha_theory import sensors_scene

    for mac in ("aloha", "sfama"):
        sc = sensors_scene(8, 1.5, 300.0, 300.0, mac=mac, fifo=2000, seed=5)
        run = simulate(sc, seed=None, duration=None, trace_path=tmp_path / f"{mac}.jsonl", progress=False)
        a = run.analysis
        assert sum(sum(f.drops.values()) for f in a.flows.values()) > 0
        same_analysis(a, analyse(tmp_path / f"{mac}.jsonl"))
        if mac == "sfama":
            assert sum(f.ctrl_sent for f in a.flows.values()) > 0


def test_gzip_trace_is_the_same_trace(tmp_path):
    sc = load_scene_file(str(ROOT / "scenes/examples/two-nodes.xml"))
    simulate(sc, seed=1, duration=None, trace_path=tmp_path / "t.jsonl", progress=False)
    simulate(sc, seed=1, duration=None, trace_path=tmp_path / "t.jsonl.gz", progress=False)
    assert gzip.decompress((tmp_path / "t.jsonl.gz").read_bytes()) == (tmp_path / "t.jsonl").read_bytes()


NO_RECORD = """
import sys
from uwsimnet_zenoh.trace import tracer
def boom(*a, **k):
    raise AssertionError("a record was built")
tracer.record = boom
from uwsimnet_zenoh.app.virtual import load_scene_file, simulate
run = simulate(load_scene_file(sys.argv[1]), seed=1, duration=None, trace_path=None, progress=False)
print(run.analysis.flows["alpha-to-bravo"].delivered)
"""


def test_no_listener_no_record(monkeypatch, tmp_path):
    """Without a trace the run builds no record (record() is never called: pure Python, where the patch
    reaches the tracer's calls; compiled, the same code) and writes no file."""
    scene = str(ROOT / "scenes/examples/two-nodes.xml")
    out = subprocess.run([sys.executable, "-c", NO_RECORD, scene], env={**os.environ, "UWSIMNET_PURE": "1"},
                         capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["60"]
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    assert main(["run", scene]) == 0
    assert os.listdir(tmp_path) == []


def test_record_sinks_still_get_dicts():
    sc = load_scene_file(str(ROOT / "scenes/examples/two-nodes.xml"))
    net = Network(sc)
    got: list[dict] = []
    net.tracer.add(got.append)
    net.run()
    assert [r["ev"] for r in got[:3]] == ["enq", "tx", "rx"]
    assert list(got[2]) == ["t", "ev", "ch", "dev", "src", "dst", "seq", "size", "flow", "kind", "dist"]


REF = json.JSONEncoder(separators=(",", ":"), ensure_ascii=False).encode


@pytest.mark.parametrize("t, dist", [
    (0.0, None), (5e-05, None), (1e-4, 3.0), (12.345678912, 0.0), (3.2e-07, 1e-05), (1e16, 2.5e16),
    (7.5, math.nan), (7.5, math.inf), (123456.000000001, 499.9995), (1e15, 1e-4), (0.1 + 0.2, 0.001)])
def test_fast_lines_are_json_lines(t, dist):
    """msgspec writes floats as Python does except in exponent form (1e-05 vs 1e-5): those fall back."""
    frame = Frame(3, 255, 17, 40, 37, flow="fl\u00f6w \"q\"\n", dev="d\u00e9v")
    for reason, fifo in ((None, None), ("col", None), (None, 80), ("fifo", 0)):
        fast, ref = io.BytesIO(), io.StringIO()
        sink = JsonlSink(fast)
        sink.event(t, "drop", 2, "d\u00e9v\u2028", frame, reason, fifo, dist)
        sink.flush()
        ref.write(REF(events.record(t, "drop", 2, "d\u00e9v\u2028", frame, reason, fifo, dist)) + "\n")
        assert fast.getvalue().decode("utf-8") == ref.getvalue()


_FLOATS = st.one_of(
    st.floats(allow_nan=False, allow_infinity=False, min_value=0.0, max_value=2e6),
    st.floats(min_value=0.0, max_value=1e-3), st.floats(min_value=1e14, max_value=1e17),
    st.integers(0, 10**15).map(lambda k: k / 1e9), st.floats(), st.integers(-5, 10**7))
_NAMES = st.text(st.characters(codec="utf-8"), max_size=6)


@settings(max_examples=400, deadline=None)
@given(rows=st.lists(st.tuples(
    _FLOATS, st.sampled_from(["enq", "tx", "rx", "drop"]), st.integers(0, 300), _NAMES, st.integers(0, 255),
    st.integers(0, 255), st.integers(0, 2**40), st.integers(0, 10**6), st.none() | _NAMES, _NAMES,
    st.none() | _NAMES, st.none() | st.integers(0, 10**6), st.none() | _FLOATS, st.booleans()), max_size=8))
def test_batches_are_written_as_json_writes_their_records(rows):
    """Any batch of rows (the tracer's types, any finite time, any distance or name): the JSONL writer's
    batch path writes, byte for byte, what Python's json writes of each row's record."""
    rows = [r for r in rows if math.isfinite(r[0])]
    t9 = [round(r[0], 9) for r in rows]
    fast = io.BytesIO()
    JsonlSink(fast).write_batch(events.Batch(rows, t9))
    assert fast.getvalue().decode("utf-8") == "".join(REF(events.finite(events.row_record(t9[k], rows[k]))) + "\n"
                                                      for k in range(len(rows)))


def test_batched_lines_keep_their_order_around_fallbacks():
    frame = Frame(1, 2, 0, 10, 10, flow=None)
    fast = io.StringIO()
    sink = JsonlSink(fast, batch=3)
    expect = []
    for i, t in enumerate([0.0, 1e-6, 0.5, 0.75, 2e-5, 1.0, 2.0, 3.0]):
        frame.seq = i
        sink.event(t, "tx", 0, "a", frame, None, 0, None)
        expect.append(REF(events.record(t, "tx", 0, "a", frame, None, 0, None)))
    sink.header({"ev": "meta"})
    sink.flush()
    assert fast.getvalue().splitlines() == expect + ['{"ev":"meta"}']


def test_listeners_see_every_event_once():
    tr = Tracer()
    seen = []
    tr.listen(Callback(lambda *a: seen.append(a[1])))
    tr.emit(1.0, "tx", 0, "a", Frame(1, 2, 0, 10, 10))
    assert seen == ["tx"] and tr.count("tx") == 1


@pytest.mark.parametrize("mac", ["aloha", "none"])        # none: implicit receptions too
def test_columnar_trace_reads_back_as_the_jsonl_trace(tmp_path, mac):
    pytest.importorskip("pyarrow")
    from test_aloha_theory import sensors_scene

    sc = sensors_scene(6, 1.0, 200.0, 400.0, mac=mac, fifo=500, seed=2)
    a = simulate(sc, seed=None, duration=None, trace_path=tmp_path / "t.arrow", progress=False)
    simulate(sc, seed=None, duration=None, trace_path=tmp_path / "t.jsonl", progress=False)
    same_analysis(analyse(tmp_path / "t.arrow"), analyse(tmp_path / "t.jsonl"))
    same_analysis(a.analysis, analyse(tmp_path / "t.arrow"))
    ma, ea = read_trace(tmp_path / "t.arrow")
    mj, ej = read_trace(tmp_path / "t.jsonl")
    assert ma == mj
    assert list(ea) == list(ej)


def test_cli_report_reads_the_columnar_trace(tmp_path, capsys):
    pytest.importorskip("pyarrow")
    scene = str(ROOT / "scenes/examples/two-nodes.xml")
    assert main(["run", scene, "--trace", str(tmp_path / "t.arrow")]) == 0
    run_out = capsys.readouterr().out
    assert main(["report", str(tmp_path / "t.arrow")]) == 0
    rep = capsys.readouterr().out
    assert rep.strip() and rep.strip() in run_out


def test_online_summary_skips_implicit_receptions_as_the_report_does(tmp_path):
    """NOMAC's implicit broadcast (the default): modems that are not the addressee trace `rx` with
    `implicit: true`; neither the report nor the online summary counts them as deliveries."""
    from test_aloha_theory import sensors_scene

    sc = sensors_scene(6, 1.0, 200.0, 300.0, mac="none", fifo=500, seed=4)
    run = simulate(sc, seed=None, duration=None, trace_path=tmp_path / "t.jsonl", progress=False)
    assert '"implicit":true' in (tmp_path / "t.jsonl").read_text()
    same_analysis(run.analysis, analyse(tmp_path / "t.jsonl"))
    assert run.analysis.flows["s0"].delivered <= run.analysis.flows["s0"].sent


# -- the batched metrics against the event-by-event definition of before (tests/metrics_reference.py) --------
def _as_ref(a) -> tuple:
    """An Analysis (batched or reference) as plain data."""
    return ({k: f.to_dict() for k, f in a.flows.items()}, list(a.flows),
            {k: c.to_dict() for k, c in a.channels.items()},
            list(a.conservation), a.conservation.total, a.conservation.frames, a.conservation.end,
            [(x.dev, x.seq, x.flow, x.state, x.t_enq, x.t_tx) for x in a.conservation.in_flight])


def _records(sc, seed=None, duration=None) -> tuple[dict, list[dict]]:
    net = Network(sc, seed=seed, duration=duration)
    recs: list[dict] = []
    net.tracer.add(recs.append)
    net.run()
    return net.meta(), recs


def _agree(meta: dict, recs: list[dict], **kw) -> tuple:
    """The reference, the Accumulator on batches of records (analyse) and on one event at a time: all equal."""
    import metrics_reference as ref

    from uwsimnet_zenoh.analysis import Accumulator

    want = _as_ref(ref.analyse([meta, *recs], **kw))
    assert _as_ref(analyse([meta, *recs], **kw)) == want
    one = Accumulator(meta)
    for r in recs:
        one.event(r["t"], r["ev"], r["ch"], r["dev"], r["src"], r.get("dst"), r["seq"], r["size"], r.get("flow"),
                  r.get("kind", "data"), r.get("reason"), "dist" in r, bool(r.get("implicit")))
    assert _as_ref(one.result(**kw)) == want
    return want


@pytest.mark.parametrize("scene", SCENES)
def test_batched_metrics_equal_the_event_by_event_definition_on_every_scene(scene):
    sc = load_scene_file(str(ROOT / scene))
    meta, recs = _records(sc, seed=3, duration=min(sc.simulation.duration or 40.0, 40.0))
    _agree(meta, recs)
    for cut in (0.3, 0.7):      # a trace cut short: frames in flight, outcomes missing
        _agree(meta, recs[:int(len(recs) * cut)], horizon=1.0)


@pytest.mark.parametrize("mac, shared, fifo", [("none", True, 0), ("none", False, 0), ("aloha", True, 2000),
                                                ("sfama", True, 2000), ("none", True, 500)])
def test_batched_metrics_equal_the_event_by_event_definition_on_busy_channels(mac, shared, fifo):
    from test_aloha_theory import sensors_scene

    sc = sensors_scene(12, 1.5, 1500.0, 300.0, mac=mac, shared=shared, fifo=fifo, seed=7)
    meta, recs = _records(sc)
    assert len(recs) > 3 * 4096            # several batches
    _agree(meta, recs)


def test_online_batches_equal_the_event_by_event_definition():
    """The run's own batches (Tracer.consume, times rounded per batch) against the reference on its records."""
    import metrics_reference as ref
    from test_aloha_theory import sensors_scene

    from uwsimnet_zenoh.analysis import Accumulator

    sc = sensors_scene(16, 1.0, 1000.0, 500.0, mac="none", fifo=0, seed=2)
    net = Network(sc)
    recs: list[dict] = []
    net.tracer.add(recs.append)
    acc = Accumulator(net.meta())
    net.tracer.consume(acc.on_batch)
    net.run()
    net.tracer.flush()
    assert _as_ref(acc.result()) == _as_ref(ref.analyse([net.meta(), *recs]))
    assert len(recs) > 3 * 4096            # several batches
    assert net.tracer.count("tx") == sum(r["ev"] == "tx" for r in recs)


def test_batched_metrics_report_the_same_violations():
    """Records lost, repeated or delivered twice: the same conservation messages, in the same order."""
    from test_aloha_theory import sensors_scene

    sc = sensors_scene(6, 1.2, 300.0, 300.0, mac="aloha", fifo=2000, seed=3)
    meta, recs = _records(sc)
    bad = [r for i, r in enumerate(recs) if i % 97 != 5]                  # some records lost
    bad += [dict(r) for r in recs[::211]]                                 # some repeated at the end
    want = _agree(meta, bad, limit=10)
    assert want[3] and want[4] > 10                                      # violations, truncated


def test_batched_metrics_equal_the_event_by_event_definition_hypothesis():
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st
    from test_aloha_theory import sensors_scene

    @settings(max_examples=25, deadline=None, suppress_health_check=list(HealthCheck))
    @given(n=st.integers(1, 20), load=st.floats(0.2, 3.0), mac=st.sampled_from(["none", "aloha", "sfama"]),
           shared=st.booleans(), fifo=st.sampled_from([0, 200, 2000]), seed=st.integers(0, 2**16),
           cut=st.floats(0.2, 1.0), lose=st.integers(0, 40))
    def check(n, load, mac, shared, fifo, seed, cut, lose):
        sc = sensors_scene(n, load, 200.0, 300.0, mac=mac, shared=shared, fifo=fifo, seed=seed)
        meta, recs = _records(sc)
        recs = recs[:int(len(recs) * cut)]
        if lose:
            recs = [r for i, r in enumerate(recs) if i % (lose + 7) != 3]
        _agree(meta, recs, horizon=5.0)

    check()


def test_rounded_is_round_exactly():
    """The batch's rounding (numpy, with Python's round for the values it cannot be sure of) against round()."""
    import random

    from hypothesis import given, settings
    from hypothesis import strategies as st

    from uwsimnet_zenoh.trace.events import rounded

    rng = random.Random(5)
    xs = [rng.random() * 10 ** rng.randint(-12, 7) for _ in range(20000)]
    xs += [k / 1024 for k in range(3000)] + [i * 1e-9 + 5e-10 for i in range(3000)]
    xs += [i * 1e-3 + 5e-4 for i in range(3000)]
    xs += [0.0, -0.0, 1e16, 4.6e6, 1e300, math.inf, -math.inf, 2.5e-9, 3, 0, 10**20]
    for nd in (9, 3):
        got, want = rounded(xs, nd), [round(x, nd) for x in xs]
        assert [(type(g), g) for g in got] == [(type(w), w) for w in want]
        assert [math.copysign(1, g) for g in got] == [math.copysign(1, w) for w in want]
    assert math.isnan(rounded([math.nan], 9)[0])

    @settings(max_examples=300, deadline=None)
    @given(st.lists(st.floats(allow_nan=False), max_size=50), st.sampled_from([3, 9]))
    def check(xs, nd):
        assert rounded(xs, nd) == [round(x, nd) for x in xs]

    check()


def test_batched_lines_are_the_event_lines():
    """The batch writer (one struct per row, rounding per batch, fallbacks in place) writes the bytes that
    `event()` writes line by line, on the awkward values and on a run."""
    values = [(0.0, None), (5e-05, None), (1e-4, 3.0), (12.345678912, 0.0), (3.2e-07, 1e-05), (1e16, 2.5e16),
              (7.5, math.nan), (7.5, math.inf), (123456.000000001, 499.9995), (1e15, 1e-4), (0.1 + 0.2, 0.001),
              (3, 2), (2.0000000005, 1.0005)]
    frame = Frame(3, 255, 17, 40, 37, flow="fl\u00f6w \"q\"\n", dev="d\u00e9v")
    tr = Tracer(batch=5)
    batched, one = io.BytesIO(), io.BytesIO()
    bsink, esink = JsonlSink(batched), JsonlSink(one, batch=7)
    tr.consume(bsink.write_batch)
    for k, (t, dist) in enumerate(values * 3):
        reason, fifo = [(None, None), ("col", None), (None, 80), ("fifo", 0)][k % 4]
        for implicit in (False, True, 0):
            tr.emit(t, "rx" if dist is not None else "drop", 2, "d\u00e9v\u2028", frame, reason, fifo, dist, implicit)
            esink.event(t, "rx" if dist is not None else "drop", 2, "d\u00e9v\u2028", frame, reason, fifo, dist,
                        implicit)
    tr.flush()
    esink.flush()
    assert batched.getvalue() == one.getvalue()
    assert sum(tr.counts.values()) == 3 * 3 * len(values)


def test_run_trace_is_the_listener_trace(tmp_path):
    """`uwsimnet run --trace` (batches) writes the same file as the per-event listener of before."""
    from test_aloha_theory import sensors_scene

    sc = sensors_scene(8, 1.5, 300.0, 300.0, mac="sfama", fifo=2000, seed=5)
    simulate(sc, seed=None, duration=None, trace_path=tmp_path / "b.jsonl", progress=False, metrics=False)
    net = Network(sc)
    with open(tmp_path / "e.jsonl", "wb") as fh:
        sink = JsonlSink(fh)
        sink.header(net.meta())
        net.tracer.listen(sink)
        net.run()
        sink.flush()
    assert (tmp_path / "b.jsonl").read_bytes() == (tmp_path / "e.jsonl").read_bytes()


def test_mean_is_numpys():
    import numpy as np
    from hypothesis import given, settings
    from hypothesis import strategies as st

    from uwsimnet_zenoh.analysis.metrics import mean

    @settings(max_examples=300, deadline=None)
    @given(st.lists(st.floats(-1e6, 1e6, allow_nan=False), min_size=1, max_size=600))
    def check(xs):
        assert mean(xs) == float(np.mean(np.array(xs)))

    check()
    rng = np.random.default_rng(4)          # past the 128-value blocks of numpy's pairwise sum, and its halves
    for n in (7, 8, 9, 127, 128, 129, 136, 1000, 4097, 70001):
        d = rng.exponential(0.5, n) * rng.choice([1e-3, 1.0, 1e3], n)
        assert mean(d.tolist()) == float(np.mean(d))


def test_median_p95_are_numpys():
    import numpy as np
    from hypothesis import given, settings
    from hypothesis import strategies as st

    from uwsimnet_zenoh.analysis.metrics import median_p95

    @settings(max_examples=400, deadline=None)
    @given(st.lists(st.floats(-1e6, 1e6, allow_nan=False), min_size=1, max_size=400))
    def check(xs):
        d = np.array(xs)
        assert median_p95(d) == (float(np.median(d)), float(np.percentile(d, 95)))

    check()
    rng = np.random.default_rng(3)
    for n in (1, 2, 3, 20, 21, 101, 4096, 4097):
        d = rng.exponential(0.5, n)
        assert median_p95(d) == (float(np.median(d)), float(np.percentile(d, 95)))



def test_odd_addresses_and_sequence_numbers_agree_with_the_reference():
    """Source addresses past the fold's address list (>= 4096, negative), and two frames of a sender whose
    seqs are swapped (3 seen before 2: when 2 arrives, 3 is both the next in line and already known): the
    reference's numbers, and for the swap the numbers of the trace as it was."""
    from test_aloha_theory import sensors_scene

    sc = sensors_scene(4, 1.0, 200.0, 200.0, mac="aloha", fifo=200, seed=5)
    meta, recs = _records(sc)
    src = next(r["src"] for r in recs if r["ev"] == "enq")
    at: dict[int, list[int]] = {}
    for i, r in enumerate(recs):
        if r["src"] == src and r.get("kind", "data") == "data":
            at.setdefault(r["seq"], []).append(i)
    k = next(k for k in sorted(at) if k + 1 in at and at[k + 1][0] < at[k][-1])   # two frames interleaved
    swapped = [dict(r) for r in recs]
    for i in at[k] + at[k + 1]:
        swapped[i]["seq"] = 2 * k + 1 - swapped[i]["seq"]
    # frame k + 1 is seen first (skipping ahead), then frame k (the next in line), then k + 1 again
    assert at[k][0] < at[k + 1][0] < at[k][-1]
    want = _agree(meta, swapped, horizon=5.0)
    assert want[0] == _as_ref(analyse([meta, *recs], horizon=5.0))[0]

    moved = {}
    for r in recs:
        for k in ("src", "dst"):
            v = r.get(k)
            if isinstance(v, int) and v != 255:
                r[k] = moved.setdefault(v, (70000, -3, 4096, 5000, 9)[len(moved) % 5] + len(moved))
    assert len(moved) >= 4
    _agree(meta, recs, horizon=5.0)
