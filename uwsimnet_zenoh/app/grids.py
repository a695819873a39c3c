"""Bellhop grids of a campaign computed before its runs, on the campaign's own workers (docs/ocean.md).

Every run builds its network, and a network whose channel model is `bellhop` computes the grids it misses;
a sweep's runs would each compute the same grids at once, each on one worker.  So the campaign builds each
distinct (scene, overrides) that uses bellhop once, first, with the grid jobs (one per grid and source
depth) on its executor: its process pool, or its Dask cluster through `Client.get_executor()`.  The runs then
find the grids in the cache."""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from concurrent.futures import Executor
from typing import Any

from ..engine.network import Network
from ..phy.bellhop import grid_executor
from .overrides import apply
from .virtual import load_scene_file


def uses_bellhop(scene: Any) -> bool:
    return any(c.model is not None and c.model.name == "bellhop" for c in scene.channels)


def precompute(jobs: Iterable[Mapping[str, Any]], executor: Executor) -> int:
    """Build, once per distinct (scene, overrides) that uses bellhop, the network of `jobs` (campaign run
    specs) with the grid jobs on `executor`; how many were built.  A failure is left to the run, which records
    it in its row."""
    seen: set[tuple[str, str]] = set()
    built = 0
    with grid_executor(executor):
        for j in jobs:
            key = (str(j["scene"]), json.dumps(j["overrides"], sort_keys=True, default=str))
            if key in seen:
                continue
            seen.add(key)
            try:
                sc = apply(load_scene_file(str(j["scene"])), j["overrides"])
                if uses_bellhop(sc):
                    Network(sc, seed=j["seed"], duration=j["duration"])
                    built += 1
            except Exception:  # noqa: BLE001, S112 - the run itself fails with this error and records it
                continue
    return built
