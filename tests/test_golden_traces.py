"""Every scene under scenes/ gives the same trace, byte for byte, as when these hashes were recorded.

A change that alters a trace on purpose (a model fix) updates tests/golden_traces.json in the same commit and
says why; a refactor never does.  Runs are capped at 60 s of simulated time (a few seconds of CPU in all).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from uwsimnet_zenoh.app.virtual import load_scene_file, run_virtual

ROOT = Path(__file__).resolve().parent.parent
GOLDEN = json.loads((Path(__file__).parent / "golden_traces.json").read_text())
CASES = [(scene, seed) for scene, seeds in sorted(GOLDEN["sha256"].items()) for seed in seeds]


def test_every_scene_has_a_golden_hash():
    scenes = {str(p.relative_to(ROOT)) for p in (ROOT / "scenes").rglob("*.xml")}
    assert scenes == set(GOLDEN["sha256"])


@pytest.mark.parametrize("scene, seed", CASES)
def test_trace_is_byte_identical(scene, seed, tmp_path, monkeypatch):
    monkeypatch.setenv("UWSIMNET_CACHE", str(ROOT / "tests" / "data" / "twinbot-ocean"))  # the Bellhop scene's grid
    sc = load_scene_file(str(ROOT / scene))
    duration = min(sc.simulation.duration or GOLDEN["duration_cap_s"], GOLDEN["duration_cap_s"])
    out = tmp_path / "t.jsonl"
    run_virtual(sc, seed=int(seed), duration=duration, trace_path=out, progress=False)
    assert hashlib.sha256(out.read_bytes()).hexdigest() == GOLDEN["sha256"][scene][seed]
