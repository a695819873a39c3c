"""TEOS-10 sound speed through `gsw` (docs/ocean.md): the scene's <equation>teos10</equation> against the
check values the TEOS-10 toolbox publishes for its own functions (the GSW Matlab help pages, as copied into
the R package gsw's examples: gsw_z_from_p, gsw_SA_from_SP, gsw_sound_speed_t_exact, all at 188 E, 4 N),
never against this project's output; and the one-line error when gsw is not installed."""

from __future__ import annotations

import subprocess
import sys

import pytest

from uwsimnet_zenoh.phy.ocean import SoundSpeedProfile
from uwsimnet_zenoh.scene import SceneError, load_scene_text

P_DBAR = (10, 50, 125, 250, 600, 1000)
Z_FROM_P_4N = (-9.9445834469453, -49.7180897012550, -124.2726219409978, -248.4700576548589, -595.8253480356214,
               -992.0919060719987)
"""gsw_z_from_p(p, 4): the depth (m) of each sea pressure; TEOS-10 check values."""
SP = (34.5487, 34.7275, 34.8605, 34.6810, 34.5680, 34.56)
"""Practical Salinity; gsw_SA_from_SP(SP, p, 188, 4) = 34.7118, 34.8915, 35.0256, 34.8472, 34.7366, 34.7324 (to
the 4 decimals its sound-speed example is given with)."""
T = (28.7856, 28.4329, 22.8103, 10.2600, 6.8863, 4.4036)
"""In-situ temperature, degC."""
SOUND_SPEED = (1542.615803587414, 1542.703534065789, 1530.844979136360, 1494.409996920661, 1487.377102518027,
               1483.934609078705)
"""gsw_sound_speed_t_exact(SA, t, p), m/s: TEOS-10 check values."""

SCENE = """<?xml version="1.0"?>
<UWSimScene>
  <environment>
    <origin>{origin}</origin>
    <temperature>{temp}</temperature>
    <salinity>{sal}</salinity>
    <equation>{eq}</equation>
    <bathymetry>flat 1500</bathymetry>
  </environment>
  <CustomCommsChannel><id>0</id></CustomCommsChannel>
</UWSimScene>
"""


def _scene(eq: str = "teos10", origin: str = "4 -172") -> str:
    temp = ", ".join(f"{-z!r} {t}" for z, t in zip(Z_FROM_P_4N, T, strict=True))
    sal = ", ".join(f"{-z!r} {s}" for z, s in zip(Z_FROM_P_4N, SP, strict=True))
    return SCENE.format(origin=origin, temp=temp, sal=sal, eq=eq)


def test_teos10_profile_is_the_published_sound_speed():
    pytest.importorskip("gsw", reason="gsw (the TEOS-10 toolbox, extra 'teos10') is not installed")
    env = load_scene_text(_scene(), "s.xml").environment
    assert env is not None and env.profile_name == "teos10"
    got = [c for _, c in env.profile]
    assert [d for d, _ in env.profile] == pytest.approx([-z for z in Z_FROM_P_4N], abs=1e-12)
    # the published SA are to 4 decimals and gsw 3.6's salinity atlas moves SA by < 1e-4 g/kg: ~1e-4 m/s
    assert got == pytest.approx(SOUND_SPEED, abs=1e-3)
    # Mackenzie's nine terms on the same water differ by tenths of a m/s: the equation is really switched
    mack = load_scene_text(_scene("mackenzie"), "s.xml").environment
    assert max(abs(a - b) for (_, a), (_, b) in zip(mack.profile, env.profile, strict=True)) > 0.1


def test_teos10_without_an_origin_uses_reference_salinity_at_45_degrees():
    gsw = pytest.importorskip("gsw", reason="gsw (the TEOS-10 toolbox, extra 'teos10') is not installed")
    text = _scene().replace("<origin>4 -172</origin>", "")
    env = load_scene_text(text, "s.xml").environment
    assert env is not None and env.origin is None
    # the anomaly left out: within a few cm/s of the atlas' answer at 4 N
    assert [c for _, c in env.profile] == pytest.approx(SOUND_SPEED, abs=0.05)
    assert gsw.SR_from_SP(35.0) == pytest.approx(35.16504)   # TEOS-10's reference composition: 35.16504/35


def test_salinity_pairs_are_taken_at_the_temperature_depths():
    text = SCENE.format(origin="41 2", temp="0 20, 100 10", sal="0 36, 200 38", eq="mackenzie")
    env = load_scene_text(text, "s.xml").environment
    want = SoundSpeedProfile.from_ts([(0.0, 20.0, 36.0), (100.0, 10.0, 37.0)])
    assert [c for _, c in env.profile] == pytest.approx(want.speeds, abs=1e-9)


@pytest.mark.parametrize(("sal", "eq", "msg", "line"), [
    ("35", "unesco", "equation: expected mackenzie or teos10", 7),
    ("0 35, 0 36", "mackenzie", "salinity: depths must increase", 6),
    ("0 35, 10 60", "mackenzie", "salinity: expected 0-45", 6),
])
def test_bad_equation_or_salinity_is_one_line(sal, eq, msg, line):
    with pytest.raises(SceneError) as e:
        load_scene_text(SCENE.format(origin="41 2", temp="0 20, 100 10", sal=sal, eq=eq), "s.xml")
    assert str(e.value).startswith(f"s.xml:{line}: {msg}")


def test_teos10_without_gsw_fails_in_one_line_saying_how_to_get_it(tmp_path):
    """`uwsimnet validate` in a process where `import gsw` fails (a None entry in sys.modules, as Python's
    own way to block an import): exit 2, one line at the <equation>, naming the extra."""
    p = tmp_path / "teos.xml"
    p.write_text(_scene())
    code = ("import sys; sys.modules['gsw'] = None; sys.argv = ['uwsimnet', 'validate', sys.argv[1]];"
            " from uwsimnet_zenoh.cli import command; sys.exit(command())")
    r = subprocess.run([sys.executable, "-c", code, str(p)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    assert r.stderr.strip() == (f"{p}:7: equation: TEOS-10 needs the gsw package (the Gibbs SeaWater toolbox):"
                                " pip install 'uwsimnet-zenoh[teos10]' (or pip install gsw)")
