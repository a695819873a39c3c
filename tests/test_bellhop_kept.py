"""The channel model "bellhop" keeps its answers (docs/ocean.md, "Kept answers"): a kept answer is the one the
grid gives at that geometry, and a pose that changes is never answered from before the change.  The
interpolation itself is checked against Bellhop and theory elsewhere (test_bellhop*.py); here the reference
is the same model with nothing kept."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from uwsimnet_zenoh.engine.network import Network
from uwsimnet_zenoh.kernel.frame import Frame
from uwsimnet_zenoh.mobility.trajectory import PoseTable
from uwsimnet_zenoh.phy import bellhop
from uwsimnet_zenoh.phy.models import Query
from uwsimnet_zenoh.scene import load_scene

DATA = Path(__file__).resolve().parent / "data"


@pytest.fixture
def model(monkeypatch: pytest.MonkeyPatch) -> bellhop.BellhopModel:
    monkeypatch.setenv("UWSIMNET_CACHE", str(DATA))
    monkeypatch.setenv("UWSIMNET_BELLHOP", "/nonexistent/bellhop")
    return Network(load_scene(DATA / "ocean-shadow.xml")).modems["buoy-modem"].error


def _fresh(model: bellhop.BellhopModel, q: Query) -> np.ndarray:
    """The answer with nothing kept, as an array (per, delay, level, Doppler) x receivers."""
    model._memo.clear()
    model._links.clear()
    return _arr(model.answer(q))


def _arr(ans: object) -> np.ndarray:
    return np.array([list(c) for c in ans], dtype=float)          # type: ignore[union-attr]


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal doubles, nan (beyond the grid) where nan."""
    return a.shape == b.shape and bool(np.array_equal(a, b, equal_nan=True))


def _q(poses: PoseTable, n: int, size: int = 32) -> Query:
    pts = poses.points(0.0)
    return Query(0.0, Frame(1, 2, 0, size, size), [math.dist(pts[0], pts[i + 1]) for i in range(n)],
                 list(range(n)), poses, 0, list(range(1, n + 1)))


@pytest.mark.parametrize("n", [1, 3, bellhop.MANY + 8])
def test_still_network_kept_until_a_pose_changes(model: bellhop.BellhopModel, n: int) -> None:
    poses = PoseTable(["tx"] + [f"rx{i}" for i in range(n)])
    poses.set_static("tx", (0.0, 0.0, -10.0))
    for i in range(n):
        poses.set_static(f"rx{i}", (300.0 + 60.0 * i, 0.0, -20.0))       # 300 m (lit) to the shadow
    assert not poses.moving
    q = _q(poses, n)
    first = model.answer(q)
    assert model.answer(_q(poses, n)) is first                            # kept
    assert _same(_arr(first), _fresh(model, q))
    assert _same(_arr(model.answer(_q(poses, n, size=64))), _fresh(model, _q(poses, n, size=64)))
    poses.set_static(f"rx{n - 1}", (1000.0, 0.0, -100.0))                # a dive below the layer
    moved = _arr(model.answer(_q(poses, n)))
    assert _same(moved, _fresh(model, _q(poses, n)))
    assert moved[1][-1] != first.delay[-1]                                 # not the answer from before the move


def test_moving_table_keeps_links_whose_ends_are_unchanged(model: bellhop.BellhopModel) -> None:
    """Poses from Zenoh (the table is `moving`): a vehicle that sends the same state again keeps its links'
    answers; one that moved, or changed speed, is answered anew."""
    poses = PoseTable(["tx", "a", "b"])
    for name in poses.names:
        poses.set_external(name)
    poses.update("tx", 0.0, (0.0, 0.0, -10.0))
    poses.update("a", 0.0, (800.0, 0.0, -20.0))
    poses.update("b", 0.0, (1000.0, 0.0, -20.0), (0.0, 0.0, -1.0))
    assert poses.moving
    before = _arr(model.answer(_q(poses, 2)))
    assert _same(before, _fresh(model, _q(poses, 2)))
    model.answer(_q(poses, 2))
    poses.update("a", 0.5, (800.0, 0.0, -20.0))                           # the same state again
    assert len(model._links) == 2
    assert _same(_arr(model.answer(_q(poses, 2))), before)
    assert len(model._links) == 2                                         # answered from the kept links
    poses.update("b", 0.5, (1000.0, 0.0, -20.0), (0.0, 0.0, -2.0))        # faster: another arrival point
    again = _arr(model.answer(_q(poses, 2)))
    assert _same(again, _fresh(model, _q(poses, 2)))
    assert again[1][1] != before[1][1]


def test_receivers_out_of_reach_are_not_looked_up(monkeypatch: pytest.MonkeyPatch, model: bellhop.BellhopModel) -> None:
    """A receiver beyond the sender's maxDistance is dropped by the channel (`range`) without reading the
    model's answer: the model answers it lost without a lookup, and every other receiver as before."""
    from uwsimnet_zenoh.scene import load_scene_text

    text = (DATA / "ocean-shadow.xml").read_text().replace(
        "<sourceLevel>184</sourceLevel>", "<sourceLevel>184</sourceLevel><maxDistance>500</maxDistance>", 1)
    near = Network(load_scene_text(text, str(DATA / "ocean-shadow.xml"))).modems["buoy-modem"].error
    assert near.reach == (0.0, 500.0)
    poses = PoseTable(["tx", "a", "b"])
    poses.set_static("tx", (0.0, 0.0, -10.0))
    poses.set_static("a", (300.0, 0.0, -20.0))
    poses.set_static("b", (1000.0, 0.0, -100.0))
    calls = []
    real = near._point
    monkeypatch.setattr(near, "_point", lambda *a: calls.append(a) or real(*a))
    got = _arr(near.answer(_q(poses, 2)))
    assert len(calls) == 1                                                # only the receiver in reach
    full = _fresh(model, _q(poses, 2))
    assert _same(got[:, 0], full[:, 0])
    assert got[0, 1] == 1.0 and full[0, 1] < 1.0                          # b: lost unread, though lit
