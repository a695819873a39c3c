"""A stopped app costs only itself, over real Zenoh (#11, #21): a process subscribed to a busy modem's rx is
SIGSTOPped while two other apps exchange frames through the same broker.

Before the edge, the broker's engine thread made the rx puts itself with BLOCK congestion control: once
the stopped subscriber's buffers were full every put waited up to 5 s (Zenoh's wait_before_close) and every
modem with it (an unrelated app's frames took 4.9 s and over 8 s instead of 69 ms).  Now the busy modem's
outbox fills and its losses are counted on its `info` ("edge") and in the run summary; the pair's frames
keep their modelled delay.  Bounds: the median within 50 ms (tests/test_broker_e2e.py's WALL_SLACK; the
bench's p99 is ~1 ms on a quiet machine, this one has 2 shared cores and a 4 MB/s flood running) and every
frame within 1 s: far below the stalls it guards against (5 s with the engine putting; 1.3-1.9 s for every
app when the router's puts to the stopped one waited Zenoh's default 5 s, see docs/runtime.md)."""

from __future__ import annotations

import contextlib
import json
import signal
import statistics
import subprocess
import sys
import time

import pytest
from test_broker_e2e import (  # noqa: F401 - procs is a fixture
    WALL_SLACK,
    App,
    Broker,
    Proc,
    device_xml,
    modelled,
    procs,
    scene_xml,
    vehicle_xml,
)

pytest.importorskip("uwsimnet_gli")

STALLED = """
import json, sys, time
import zenoh
ep, key = sys.argv[1], sys.argv[2]
conf = zenoh.Config()
conf.insert_json5("mode", '"client"')
conf.insert_json5("connect/endpoints", json.dumps([ep]))
n = [0]
with zenoh.open(conf) as s:
    sub = s.declare_subscriber(key, lambda sample: n.__setitem__(0, n[0] + 1))
    print("ready", s.zid(), flush=True)
    while True:
        time.sleep(0.2)
        print(n[0], flush=True)
"""


def _fast_device(dev: str, mac: int) -> str:
    return f"""<CustomCommsDevice><dccommsId>{dev}</dccommsId><mac>{mac}</mac><txChannelId>1</txChannelId>
      <rxChannelId>1</rxChannelId><bitrate>200000000</bitrate><txFifoSize>1000000</txFifoSize>
      <maxDistance>2000</maxDistance><maxFrameBytes>65536</maxFrameBytes></CustomCommsDevice>"""


N_SENDS = 28
"""The pair's frames, one every 0.4 s from 2 s after the stop: past Zenoh's default `wait_before_close` (5 s
after the stopped consumer's buffers are full, about 8.5 s after the stop here) and its 10 s lease."""


def test_a_stopped_subscriber_costs_only_its_modem(tmp_path, procs):  # noqa: F811
    world = "stall"
    scene = tmp_path / "stall.xml"
    flood = ("<flow><name>flood</name><src>src-m</src><dst>4</dst><size>64000</size><interval>0.016</interval>"
             "</flow>")                       # 4 MB/s of rx for busy-m's subscribers, in few frames
    scene.write_text(scene_xml(world=world, channels=(0, 1), flows=flood, vehicles="".join([
        vehicle_xml("a", (0, 0, 0), device_xml("a-m", 1)),
        vehicle_xml("b", (300, 0, 0), device_xml("b-m", 2)),
        vehicle_xml("s", (0, 0, 10), _fast_device("src-m", 3)),
        vehicle_xml("busy", (0, 10, 10), _fast_device("busy-m", 4)),
    ])))
    b = Broker(scene, tmp_path / "t.jsonl")
    procs.append(b)
    script = tmp_path / "stalled.py"
    script.write_text(STALLED)
    stalled = Proc([sys.executable, str(script), b.endpoint, f"uwsimnet/{world}/modem/busy-m/rx"])
    procs.append(stalled)
    assert stalled.next_line(15).split()[0] == "ready"
    deadline = time.monotonic() + 10
    while int(stalled.next_line(5)) < 50:           # it does receive the flood
        assert time.monotonic() < deadline
    app = App(b.endpoint, world)
    procs.append(app)
    for m in ("a-m", "b-m"):
        assert app.call(cmd="modem", id=m)["kind"] == "sim"
    info = app.call(cmd="info", id="b-m")

    stalled.p.send_signal(signal.SIGSTOP)
    try:
        time.sleep(2.0)                             # its buffers fill; the broker's puts to it block
        sends = []
        for i in range(N_SENDS):                    # until 2 + 28 x 0.4 = 13.2 s after the stop
            sends.append(app.call(cmd="send", id="a-m", dst=2, data_hex=bytes([i]).hex() * 20))
            time.sleep(0.4)
        frames = app.call(cmd="recv", id="b-m", n=N_SENDS, timeout=15)["frames"]
        busy = app.call(cmd="info", id="busy-m")
    finally:
        stalled.p.send_signal(signal.SIGCONT)
    assert [bytes.fromhex(f["data_hex"]) for f in frames] == [bytes([i]) * 20 for i in range(N_SENDS)]
    want = modelled(300, 20, info) + 0.001          # + the intrinsic tx delay
    late = [f["wall"] - s["wall"] - want for f, s in zip(frames, sends, strict=True)]
    # the bug this guards against made every frame of the pair ~5 s late (the broker's put blocked behind the
    # stopped consumer); a loaded machine (load 6 on 2 cores, the flood's own CPU) delays a frame by 0.1-0.2 s
    # now and then, so: the typical frame within the realtime slack, none anywhere near the blocked put
    assert statistics.median(abs(x) for x in late) < WALL_SLACK, late
    assert max(abs(x) for x in late) < 1.0, late
    # the stopped consumer: its put waited (at most 2 s, bus.session.WAIT_BEFORE_CLOSE_US, then Zenoh gives it up),
    # said on busy-m's info, in a warning and in the summary; nothing lost nor stalled on the pair's modems
    assert busy["edge"]["stalled"].get("rx", 0) >= 1 and 0.5 <= busy["edge"]["stalled_max"] < 3.0, busy["edge"]
    assert busy["edge"]["queued"] <= busy["edge"]["capacity"]
    for m in ("a-m", "b-m"):
        edge = app.call(cmd="info", id=m)["edge"]
        assert edge["dropped"] == {} and edge["stalled"] == {}, edge
    with contextlib.suppress(subprocess.TimeoutExpired):
        stalled.stop(signal.SIGKILL, timeout=5)
    procs.remove(stalled)
    assert b.stop(signal.SIGINT) == 0, b.output()
    out = b.output()
    assert "busy-m: a rx put waited" in out and "a subscriber does not read" in out
    assert "stalled at the edge: busy-m:" in out and " rx put(s) waited up to " in out
    assert "stalled at the edge: a-m" not in out and "stalled at the edge: b-m" not in out
    assert "Traceback" not in out


READER = """
import json, sys
import zenoh
from uwsimnet_gli import wire
ep, key, out = sys.argv[1], sys.argv[2], sys.argv[3]
conf = zenoh.Config()
conf.insert_json5("mode", '"client"')
conf.insert_json5("connect/endpoints", json.dumps([ep]))
got = []
def rx(smp):
    f = wire.decode_rx(smp.payload.to_bytes())
    got.append([f.src, f.seq])
with zenoh.open(conf) as s:
    sub = s.declare_subscriber(key, rx)
    print("ready", s.zid(), flush=True)
    for _ in sys.stdin:                  # what it has taken so far, each time it is asked
        with open(out, "w") as fh:
            json.dump(list(got), fh)
        print("done", flush=True)
"""


@pytest.mark.parametrize("run_s", [4.0, 14.0])
def test_a_reading_app_gets_every_frame_the_trace_says_it_received(tmp_path, procs, run_s):  # noqa: F811
    """#41: three modems flooded, one subscriber of every modem's rx SIGSTOPped, one app reading busy0's rx.
    Zenoh lets one put at a time wait for the stopped consumer's link, so the outboxes' puts wait in turn
    (2, 4, 6 ... s: measured, up to that consumer's lease).  Whatever happens, every frame the trace records
    received at busy0 after the app subscribed reached the app, or the trace's end record names it as lost
    at the edge, or Zenoh cut the app off and the trace says so (`disconnected`, with `back`).  The broker
    is stopped during the stall (4 s: frames still queued behind it, put at the stop, which a loaded reader had
    not taken when the broker's session closed: lost with Zenoh's shared memory, bus/session.SHARED_MEMORY) and
    after the stopped consumer's lease (14 s)."""
    world = "frozen"
    flows = "".join(f"<flow><name>flood{k}</name><src>src{k}</src><dst>{2 * k + 4}</dst><size>64000</size>"
                    f"<interval>0.016</interval></flow>" for k in range(3))
    vs = "".join(vehicle_xml(f"s{k}", (0, 0, 10), _fast_device(f"src{k}", 2 * k + 3))
                 + vehicle_xml(f"busy{k}", (0, 10, 10), _fast_device(f"busy{k}", 2 * k + 4)) for k in range(3))
    scene = tmp_path / "frozen.xml"
    scene.write_text(scene_xml(world=world, channels=(0, 1), flows=flows, vehicles=vs))
    b = Broker(scene, tmp_path / "t.jsonl")
    procs.append(b)
    (tmp_path / "stalled.py").write_text(STALLED)
    (tmp_path / "reader.py").write_text(READER)
    stalled = Proc([sys.executable, str(tmp_path / "stalled.py"), b.endpoint, f"uwsimnet/{world}/modem/*/rx"])
    procs.append(stalled)
    word, stalled_zid = stalled.next_line(15).split()
    assert word == "ready"
    reader = Proc([sys.executable, str(tmp_path / "reader.py"), b.endpoint, f"uwsimnet/{world}/modem/busy0/rx",
                   str(tmp_path / "got.json")], stdin=True)
    procs.append(reader)
    word, reader_zid = reader.next_line(15).split()
    assert word == "ready"
    time.sleep(1.0)
    stalled.p.send_signal(signal.SIGSTOP)
    try:
        time.sleep(run_s)
        assert b.stop(signal.SIGINT) == 0, b.output()
    finally:
        stalled.p.send_signal(signal.SIGCONT)
    lines = (tmp_path / "t.jsonl").read_text().splitlines()
    end = json.loads(lines[-1])
    assert end["ev"] == "end"
    lost = {tuple(x) for x in end.get("lost_at_edge", {}).get("busy0", {}).get("frames", [])}
    rx = [(r["src"], r["seq"]) for r in map(json.loads, lines[1:-1]) if r["ev"] == "rx" and r["dev"] == "busy0"]
    # what the broker put may still be on its way (socket buffers, the reader's Zenoh queue: ~10 MB here,
    # 150 frames, behind a reader that a loaded machine slows down): asked again until it has all arrived
    deadline = time.monotonic() + 60
    while True:
        reader.p.stdin.write("\n")
        reader.p.stdin.flush()
        assert reader.next_line(20).strip() == "done"
        got = {tuple(x) for x in json.loads((tmp_path / "got.json").read_text())}
        assert got
        first = min(seq for _, seq in got)
        recorded = [x for x in rx if x[1] >= first]
        missing = [x for x in recorded if x not in got and x not in lost]
        if not missing or time.monotonic() > deadline:
            break
        time.sleep(0.5)
    assert len(recorded) > 100
    out = b.output()
    gone = {e["zid"]: e for e in end.get("disconnected", [])}
    # under load Zenoh may cut the reading app off (its link's queue full for wait_before_close: docs/runtime.md,
    # 2 runs of 23 beside two busy loops) and let it back in: what was put meanwhile is lost, and said
    # (or cut it off for good before the run ended: disconnected, not back)
    if reader_zid not in gone:
        assert missing == [], (missing[:20], len(missing), len(recorded), gone, out[-3000:])
    elif "back" in gone[reader_zid]:
        assert f"cut off: client {reader_zid} for " in out, out
    # the stopped consumer may be closed (by its lease: not always within 14 s with a put waiting on it), but
    # stopped, it cannot have come back
    assert "back" not in gone.get(stalled_zid, {}), gone
    assert "stalled at the edge:" in out and "Traceback" not in out
    # and the frames whose put waited on the stopped consumer (it may not have them) are named with the wait
    stalled = end["stalled_at_edge"]
    assert stalled and all(w >= 0.5 and [s, q] in [[r["src"], r["seq"]] for r in map(json.loads, lines[1:-1])
                                                    if r["ev"] == "rx" and r["dev"] == dev]
                           for dev, xs in stalled.items() for s, q, w in xs), stalled
