"""Bellhop grids computed in parallel (phy/bellhop_grid.py `compute_grids`, app/grids.py): one job per (grid,
source depth) on worker threads each running Bellhop as a process, or on a campaign's executor (a process
pool, a Dask cluster's); a progress line on stderr per job; the same bytes as one job after the other.  With
the real Bellhop (`make bellhop`); skipped, saying so, without it."""

from __future__ import annotations

import re
from concurrent.futures import Executor, Future, ProcessPoolExecutor, ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from uwsimnet_zenoh.app.grids import precompute
from uwsimnet_zenoh.phy import bellhop
from uwsimnet_zenoh.phy.ocean import PRESETS

PROGRAM = bellhop.find_program()
pytestmark = pytest.mark.skipif(PROGRAM is None, reason="Bellhop is not installed (`make bellhop`)")
DATA = Path(__file__).resolve().parent / "data"
PROFILE = list(zip(PRESETS["summer-thermocline"][1].depths, PRESETS["summer-thermocline"][1].speeds, strict=True))
SEABED = (1550.0, 1.5, 1.0)
RDS = [float(z) for z in np.arange(1.0, 100.0, 6.0)]
RRS = [float(r) for r in np.arange(50.0, 801.0, 50.0)]
LINE = re.compile(r"bellhop: grid (\d)/3 source depth (\d+) m at 26 kHz ... \d+\.\d s")


def _specs() -> list[bellhop.GridSpec]:
    """Two missing grids: two source depths at 26 kHz, one at 26 kHz over another seabed."""
    return [bellhop.GridSpec(26_000.0, PROFILE, 100.0, SEABED, [10.0, 40.0], RDS, RRS),
            bellhop.GridSpec(26_000.0, PROFILE, 100.0, (1700.0, 1.9, 0.5), [20.0], RDS, RRS)]


def _same(a: list[bellhop.Grid], b: list[bellhop.Grid]) -> None:
    assert len(a) == len(b) == 2
    for x, y in zip(a, b, strict=True):
        for name in ("sd", "rd", "rr", "tl", "delay", "spread", "late"):
            assert getattr(x, name).tobytes() == getattr(y, name).tobytes(), name


def test_two_missing_grids_on_two_workers_are_the_bytes_of_one_after_the_other(capfd):
    assert PROGRAM is not None
    one = bellhop.compute_grids(PROGRAM, _specs(), workers=1)
    capfd.readouterr()
    two = bellhop.compute_grids(PROGRAM, _specs(), workers=2)
    lines = capfd.readouterr().err.splitlines()
    _same(one, two)
    assert sorted(int(m.group(1)) for m in map(LINE.fullmatch, lines) if m) == [1, 2, 3], lines
    assert sorted(int(LINE.fullmatch(x).group(2)) for x in lines) == [10, 20, 40]     # every job once
    with ProcessPoolExecutor(max_workers=2) as pool, bellhop.grid_executor(pool):   # a campaign's processes
        _same(one, bellhop.compute_grids(PROGRAM, _specs(), workers=1))
    assert np.isfinite(one[0].tl).mean() > 0.9 and not np.array_equal(one[0].tl[0], one[1].tl[0])


class Counting(Executor):
    """A thread pool that counts the jobs handed to it (the campaign's executor, seen from outside)."""

    def __init__(self) -> None:
        self.pool = ThreadPoolExecutor(max_workers=2)
        self.jobs = 0

    def submit(self, fn: Any, /, *args: Any, **kwargs: Any) -> Future:
        self.jobs += 1
        return self.pool.submit(fn, *args, **kwargs)

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        self.pool.shutdown(wait=wait, cancel_futures=cancel_futures)


def test_a_campaign_computes_each_grid_once_on_its_executor_before_the_runs(tmp_path, monkeypatch, capfd):
    """Three runs of two distinct scenes (two seeds of one): the grids of each (one source depth each) on the
    campaign's executor once; the runs then load them (no progress line)."""
    monkeypatch.setenv("UWSIMNET_CACHE", str(tmp_path))
    text = (DATA / "ocean-shadow.xml").read_text().replace("<maxRange>2000</maxRange>", "<maxRange>400</maxRange>")
    scenes = []
    for depth in ("60", "80"):
        p = tmp_path / f"s{depth}.xml"
        p.write_text(text.replace("<maxDepth>200</maxDepth>", f"<maxDepth>{depth}</maxDepth>"))
        scenes.append(p)
    jobs = [{"scene": str(s), "overrides": {}, "seed": seed, "duration": 5.0}
            for s, seed in ((scenes[0], 1), (scenes[0], 2), (scenes[1], 1))]
    ex = Counting()
    with ex:
        assert precompute(jobs, ex) == 2
    assert ex.jobs == 2 and len(list((tmp_path / "bellhop").glob("*.npz"))) == 2
    assert len(capfd.readouterr().err.splitlines()) == 2
    from uwsimnet_zenoh.app.campaign import run_one
    row = run_one({**jobs[1], "key": "k", "scene_name": "s", "version": "v"})
    assert row["status"] == "ok", row
    assert "bellhop:" not in capfd.readouterr().err


def test_the_grids_run_on_a_dask_cluster_through_its_executor(tmp_path, monkeypatch):
    distributed = pytest.importorskip("distributed", reason="dask.distributed (extra 'campaigns') is absent")
    assert PROGRAM is not None
    one = bellhop.compute_grids(PROGRAM, _specs(), workers=1)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                                  dashboard_address=None) as cluster, distributed.Client(cluster) as client:
        with bellhop.grid_executor(client.get_executor(pure=False)), \
                distributed.get_task_stream(client=client) as stream:       # what the scheduler ran, recorded
            on_dask = bellhop.compute_grids(PROGRAM, _specs(), workers=1)   # as it ran (its task groups are
        keys = [str(t["key"]) for t in stream.data]                          # forgotten once released)
        assert sum("depth_job" in k for k in keys) == sum(len(s.sds) for s in _specs()), keys
    _same(one, on_dask)
