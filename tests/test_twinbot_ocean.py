"""The TWINBOT acoustic group in a summer thermocline (docs/ocean.md; experiments/twinbot_ocean.py): the doc's
numbers against the command that makes them, and the runs against ray theory.  No Bellhop needed: the grid is
the one Bellhop made for this scene, shipped in tests/data/twinbot-ocean/bellhop/ (tests/data/make_bellhop_grid.py)."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from uwsimnet_zenoh.experiments import twinbot_ocean

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data" / "twinbot-ocean"
UWSIMNET = str(Path(sys.executable).parent / "uwsimnet")


@pytest.fixture
def shipped_grid(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("UWSIMNET_CACHE", str(DATA))


def test_the_example_scene_is_the_generators() -> None:
    assert twinbot_ocean.SCENE.read_text(encoding="utf-8") == twinbot_ocean.scene_xml()


def _env(**kw: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "UWSIMNET_BELLHOP"}
    return {**env, "UWSIMNET_CACHE": str(DATA), **kw}


def test_the_docs_numbers_are_the_commands(tmp_path: Path) -> None:
    """docs/ocean.md's table is what `uwsimnet experiment twinbot-ocean` prints (seeds 1-10, byte for byte:
    virtual time), and the command writes the figures the doc shows."""
    r = subprocess.run([UWSIMNET, "experiment", "twinbot-ocean", "--out", str(tmp_path)], env=_env(),
                       capture_output=True, text=True, timeout=1800)
    assert r.returncode == 0, r.stderr
    rows = ("| NOMAC |", "| CS-ALOHA |", "| S-FAMA |")
    made = [ln for ln in (tmp_path / "summary.md").read_text().splitlines() if ln.startswith(rows)]
    doc = (ROOT / "docs" / "ocean.md").read_text(encoding="utf-8")
    section = doc[doc.index("## TWINBOT in a summer thermocline"):]
    shown = [ln for ln in section.splitlines() if ln.startswith(rows)]
    assert len(shown) == 24
    assert shown == made
    for name in ("links.png", "delay.png", "tl-field-E3.png", "tl-field-buoy.png"):
        assert (tmp_path / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_without_bellhop_or_grid_one_line(tmp_path: Path) -> None:
    r = subprocess.run([UWSIMNET, "experiment", "twinbot-ocean", "--seeds", "1", "--out", str(tmp_path / "o")],
                       env=_env(UWSIMNET_CACHE=str(tmp_path), UWSIMNET_BELLHOP=str(tmp_path / "none")),
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr
    assert "twinbot-thermocline.xml:" in r.stderr and "Bellhop not found" in r.stderr


# -- theory: Mackenzie (1981) for the preset's points, straight rays where lit, the bottom image in the shadow
def _mackenzie(t: float, s: float, d: float) -> float:
    return (1448.96 + 4.591 * t - 5.304e-2 * t ** 2 + 2.374e-4 * t ** 3 + 1.340 * (s - 35) + 1.630e-2 * d
            + 1.675e-7 * d ** 2 - 1.025e-2 * t * (s - 35) - 7.139e-13 * t * d ** 3)


PROFILE = [(d, _mackenzie(t, 37.0, d)) for d, t in ((0.0, 24.0), (10.0, 22.5), (40.0, 14.0), (300.0, 13.5))]
"""The summer-thermocline preset as docs/ocean.md states it: temperatures at four depths, S = 37 ppt."""


def _c(z: float) -> float:
    for (d0, c0), (d1, c1) in zip(PROFILE, PROFILE[1:], strict=False):
        if z <= d1:
            return c0 + (c1 - c0) * (max(z, d0) - d0) / (d1 - d0)
    return PROFILE[-1][1]


def _harmonic(a: float, b: float, n: int = 4000) -> float:
    """Harmonic mean of c over depths a..b (the travel-time mean of a ray through the layers)."""
    lo, hi = min(a, b), max(a, b)
    h = (hi - lo) / n
    return (hi - lo) / sum(h / _c(lo + (k + 0.5) * h) for k in range(n))


def _delays(trace: Path, flow: str, dev: str, ev: tuple[str, ...]) -> list[tuple[float, float]]:
    """(straight-line distance from the record, propagation delay) of the flow's frames at dev:
    outcome time - first bit - frame duration (1900 bps)."""
    tx, out = {}, []
    for line in trace.read_text().splitlines():
        r = json.loads(line)
        if r["ev"] == "tx" and r.get("flow") == flow:
            tx[r["seq"]] = (r["t"], r["size"])
        elif r["ev"] in ev and r.get("flow") == flow and r["dev"] == dev and r["seq"] in tx:
            if r["ev"] == "drop" and r.get("reason") != "prop":
                continue
            t0, size = tx[r["seq"]]
            out.append((r["dist"], r["t"] - t0 - size * 8 / 1900))
    return out


def test_lit_links_straight_rays_and_the_shadow_the_bottom_image(shipped_grid: None, tmp_path: Path) -> None:
    """One NOMAC run with Bellhop: the buoy's frames at the lit explorers (440-470 m) arrive after the
    straight-line time at the harmonic-mean speed between the two depths (within 0.5 ms); the north explorer's
    frames at the buoy (650-680 m, in the shadow) are lost in most cases, and those the buoy hears or loses
    arrive by the bottom-reflected path: the image source 2 x 1000 m down, at the water column's harmonic mean
    speed (within 1 %)."""
    run = twinbot_ocean.run_one("nomac", "bellhop", 1, tmp_path)
    c_lit = _harmonic(twinbot_ocean.BUOY_DEPTH, twinbot_ocean.EXPLORER_DEPTH)
    lit = _delays(run["trace"], "buoy", "e0-acomm", ("rx",))
    assert len(lit) > 50
    for dist, delay in lit:
        assert abs(delay - dist / c_lit) < 5e-4, (dist, delay, dist / c_lit)
    e3 = run["links"][("E3", "buoy-acomm")]
    assert e3["delivered"] < 0.15 * e3["offered"]
    shadow = _delays(run["trace"], "E3", "buoy-acomm", ("rx", "drop"))
    assert len(shadow) > 20
    c_col = _harmonic(0.0, 1000.0)
    zs, zr = twinbot_ocean.EXPLORER_DEPTH, twinbot_ocean.BUOY_DEPTH
    for dist, delay in shadow:
        r = math.sqrt(dist ** 2 - (zs - zr) ** 2)
        bounce = math.hypot(r, 2 * 1000.0 - zs - zr) / c_col
        assert abs(delay - bounce) < 0.01 * bounce, (dist, delay, bounce)
        assert delay > 2.5 * dist / c_lit                     # not the straight path's
    straight = twinbot_ocean.run_one("nomac", "straight", 1, tmp_path)["links"][("E3", "buoy-acomm")]
    assert straight["delivered"] > 0.85 * straight["offered"]
