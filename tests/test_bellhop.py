"""The channel model "bellhop" (issue #37 c).  Without Bellhop: the shadow zone of tests/data/ocean-shadow.xml
from the grid Bellhop made (tests/data/bellhop/, by tests/data/make_bellhop_grid.py) against the straight-path
model, and the one-line refusal that says how to get Bellhop.  With the real program (skipped when absent):
TL and first arrival at 20 random geometries, the cached grid against a direct Bellhop run."""

from __future__ import annotations

import json
import math
import os
import random
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

from uwsimnet_zenoh.engine.network import Network
from uwsimnet_zenoh.phy import bellhop
from uwsimnet_zenoh.phy.ocean import PRESETS
from uwsimnet_zenoh.scene import load_scene, load_scene_text

DATA = Path(__file__).resolve().parent / "data"
SCENE = DATA / "ocean-shadow.xml"


def run(text: str) -> list[dict]:
    net = Network(load_scene_text(text, str(SCENE)))
    rec: list[dict] = []
    net.tracer.add(rec.append)
    net.run()
    return rec


def outcomes(rec: list[dict]) -> dict[float, str]:
    """tx time of each frame of the flow -> its outcome at the AUV (rx or the drop reason)."""
    tx = {r["seq"]: r["t"] for r in rec if r["ev"] == "tx" and r["dev"] == "buoy-modem"}
    out = {}
    for r in rec:
        if r["dev"] == "auv-modem" and r["ev"] in ("rx", "drop"):
            out[tx[r["seq"]]] = "rx" if r["ev"] == "rx" else r["reason"]
    assert len(out) == len(tx) == 100
    return out


def test_frames_are_lost_in_the_shadow_zone_and_delivered_below_the_layer(monkeypatch):
    monkeypatch.setenv("UWSIMNET_CACHE", str(DATA))
    monkeypatch.setenv("UWSIMNET_BELLHOP", "/nonexistent/bellhop")    # the shipped grid, not the program
    ray = outcomes(run(SCENE.read_text()))
    shallow = [o for t, o in ray.items() if t < 60]                   # the AUV at 20 m, 1000 m away
    deep = [o for t, o in ray.items() if t > 90]                      # the AUV at 100 m
    assert len(shallow) == 30 and set(shallow) == {"prop"}
    assert len(deep) == 54 and set(deep) == {"rx"}
    # the straight-path acoustic model (the same scene, no <channelModel>) delivers every frame
    start, end = SCENE.read_text().index("<channelModel>\n"), SCENE.read_text().index("</channelModel>")
    straight = outcomes(run(SCENE.read_text()[:start] + SCENE.read_text()[end + len("</channelModel>"):]))
    assert set(straight.values()) == {"rx"}


def test_the_delay_is_bellhops_first_arrival(monkeypatch):
    monkeypatch.setenv("UWSIMNET_CACHE", str(DATA))
    monkeypatch.setenv("UWSIMNET_BELLHOP", "/nonexistent/bellhop")    # the shipped grid, whatever Bellhop is here
    rec = run(SCENE.read_text())
    tx = {r["seq"]: r["t"] for r in rec if r["ev"] == "tx" and r["dev"] == "buoy-modem"}
    grid = bellhop.Grid.load(next((DATA / "bellhop").glob("*.npz")))
    first = float(grid.lookup([10.0], [100.0], [1000.0])[1][0])
    air = 32 * 8 / 13900
    late = [r["t"] - tx[r["seq"]] - air for r in rec if r["ev"] == "rx" and tx[r["seq"]] > 90]
    assert late and all(abs(d - first) < 1e-9 for d in late)
    assert abs(first - math.dist((0, 0, -10), (1000, 0, -100)) / 1507.0) < 5e-3    # ~ the straight path


def test_without_bellhop_a_scene_that_asks_for_it_fails_in_one_line_saying_how(tmp_path):
    env = {"UWSIMNET_CACHE": str(tmp_path), "UWSIMNET_BELLHOP": "/nonexistent/bellhop",
           "PATH": "/usr/bin:/bin", "PYTHONPATH": str(Path(bellhop.__file__).resolve().parents[2])}
    p = subprocess.run([sys.executable, "-m", "uwsimnet_zenoh.cli", "validate", str(SCENE)], capture_output=True,
                       text=True, env=env, timeout=120)
    line = SCENE.read_text()[:SCENE.read_text().index("<channelModel>\n")].count("\n") + 1
    err = p.stderr.strip().splitlines()
    assert p.returncode == 2 and len(err) == 1, p.stderr
    assert err[0].startswith(f"{SCENE}:{line}: ") and "make bellhop" in err[0] and "Traceback" not in p.stderr


PROGRAM = bellhop.find_program()


@pytest.mark.skipif(PROGRAM is None, reason="Bellhop is not installed (`make bellhop`)")
def test_cached_grid_against_a_direct_bellhop_run_at_20_random_geometries(monkeypatch):
    monkeypatch.setenv("UWSIMNET_CACHE", str(DATA))
    grid = bellhop.Grid.load(next((DATA / "bellhop").glob("*.npz")))
    scene = load_scene(SCENE)
    env = scene.environment
    prof = PRESETS["summer-thermocline"][1]
    assert env is not None and list(env.profile) == list(zip(prof.depths, prof.speeds, strict=True))
    seabed = (env.seabed_speed_mps, env.seabed_density, env.seabed_attenuation)
    profile = [tuple(p) for p in env.profile]
    freq = Network(scene).modems["buoy-modem"].error.freq_hz      # the device's carrier: the grid's frequency
    rnd = random.Random(37)
    worst_tl = worst_dt = 0.0
    for _ in range(20):
        zr, r = rnd.uniform(1.0, 199.0), rnd.uniform(30.0, 1990.0)
        with tempfile.TemporaryDirectory() as d:
            shd = bellhop.run_bellhop(PROGRAM, bellhop.env_text(freq, profile, env.depth_m, seabed, [10.0], [zr],
                                                                [r], "I"), "shd", d)
        with tempfile.TemporaryDirectory() as d:
            arr = bellhop.run_bellhop(PROGRAM, bellhop.env_text(freq, profile, env.depth_m, seabed, [10.0], [zr],
                                                                [r], "A"), "arr", d)
        _, _, _, p = bellhop.read_shd(shd)
        first, _, _ = bellhop.read_arrivals(arr.decode())
        tl, dl = grid.lookup([10.0], [zr], [r])
        worst_tl = max(worst_tl, abs(tl[0] + 20 * math.log10(abs(p[0, 0, 0]))))
        worst_dt = max(worst_dt, abs(dl[0] - first[0, 0, 0]))
    print(f"worst TL error {worst_tl:.3f} dB, worst first-arrival error {worst_dt * 1e3:.4f} ms")
    assert worst_tl < 1.0 and worst_dt < 0.5e-3, (worst_tl, worst_dt)


@pytest.mark.skipif(PROGRAM is None, reason="Bellhop is not installed (`make bellhop`)")
def test_a_missing_grid_is_computed_and_cached(tmp_path, monkeypatch):
    monkeypatch.setenv("UWSIMNET_CACHE", str(tmp_path))
    text = SCENE.read_text().replace("<maxRange>2000</maxRange>", "<maxRange>600</maxRange>").replace(
        "<maxDepth>200</maxDepth>", "<maxDepth>60</maxDepth>")
    net = Network(load_scene_text(text, str(SCENE)))
    path = net.modems["buoy-modem"].error.path
    assert path.exists() and path.parent == tmp_path / "bellhop"
    again = Network(load_scene_text(text, str(SCENE)))          # from the cache: the same grid
    assert (again.modems["auv-modem"].error.grid.tl == net.modems["buoy-modem"].error.grid.tl).all()


def test_uwsimnet_run_writes_the_shadow_in_its_trace(tmp_path):
    env = {**os.environ, "UWSIMNET_CACHE": str(DATA), "UWSIMNET_BELLHOP": "/nonexistent/bellhop"}
    trace = tmp_path / "shadow.jsonl"
    p = subprocess.run([sys.executable, "-m", "uwsimnet_zenoh.cli", "run", str(SCENE), "--trace", str(trace)],
                       capture_output=True, text=True, env=env, timeout=300)
    assert p.returncode == 0, p.stderr
    rec = [json.loads(line) for line in trace.read_text().splitlines()]
    got = outcomes([r for r in rec if "ev" in r and "seq" in r])
    assert [o for t, o in sorted(got.items()) if t < 60] == ["prop"] * 30
    assert [o for t, o in sorted(got.items()) if t > 90] == ["rx"] * 54


def test_plot_draws_the_tl_field_of_the_bellhop_link(tmp_path):
    env = {**os.environ, "UWSIMNET_CACHE": str(DATA), "UWSIMNET_BELLHOP": "/nonexistent/bellhop"}
    trace = tmp_path / "shadow.jsonl"
    cli = [sys.executable, "-m", "uwsimnet_zenoh.cli"]
    assert subprocess.run([*cli, "run", str(SCENE), "--trace", str(trace)], env=env, capture_output=True,
                          timeout=300).returncode == 0
    p = subprocess.run([*cli, "plot", str(trace), "-o", str(tmp_path / "fig"), "--scene", str(SCENE)], env=env,
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    png = tmp_path / "fig" / "tl-field-down.png"
    assert str(png) in p.stdout.split() and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_moving_receiver_gets_the_delay_where_the_sound_reaches_it(monkeypatch):
    monkeypatch.setenv("UWSIMNET_CACHE", str(DATA))
    from uwsimnet_zenoh.phy import testing

    model = Network(load_scene(SCENE)).modems["buoy-modem"].error
    h = testing.Harness(model)
    still = h.answer([(1000.0, 0.0, -100.0)], tx=(0.0, 0.0, -10.0))
    v = (4.0, 0.0, 0.0)
    moving = h.answer([(1000.0, 0.0, -100.0)], tx=(0.0, 0.0, -10.0), rx_velocities=[v])
    d = moving.delay[0]
    at = h.answer([(1000.0 + 4.0 * d, 0.0, -100.0)], tx=(0.0, 0.0, -10.0))      # still, where it arrived
    assert abs(d - at.delay[0]) < 1e-9 and d > still.delay[0]
    c = model.profile.mean_speed(10.0, 100.0)
    u = (1000.0 + 4.0 * d) / math.hypot(1000.0 + 4.0 * d, 90.0)
    assert abs(moving.doppler[0] - (c - 4.0 * u) / c) < 1e-12 and still.doppler[0] == 1.0


def test_delay_spread_loss_is_opt_in_and_follows_its_formula(monkeypatch):
    """<isi>on</isi>: Eb/N0 = (1 - f) SNR / (1 + f SNR) · B/R, f the grid's energy fraction later than one bit;
    off (the default): f = 0.  A value other than on/off is refused in one line."""
    monkeypatch.setenv("UWSIMNET_CACHE", str(DATA))
    monkeypatch.setenv("UWSIMNET_BELLHOP", "/nonexistent/bellhop")
    text = SCENE.read_text()
    models = {}
    for isi in ("off", "on"):
        net = Network(load_scene_text(text.replace("<name>bellhop</name>", f"<name>bellhop</name><isi>{isi}</isi>"),
                                      str(SCENE)))
        models[isi] = net.modems["buoy-modem"].error
    assert not Network(load_scene_text(text, str(SCENE))).modems["buoy-modem"].error.isi
    off, on = models["off"], models["on"]
    g = on.grid
    zs_, zr_, r_ = np.meshgrid(g.sd, g.rd, g.rr, indexing="ij")
    late = g.late_fraction(zs_.ravel(), zr_.ravel(), r_.ravel(), on.bit_s).reshape(g.tl.shape)
    i, j, k = (int(x[0]) for x in np.nonzero((late > 0.01) & (late < 0.99) & np.isfinite(g.tl)))
    zs, zr, r = float(g.sd[i]), float(g.rd[j]), float(g.rr[k])
    tl, _, f_on = on._point(zs, zr, r)
    assert off._point(zs, zr, r)[2] == 0.0 and f_on == pytest.approx(float(late[i, j, k]), rel=1e-9)
    snr = 10 ** (0.1 * (on.snr_const - tl))
    want = (1 - f_on) * snr / (1 + f_on * snr) * on.to_ebn0
    assert want < snr * on.to_ebn0
    with pytest.raises(ValueError, match="isi must be on or off"):
        Network(load_scene_text(text.replace("<name>bellhop</name>", "<name>bellhop</name><isi>yes</isi>"),
                                str(SCENE)))
