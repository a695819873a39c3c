"""Trace report and plots on small synthetic traces whose metrics are computed by hand."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from rich.table import Table

from uwsimnet_zenoh.analysis import (
    Conservation,
    TraceError,
    analyse,
    conservation,
    flow_metrics,
    format_markdown,
    format_report,
    format_text,
    read_trace,
    report_json,
)
from uwsimnet_zenoh.analysis.figures import compare_markdown, compare_table, plot_compare, plot_trace
from uwsimnet_zenoh.analysis.tables import FlowTable

PNG = b"\x89PNG\r\n\x1a\n"


def E(t, ev, dev, src, dst, seq, size, flow, kind="data", ch=0, **kw):
    rec = {"t": t, "ev": ev, "ch": ch, "dev": dev, "src": src, "dst": dst, "seq": seq, "size": size,
           "flow": flow, "kind": kind}
    rec.update(kw)
    return rec


def write(path: Path, records, meta=None) -> Path:
    lines = [] if meta is None else [json.dumps(meta)]
    lines += [json.dumps(r) for r in sorted(records, key=lambda r: r["t"])]
    path.write_text("\n".join(lines) + "\n")
    return path


def dev(address, vehicle, ch, bitrate, header):
    return {"address": address, "vehicle": vehicle, "tx_channel": ch, "rx_channel": ch, "bitrate": bitrate,
            "header_bytes": header}


DEVICES = {
    "A": dev(1, "rov0", 0, 1500.0, 5),
    "B": dev(2, "rov1", 0, 1500.0, 5),
    # channel 1 reuses address 1: frames are told apart by (channel, address)
    "C": dev(1, "buoy", 1, 1900.0, 0),
    "D": dev(2, "e0", 1, 1900.0, 0),
    "E": dev(3, "e1", 1, 1900.0, 0),
    "F": dev(4, "e2", 1, 1900.0, 0),
}
F1 = {"src": "A", "dst": 2, "size": 20, "interval": 1.0, "arrival": "periodic", "start": 5.0, "stop": 15.0}
BC = {"src": "C", "dst": 255, "size": 10, "interval": 2.0, "arrival": "periodic", "start": 0.0, "stop": None}


def meta(flows, duration=20.0, devices=DEVICES):
    return {"ev": "meta", "t": 0.0, "version": 1, "scene": "test", "seed": 1, "duration": duration,
            "flows": flows, "devices": devices}


# f1: 10 frames of 20 B payload + 5 B header, window [5, 15]: 7 delivered, 2 lost to collisions,
# 1 FIFO drop, seq 3 retransmitted once (first attempt collided), 3 ACKs of 10 B sent by B.
F1_DELAY = {0: 0.3, 2: 0.4, 3: 0.75, 4: 0.3, 6: 0.5, 7: 0.3, 8: 0.35}


def f1_records():
    recs = []
    for i in range(10):
        t = 5.0 + i
        if i == 9:
            recs += [E(t, "enq", "A", 1, 2, i, 25, "f1", fifo=50),
                     E(t, "drop", "A", 1, 2, i, 25, "f1", reason="fifo", fifo=50)]
            continue
        recs += [E(t, "enq", "A", 1, 2, i, 25, "f1", fifo=25),
                 E(t + 0.1, "tx", "A", 1, 2, i, 25, "f1", fifo=0)]
        if i in (1, 5):
            recs.append(E(t + 0.3, "drop", "B", 1, 2, i, 25, "f1", reason="col", dist=2.0))
            continue
        if i == 3:
            recs += [E(t + 0.3, "drop", "B", 1, 2, i, 25, "f1", reason="col", dist=2.0),
                     E(t + 0.5, "tx", "A", 1, 2, i, 25, "f1", fifo=0)]
        recs.append(E(t + F1_DELAY[i], "rx", "B", 1, 2, i, 25, "f1", dist=2.0))
        if i in (0, 2, 4):     # ACKs: control frames serving f1, sent by B
            ta = t + F1_DELAY[i] + 0.01
            recs += [E(ta, "tx", "B", 2, 1, i, 10, "f1", kind="ctrl", fifo=0),
                     E(ta + 0.1, "rx", "A", 2, 1, i, 10, "f1", kind="ctrl", dist=2.0)]
    recs.append(E(5.02, "drop", "A", 2, 1, 99, 10, "f1", kind="ctrl", reason="col", dist=2.0))  # not data
    return recs


# bc: 4 broadcast frames from C (address 1 on channel 1) to D, E, F; window [0, 20].
def bc_records():
    r = []
    for i in range(4):
        t = 1.0 + 2 * i
        r.append(E(t, "enq", "C", 1, 255, i, 10, "bc", ch=1, fifo=0))
        if i == 3:
            r.append(E(t, "drop", "C", 1, 255, i, 10, "bc", ch=1, reason="fifo", fifo=10))
            continue
        r.append(E(t + 0.01, "tx", "C", 1, 255, i, 10, "bc", ch=1, fifo=0))
        outcome = {0: ("rx", "rx", "rx"), 1: ("rx", "rx", "prop"), 2: ("range", "col", "rx")}[i]
        for dev, o in zip("DEF", outcome, strict=True):
            if o == "rx":
                r.append(E(t + 0.2, "rx", dev, 1, 255, i, 10, "bc", ch=1, dist=3.0))
            else:
                r.append(E(t + 0.01 if o == "range" else t + 0.2, "drop", dev, 1, 255, i, 10, "bc", ch=1,
                           reason=o, dist=9.0 if o == "range" else 3.0))
    return r


@pytest.fixture
def main_trace(tmp_path):
    return write(tmp_path / "main.jsonl", f1_records() + bc_records(), meta({"f1": F1, "bc": BC}))


# -- metrics ------------------------------------------------------------------------------------
def test_unicast_flow_by_hand(main_trace):
    m = flow_metrics(main_trace)
    assert list(m) == ["f1", "bc"]
    f = m["f1"]
    assert f.src == "A" and f.dst == 2 and f.payload == 20
    assert f.window == (5.0, 15.0)
    assert (f.enqueued, f.sent, f.unique_sent, f.delivered) == (10, 10, 9, 7)
    assert f.payload_delivered == 140 and f.payload_offered == 200
    assert f.data_bytes_on_air == 250 and f.ctrl_sent == 3 and f.ctrl_bytes_on_air == 30
    assert f.bytes_on_air == 280
    assert f.throughput == pytest.approx(14.0)
    assert f.offered == pytest.approx(20.0)
    assert f.efficiency == pytest.approx(140 / 280)
    assert f.delivery_ratio == pytest.approx(7 / 9)
    delays = [F1_DELAY[i] for i in sorted(F1_DELAY)]        # rx order = seq order here
    assert f.delay_mean == pytest.approx(sum(delays) / 7)
    assert f.delay_median == pytest.approx(0.35)
    assert f.delay_p95 == pytest.approx(0.5 + 0.7 * (0.75 - 0.5))    # linear interpolation, rank 5.7
    jitter = sum(abs(b - a) for a, b in zip(delays, delays[1:], strict=False)) / 6
    assert jitter == pytest.approx(0.225)
    assert f.jitter == pytest.approx(jitter)
    assert f.drops == {"col": 2, "fifo": 1}
    assert f.superseded == {"col": 1}           # the first attempt of seq 3
    assert f.in_flight == 0


def test_broadcast_flow_and_channel_scoped_addresses(main_trace):
    b = flow_metrics(main_trace)["bc"]
    assert b.src == "C" and b.broadcast
    assert (b.enqueued, b.sent, b.unique_sent, b.delivered) == (4, 3, 3, 6)
    assert b.delivery_ratio == pytest.approx(6 / 9)       # 3 frames x 3 receivers
    assert b.window == (0.0, 20.0)
    assert b.throughput == pytest.approx(6 * 10 / 20)
    assert b.efficiency == pytest.approx(60 / 30)         # broadcast: each byte on air serves 3 receivers
    assert b.drops == {"col": 1, "fifo": 1, "prop": 1, "range": 1}
    assert b.delay_mean == pytest.approx(0.2)
    assert b.jitter == pytest.approx(0.0, abs=1e-12)
    # C (address 1 on channel 1) did not leak into A (address 1 on channel 0)
    assert flow_metrics(main_trace)["f1"].delivered == 7


def test_clean_trace_conserves(main_trace):
    c = conservation(main_trace)
    assert isinstance(c, Conservation)
    assert c == [] and c.ok and c.in_flight == []
    assert c.frames == 14


def test_fallbacks_without_meta(tmp_path):
    p = write(tmp_path / "nometa.jsonl", f1_records())
    m, events = read_trace(p)
    assert m == {}
    assert next(events)["ev"] == "enq"
    f = flow_metrics(p)["f1"]
    # no flow size and no header known: payload = bytes on air; window = first enq .. last data event
    assert f.payload_delivered == 7 * 25
    assert f.window == (5.0, 14.0)
    assert f.throughput == pytest.approx(175 / 9)
    # devices known (header 5 B) but no flows: payload = size - header
    f = flow_metrics(p, meta={"devices": DEVICES})["f1"]
    assert f.payload_delivered == 140
    assert f.throughput == pytest.approx(140 / 9)


def test_records_instead_of_a_file():
    recs = [meta({"f1": F1})] + sorted(f1_records(), key=lambda r: r["t"])
    f = flow_metrics(recs)["f1"]
    assert f.throughput == pytest.approx(14.0)
    assert f.efficiency == pytest.approx(0.5)


def test_external_app_frames_grouped_by_transmitter(tmp_path):
    recs = [E(1.0, "enq", "B", 2, 1, 0, 15, None), E(1.1, "tx", "B", 2, 1, 0, 15, None),
            E(1.5, "rx", "A", 2, 1, 0, 15, None, dist=1.0),
            # an ACK from A about B's frame, no flow: counted for B's traffic
            E(1.6, "tx", "A", 1, 2, 0, 4, None, kind="ctrl"),
            E(1.7, "rx", "B", 1, 2, 0, 4, None, kind="ctrl", dist=1.0)]
    p = write(tmp_path / "ext.jsonl", recs, meta({}, duration=10.0))
    m = flow_metrics(p)
    assert list(m) == ["B"]
    b = m["B"]
    assert b.src == "B" and b.delivered == 1
    assert b.payload_delivered == 10                       # 15 B on air - 5 B header
    assert b.ctrl_sent == 1 and b.bytes_on_air == 19
    assert b.efficiency == pytest.approx(10 / 19)
    assert b.delay_mean == pytest.approx(0.5)
    assert b.jitter is None                                 # one delay only
    assert conservation(p) == []


def test_retries_final_outcome(tmp_path):
    recs = [
        # seq 0: two collided attempts then the MAC gives up: one final outcome (retry)
        E(1.0, "enq", "A", 1, 2, 0, 25, "f1"), E(1.1, "tx", "A", 1, 2, 0, 25, "f1"),
        E(1.3, "drop", "B", 1, 2, 0, 25, "f1", reason="col", dist=1.0),
        E(2.1, "tx", "A", 1, 2, 0, 25, "f1"), E(2.3, "drop", "B", 1, 2, 0, 25, "f1", reason="col", dist=1.0),
        E(3.1, "drop", "A", 1, 2, 0, 25, "f1", reason="retry", fifo=0),
        # seq 1: delivered but the ACK was lost: the transmitter's retry drop is not the final outcome
        E(4.0, "enq", "A", 1, 2, 1, 25, "f1"), E(4.1, "tx", "A", 1, 2, 1, 25, "f1"),
        E(4.4, "rx", "B", 1, 2, 1, 25, "f1", dist=1.0),
        E(5.1, "drop", "A", 1, 2, 1, 25, "f1", reason="retry", fifo=0),
    ]
    p = write(tmp_path / "retry.jsonl", recs, meta({"f1": F1}))
    f = flow_metrics(p)["f1"]
    assert f.sent == 3 and f.unique_sent == 2 and f.delivered == 1
    assert f.drops == {"retry": 1}
    assert f.superseded == {"col": 2, "retry": 1}
    assert f.delivery_ratio == pytest.approx(0.5)
    assert conservation(p) == []


# -- conservation -------------------------------------------------------------------------------
def test_conservation_violations_and_in_flight(tmp_path):
    recs = [
        # seq 0: one transmission, two outcomes at B
        E(1.0, "enq", "A", 1, 2, 0, 25, "f1"), E(1.1, "tx", "A", 1, 2, 0, 25, "f1"),
        E(1.3, "rx", "B", 1, 2, 0, 25, "f1"), E(1.3, "drop", "B", 1, 2, 0, 25, "f1", reason="col"),
        # seq 1: transmitted long before the end, never an outcome
        E(2.0, "enq", "A", 1, 2, 1, 25, "f1"), E(2.1, "tx", "A", 1, 2, 1, 25, "f1"),
        # seq 2: dropped from the FIFO and transmitted anyway
        E(3.0, "enq", "A", 1, 2, 2, 25, "f1"), E(3.0, "drop", "A", 1, 2, 2, 25, "f1", reason="fifo"),
        E(3.1, "tx", "A", 1, 2, 2, 25, "f1"), E(3.3, "rx", "B", 1, 2, 2, 25, "f1"),
        # seq 3: delivered twice
        E(4.0, "enq", "A", 1, 2, 3, 25, "f1"), E(4.1, "tx", "A", 1, 2, 3, 25, "f1"),
        E(4.3, "rx", "B", 1, 2, 3, 25, "f1"), E(4.4, "rx", "B", 1, 2, 3, 25, "f1"),
        # seq 4: never enqueued
        E(50.1, "tx", "A", 1, 2, 4, 25, "f1"), E(50.3, "rx", "B", 1, 2, 4, 25, "f1"),
        # seq 5: on air when the run ends; seq 6: still queued behind it
        E(95.0, "enq", "A", 1, 2, 5, 25, "f1"), E(95.1, "tx", "A", 1, 2, 5, 25, "f1"),
        E(99.0, "enq", "A", 1, 2, 6, 25, "f1"),
    ]
    p = write(tmp_path / "bad.jsonl", recs, meta({"f1": F1}, duration=100.0))
    c = conservation(p)
    assert not c.ok
    text = "\n".join(c)
    assert any(v.startswith("A seq 0 ") and "2 outcomes at B for 1 transmission" in v for v in c)
    assert any(v.startswith("A seq 1 ") and "no outcome" in v for v in c)
    assert any(v.startswith("A seq 2 ") and "after its transmitter-side drop (fifo)" in v for v in c)
    assert any(v.startswith("A seq 3 ") and "delivered 2 times at B" in v for v in c)
    assert any(v.startswith("A seq 4 ") and "no enq record" in v for v in c)
    assert "seq 5" not in text and "seq 6" not in text
    assert all("\n" not in v for v in c)
    assert sorted((f.seq, f.state) for f in c.in_flight) == [(5, "on air"), (6, "queued")]
    assert c.in_flight[0].flow == "f1"
    # a shorter horizon: seq 5 should have had its outcome by now
    c = conservation(p, horizon=1.0)
    assert any(v.startswith("A seq 5 ") for v in c)
    assert [f.seq for f in c.in_flight] == [6]


def test_skipped_frame_in_fifo_is_a_violation(tmp_path):
    recs = [E(1.0, "enq", "A", 1, 2, 0, 25, "f1"), E(1.5, "enq", "A", 1, 2, 1, 25, "f1"),
            E(2.0, "tx", "A", 1, 2, 1, 25, "f1"), E(2.2, "rx", "B", 1, 2, 1, 25, "f1")]
    p = write(tmp_path / "skip.jsonl", recs, meta({"f1": F1}))
    c = conservation(p)
    assert len(c) == 1 and c[0].startswith("A seq 0 ") and "never transmitted" in c[0]
    assert c.in_flight == []


def test_broadcast_conservation(tmp_path):
    ok = bc_records()
    assert conservation(write(tmp_path / "bc.jsonl", ok, meta({"bc": BC}))) == []
    # a receiver with two outcomes; a frame with none
    bad = ok + [E(1.25, "drop", "E", 1, 255, 0, 10, "bc", ch=1, reason="col", dist=3.0),
                E(11.0, "enq", "C", 1, 255, 4, 10, "bc", ch=1),
                E(11.01, "tx", "C", 1, 255, 4, 10, "bc", ch=1)]
    c = conservation(write(tmp_path / "bc-bad.jsonl", bad, meta({"bc": BC}, duration=100.0)))
    assert len(c) == 2
    assert c[0].startswith("C seq 0 ") and "2 outcomes at E" in c[0]
    assert c[1].startswith("C seq 4 ") and "no outcome" in c[1]


def test_unicast_outcome_at_the_wrong_receiver(tmp_path):
    recs = [E(1.0, "enq", "A", 1, 2, 0, 25, "f1"), E(1.1, "tx", "A", 1, 2, 0, 25, "f1"),
            E(1.3, "rx", "C", 1, 2, 0, 25, "f1")]
    c = conservation(write(tmp_path / "wrong.jsonl", recs, meta({"f1": F1})))
    assert len(c) == 1 and "not at its addressee B" in c[0]


# -- reading ------------------------------------------------------------------------------------
def test_malformed_line_names_the_line(tmp_path):
    p = tmp_path / "broken.jsonl"
    p.write_text(json.dumps(meta({"f1": F1})) + "\n" + json.dumps(f1_records()[0]) + "\n{oops\n")
    with pytest.raises(TraceError) as ei:
        flow_metrics(p)
    msg = str(ei.value)
    assert msg.startswith(f"{p}:3: ") and "\n" not in msg
    p.write_text(json.dumps({"t": 1.0, "ev": "tx", "ch": 0, "dev": "A"}) + "\n")
    with pytest.raises(TraceError, match=r":1: tx event: missing or non-integer 'src'"):
        flow_metrics(p)
    p.write_text("[1, 2]\n")
    with pytest.raises(TraceError, match=r":1: expected a JSON object"):
        read_trace(p)
    with pytest.raises(TraceError, match="cannot read"):
        read_trace(tmp_path / "missing.jsonl")


def test_unknown_fields_and_events_are_ignored(tmp_path, main_trace):
    recs = [dict(r, extra={"x": 1}, note="hi") for r in f1_records() + bc_records()]
    recs += [{"t": 3.0, "ev": "pose", "vehicle": "rov0", "p": [0, 0, 0]}, {"ev": "checkpoint"},
             {"t": 2.0, "ev": "meta", "scene": "not the first line"}]
    p = tmp_path / "extra.jsonl"
    p.write_text("\n".join([json.dumps(meta({"f1": F1, "bc": BC}))] +
                           [json.dumps(r) for r in sorted(recs, key=lambda r: r.get("t", 0.0))]) + "\n\n")
    assert report_json(flow_metrics(p)) == report_json(flow_metrics(main_trace))
    assert conservation(p) == []


def test_gzip_trace(tmp_path, main_trace):
    import gzip
    gz = tmp_path / "main.jsonl.gz"
    gz.write_bytes(gzip.compress(main_trace.read_bytes()))
    assert flow_metrics(gz)["f1"].throughput == pytest.approx(14.0)


# -- rendering ----------------------------------------------------------------------------------
def test_renderings(main_trace):
    a = analyse(main_trace)
    table = format_report(a.flows)
    assert isinstance(table, FlowTable) and len(table.rows) == 2
    assert all(isinstance(t, Table) for t in table.layout(80))
    text = format_text(a.flows)
    lines = text.splitlines()
    assert lines[0].split()[0] == "flow" and len(lines) == 4
    assert "f1" in text and "14.00" in text and "col:2 fifo:1" in text
    md = format_markdown(a.flows)
    assert md.startswith("| flow |") and "| f1 |" in md
    j = report_json(a.flows)
    assert j["version"] == 1
    back = json.loads(json.dumps(j))
    assert back["flows"]["f1"]["throughput"] == pytest.approx(14.0)
    assert back["flows"]["f1"]["window"] == [5.0, 15.0]
    assert back["flows"]["f1"]["bytes_on_air"] == 280
    assert back["flows"]["bc"]["drops"] == {"col": 1, "fifo": 1, "prop": 1, "range": 1}


# -- plots --------------------------------------------------------------------------------------
def every_reason_trace(path: Path, shift: float = 0.0) -> Path:
    """Two crossing flows over 60 s with every drop reason, distances and FIFO occupancy."""
    recs = []
    reasons = ["rx", "rx", "prop", "rx", "col", "mult", "rx", "range", "rx", "retry"]
    for flow, dev, src, dst, rcv, t0 in (("f1", "A", 1, 2, "B", 0.0), ("f2", "B", 2, 1, "A", 0.5)):
        for i in range(60):
            t = t0 + i
            d = 1.0 + 5.0 * abs(((t / 30.0) % 2.0) - 1.0)
            recs.append(E(t, "enq", dev, src, dst, i, 25, flow, fifo=25 * (i % 4)))
            if i % 13 == 12:
                recs.append(E(t, "drop", dev, src, dst, i, 25, flow, reason="fifo", fifo=75))
                continue
            recs.append(E(t + 0.05, "tx", dev, src, dst, i, 25, flow, fifo=25 * (i % 3)))
            what = reasons[i % len(reasons)]
            if what == "rx":
                recs.append(E(t + 0.2 + 0.01 * d + shift, "rx", rcv, src, dst, i, 25, flow, dist=d))
            elif what == "retry":
                recs.append(E(t + 0.9, "drop", dev, src, dst, i, 25, flow, reason="retry", fifo=0))
            else:
                recs.append(E(t + 0.25, "drop", rcv, src, dst, i, 25, flow, reason=what, dist=d))
    flows = {"f1": dict(F1, start=0.0, stop=None), "f2": dict(F1, src="B", dst=1, start=0.0, stop=None)}
    return write(path, recs, meta(flows, duration=61.0))


def assert_png(p: Path) -> None:
    data = p.read_bytes()
    assert data[:8] == PNG
    assert len(data) > 10_000, f"{p.name} is only {len(data)} bytes"


def test_plot_trace(tmp_path):
    trace = every_reason_trace(tmp_path / "all.jsonl")
    assert conservation(trace) == []
    files = plot_trace(trace, tmp_path / "figs")
    assert [f.name for f in files] == ["fig3-packets.png", "fig4-delay.png"]
    for f in files:
        assert_png(f)


def test_plot_trace_without_data(tmp_path):
    p = write(tmp_path / "empty.jsonl", [], meta({}))
    assert plot_trace(p, tmp_path / "figs") == []


def test_plot_compare_and_tables(tmp_path):
    traces = {"NOMAC": every_reason_trace(tmp_path / "n.jsonl", 0.0),
              "ALOHA": every_reason_trace(tmp_path / "a.jsonl", 0.1),
              "SFAMA": every_reason_trace(tmp_path / "s.jsonl", 0.2)}
    files = plot_compare(traces, tmp_path / "cmp", title="MAC comparison")
    assert [f.name for f in files] == ["fig7-mac-comparison.png"]
    assert_png(files[0])
    table = compare_table(traces)
    assert isinstance(table, Table) and table.row_count == 2 and len(table.columns) == 1 + 3 * 4
    md = compare_markdown({k: flow_metrics(v) for k, v in traces.items()})    # metrics work too
    lines = md.splitlines()
    assert lines[0].startswith("| flow | NOMAC throughput (B/s) |")
    assert len(lines) == 4 and lines[2].startswith("| f1 |")
