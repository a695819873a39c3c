"""The HIL formation experiment (virtual time): scene files match their generator, followers keep formation."""

from __future__ import annotations

from pathlib import Path

import pytest

from uwsimnet_zenoh.experiments import hil_formation
from uwsimnet_zenoh.experiments import hil_spec as h
from uwsimnet_zenoh.scene.load import load_scene


def test_scene_files_match_the_generator():
    for traffic in h.TRAFFIC:
        for mac in h.PROTOCOLS:
            path = h.scene_path(mac, traffic)
            assert path.read_text() == h.scene_xml(mac, traffic), \
                f"rewrite with: python -m {h.__name__} --write-scenes"
            scene = load_scene(path)
            assert {v.name for v in scene.vehicles if v.pose_source == "zenoh"} == set(h.VEHICLES)
            assert scene.world == h.world_name(mac, traffic)


def test_paper_traffic_adds_the_section_3_2_image_flows():
    """'The transmission fluxes were the same as those indicated in Section 3.2': each BlueROV (an explorer
    there) sends 400-byte frames to the operator (the buoy) at Table 1's rate for the MAC."""
    for mac, bps in h.IMAGE_BYTES_PER_S.items():
        flows = load_scene(h.scene_path(mac, "paper")).flows
        assert {f.src for f in flows} == {f"{n}-modem" for n in h.VEHICLES}
        for f in flows:
            assert f.dst == h.OPERATOR[1] and f.size == 400
            assert f.size / f.interval == pytest.approx(bps, rel=1e-5)
        assert not load_scene(h.scene_path(mac, "control")).flows


def test_timing_splits_the_leader_positions_delay():
    r = hil_formation.simulate("aloha", duration=30.0, traffic="control")
    t = r["timing"]
    assert t["delivered"] == t["frames"] > 10
    # an unhindered broadcast: 50 ms intrinsic on the way out, then 24 B at 6900 bit/s and the nearest
    # follower's distance (1.5 m in formation, a little more while the leader pulls away) at 1500 m/s
    assert t["queue_mean"] == pytest.approx(h.INTRINSIC_MS / 1e3, abs=1e-6)
    frame = 24 * 8 / h.BITRATE
    assert frame + 1.4 * 0.6667e-3 < t["air_mean"] < frame + 2.0 * 0.6667e-3
    assert t["delay_mean"] == pytest.approx(t["queue_mean"] + t["access_mean"] + t["air_mean"], abs=1e-9)


def test_formation_converges_with_both_macs(tmp_path: Path):
    stats = hil_formation.run(tmp_path, duration=110.0, traffic="control", seeds=[1])   # two waypoint changes
    assert (tmp_path / "fig9-hil-formation.png").stat().st_size > 10_000
    for mac in h.PROTOCOLS:
        st = stats[mac]
        for n in h.VEHICLES:
            assert st[n]["settled_mean"] < 0.1, (mac, n, st[n])     # in place 30 s after each change
            assert st[n]["final"] < 0.1
        assert st["delivery"]["leader_positions"] > 0.9
    # S-FAMA's handshakes delay the leader's positions: the followers lag more than with CS-ALOHA
    assert stats["sfama"]["follower1"]["mean"] > stats["aloha"]["follower1"]["mean"]


def test_traffic_option_applies_to_hil_formation_only(tmp_path: Path):
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "uwsimnet_zenoh.cli", "experiment", "phy-layer", "--traffic", "paper",
                        "--out", str(tmp_path)], capture_output=True, text=True)
    assert r.returncode == 2 and r.stderr.strip() == "uwsimnet experiment: --traffic applies to hil-formation only"
    r = subprocess.run([sys.executable, "-m", "uwsimnet_zenoh.cli", "experiment", "hil-formation", "--virtual",
                        "--traffic", "heavy", "--out", str(tmp_path)], capture_output=True, text=True)
    assert r.returncode == 2 and "--traffic" in r.stderr and "Traceback" not in r.stderr


def test_with_the_image_flows_s_fama_lags_because_its_positions_queue():
    """The paper traffic (docs/paper-hil.md): S-FAMA's followers are further from formation than
    CS-ALOHA's, and the trace says why: the leader's position frames wait in its modem's queue (behind image
    frames and their handshakes) many times longer than with CS-ALOHA; on air they take the same time."""
    o = hil_formation.over_seeds("paper", h.DURATION, seeds=(1, 2))
    assert all(r > 1.3 for r in o["ratio_followers"]), o["ratio_followers"]
    for seed in (1, 2):
        a = hil_formation.simulate("aloha", seed=seed, traffic="paper")["timing"]
        s = hil_formation.simulate("sfama", seed=seed, traffic="paper")["timing"]
        assert s["queue_mean"] > 3 * a["queue_mean"] and s["queue_mean"] > 0.5 * s["delay_mean"]
        assert s["air_mean"] == pytest.approx(a["air_mean"], abs=1e-3)
        assert s["rts_per_frame"] >= 1.0 and a["rts_per_frame"] == 0
