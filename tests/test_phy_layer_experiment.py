"""The main job (`make paper`): the paper's physical-layer experiment (Sec. 3.1, Figs. 3-4) run as users
run it, its summary checked against the model and the paper's qualitative findings."""

from __future__ import annotations

from pathlib import Path

import pytest

from uwsimnet_zenoh.experiments import phy_layer
from uwsimnet_zenoh.scene.load import load_scene


def test_delay_formula_is_the_scenes():
    scene = load_scene(phy_layer.SCENES / "phy-layer-acoustic.xml")
    f = phy_layer.delay_formula(scene, phy_layer.FLOW)
    # intrinsic 1 ms + 0.6667 ms/m + (22 payload + 8 header) bytes at 1800 bit/s
    for d in (0.0, 0.8, 4.5):
        assert f(d) == pytest.approx(0.001 + 0.6667e-3 * d + 30 * 8 / 1800, abs=1e-12)


@pytest.fixture(scope="module")
def summary(tmp_path_factory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("phy")
    return out, phy_layer.run(out, progress=False)


def test_figures_and_summary_are_written(summary):
    out, s = summary
    assert (out / "summary.md").read_text().startswith("#")
    for variant in ("rf", "acoustic"):
        figs = [Path(p) for p in s[variant]["figures"]]
        assert figs and all(p.stat().st_size > 10_000 for p in figs)


def test_loss_follows_the_ber_expression(summary):
    _, s = summary
    rows = s["rf"]["loss_vs_distance"]
    assert sum(r["frames"] for r in rows) > 200                    # rov0 alone, before rov1 sends at 37 s
    assert all(abs(r["z"]) < 4 for r in rows), rows


def test_delay_alone_is_the_formula_and_grows_when_both_send(summary):
    _, s = summary
    d = s["acoustic"]["delay"]
    assert d["alone_max_formula_error_s"] < 1e-6                  # trace distances are kept to the mm
    assert d["both_max_s"] > d["alone_max_s"] + 0.05              # queueing behind the other flow (Fig. 4)
    assert d["after_mean_s"] == pytest.approx(d["alone_min_s"], abs=0.01)   # back to the 3.3 m figure


def test_loss_mechanisms_by_stage(summary):
    """Fig. 3: attenuation losses only past 4 m, both mechanisms when rov1 starts at 4.5 m, collisions
    alone at 3.3 m, nothing lost at 0.8 m."""
    _, s = summary
    st = {(r["flow"], r["stage"]): r for r in s["rf"]["stages"]}
    f = phy_layer.FLOW
    assert st[(f, "0.8 m hold")]["prop"] == st[(f, "0.8 m hold")]["col"] == 0
    assert st[(f, "moving away")]["prop"] > 0 and st[(f, "moving away")]["col"] == 0
    assert st[(f, "both send, 4.5 m")]["col"] > 0 and st[(f, "both send, 4.5 m")]["mult"] > 0
    assert st[(f, "both send, 3.3 m")]["col"] > 0 and st[(f, "both send, 3.3 m")]["prop"] == 0
