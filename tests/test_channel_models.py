"""docs/channel-models.md as it stands: its Rician plug-in installed as a separate package (a .dist-info with
its entry point on PYTHONPATH, in subprocesses), its scene run by `uwsimnet validate` and `uwsimnet run`, the
delivery against the Rician average of the BPSK PER, bad parameters and names refused in one line."""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
DOC = (ROOT / "docs" / "channel-models.md").read_text()
PY = sys.executable


def blocks(lang: str) -> list[str]:
    return re.findall(rf"^```{lang}\n(.*?)^```", DOC, flags=re.S | re.M)


PLUGIN = next(b for b in blocks("python") if "class RicianFading" in b)
ENTRY = tomllib.loads(blocks("toml")[0])
SCENE = next(b for b in blocks("xml") if b.startswith("<?xml"))


@pytest.fixture
def installed(tmp_path: Path) -> dict[str, str]:
    """The plug-in as an installed distribution: its module and a dist-info with the doc's entry points."""
    site = tmp_path / "site"
    site.mkdir()
    (site / "rician_fading.py").write_text(PLUGIN)
    info = site / "rician_fading-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: rician-fading\nVersion: 0.1\n")
    eps = ENTRY["project"]["entry-points"]
    (info / "entry_points.txt").write_text("".join(
        f"[{group}]\n" + "".join(f"{k} = {v}\n" for k, v in names.items()) + "\n" for group, names in eps.items()))
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(site), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    return env


def cli(env: dict[str, str], *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([PY, "-m", "uwsimnet_zenoh.cli", *args], capture_output=True, text=True, env=env,
                          timeout=300, cwd=ROOT)


def expected_delivery(k: float, snr_db: float, size: int) -> float:
    """E[(1 - BER(g SNR))^(8 L)] over the Rician power gain g of mean 1 (its density, numerically)."""
    g = np.linspace(1e-9, 40.0, 400_001)
    pdf = (k + 1) * np.exp(-k - (k + 1) * g) * np.i0(2 * np.sqrt(k * (k + 1) * g))
    snr = 10 ** (snr_db / 10) * g
    ber = 0.5 * np.array([math.erfc(math.sqrt(s)) for s in snr[::100]])
    ok = (1 - ber) ** (8 * size)
    w = pdf[::100]
    return float(np.trapezoid(ok * w, g[::100]) / np.trapezoid(w, g[::100]))


def test_the_plugin_is_under_60_lines_and_the_entry_point_is_the_documented_group():
    assert len(PLUGIN.strip().splitlines()) < 60
    assert list(ENTRY["project"]["entry-points"]) == ["uwsimnet.channel_models"]


def test_the_documented_scene_runs_the_installed_plugin_and_delivers_what_rician_theory_says(installed, tmp_path):
    scene = tmp_path / "rician.xml"
    scene.write_text(SCENE)
    v = cli(installed, "validate", str(scene))
    assert v.returncode == 0, v.stderr
    trace = tmp_path / "rician.jsonl"
    r = cli(installed, "run", str(scene), "--trace", str(trace))
    assert r.returncode == 0, r.stderr
    ev = [json.loads(line) for line in trace.read_text().splitlines()]
    tx = [e for e in ev if e.get("ev") == "tx" and e.get("flow") == "alpha-to-bravo"]
    rx = [e for e in ev if e.get("ev") == "rx" and e.get("dev") == "bravo-modem"]
    lost = [e for e in ev if e.get("ev") == "drop" and e.get("dev") == "bravo-modem"]
    assert len(tx) == 400 and len(rx) + len(lost) == 400
    assert {e["reason"] for e in lost} <= {"prop"}
    p = expected_delivery(4.0, 9.0 - 10 * 1.5 * math.log10(1000 / 1000), 32)
    sd = math.sqrt(p * (1 - p) / 400)
    assert abs(len(rx) / 400 - p) < 4 * sd, (len(rx), p)
    assert 0.5 < p < 0.95                      # the case is neither lossless nor hopeless
    # reproducible from (scene, seed): the same trace again
    r2 = cli(installed, "run", str(scene), "--trace", str(tmp_path / "again.jsonl"))
    assert r2.returncode == 0 and (tmp_path / "again.jsonl").read_text() == trace.read_text()


@pytest.mark.parametrize(("change", "message"), [
    ("<K>-1</K>", "K must be >= 0"),
    ("<K>abc</K>", "could not convert string to float"),
    ("<Kay>3</Kay>", "unknown parameter(s) Kay"),
])
def test_bad_parameters_are_refused_in_one_line_at_the_model_element(installed, tmp_path, change, message):
    text = SCENE.replace("<K>4</K>", change)
    scene = tmp_path / "bad.xml"
    scene.write_text(text)
    line = text[:text.index("<channelModel>")].count("\n") + 1
    for cmd in ("validate", "run"):
        p = cli(installed, cmd, str(scene))
        assert p.returncode == 2, (cmd, p.stdout, p.stderr)
        err = p.stderr.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"{scene}:{line}: "), (cmd, p.stderr)
        assert message in err[0] and "Traceback" not in p.stderr


def test_an_unknown_model_name_is_refused_at_its_name_line(installed, tmp_path):
    text = SCENE.replace("<name>rician</name>", "<name>ricean</name>")
    scene = tmp_path / "bad.xml"
    scene.write_text(text)
    line = text[:text.index("<name>ricean")].count("\n") + 1
    for cmd in ("validate", "run"):
        p = cli(installed, cmd, str(scene))
        err = p.stderr.strip().splitlines()
        assert p.returncode == 2 and len(err) == 1, (cmd, p.stderr)
        assert err[0].startswith(f"{scene}:{line}: channelModel/name: unknown channel model 'ricean'"), err[0]
        assert "uwsimnet.channel_models" in err[0]


def test_without_the_package_the_name_is_unknown(tmp_path):
    scene = tmp_path / "rician.xml"
    scene.write_text(SCENE)
    p = cli(dict(os.environ), "validate", str(scene))
    assert p.returncode == 2 and "unknown channel model 'rician'" in p.stderr


def test_the_harness_block_runs_as_it_stands():
    block = next(b for b in blocks("python") if "testing.Harness" in b)
    exec(compile(block, "docs/channel-models.md", "exec"), {})  # noqa: S102 - our own documentation


def test_the_plugin_through_the_harness(installed):
    """The plug-in author's own test: the contract, and the delivery the harness draws against the theory."""
    import importlib.util
    import sys as _sys

    site = installed["PYTHONPATH"].split(os.pathsep)[0]
    spec = importlib.util.spec_from_file_location("rician_fading", os.path.join(site, "rician_fading.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    _sys.modules.pop("rician_fading", None)
    from uwsimnet_zenoh.phy import testing

    h = testing.Harness(mod.RicianFading, {"K": "4", "snr1km": "9"}, seed=11)
    assert h.check() == []
    got = h.delivery((1000.0, 0.0, 0.0), frames=3000, size=32)
    p = expected_delivery(4.0, 9.0, 32)
    assert abs(got - p) < 4 * math.sqrt(p * (1 - p) / 3000), (got, p)
    with pytest.raises(ValueError, match="K must be >= 0"):
        testing.Harness(mod.RicianFading, {"K": "-2"})
