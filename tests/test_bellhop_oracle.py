"""The Bellhop plumbing of phy/bellhop.py (.env writer, runner, .shd and .arr readers) against things that are
not this project: the readers of the Bellhop distribution we run (aubellhop's `readers.py`, run in its own
Python 3.12 tool venv, on the very files Bellhop wrote), and ray theory where it is exact (an isovelocity
ocean: the direct and surface-reflected paths of the image method, times and incoherent TL).  All need the
real program (`make bellhop`) and skip with the reason when it is absent."""

from __future__ import annotations

import json
import math
import subprocess
from pathlib import Path

import numpy as np
import pytest

from uwsimnet_zenoh.phy import bellhop

PROGRAM = bellhop.find_program()
pytestmark = pytest.mark.skipif(PROGRAM is None, reason="Bellhop is not installed (`make bellhop`)")

C = 1500.0                      # isovelocity water, m/s
DEEP = 5000.0                   # a bottom far enough that its paths are long, late and weak
SEABED = (1600.0, 1.8, 0.8)
F2 = 25.0 ** 2                  # the test frequency, kHz, squared
THORP_DB_PER_M = (3.3e-3 + 0.11 * F2 / (1 + F2) + 44 * F2 / (4100 + F2) + 3e-4 * F2) / 1000
THERMO = [(0.0, 1520.0), (20.0, 1519.0), (40.0, 1490.0), (60.0, 1485.0), (200.0, 1487.0)]


def _tool_python(program: str) -> Path | None:
    """The Python of the venv the program was installed into (aubellhop ships it inside its package)."""
    for d in Path(program).resolve().parents:
        if (d / "pyvenv.cfg").is_file():
            return d / "bin" / "python"
    return None


READ = r"""
import json, sys
import numpy as np
from aubellhop.readers import read_arrivals, read_shd
shd, arr = sys.argv[1], sys.argv[2]
p = read_shd(shd)
a = read_arrivals(arr)
print(json.dumps({"re": np.real(p.values).tolist(), "im": np.imag(p.values).tolist(),
                  "rd": [float(x) for x in p.index], "rr": [float(x) for x in p.columns],
                  "arr": [[int(r.receiver_depth_ndx), int(r.receiver_range_ndx), float(abs(r.arrival_amplitude)),
                           float(r.time_of_arrival)] for r in a.itertuples()]}))
"""


def _run_both(tmp_path: Path, profile, bottom, sds, rds, rrs) -> tuple[bytes, str]:
    (tmp_path / "i").mkdir()
    (tmp_path / "a").mkdir()
    shd = bellhop.run_bellhop(PROGRAM, bellhop.env_text(25_000.0, profile, bottom, SEABED, sds, rds, rrs, "I"),
                              "shd", str(tmp_path / "i"))
    arr = bellhop.run_bellhop(PROGRAM, bellhop.env_text(25_000.0, profile, bottom, SEABED, sds, rds, rrs, "A"),
                              "arr", str(tmp_path / "a"))
    return shd, arr.decode()


def test_the_readers_agree_with_the_bellhop_distributions_own_readers(tmp_path):
    py = _tool_python(PROGRAM)
    if py is None or subprocess.run([str(py), "-c", "import aubellhop.readers"], capture_output=True,
                                    timeout=300).returncode != 0:
        pytest.skip("the Bellhop found is not aubellhop's (no readers to compare with)")
    rds = [1.0, 15.0, 30.0, 55.0, 90.0, 150.0]
    rrs = [50.0, 300.0, 800.0, 1500.0]
    shd, arr = _run_both(tmp_path, THERMO, 200.0, [10.0], rds, rrs)
    out = subprocess.run([str(py), "-c", READ, str(tmp_path / "i" / "run.shd"), str(tmp_path / "a" / "run.arr")],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    ref = json.loads(out.stdout)
    sd, rd, rr, p = bellhop.read_shd(shd)
    assert sd.tolist() == [10.0] and rd.tolist() == ref["rd"] == rds
    assert rr.tolist() == ref["rr"] == rrs            # the ranges asked for, in m (the .env has them in km)
    assert np.array_equal(p[0], np.array(ref["re"]) + 1j * np.array(ref["im"]))    # bit for bit (float32)
    first, spread, _ = bellhop.read_arrivals(arr)
    n_cells = 0
    for j in range(len(rds)):
        for k in range(len(rrs)):
            rows = [(amp, t) for jj, kk, amp, t in ref["arr"] if (jj, kk) == (j, k)]
            if not rows:
                assert math.isnan(first[0, j, k])
                continue
            amp = np.array([a for a, _ in rows])
            t = np.array([t for _, t in rows])
            strong = amp >= amp.max() * 10 ** (-20 / 20)          # earliest within 20 dB of the strongest
            assert first[0, j, k] == pytest.approx(t[strong].min(), abs=1e-9)
            w = amp ** 2
            mean = (w * t).sum() / w.sum()
            assert spread[0, j, k] == pytest.approx(math.sqrt((w * (t - mean) ** 2).sum() / w.sum()), abs=1e-9)
            n_cells += 1
    assert n_cells >= 20                              # most cells have arrivals (a few may be in the shadow)


def test_isovelocity_arrivals_and_tl_match_the_image_method(tmp_path):
    """Direct path R1 = sqrt(r^2 + (zr - zs)^2), surface image R2 = sqrt(r^2 + (zr + zs)^2): the first
    significant arrival is R1 / c, and the incoherent TL is -10 log10(10^(-a R1/10)/R1^2 + 10^(-a R2/10)/R2^2)
    (the pressure-release surface reflects with |R| = 1; the bottom's paths, over 5 km down and back, add
    < 0.1 dB), with Thorp's volume attenuation a (the .env's top option 'T'), written as in Jensen, Kuperman,
    Porter & Schmidt, Computational Ocean Acoustics, 2nd ed., eq. 1.47: 3.3e-3 + 0.11 f^2/(1 + f^2)
    + 44 f^2/(4100 + f^2) + 3e-4 f^2 dB/km, f in kHz."""
    zs, rds, rrs = 50.0, [10.0, 45.0, 120.0, 400.0], [100.0, 400.0, 1000.0, 2000.0]
    shd, arr = _run_both(tmp_path, [(0.0, C), (DEEP, C)], DEEP, [zs], rds, rrs)
    _, _, _, p = bellhop.read_shd(shd)
    first, _, _ = bellhop.read_arrivals(arr)
    worst_t = worst_tl = 0.0
    for j, zr in enumerate(rds):
        for k, r in enumerate(rrs):
            r1, r2 = math.hypot(r, zr - zs), math.hypot(r, zr + zs)
            worst_t = max(worst_t, abs(first[0, j, k] - r1 / C))
            tl = -20 * math.log10(abs(p[0, j, k]))
            theory = -10 * math.log10(sum(10 ** (-THORP_DB_PER_M * x / 10) / x ** 2 for x in (r1, r2)))
            worst_tl = max(worst_tl, abs(tl - theory))
    assert worst_t < 1e-6, worst_t                    # 16 geometries: ray travel time = geometry / c
    assert worst_tl < 1.0, worst_tl


def test_a_bellhop_failure_is_one_line_with_its_print_file_message(tmp_path):
    bad = bellhop.env_text(25_000.0, [(0.0, C), (100.0, C)], 100.0, SEABED, [50.0], [10.0], [100.0], "I")
    assert bad.count("\n'CVW") == 1
    bad = bad.replace("\n'CVW", "\n'ZVW")              # 'Z' is no SSP interpolation type Bellhop knows
    with pytest.raises(ValueError) as e:
        bellhop.run_bellhop(PROGRAM, bad, "shd", str(tmp_path))
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith("Bellhop failed (")
    prt = (tmp_path / "run.prt").read_text()
    assert "Unknown option for SSP approximation" in prt and "Unknown option for SSP approximation" in msg
