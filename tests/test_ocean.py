"""The water (issue #37 parts a and b): lat/lon placement against an independent geodesic (Vincenty's inverse,
written here from his 1975 paper), the sound-speed presets against their formulas, the <environment>
element's checks (file:line), and motion during flight: arrival times against a numerical solution of the
wavefront meeting a moving receiver, Doppler factors against the arrival-time compression of two bits."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import device, scene, vehicle

from uwsimnet_zenoh.engine.network import Network
from uwsimnet_zenoh.phy import testing
from uwsimnet_zenoh.phy.ocean import PRESETS, Bathymetry, SoundSpeedProfile, geodetic_to_enu, munk_profile
from uwsimnet_zenoh.scene import SceneError, load_scene_text
from uwsimnet_zenoh.scene.model import Channel, Environment, Flow, ModelSpec, Waypoint

A, F = 6378137.0, 1 / 298.257223563
B = A * (1 - F)


def vincenty(lat1: float, lon1: float, lat2: float, lon2: float) -> float:
    """Geodesic distance on WGS-84, m: T. Vincenty, Survey Review 23(176):88-93, 1975, the inverse formula."""
    u1 = math.atan((1 - F) * math.tan(math.radians(lat1)))
    u2 = math.atan((1 - F) * math.tan(math.radians(lat2)))
    big_l = math.radians(lon2 - lon1)
    lam = big_l
    for _ in range(200):
        sl, cl = math.sin(lam), math.cos(lam)
        sin_s = math.hypot(math.cos(u2) * sl, math.cos(u1) * math.sin(u2) - math.sin(u1) * math.cos(u2) * cl)
        cos_s = math.sin(u1) * math.sin(u2) + math.cos(u1) * math.cos(u2) * cl
        sigma = math.atan2(sin_s, cos_s)
        sin_a = math.cos(u1) * math.cos(u2) * sl / sin_s
        cos2a = 1 - sin_a ** 2
        cos2sm = cos_s - 2 * math.sin(u1) * math.sin(u2) / cos2a if cos2a else 0.0
        c = F / 16 * cos2a * (4 + F * (4 - 3 * cos2a))
        prev = lam
        lam = big_l + (1 - c) * F * sin_a * (sigma + c * sin_s * (cos2sm + c * cos_s * (-1 + 2 * cos2sm ** 2)))
        if abs(lam - prev) < 1e-13:
            break
    u_sq = cos2a * (A * A - B * B) / (B * B)
    a_ = 1 + u_sq / 16384 * (4096 + u_sq * (-768 + u_sq * (320 - 175 * u_sq)))
    b_ = u_sq / 1024 * (256 + u_sq * (-128 + u_sq * (74 - 47 * u_sq)))
    ds = b_ * sin_s * (cos2sm + b_ / 4 * (cos_s * (-1 + 2 * cos2sm ** 2)
                                          - b_ / 6 * cos2sm * (-3 + 4 * sin_s ** 2) * (-3 + 4 * cos2sm ** 2)))
    return B * a_ * (sigma - ds)


@pytest.mark.parametrize("origin", [(41.38, 2.18), (-33.9, 151.2), (69.6, 18.9), (0.5, -30.0)])
def test_lat_lon_ranges_match_the_geodesic_within_0_05_percent_over_10_km(origin):
    lat0, lon0 = origin
    worst = 0.0
    for k in range(12):
        brg = math.radians(30 * k + 7)
        for dist in (50.0, 1000.0, 5000.0, 10_000.0):
            lat = lat0 + dist * math.cos(brg) / 111_000
            lon = lon0 + dist * math.sin(brg) / (111_000 * math.cos(math.radians(lat0)))
            x, y, _ = geodetic_to_enu(lat, lon, 0.0, lat0, lon0)
            g = vincenty(lat0, lon0, lat, lon)
            worst = max(worst, abs(math.hypot(x, y) - g) / g)
            # two points, neither at the origin
            x2, y2, _ = geodetic_to_enu(lat0 - 0.01, lon0 + 0.01, 0.0, lat0, lon0)
            g2 = vincenty(lat0 - 0.01, lon0 + 0.01, lat, lon)
            worst = max(worst, abs(math.hypot(x - x2, y - y2) - g2) / g2)
    assert worst < 5e-4


def test_presets_are_their_formulas():
    munk = munk_profile()
    for z in (0.0, 650.0, 1300.0, 4000.0):
        eta = 2 * (z - 1300) / 1300
        assert munk(z) == pytest.approx(1500 * (1 + 0.00737 * (eta - 1 + math.exp(-eta))), abs=1e-9)
    assert munk(1300.0) == pytest.approx(1500.0) and min(munk.speeds) == pytest.approx(1500.0)
    # Mackenzie (1981), the check value of MBARI's implementation: 1718.774 m/s at 40 ppt, 40 degC, 10 km
    assert SoundSpeedProfile.from_ts([(10_000.0, 40.0, 40.0)]).speeds == pytest.approx([1718.774], abs=1e-3)
    summer = PRESETS["summer-thermocline"][1]
    assert summer(10.0) - summer(60.0) > 20.0          # downward refracting across the thermocline
    assert PRESETS["isovelocity"][1](3000.0) == 1500.0


def test_harmonic_mean_speed_is_the_travel_time_of_the_layers():
    p = SoundSpeedProfile([(0.0, 1540.0), (100.0, 1480.0)])
    n = 200_000                                          # midpoint rule on the slowness
    t = sum(1.0 / p(30.0 + (i + 0.5) * 50.0 / n) for i in range(n)) * 50.0 / n
    assert p.mean_speed(30.0, 80.0) == pytest.approx(50.0 / t, rel=1e-10)


SCENE = """<?xml version="1.0"?>
<UWSimScene>
  <simulation><duration>5</duration></simulation>
  <environment>
    <origin>41.38 2.18</origin>
    {sound}
    <bathymetry>{bathy}</bathymetry>
    <seabed><soundSpeed>1650</soundSpeed><density>1.9</density></seabed>
  </environment>
  <CustomCommsChannel><id>0</id></CustomCommsChannel>
  <vehicle><name>a</name><geoPosition>{geo}</geoPosition></vehicle>
</UWSimScene>
"""


def load(sound: str = "<preset>munk</preset>", bathy: str = "flat 120", geo: str = "41.39 2.19 15"):
    return load_scene_text(SCENE.format(sound=sound, bathy=bathy, geo=geo), "s.xml")


def test_environment_is_read():
    sc = load("<temperature>0 20, 30 20; 60 13</temperature><salinity>37</salinity>", "slope 100 0.01 -0.02")
    env = sc.environment
    assert env is not None and env.origin == (41.38, 2.18) and env.seabed_speed_mps == 1650
    assert env.sound_speed()(0.0) == pytest.approx(SoundSpeedProfile.from_ts([(0.0, 20.0, 37.0)]).speeds[0])
    assert env.seafloor().depth(1000.0, 500.0) == pytest.approx(100 + 10 - 10)
    x, y, z = sc.vehicles[0].position
    assert (x, y, z) == pytest.approx(geodetic_to_enu(41.39, 2.19, 15, 41.38, 2.18)) and z == -15


@pytest.mark.parametrize(("sound", "bathy", "geo", "line", "msg"), [
    ("<preset>arctic</preset>", "flat 120", "41.39 2.19 15", 6, "preset: expected isovelocity"),
    ("<profile>0 1500, 10 1490, 5 1480</profile>", "flat 120", "41.39 2.19 15", 6, "depths must increase"),
    ("<profile>0 1500, 10</profile>", "flat 120", "41.39 2.19 15", 6, "expected 'depth speed' pairs"),
    ("<profile>0 150</profile>", "flat 120", "41.39 2.19 15", 6, "1300-1800 m/s"),
    ("<preset>munk</preset><profile>0 1500</profile>", "flat 120", "41.39 2.19 15", 6, "give one of"),
    ("<preset>munk</preset>", "hill 3", "41.39 2.19 15", 7, "expected 'flat DEPTH'"),
    ("<preset>munk</preset>", "flat -3", "41.39 2.19 15", 7, "greater than 0"),
    ("<preset>munk</preset>", "grid nowhere.txt", "41.39 2.19 15", 7, "No such file"),
    ("<preset>munk</preset>", "flat 120", "41.39 2.19", 11, "expected 'latitude longitude depth'"),
    ("<preset>munk</preset>", "flat 120", "95 2.19 3", 11, "latitude within"),
])
def test_bad_environment_is_one_line_at_its_element(sound, bathy, geo, line, msg):
    with pytest.raises(SceneError) as e:
        load(sound, bathy, geo)
    assert e.value.line == line and msg in str(e.value) and str(e.value).startswith(f"s.xml:{line}: ")


def test_geo_position_needs_an_origin_and_validate_says_so_in_one_line(tmp_path):
    text = SCENE.format(sound="", bathy="flat 50", geo="41.39 2.19 15").replace("<origin>41.38 2.18</origin>", "")
    p = tmp_path / "noorigin.xml"
    p.write_text(text)
    r = subprocess.run([sys.executable, "-m", "uwsimnet_zenoh.cli", "validate", str(p)], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 2 and r.stderr.strip() == f"{p}:11: geoPosition: needs <environment><origin>"


def test_bathymetry_grid_file(tmp_path):
    g = tmp_path / "b.txt"
    g.write_text("# x y depth\n0 0 100\n1000 0 200\n0 1000 100\n1000 1000 300\n")
    b = Bathymetry.read_grid(str(g))
    assert b.depth(500, 500) == pytest.approx((100 + 200 + 100 + 300) / 4) and b.depth(-50, 0) == 100
    (tmp_path / "s.xml").write_text(SCENE.format(sound="", bathy="grid b.txt", geo="41.38 2.18 1"))
    from uwsimnet_zenoh.scene import load_scene
    assert load_scene(tmp_path / "s.xml").environment.seafloor().depth(1000, 1000) == 300
    g.write_text("0 0 100\n1000 0 200\n0 1000 100\n")
    with pytest.raises(ValueError, match="not a full rectilinear grid"):
        Bathymetry.read_grid(str(g))


# --- motion during flight ----------------------------------------------------------------------------
C = 1500.0


def solve_arrival(ps, pr, vr, c=C):
    """Bisection on |pr + vr tau - ps| - c tau = 0 (decreasing in tau for |vr| < c)."""
    lo, hi = 0.0, 100.0
    for _ in range(200):
        mid = (lo + hi) / 2
        gap = math.dist([p + v * mid for p, v in zip(pr, vr, strict=True)], ps) - c * mid
        lo, hi = (mid, hi) if gap > 0 else (lo, mid)
    return (lo + hi) / 2


@pytest.mark.parametrize(("va", "vb"), [((0, 0, 0), (5, 0, 0)), ((0, 0, 0), (-5, 0, 0)), ((3, 4, 0), (0, -5, 0)),
                                        ((-2, 0, 1), (2.9, 2.9, -2.9)), ((5, 0, 0), (5, 0, 0))])
def test_arrival_with_both_ends_moving_within_1_us_of_the_intercept(va, vb):
    pa, pb = (0.0, 0.0, -10.0), (5000.0, 0.0, -40.0)
    wa = (Waypoint(t=0, x=pa[0], y=pa[1], z=pa[2]), Waypoint(t=100, x=pa[0] + 100 * va[0], y=pa[1] + 100 * va[1],
                                                             z=pa[2] + 100 * va[2]))
    wb = (Waypoint(t=0, x=pb[0], y=pb[1], z=pb[2]), Waypoint(t=100, x=pb[0] + 100 * vb[0], y=pb[1] + 100 * vb[1],
                                                             z=pb[2] + 100 * vb[2]))
    sc = scene([vehicle("a", pa, device("a", 1), trajectory=wa), vehicle("b", pb, device("b", 2), trajectory=wb)],
               [Flow(name="f", src="a", dst=2, size=16, interval=7.0, stop=60)],
               channels=[Channel(id=0, prop_s_per_m=1 / C, model=ModelSpec(name="ocean"))], duration=80)
    net = Network(sc)
    rec: list[dict] = []
    net.tracer.add(rec.append)
    net.run()
    tx = {r["seq"]: r["t"] for r in rec if r["ev"] == "tx"}
    rx = [r for r in rec if r["ev"] == "rx"]
    assert len(rx) == len(tx) >= 8
    for r in rx:
        t0 = tx[r["seq"]]
        ps = [p + v * t0 for p, v in zip(pa, va, strict=True)]
        pr = [p + v * t0 for p, v in zip(pb, vb, strict=True)]
        expect = t0 + solve_arrival(ps, pr, vb) + 16 * 8 / 1000
        assert abs(r["t"] - expect) < 1e-6, (r["t"], expect)


@pytest.mark.parametrize(("vs", "vr"), [((5, 0, 0), (0, 0, 0)), ((0, 0, 0), (5, 0, 0)), ((-3, 4, 0), (1, -2, 2)),
                                        ((4, 3, 0), (-4, -3, 0)), ((0, 5, 0), (0, 5, 0))])
def test_doppler_factor_is_the_classical_formula_and_the_arrival_compression(vs, vr):
    h = testing.Harness("ocean")
    ps, pr = (0.0, 0.0, -10.0), (4000.0, 1500.0, -60.0)
    d = h.answer([pr], tx=ps, tx_velocity=vs, rx_velocities=[vr]).doppler[0]
    tau = solve_arrival(ps, pr, vr)
    at = [p + v * tau for p, v in zip(pr, vr, strict=True)]
    u = [(a - b) / math.dist(at, ps) for a, b in zip(at, ps, strict=True)]
    def dot(a, b):
        return sum(x * y for x, y in zip(a, b, strict=True))

    classical = (C - dot(vr, u)) / (C - dot(vs, u))
    assert abs(d - classical) < 1e-9
    # physics: a bit sent dt later (from the moved sender) arrives dt / D later
    dt = 1e-3
    ps2 = [p + v * dt for p, v in zip(ps, vs, strict=True)]
    pr2 = [p + v * dt for p, v in zip(pr, vr, strict=True)]
    tau2 = solve_arrival(ps2, pr2, vr)
    assert dt / (dt + tau2 - tau) == pytest.approx(d, abs=1e-8)


def test_ocean_model_uses_the_profile_speed_and_the_devices_loss():
    sc = scene([vehicle("a", (0.0, 0.0, -10.0), device("a", 1, error=("1e-4*m", "packet"))),
                vehicle("b", (3000.0, 0.0, -90.0), device("b", 2))],
               [Flow(name="f", src="a", dst=2, size=16, interval=1.0, stop=40)],
               channels=[Channel(id=0, model=ModelSpec(name="ocean"))], duration=50)
    sc = sc.model_copy(update={"environment": Environment(profile=((0.0, 1540.0), (100.0, 1480.0)))})
    net = Network(sc)
    rec: list[dict] = []
    net.tracer.add(rec.append)
    net.run()
    tx = {r["seq"]: r["t"] for r in rec if r["ev"] == "tx"}
    rx = [r for r in rec if r["ev"] == "rx"]
    c = SoundSpeedProfile([(0.0, 1540.0), (100.0, 1480.0)]).mean_speed(10, 90)
    d = math.dist((0, 0, -10), (3000, 0, -90))
    for r in rx:
        assert r["t"] == pytest.approx(tx[r["seq"]] + d / c + 0.128, abs=1e-9)
    drops = [r for r in rec if r["ev"] == "drop"]
    assert len(rx) + len(drops) == 40 and {r["reason"] for r in drops} <= {"prop"}
    assert 0 < len(drops) < 40          # PER = 0.3 at 3 km


def test_scene_files_name_the_ocean_model(tmp_path):
    text = SCENE.format(sound="<preset>summer-thermocline</preset>", bathy="flat 80", geo="41.38 2.18 10")
    text = text.replace("<CustomCommsChannel><id>0</id></CustomCommsChannel>",
                        "<CustomCommsChannel><id>0</id><channelModel><name>ocean</name><speed>3</speed>"
                        "</channelModel></CustomCommsChannel>")
    p = Path(tmp_path / "o.xml")
    p.write_text(text)
    r = subprocess.run([sys.executable, "-m", "uwsimnet_zenoh.cli", "validate", str(p)], capture_output=True,
                       text=True, timeout=120)
    # a vehicle without devices builds no model: validate is fine; the parameter is checked when one transmits
    assert r.returncode == 0, r.stderr


def test_doppler_tolerance_loses_the_frames_of_a_fast_closing_pair():
    h = testing.Harness("ocean", {"dopplerTolerance": "3"})
    slow = h.answer([(2000.0, 0.0, 0.0)], tx_velocity=(1.0, 0.0, 0.0), rx_velocities=[(-1.5, 0.0, 0.0)])
    fast = h.answer([(2000.0, 0.0, 0.0)], tx_velocity=(2.0, 0.0, 0.0), rx_velocities=[(-1.5, 3.0, 0.0)])
    across = h.answer([(2000.0, 0.0, 0.0)], tx_velocity=(0.0, 4.0, 0.0))     # 4 m/s across the path: no Doppler
    assert slow.per[0] == 0.0 and fast.per[0] == 1.0 and across.per[0] == 0.0
    with pytest.raises(ValueError, match="dopplerTolerance"):
        testing.Harness("ocean", {"dopplerTolerance": "0"})


def test_a_run_between_lat_lon_placed_vehicles_measures_the_geodesic(tmp_path):
    """uwsimnet run on a scene placed in lat/lon: the trace's rx distance against Vincenty (and the depths)."""
    lat0, lon0 = 43.0, 5.0
    places = {"a": (43.0, 5.0, 10.0), "b": (43.05, 5.07, 40.0), "c": (42.97, 4.93, 25.0)}
    vehicles = "".join(
        f"<vehicle><name>{n}</name><geoPosition>{la} {lo} {d}</geoPosition><CustomCommsDevice>"
        f"<dccommsId>{n}</dccommsId><mac>{i + 1}</mac><txChannelId>0</txChannelId><rxChannelId>0</rxChannelId>"
        f"<rateErrorModel><errorUnit>packet</errorUnit><errorRateExpr>0</errorRateExpr></rateErrorModel>"
        f"</CustomCommsDevice></vehicle>"
        for i, (n, (la, lo, d)) in enumerate(places.items()))
    text = (f'<?xml version="1.0"?><UWSimScene><simulation><duration>30</duration></simulation><environment>'
            f"<origin>{lat0} {lon0}</origin></environment><CustomCommsChannel><id>0</id><channelModel><name>ocean"
            f"</name></channelModel></CustomCommsChannel>{vehicles}"
            "<flow><name>f</name><src>a</src><dst>255</dst><size>10</size><interval>5</interval></flow></UWSimScene>")
    p = tmp_path / "geo.xml"
    p.write_text(text)
    trace = tmp_path / "geo.jsonl"
    r = subprocess.run([sys.executable, "-m", "uwsimnet_zenoh.cli", "run", str(p), "--trace", str(trace)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    rx = [json.loads(line) for line in trace.read_text().splitlines() if '"ev": "rx"' in line or '"ev":"rx"' in line]
    assert {x["dev"] for x in rx} == {"b", "c"}
    for x in rx:
        la, lo, d = places[x["dev"]]
        expect = math.hypot(vincenty(43.0, 5.0, la, lo), d - 10.0)
        assert abs(x["dist"] - expect) / expect < 5e-4, (x["dist"], expect)
        print(f"{x['dev']}: trace {x['dist']:.3f} m, Vincenty + depths {expect:.3f} m")
