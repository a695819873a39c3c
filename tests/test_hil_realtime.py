"""The HIL formation experiment in one command, for real: a router, two channel brokers (CS-ALOHA and
S-FAMA worlds), `uwsimnet vehicles`, the leader's pose from an outside process, and five applications per
world, each its own process over Zenoh on loopback.  Shortened to one waypoint leg (the change at 20 s).
What it shows: frames flowed between the processes (the apps' own counts), the leader drove towards the
commanded waypoint and the followers kept formation, and the real-time errors agree with the
virtual-time model of the same scene."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from uwsimnet_zenoh.analysis import conservation
from uwsimnet_zenoh.experiments import hil_spec as spec
from uwsimnet_zenoh.experiments.hil_apps import Follower, Goto, Leader, Send, first_due, make_app
from uwsimnet_zenoh.experiments.hil_formation import delivery

pytest.importorskip("uwsimnet_gli")
DURATION = 34.0


def test_apps_are_plain_state_machines():
    op, leader, f1 = make_app("operator"), make_app("leader"), make_app("follower1")
    assert isinstance(leader, Leader) and isinstance(f1, Follower)
    [w] = op.on_timer(20.0, None)
    assert w.dst == spec.VEHICLES["leader"][0] and len(w.data) == spec.PAYLOAD
    assert leader.on_frame(5, w.data) == [Goto((6.0, 0.0, spec.DEPTH))]
    assert leader.on_frame(5, w.data) == []                      # the same waypoint again: no new command
    [p] = leader.on_timer(22.05, (1.0, 2.0, -5.0))
    assert p.dst == 255
    assert f1.on_frame(1, p.data) == [Goto((1.0 - spec.SIDE, 2.0, -5.0))]
    assert f1.on_frame(1, b"X" * spec.PAYLOAD) == [] and f1.on_frame(1, b"") == []
    [t] = f1.on_timer(0.3, (0.0, 0.0, 0.0))
    assert isinstance(t, Send) and t.dst == spec.OPERATOR[1] and t.data[:1] == b"T"
    assert f1.on_timer(5.3, None) == []                         # no pose yet: nothing to report
    assert first_due(leader, 0.0) == 0.05 and first_due(leader, 3.0) == pytest.approx(4.05)
    assert first_due(op, 8.0) == 8.0
    with pytest.raises(ValueError, match="no application"):
        make_app("nobody")


def test_formation_errors_follow_the_papers_definition():
    d = spec.DEPTH
    poses = {"leader": (3.0, 0.0, d), "follower1": (1.5, 0.0, d), "follower2": (3.0, -2.5, d)}
    e = spec.formation_errors(25.0, poses)
    assert e["leader"] == pytest.approx(3.0)             # commanded (6, 0) since 20 s
    assert e["follower1"] == pytest.approx(0.0)          # exactly at leader + (-1.5, 0)
    assert e["follower2"] == pytest.approx(1.0)
    assert "follower3" not in e


def _rec(ev: str, dev: str, src: int, seq: int, dst: int, reason: str | None = None) -> dict:
    r = {"t": 1.0, "ev": ev, "ch": 0, "dev": dev, "src": src, "dst": dst, "seq": seq, "size": 24, "flow": None,
         "kind": "data"}
    return r | ({"reason": reason} if reason else {})


def test_delivery_leaves_out_only_what_the_stop_left_without_an_outcome():
    """A frame lost (retry) counts against delivery; one still queued at the stop (`stopped`) does not, for
    the receivers that had not got it; a broadcast that reached one follower before the stop counts there."""
    op, ld = spec.OPERATOR[1], spec.VEHICLES["leader"][0]
    recs = [_rec("enq", "operator-modem", op, s, ld) for s in range(3)]
    recs += [_rec("rx", "leader-modem", op, 0, ld), _rec("drop", "operator-modem", op, 1, ld, "retry"),
             _rec("drop", "operator-modem", op, 2, ld, "stopped")]
    recs += [_rec("enq", "leader-modem", ld, s, 255) for s in range(2)]
    recs += [_rec("rx", "follower1-modem", ld, 0, 255), _rec("rx", "follower2-modem", ld, 0, 255),
             _rec("rx", "follower1-modem", ld, 1, 255), _rec("drop", "leader-modem", ld, 1, 255, "stopped")]
    d = delivery(recs)
    assert d["waypoints"] == 0.5                      # 1 of 2: the stopped one is out, the retried one is not
    assert d["leader_positions"] == 3 / 4             # frame 0: 2 of 3; frame 1: follower1 got it, 1 of 1
    assert d["telemetry"] == 0.0                      # no telemetry frame at all


def test_one_command_runs_the_hil_experiment_as_processes(tmp_path: Path):
    out = tmp_path / "hil"
    # the control-only traffic: with the Sec. 3.2 image flows (the default) S-FAMA's leader positions wait
    # seconds behind image frames and the formation bound below does not hold on one leg (docs/paper-hil.md)
    r = subprocess.run([sys.executable, "-m", "uwsimnet_zenoh.cli", "experiment", "hil-formation",
                        "--traffic", "control", "--duration", f"{DURATION:g}", "--out", str(out)],
                       capture_output=True, text=True, timeout=DURATION + 120)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    # piped: the progress is plain lines (a rich bar would print nothing), from 0 to the end
    progress = [ln for ln in r.stdout.splitlines() if ln.startswith("HIL formation, real time: ")]
    assert progress[0].startswith("HIL formation, real time: 0/") and progress[-1].endswith("(100%)"), r.stdout
    assert (out / "fig9-hil-formation.png").stat().st_size > 20_000
    logs = out / "logs"
    for mac in spec.PROTOCOLS:
        for part in ("broker", "vehicles", "robot", "operator", *spec.VEHICLES):
            assert (logs / f"{mac}-{part}.log").exists(), (mac, part)
        # the apps' own counts: each received frames from another process through its world's broker
        for name in ("operator", *spec.VEHICLES):
            last = (logs / f"{mac}-{name}.log").read_text().strip().splitlines()[-1]
            assert "received" in last and int(last.rsplit(" ", 1)[1]) > 0, (mac, name, last)
        assert not conservation(out / f"{mac}.trace.jsonl"), mac
    s = json.loads((out / "summary.json").read_text())
    assert s["traffic"] == "control"
    for mac in spec.PROTOCOLS:
        assert s["realtime"][mac]["timing"]["delivered"] > 0, s["realtime"][mac]["timing"]   # read from the trace
        rt, model = s["realtime"][mac], s["virtual"][mac]
        assert rt["delivery"]["waypoints"] > 0.8, (mac, rt["delivery"])
        # the leader got the 20 s waypoint (6 m away) and drove towards it at up to 0.3 m/s
        assert 6.0 - 0.3 * (DURATION - 20) - 0.3 < rt["leader"]["final"] < 5.0, (mac, rt["leader"])
        for n in spec.VEHICLES:
            # the same run in wall time: within 0.5 m of the model's mean error (0.35 m seen under a load of 6
            # on 2 cores; a formation that broke is off by metres)
            assert abs(rt[n]["mean"] - model[n]["mean"]) < 0.5, (mac, n, rt[n], model[n])
            if n != "leader":
                assert rt[n]["max"] < 2.5, (mac, n, rt[n])   # formation kept: within ~one leg update


def test_sigterm_stops_every_process(tmp_path: Path):
    """SIGTERM (or Ctrl-C) during the run stops the children too: the command exits 130 and, last of
    all, the router no longer listens."""
    import re
    import signal
    import socket
    import time

    out = tmp_path / "hil"
    p = subprocess.Popen([sys.executable, "-m", "uwsimnet_zenoh.cli", "experiment", "hil-formation", "--duration", "60",
                          "--out", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        last = out / "logs" / "sfama-follower3.log"              # the last process started
        deadline = time.monotonic() + 60
        while not (last.exists() and "ready" in last.read_text()):
            assert p.poll() is None and time.monotonic() < deadline, p.communicate()
            time.sleep(0.1)
        p.send_signal(signal.SIGTERM)
        _, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 130 and "interrupted" in err, err
    port = int(re.search(r"tcp/127\.0\.0\.1:(\d+)", (out / "logs" / "router.log").read_text()).group(1))
    with socket.socket() as s:
        assert s.connect_ex(("127.0.0.1", port)) != 0                # the router is gone
