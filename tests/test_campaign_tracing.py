"""Campaign runs carry the scene's tracing class and keep their traces on request (issue #36,
docs/campaigns.md): a user's `netTracingScript` class sees every event of every run, whether the run executes
in the sweep's process, in worker processes or on Dask workers (a real LocalCluster of processes), and a
kept trace is byte for byte the trace `uwsimnet run --trace` writes for the same scene and seed."""

from __future__ import annotations

import collections
import gzip
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from uwsimnet_zenoh.app import campaign as cp

ROOT = Path(__file__).resolve().parent.parent
TWO_NODES = ROOT / "scenes" / "examples" / "two-nodes.xml"
UWSIMNET = [sys.executable, "-m", "uwsimnet_zenoh.cli"]

COUNTER = '''\
import json, os, uuid

class Count:
    """One line per callback: the process, the instance (one per run) and the event."""

    def __init__(self):
        self.run = uuid.uuid4().hex

    def _seen(self, rec):
        with open(os.environ["TRACING_COUNTS"], "a") as f:
            f.write(json.dumps({"pid": os.getpid(), "run": self.run, "ev": rec["ev"]}) + "\\n")

    on_enq = on_tx = on_rx = on_drop = _seen
'''


def traced_scene(tmp_path: Path, cls: str = "campcount:Count") -> Path:
    """two-nodes with distance-dependent loss and Poisson traffic (the seed matters) and a tracing class."""
    text = TWO_NODES.read_text().replace("<errorRateExpr>0</errorRateExpr>                <!-- no loss -->",
                                         "<errorRateExpr>0.002*m</errorRateExpr>")
    text = text.replace("<arrival>periodic</arrival>", "<arrival>poisson</arrival>")
    text = text.replace("<UWSimScene>", f"<UWSimScene>\n  <netTracingScript><className>{cls}</className>"
                                        "</netTracingScript>", 1)
    assert cls in text
    p = tmp_path / "traced.xml"
    p.write_text(text)
    return p


@pytest.fixture
def counter(tmp_path, monkeypatch) -> Path:
    """The tracing module importable here and in every process started from here; its count file."""
    mod = tmp_path / "mods"
    mod.mkdir()
    (mod / "campcount.py").write_text(COUNTER)
    monkeypatch.syspath_prepend(str(mod))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(filter(None, [str(mod), os.environ.get("PYTHONPATH")])))
    counts = tmp_path / "counts.jsonl"
    monkeypatch.setenv("TRACING_COUNTS", str(counts))
    return counts


def trace_counts(path: Path) -> dict[str, int]:
    """Frame events per kind in a kept trace (the meta line and an end record are not frame events)."""
    recs = [json.loads(x) for x in gzip.decompress(path.read_bytes()).decode().splitlines()]
    assert recs[0]["ev"] == "meta"
    return dict(collections.Counter(r["ev"] for r in recs[1:] if r["ev"] != "end"))


@pytest.mark.parametrize("where", ["sweep-process", "2-processes", "dask-2-workers"])
def test_the_scenes_tracing_class_sees_every_event_of_every_run(tmp_path, counter, where):
    if where.startswith("dask"):
        pytest.importorskip("distributed")
    workers, scheduler = {"sweep-process": (1, None), "2-processes": (2, None), "dask-2-workers": (2, "local")}[where]
    c = cp.Campaign(scenes=[str(traced_scene(tmp_path))], sets={"device.*.bitrate": ["500", "1000"]},
                    seeds=[1, 2, 3], out=tmp_path / "o", duration=15, workers=workers, scheduler=scheduler,
                    keep_traces=True)
    rep = cp.execute(c)
    assert (rep["ran"], rep["failed"]) == (6, 0)

    lines = [json.loads(x) for x in counter.read_text().splitlines()]
    per_run: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
    per_pid: collections.Counter = collections.Counter()
    for ln in lines:
        per_run[ln["run"]][ln["ev"]] += 1
        per_pid[ln["pid"]] += 1
    # one tracing object per run, and each saw exactly the events of one run's trace
    def by_counts(d: dict) -> list:
        return sorted(d.items())
    kept = sorted((trace_counts(p) for p in (c.out / "rows").glob("*.jsonl.gz")), key=by_counts)
    seen = sorted((dict(n) for n in per_run.values()), key=by_counts)
    assert len(kept) == 6 and seen == kept
    assert sum(per_pid.values()) == sum(sum(d.values()) for d in kept)
    print(f"{where}: callbacks per run {[sum(d.values()) for d in seen]}, per process {dict(per_pid)}")
    if workers == 1:
        assert set(per_pid) == {os.getpid()}                      # in the sweep's own process
    else:
        assert os.getpid() not in per_pid and 1 <= len(per_pid) <= 2   # in the workers, none in the driver


def test_a_kept_trace_is_the_trace_uwsimnet_run_writes(tmp_path):
    out = tmp_path / "o"
    r = subprocess.run([*UWSIMNET, "sweep", str(TWO_NODES), "--seeds", "1-2", "--duration", "20", "--keep-traces",
                        "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    rows = {json.loads(p.read_text())["seed"]: p for p in (out / "rows").glob("*.json")}
    assert sorted(rows) == [1, 2]
    for seed, row in rows.items():
        ref = tmp_path / f"run{seed}.jsonl"
        done = subprocess.run([*UWSIMNET, "run", str(TWO_NODES), "--seed", str(seed), "--duration", "20",
                               "--trace", str(ref)], capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stderr
        kept = row.with_suffix(".jsonl.gz")
        assert gzip.decompress(kept.read_bytes()) == ref.read_bytes()
        rep = subprocess.run([*UWSIMNET, "report", str(kept), "--json"], capture_output=True, text=True, timeout=120)
        assert rep.returncode == 0, rep.stderr
    # kept traces are the same bytes wherever and whenever they were made (gzip without a time stamp)
    again = tmp_path / "again"
    cp.execute(cp.Campaign(scenes=[str(TWO_NODES)], seeds=[1, 2], duration=20, out=again, workers=2,
                           keep_traces=True))
    for row in rows.values():
        kept = row.with_suffix(".jsonl.gz")
        assert (again / "rows" / kept.name).read_bytes() == kept.read_bytes()


def test_keep_traces_on_a_finished_campaign_runs_only_what_has_no_trace(tmp_path):
    c = cp.Campaign(scenes=[str(TWO_NODES)], seeds=[1, 2, 3], duration=5, out=tmp_path / "o")
    assert cp.execute(c)["ran"] == 3
    assert not list((c.out / "rows").glob("*.jsonl.gz"))
    c.keep_traces = True
    (c.out / "rows" / next(iter(sorted((c.out / "rows").glob("*.json")))).name).unlink()
    dry = subprocess.run([*UWSIMNET, "sweep", str(TWO_NODES), "--seeds", "1-3", "--duration", "5", "--out", str(c.out),
                          "--dry-run", "--keep-traces"], capture_output=True, text=True, timeout=120)
    assert dry.returncode == 0 and [ln.split()[1] for ln in dry.stdout.splitlines()] == ["todo"] * 3, dry
    rep = cp.execute(c)
    assert (rep["ran"], rep["reused"]) == (3, 0) and len(list((c.out / "rows").glob("*.jsonl.gz"))) == 3
    assert (cp.execute(c)["ran"]) == 0


def test_a_campaign_file_keeps_traces(tmp_path):
    f = tmp_path / "c.toml"
    f.write_text(f'scenes = ["{TWO_NODES}"]\nseeds = "1-2"\nduration = 5\nkeep_traces = true\nout = "o"\n')
    c = cp.load_campaign(f)
    assert c.keep_traces and c.out == tmp_path / "o"
    cp.execute(c)
    assert len(list((tmp_path / "o" / "rows").glob("*.jsonl.gz"))) == 2
    f.write_text(f'scenes = ["{TWO_NODES}"]\nkeep_traces = "yes"\n')
    with pytest.raises(cp.UserError, match="keep_traces must be true or false"):
        cp.load_campaign(f)


def test_a_tracing_class_that_does_not_load_stops_the_sweep_before_any_run(tmp_path):
    scene = traced_scene(tmp_path, "nosuchmodule_x:Count")
    out = tmp_path / "o"
    r = subprocess.run([*UWSIMNET, "sweep", str(scene), "--seeds", "1-2", "--out", str(out)], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    last = r.stderr.strip().splitlines()[-1]
    line = 1 + scene.read_text().splitlines().index("  <netTracingScript><className>nosuchmodule_x:Count</className>"
                                                   "</netTracingScript>")
    assert last.startswith(f"{scene}:{line}: ") and "nosuchmodule_x:Count" in last, r.stderr
    assert not (out / "rows").exists() or not list((out / "rows").iterdir())


def test_a_tracing_class_that_raises_makes_its_run_an_error_row(tmp_path, monkeypatch):
    mod = tmp_path / "mods"
    mod.mkdir()
    (mod / "campbad.py").write_text("class Bad:\n    def on_rx(self, rec):\n        raise RuntimeError('boom')\n")
    monkeypatch.syspath_prepend(str(mod))
    c = cp.Campaign(scenes=[str(traced_scene(tmp_path, "campbad:Bad"))], seeds=[1], duration=10, out=tmp_path / "o",
                    keep_traces=True)
    rep = cp.execute(c)
    rows = [json.loads(p.read_text()) for p in (c.out / "rows").glob("*.json")]
    assert rep["failed"] == 1 and rows[0]["status"] == "error"
    assert "tracing class campbad:Bad raised RuntimeError: boom" in rows[0]["error"]
    assert not list((c.out / "rows").glob("*.jsonl.gz"))
