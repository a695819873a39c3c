"""The first arrival where it changes path (docs/ocean.md "Where the first arrival changes path"): in a grid
cell whose corners' first arrivals are different paths (the direct path at one, the bottom bounce a second
later at the next), the model follows one path instead of mixing them.  Without Bellhop: the grids Bellhop
made for tests/data/ocean-shadow.xml and the TWINBOT scene (tests/data/make_bellhop_grid.py), the three
lookups against each other and against the corners; with the real program (skipped when absent): the model
against a direct Bellhop run at 30 random points in those cells."""

from __future__ import annotations

import math
import random
import tempfile
from pathlib import Path

import numpy as np
import pytest

from uwsimnet_zenoh.engine.network import Network
from uwsimnet_zenoh.phy import bellhop
from uwsimnet_zenoh.phy.bellhop_grid import _trilinear
from uwsimnet_zenoh.scene import load_scene

DATA = Path(__file__).resolve().parent / "data"
SCENE = DATA / "ocean-shadow.xml"
GRIDS = [next((DATA / "bellhop").glob("*.npz")), next((DATA / "twinbot-ocean" / "bellhop").glob("*.npz"))]


def _points(grid: bellhop.Grid, n: int, seed: int, frac: float | None = None) -> np.ndarray:
    """n points (source depth, receiver depth, range) in the grid's path-change cells: uniform in the cell,
    or `frac` of the way from a random corner along the receiver's depth and range."""
    rnd = random.Random(seed)
    cells = [tuple(int(x) for x in c) for c in np.argwhere(grid.path_changes())]
    out = []
    for i, j, k in rnd.sample(cells, n):
        def at(ax: np.ndarray, m: int) -> float:
            t = rnd.random() if frac is None else (frac if rnd.random() < 0.5 else 1 - frac)
            return float(ax[m] + t * (ax[min(m + 1, len(ax) - 1)] - ax[m]))
        out.append((at(grid.sd, i), at(grid.rd, j), at(grid.rr, k)))
    return np.array(out)


def _corners(grid: bellhop.Grid, zs: float, zr: float, r: float) -> np.ndarray:
    idx = []
    for ax, q in ((grid.sd, zs), (grid.rd, zr), (grid.rr, r)):
        m = int(np.clip(np.searchsorted(ax, q, side="right") - 1, 0, max(len(ax) - 2, 0)))
        idx.append((m, min(m + 1, len(ax) - 1)))
    return np.array([grid.delay[a, b, c] for a in idx[0] for b in idx[1] for c in idx[2]])


@pytest.mark.parametrize("path", GRIDS, ids=["ocean-shadow", "twinbot"])
def test_a_delay_in_a_path_change_cell_is_one_paths_time(path: Path) -> None:
    """In every path-change cell, the delay is within 0.1 s of a corner's time (a path's time near there;
    the paths differ by about a second).  Plain trilinear interpolation is not, at most of these points (this
    test bites); the cells are found on both shipped grids (the shadow's edges)."""
    grid = bellhop.Grid.load(path)
    assert grid.path_changes().sum() > 100
    pts = _points(grid, 100, 1)
    _, dl = grid.lookup(pts[:, 0], pts[:, 1], pts[:, 2])
    plain = _trilinear(grid.sd, grid.rd, grid.rr, grid.delay, pts[:, 0], pts[:, 1], pts[:, 2])
    mixed = 0
    for (zs, zr, r), d, p in zip(pts, dl, plain, strict=True):
        corners = _corners(grid, zs, zr, r)
        assert np.abs(corners - d).min() < 0.1, (zs, zr, r, d, corners)
        mixed += np.abs(corners - p).min() > 0.1
    assert mixed >= 50, mixed


@pytest.mark.parametrize("path", GRIDS, ids=["ocean-shadow", "twinbot"])
def test_outside_path_change_cells_the_delay_is_the_trilinear_one_bit_for_bit(path: Path) -> None:
    grid = bellhop.Grid.load(path)
    rng = np.random.default_rng(5)
    zs = rng.uniform(grid.sd[0], grid.sd[-1], 5000)
    zr, r = rng.uniform(0.0, grid.rd[-1], 5000), rng.uniform(grid.rr[0], grid.rr[-1], 5000)
    _, dl = grid.lookup(zs, zr, r)
    plain = _trilinear(grid.sd, grid.rd, grid.rr, grid.delay, zs, zr, r)
    changed = dl != plain
    assert 0 < changed.sum() < 5000 * 0.2
    i = np.clip(np.searchsorted(grid.sd, zs, side="right") - 1, 0, max(len(grid.sd) - 2, 0))
    j = np.clip(np.searchsorted(grid.rd, zr, side="right") - 1, 0, len(grid.rd) - 2)
    k = np.clip(np.searchsorted(grid.rr, r, side="right") - 1, 0, len(grid.rr) - 2)
    assert np.array_equal(changed, grid.path_changes()[i, j, k] & changed)
    assert not changed[~grid.path_changes()[i, j, k]].any()


def test_the_buoy_between_a_bounce_and_the_direct_path(monkeypatch: pytest.MonkeyPatch) -> None:
    """The case docs/ocean.md tells: from E3's depth (15 m), at 700 m, the first arrival at 1 m is the bottom
    bounce (1.400 s) and at 2 m the direct path (0.455 s).  Between them the delay is one or the other, as the
    nearer depth says, never the 1.02 s mix."""
    grid = bellhop.Grid.load(GRIDS[1])
    s = int(np.flatnonzero(grid.sd == 5.0)[0])
    j1, j2, k = int(np.flatnonzero(grid.rd == 1.0)[0]), int(np.flatnonzero(grid.rd == 2.0)[0]), \
        int(np.flatnonzero(grid.rr == 700.0)[0])
    bounce, direct = grid.delay[s, j1, k], grid.delay[s, j2, k]
    assert bounce > 1.3 and direct < 0.5
    for zr, want in ((1.1, bounce), (1.4, bounce), (1.6, direct), (1.9, direct)):
        assert grid.lookup([5.0], [zr], [700.0])[1][0] == pytest.approx(want, abs=1e-3)


def test_the_models_three_lookups_agree_in_path_change_cells(monkeypatch: pytest.MonkeyPatch) -> None:
    """A frame's few receivers (Python floats), many receivers (numpy) and `Grid.lookup` give one delay."""
    monkeypatch.setenv("UWSIMNET_CACHE", str(DATA))
    model = Network(load_scene(SCENE)).modems["buoy-modem"].error
    grid = model.grid
    pts = _points(grid, 60, 2)
    pts = pts[pts[:, 0] == grid.sd[0]] if len(grid.sd) == 1 else pts
    tx = type("Tx", (), {"position": (0.0, 0.0, -float(grid.sd[0]))})()
    pos = np.array([(r, 0.0, -zr) for _, zr, r in pts])
    off_s = 0.0
    few = [model._at(tx, tuple(p), float(grid.sd[0]), off_s)[1] for p in pos]
    many = model._at_many(np.array(tx.position), pos, off_s)[1]
    ref = grid.lookup(np.full(len(pts), grid.sd[0]), pts[:, 1], pts[:, 2])[1]
    assert np.allclose(few, ref, rtol=0, atol=1e-12) and np.allclose(many, ref, rtol=0, atol=1e-12)


PROGRAM = bellhop.find_program()


@pytest.mark.skipif(PROGRAM is None, reason="Bellhop is not installed (`make bellhop`)")
@pytest.mark.parametrize("frac", [0.1, None], ids=["near-a-corner", "anywhere"])
def test_against_bellhop_in_path_change_cells(frac: float | None, monkeypatch: pytest.MonkeyPatch) -> None:
    """30 random points in the ocean-shadow grid's path-change cells, each run by Bellhop: where the model's
    path is Bellhop's (within 0.1 s), its time is within 0.5 ms; it is Bellhop's path at 15-17 of them (the
    shadow's edge lies anywhere in a cell); plain trilinear interpolation is within 0.5 ms at none
    (docs/ocean.md's table)."""
    monkeypatch.setenv("UWSIMNET_CACHE", str(DATA))
    grid = bellhop.Grid.load(GRIDS[0])
    scene = load_scene(SCENE)
    env = scene.environment
    assert env is not None
    seabed = (env.seabed_speed_mps, env.seabed_density, env.seabed_attenuation)
    profile = [tuple(p) for p in env.profile]
    freq = Network(scene).modems["buoy-modem"].error.freq_hz
    pts = _points(grid, 30, 37, frac)
    same = plain_ok = 0
    worst = 0.0
    for zs, zr, r in pts:
        with tempfile.TemporaryDirectory() as d:
            arr = bellhop.run_bellhop(PROGRAM, bellhop.env_text(freq, profile, env.depth_m, seabed, [zs], [zr], [r],
                                                                "A"), "arr", d)
        first = float(bellhop.read_arrivals(arr.decode())[0][0, 0, 0])
        assert math.isfinite(first)
        got = float(grid.lookup([zs], [zr], [r])[1][0])
        plain = float(_trilinear(grid.sd, grid.rd, grid.rr, grid.delay, *(np.array([x]) for x in (zs, zr, r)))[0])
        if abs(got - first) < 0.1:
            same += 1
            worst = max(worst, abs(got - first))
        plain_ok += abs(plain - first) < 0.5e-3
    print(f"frac {frac}: same path {same}/30 (worst {worst * 1e3:.3f} ms), plain within 0.5 ms {plain_ok}/30")
    assert worst < 0.5e-3 and same >= 12 and plain_ok <= 3, (same, worst, plain_ok)
