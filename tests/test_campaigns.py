"""Campaigns (docs/campaigns.md): the run API, override paths, sweeps on 1 and 2 processes and on a Dask
LocalCluster giving identical rows, resume after an interruption, failed runs recorded, intervals."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

import uwsimnet_zenoh as uw
from uwsimnet_zenoh.analysis import flow_metrics
from uwsimnet_zenoh.analysis.intervals import mean_ci, t975, wilson
from uwsimnet_zenoh.app import campaign as cp
from uwsimnet_zenoh.app.overrides import apply
from uwsimnet_zenoh.app.virtual import load_scene_file, run_virtual
from uwsimnet_zenoh.errors import UserError

ROOT = Path(__file__).resolve().parent.parent
TWO_NODES = ROOT / "scenes" / "examples" / "two-nodes.xml"


def lossy(tmp_path: Path) -> Path:
    """two-nodes with a distance-dependent loss and Poisson traffic: results that depend on the seed."""
    text = TWO_NODES.read_text().replace("<errorRateExpr>0</errorRateExpr>                <!-- no loss -->",
                                         "<errorRateExpr>0.002*m</errorRateExpr>")
    text = text.replace("<arrival>periodic</arrival>", "<arrival>poisson</arrival>")
    p = tmp_path / "lossy.xml"
    p.write_text(text)
    return p


# -- the run API and overrides ---------------------------------------------------------------------------
def test_run_gives_the_metrics_uwsimnet_report_gives(tmp_path):
    r = uw.run(TWO_NODES, seed=1)
    sc = load_scene_file(str(TWO_NODES))
    run_virtual(sc, seed=1, duration=None, trace_path=tmp_path / "t.jsonl", progress=False)
    ref = {n: m.to_dict() for n, m in flow_metrics(tmp_path / "t.jsonl").items()}
    assert r.flows == ref
    ch = r.channels[0]
    assert ch["frames"] == ref[next(iter(ref))]["sent"] and ch["collisions"] == 0
    assert ch["airtime"] == pytest.approx(ch["bytes"] * 8 / 1000)


def test_overrides_change_what_runs():
    base = uw.run(TWO_NODES, seed=1)
    name = next(iter(base.flows))
    faster = uw.run(TWO_NODES, seed=1, overrides={f"flow.{name}.rate": "2"})
    assert faster.flows[name]["enqueued"] == 2 * base.flows[name]["enqueued"]
    far = uw.run(TWO_NODES, seed=1, overrides={"vehicle.bravo.position": "200 0 10"})
    # 100 m farther at 0.6667 ms/m: every delay 66.67 ms longer
    assert far.flows[name]["delay_mean"] - base.flows[name]["delay_mean"] == pytest.approx(0.06667, abs=1e-6)
    slow = uw.run(TWO_NODES, seed=1, overrides={"device.*.bitrate": "500"})
    assert slow.flows[name]["delay_mean"] - base.flows[name]["delay_mean"] == pytest.approx(32 * 8 / 1000, abs=1e-6)


@pytest.mark.parametrize("path, value, says", [
    ("device.nope.bitrate", "1", "no device 'nope' (the scene has: alpha-modem, bravo-modem)"),
    ("device.*.colour", "1", "unknown device field 'colour'"),
    ("device.*.bitrate", "-3", "bitrate: Input should be greater than 0"),
    ("device.*.bitrate", "fast", "bitrate: Input should be a valid number"),
    ("device.*.mac", "fama", "unknown MAC protocol 'fama'"),
    ("device.*.mac", "antigravity:Fly", "a MAC given as module:Class belongs in a scene you wrote"),
    ("device.*.error.expr", "m +* 2", "override device.*.error.expr:"),
    ("flow.x.rate", "1", "no flow 'x'"),
    ("flow.*.rate", "0", "rate must be a finite number > 0"),
    ("channel.0.prop_s_per_m", "-1", "greater than or equal to 0"),
    ("vehicle.alpha.position", "1 2", "expected three numbers"),
    ("wind.speed", "3", "unknown path"),
])
def test_a_bad_override_is_one_line_naming_its_path(path, value, says):
    with pytest.raises(UserError) as e:
        apply(load_scene_file(str(TWO_NODES)), {path: value})
    assert str(e.value).startswith(f"override {path}") and says in str(e.value) and "\n" not in str(e.value)


def test_sweep_with_a_bad_path_exits_2_and_runs_nothing(tmp_path):
    out = tmp_path / "o"
    r = subprocess.run([sys.executable, "-m", "uwsimnet_zenoh.cli", "sweep", str(TWO_NODES), "--set",
                        "device.*.bitrat=1,2", "--seeds", "1-3", "--out", str(out)], capture_output=True, text=True)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr.strip().splitlines()[-1].startswith("override device.*.bitrat: unknown device field")
    assert not (out / "rows").exists() or not list((out / "rows").iterdir())


@pytest.mark.parametrize("text, seeds", [("3", [3]), ("1-4", [1, 2, 3, 4]), ("1-3,2,7", [1, 2, 3, 7])])
def test_seed_lists(text, seeds):
    assert cp.parse_seeds(text) == seeds


@pytest.mark.parametrize("bad", ["", "a", "3-1", "1-", "-2"])
def test_bad_seed_lists(bad):
    with pytest.raises(UserError, match="--seeds"):
        cp.parse_seeds(bad)


def test_a_campaign_files_scheduler_is_not_connected_to_unconfirmed(tmp_path):
    """A listening socket stands for the scheduler: without --scheduler naming it, sweep refuses in one line
    and never connects (issue #41); `out` is relative to the file."""
    import socket

    with socket.socket() as srv:
        srv.bind(("127.0.0.1", 0))
        srv.listen(1)
        srv.settimeout(0.5)
        addr = f"tcp://127.0.0.1:{srv.getsockname()[1]}"
        f = tmp_path / "c.toml"
        f.write_text(f'scenes = ["{TWO_NODES}"]\nscheduler = "{addr}"\nout = "o"\n')
        assert cp.load_campaign(f).out == tmp_path / "o"
        r = subprocess.run([sys.executable, "-m", "uwsimnet_zenoh.cli", "sweep", str(f)], capture_output=True,
                           text=True, timeout=120)
        assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
        assert r.stderr.strip().splitlines() == [
            f"{f}: scheduler {addr!r}: a campaign file does not connect to a scheduler on its own;"
            f" confirm with --scheduler {addr} (or --scheduler local)"]
        with pytest.raises(TimeoutError):
            srv.accept()                    # nobody connected
    assert not (tmp_path / "o").exists()


def test_dry_run_lists_the_runs_and_runs_none(tmp_path):
    out = tmp_path / "o"
    r = subprocess.run([sys.executable, "-m", "uwsimnet_zenoh.cli", "sweep", str(TWO_NODES), "--seeds", "1-3",
                        "--set", "device.*.bitrate=500,1000", "--out", str(out), "--dry-run"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.strip().splitlines()
    assert len(lines) == 2 * 3 and all(" todo " in x for x in lines)
    assert {x.split()[-1] for x in lines} == {"device.*.bitrate=500", "device.*.bitrate=1000"}
    assert not out.exists()


def test_an_interrupted_sweep_says_what_is_kept_and_how_to_resume(tmp_path):
    import signal
    import time

    out = tmp_path / "o"
    # started as a script's background job is (SIGINT ignored, POSIX; `trap "" INT` then exec): it still stops
    p = subprocess.Popen(["sh", "-c", 'trap "" INT; exec "$0" "$@"', sys.executable, "-m", "uwsimnet_zenoh.cli",
                          "sweep", str(TWO_NODES), "--seeds", "1-5000", "--out", str(out)],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not (out / "rows").is_dir() or not any((out / "rows").glob("*.json")):
        assert p.poll() is None, p.communicate()
        assert time.monotonic() < deadline, "no run finished"
        time.sleep(0.05)
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=120)
    assert p.returncode == 130 and "Traceback" not in err, err
    kept = len(list((out / "rows").glob("*.json")))
    assert err.strip().splitlines()[-1] == (f"uwsimnet sweep: interrupted; {kept} finished run(s) kept in {out}/rows;"
                                            " the same command resumes with the missing runs only")


# -- where runs execute does not change them ----------------------------------------------------------
def _rows(out: Path) -> list[dict]:
    return [json.loads(p.read_text()) for p in sorted((out / "rows").glob("*.json"))]


def test_identical_rows_on_1_and_2_processes_and_on_dask(tmp_path):
    scene = lossy(tmp_path)
    sets = {"device.*.bitrate": ["500", "1000"]}
    results = {}
    for label, workers, sched in (("one", 1, None), ("two", 2, None), ("dask", 2, "local")):
        pytest.importorskip("dask.distributed") if sched else None
        c = cp.Campaign(scenes=[str(scene)], sets=sets, seeds=[1, 2, 3], out=tmp_path / label, duration=15,
                        workers=workers, scheduler=sched)
        rep = cp.execute(c)
        assert rep["ran"] == 6 and rep["failed"] == 0
        results[label] = _rows(tmp_path / label)
    assert results["one"] == results["two"] == results["dask"]
    name = next(k for k in results["one"][0] if k.endswith(".delivered"))
    assert len({r[name] for r in results["one"]}) > 1           # the seeds do matter
    summary = json.loads((tmp_path / "one" / "summary.json").read_text())
    assert set(summary) == {"device.*.bitrate=500", "device.*.bitrate=1000"}
    if "pyarrow" in sys.modules or pytest.importorskip("pyarrow"):
        import pyarrow.parquet as pq

        t = pq.read_table(tmp_path / "one" / "results.parquet")
        assert t.num_rows == 6 and "param.device.*.bitrate" in t.column_names


def test_an_interrupted_campaign_resumes_with_the_missing_runs_only(tmp_path):
    c = cp.Campaign(scenes=[str(lossy(tmp_path))], sets={"flow.*.rate": ["0.5", "1"]}, seeds=[1, 2, 3],
                    out=tmp_path / "o", duration=5)

    def stop_after_two(n, total, row):
        if n == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        cp.execute(c, on_progress=stop_after_two)
    assert len(_rows(c.out)) == 2
    rep = cp.execute(c)
    assert (rep["ran"], rep["reused"], rep["runs"]) == (4, 2, 6)
    again = cp.execute(c)
    assert (again["ran"], again["reused"]) == (0, 6)
    fresh = cp.Campaign(**{**c.__dict__, "out": tmp_path / "fresh"})
    cp.execute(fresh)
    assert _rows(c.out) == _rows(fresh.out)                      # resuming changed nothing


def test_a_failing_run_is_recorded_and_the_others_complete(tmp_path):
    # maxRetries -2 passes the override check (a text parameter) and fails when the MAC is built (-1: no limit)
    c = cp.Campaign(scenes=[str(TWO_NODES)], sets={"device.*.mac": ["aloha"], "device.*.mac.maxRetries": ["2", "-2"]},
                    seeds=[1, 2], out=tmp_path / "o", duration=10)
    rep = cp.execute(c)
    rows = _rows(c.out)
    bad = [r for r in rows if r["status"] == "error"]
    assert rep["failed"] == 2 and len(rows) == 4 and len(bad) == 2
    assert all(r["param.device.*.mac.maxRetries"] == "-2" and "maxRetries: must be >= -1" in r["error"] for r in bad)
    assert "## Failed runs" in (c.out / "summary.md").read_text()


def test_campaign_file(tmp_path):
    scene = lossy(tmp_path)
    f = tmp_path / "c.toml"
    f.write_text(f'scenes = ["{scene.name}"]\nseeds = "1-2"\nduration = 10\nout = "{tmp_path / "o"}"\n'
                 '[set]\n"device.*.bitrate" = [500, 1000]\n')
    c = cp.load_campaign(f)
    assert c.scenes == [str(scene)] and c.seeds == [1, 2] and c.sets == {"device.*.bitrate": [500, 1000]}
    assert cp.execute(c)["runs"] == 4
    f.write_text('scenes = ["x.xml"]\ncolour = 1\n')
    with pytest.raises(UserError, match="unknown key"):
        cp.load_campaign(f)


# -- intervals --------------------------------------------------------------------------------------
def test_intervals_against_tables():
    assert t975(1) == 12.706 and t975(9) == 2.262 and t975(35) == 2.042 and t975(1000) == 1.96
    iv = mean_ci([1.0, 2.0, 3.0, 4.0, 5.0])
    assert iv.mean == 3.0 and iv.half == pytest.approx(2.776 * math.sqrt(2.5 / 5))
    assert mean_ci([7.0]).half is None and mean_ci([]) is None
    lo, hi = wilson(5, 10)                                        # Wilson 95 %: 0.2366 .. 0.7634
    assert lo == pytest.approx(0.2366, abs=1e-4) and hi == pytest.approx(0.7634, abs=1e-4)
    assert wilson(0, 20)[0] == 0.0 and wilson(0, 20)[1] == pytest.approx(0.1611, abs=1e-4)


def test_phy_layer_per_over_seeds_pools_frames_and_gives_wilson_intervals():
    from uwsimnet_zenoh.experiments import phy_layer
    from uwsimnet_zenoh.scene.load import load_scene

    rf = load_scene(phy_layer.SCENES / "phy-layer-rf.xml")
    traces = [uw.run(rf, seed=s, trace=True).trace for s in (1, 2, 3)]
    one = phy_layer.loss_over_seeds(traces[:1])
    three = phy_layer.loss_over_seeds(traces)
    assert [r["bin_m"] for r in one] == [r["bin_m"] for r in three]
    for a, b in zip(one, three, strict=True):
        assert b["frames"] == 3 * a["frames"]                     # the same positions, new loss draws
        lo, hi = b["ci95"]
        assert lo <= b["observed_per"] <= hi and hi - lo < a["ci95"][1] - a["ci95"][0] + 1e-12
    assert sum(r["inside"] for r in three) >= len(three) - 2       # the BER formula within nearly every interval


def test_experiment_seeds_only_where_they_apply(tmp_path):
    r = subprocess.run([sys.executable, "-m", "uwsimnet_zenoh.cli", "experiment", "hil-formation", "--seeds", "1-3",
                        "--out", str(tmp_path)], capture_output=True, text=True)
    assert r.returncode == 2
    assert r.stderr.strip() == "uwsimnet experiment: --seeds applies to phy-layer, twinbot and table1"


def test_a_huge_seed_range_is_one_line_not_a_list_built_first():
    with pytest.raises(UserError, match="more than 100000 runs"):
        cp.parse_seeds("1-99999999999999")
    scene = str(ROOT / "scenes/examples/two-nodes.xml")
    r = subprocess.run([sys.executable, "-m", "uwsimnet_zenoh.cli", "sweep", scene, "--seeds", "0-99999999999999",
                        "--out", "/nonexistent/never"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "--seeds" in r.stderr, r.stderr


def test_the_code_is_part_of_a_runs_key(tmp_path, monkeypatch):
    """A sweep after a change of the sources re-runs, never reuses rows of other code (issue #36)."""
    from uwsimnet_zenoh.app import api

    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "a.py").write_text("X = 1\n")
    before = api.sources_digest([pkg])
    (pkg / "a.py").write_text("X = 2\n")
    assert api.sources_digest([pkg]) != before
    ours = api.sources_digest([ROOT / "uwsimnet_zenoh", ROOT / "gli_clients/python/uwsimnet_gli"])
    assert api.version().endswith("+src." + ours[:12])
    c = cp.Campaign(scenes=[str(lossy(tmp_path))], sets={}, seeds=[1, 2], out=tmp_path / "o", duration=5)
    assert (cp.execute(c)["ran"], cp.execute(c)["reused"]) == (2, 2)
    monkeypatch.setattr(cp, "version", lambda: "0.1.0+src.changed")
    rep = cp.execute(c)
    assert (rep["ran"], rep["reused"]) == (2, 0)


def test_an_override_never_imports_a_module(tmp_path):
    """`--set device.*.mac=MODULE:Class` from a command line or a campaign file imports nothing (issue #41)."""
    (tmp_path / "sideeffect_probe.py").write_text("open(__file__ + '.imported', 'w').close()\n")
    r = subprocess.run([sys.executable, "-m", "uwsimnet_zenoh.cli", "sweep", str(TWO_NODES), "--set",
                        "device.*.mac=sideeffect_probe:Mac", "--seeds", "1", "--out", str(tmp_path / "o")],
                       capture_output=True, text=True, timeout=120, cwd=tmp_path,
                       env={**os.environ, "PYTHONPATH": str(tmp_path)})
    assert r.returncode == 2 and "module:Class" in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert not (tmp_path / "sideeffect_probe.py.imported").exists()


def test_a_mac_that_cannot_carry_its_load_shows_its_fifo(tmp_path):
    """S-FAMA at CS-ALOHA's TWINBOT rates (RF 62.5 B/s per flow, above S-FAMA's 34 B/s maximum,
    docs/paper-twinbot.md): every frame that went on air arrives (delivery ratio 1), so only the FIFO
    columns show the load it cannot carry; both are counted again here from the run's own trace."""
    r = uw.run(ROOT / "scenes/paper/twinbot-aloha.xml", seed=1, duration=200, overrides={"device.*.mac": "sfama"},
               trace=True)
    for name in ("leader", "follower"):
        recs = [x for x in r.trace if x.get("flow") == name and x.get("kind") == "data"]
        enq = {x["seq"] for x in recs if x["ev"] == "enq"}
        on_air = {x["seq"] for x in recs if x["ev"] == "tx"}
        refused = {x["seq"] for x in recs if x["ev"] == "drop" and x["reason"] == "fifo"}
        m = {k.split(".")[-1]: v for k, v in r.row().items() if k.startswith(f"flow.{name}.")}
        assert (m["fifo_drops"], m["left_in_fifo"]) == (len(refused), len(enq - on_air - refused))
        assert m["delivery_ratio"] >= 0.99 and m["fifo_drops"] + m["left_in_fifo"] > 0.3 * m["enqueued"], m
    carried = uw.run(ROOT / "scenes/paper/twinbot-sfama.xml", seed=1, duration=200).row()
    assert carried["flow.leader.fifo_drops"] == 0 and carried["flow.leader.left_in_fifo"] <= 2
