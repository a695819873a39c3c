"""A sloping or gridded bottom in the channel model "bellhop" (docs/ocean.md, "Range-dependent bottom"): a grid
per (source cell, bearing sector) with the bottom along the sector's centre line as a Bellhop .bty file.
Without Bellhop: the sectors, cells, keys and per-frame choice of grid, against the slope's formula (grids
stood in by a stub whose TL is the .bty's depth).  With Bellhop: TL from the cached grids against Bellhop run
directly at the geometry with the same .bty, within 1 dB."""

from __future__ import annotations

import math
import random
import tempfile

import numpy as np
import pytest

from uwsimnet_zenoh.engine.network import Network
from uwsimnet_zenoh.kernel.frame import Frame
from uwsimnet_zenoh.mobility.trajectory import PoseTable
from uwsimnet_zenoh.phy import bellhop
from uwsimnet_zenoh.phy.models import Query
from uwsimnet_zenoh.scene import load_scene_text

SCENE = """<?xml version="1.0"?>
<UWSimScene>
  <environment>
    <preset>summer-thermocline</preset>
    <bathymetry>slope 100 0.02 0</bathymetry>
  </environment>
  <AcousticCommsChannel>
    <id>0</id>
    <channelModel>
      <name>bellhop</name><sources>10</sources><sectors>{sectors}</sectors><positionStep>250</positionStep>
      <maxRange>1000</maxRange><rangeStep>{rstep}</rangeStep><depthStep>{zstep}</depthStep>
    </channelModel>
  </AcousticCommsChannel>
  <vehicle><name>buoy</name><position>0 0 -10</position>
    <AcousticCommsDevice><dccommsId>buoy-modem</dccommsId><mac>1</mac><txChannelId>0</txChannelId>
      <rxChannelId>0</rxChannelId><preset>evologics-s2cr-18-34</preset></AcousticCommsDevice></vehicle>
  <vehicle><name>auv</name>
    <trajectory><waypoint t="0" x="30" y="-40" z="-10"/><waypoint t="100" x="1010" y="20" z="-10"/></trajectory>
    <AcousticCommsDevice><dccommsId>auv-modem</dccommsId><mac>2</mac><txChannelId>0</txChannelId>
      <rxChannelId>0</rxChannelId><preset>evologics-s2cr-18-34</preset></AcousticCommsDevice></vehicle>
</UWSimScene>
"""


def slope_depth(x: float, y: float) -> float:
    """The scene's bottom, from its <bathymetry>slope 100 0.02 0</bathymetry>: 100 m at the origin, 2 cm deeper
    per metre east."""
    return 100.0 + 0.02 * x + 0.0 * y


def query(model, tx, receivers, velocities=None):
    """The model's answer for one frame from `tx` to `receivers` (positions), as the channel asks it."""
    poses = PoseTable(["tx"] + [f"r{i}" for i in range(len(receivers))])
    vel = velocities or [(0.0, 0.0, 0.0)] * len(receivers)
    for name, p, v in [("tx", tx, (0.0, 0.0, 0.0))] + [(f"r{i}", r, vel[i]) for i, r in enumerate(receivers)]:
        poses.set_external(name)
        poses.update(name, 0.0, p, v)
    dist = [math.dist(tx, r) for r in receivers]
    return model.answer(Query(0.0, Frame(1, 2, 0, 32, 32), dist, list(range(len(receivers))), poses, 0,
                              list(range(1, len(receivers) + 1))))


@pytest.fixture
def stub(monkeypatch, tmp_path):
    """Grids without Bellhop: TL at range r is the .bty's depth at r (so a query reads back the bottom along the
    sector the model chose), delay r / 1500; the specs asked for are recorded."""
    asked: list[bellhop.GridSpec] = []

    def compute_grids(program, specs, workers=2, timeout=3600.0):
        out = []
        for s in specs:
            asked.append(s)
            r_b, z_b = zip(*s.bty, strict=True)
            tl = np.interp(s.rrs, r_b, z_b)
            shape = (len(s.sds), len(s.rds), len(s.rrs))
            out.append(bellhop.Grid(s.sds, s.rds, s.rrs, np.broadcast_to(tl, shape), np.broadcast_to(
                np.array(s.rrs) / 1500.0, shape), np.zeros(shape), np.zeros((*shape, len(bellhop.LATE_S)))))
        return out

    monkeypatch.setattr(bellhop, "compute_grids", compute_grids)
    monkeypatch.setenv("UWSIMNET_BELLHOP", "/bin/true")       # a program to tag the cache with; never run
    monkeypatch.setenv("UWSIMNET_CACHE", str(tmp_path))
    return asked


def test_sectors_are_centred_on_their_bearings():
    assert [bellhop.sector_of(math.cos(math.radians(a)), math.sin(math.radians(a)), 8)
            for a in (0, 22.4, 22.6, 45, 90, 135, 180, -90, 337.6, 359)] == [0, 0, 1, 1, 2, 3, 4, 6, 0, 0]
    assert bellhop.sector_of(-1.0, -1e-9, 4) == 2 and bellhop.sector_of(0.0, 0.0, 4) == 0


def test_each_bearing_reads_the_bottom_along_its_sector_from_the_senders_cell(stub):
    net = Network(load_scene_text(SCENE.format(sectors=8, rstep=50, zstep=10), "s.xml"))
    buoy, auv = net.modems["buoy-modem"].error, net.modems["auv-modem"].error
    assert buoy.cells == [(0.0, 0.0)] and auv.cells == [(0.0, 0.0), (1000.0, 0.0)]   # waypoints on a 250 m lattice
    assert buoy.sectors == 8 and len(buoy.paths) == 8 and len(auv.paths) == 16
    # the .bty of sector k: the slope along azimuth 45 k from the cell's centre, every rangeStep, held >= 1 m
    for s in stub:
        cell = (0.0, 0.0) if "(0, 0)" in s.label else (1000.0, 0.0)
        phi = math.radians(float(s.label.split("bearing ")[1].split(" deg")[0]))
        want = [max(1.0, slope_depth(cell[0] + r * math.cos(phi), cell[1] + r * math.sin(phi))) for r, _ in s.bty]
        assert [z for _, z in s.bty] == pytest.approx(want, abs=5e-7)    # to the .bty file's 6 decimals
        cell_deepest = max(z for t in stub if t.label.endswith(s.label.split(" from ")[1]) for _, z in t.bty)
        assert s.bty[-1][0] >= 1000.0 and s.bottom_m == cell_deepest and s.sds == [10.0]
        assert s.bottom_m == pytest.approx(max(slope_depth(cell[0] + r, 0.0) for r, _ in s.bty), abs=5e-7)
    # sectors mirrored about the slope's direction (+-45, +-90, +-135 deg) see the same bottom: one file each
    assert buoy.paths[2] == buoy.paths[6] and buoy.paths[1] == buoy.paths[7] and buoy.paths[3] == buoy.paths[5]
    assert len(set(buoy.paths)) == 5 and len({*buoy.paths, *auv.paths}) == 10
    assert len(stub) == 10                   # each file computed once: the AUV's cell (0, 0) is the buoy's
    r = 600.0
    for bearing, centre in ((0, 0), (30, 45), (90, 90), (100, 90), (180, 180), (250, 270)):
        a = math.radians(bearing)
        ans = query(buoy, (0.0, 0.0, -10.0), [(r * math.cos(a), r * math.sin(a), -20.0)])
        tl = buoy.link.sl_db - ans.level_db[0]
        assert tl == pytest.approx(slope_depth(r * math.cos(math.radians(centre)), 0.0), abs=5e-7), bearing
        assert ans.delay[0] == pytest.approx(r / 1500.0)
    assert buoy.grid_for((0.0, 0.0, -10.0), (10.0, 600.0, -20.0)) is buoy.grids[2]       # north: what plot draws
    # the AUV near its last waypoint sends from the cell at (1000, 0): east of it the bottom is 20 m deeper
    ans = query(auv, (990.0, 20.0, -10.0), [(1590.0, 20.0, -20.0), (390.0, 20.0, -20.0)])
    assert [auv.link.sl_db - v for v in ans.level_db] == pytest.approx([slope_depth(1600.0, 0), slope_depth(400, 0)])


@pytest.mark.parametrize("moving", [False, True])
def test_many_receivers_over_a_slope_get_the_answers_of_one_at_a_time(stub, moving):
    """The numpy path (more than MANY receivers: a gather per (cell, sector) grid) against the per-receiver
    path, receivers all around the sender, some beyond the grid's ranges, still or moving."""
    net = Network(load_scene_text(SCENE.format(sectors=8, rstep=50, zstep=10), "s.xml"))
    model = net.modems["auv-modem"].error
    rnd = random.Random(11)
    tx = (990.0, 20.0, -10.0)
    rxs = [(tx[0] + r * math.cos(a), tx[1] + r * math.sin(a), -rnd.uniform(1.0, 90.0))
           for r, a in ((rnd.uniform(60.0, 1100.0), rnd.uniform(0, 2 * math.pi)) for _ in range(80))]
    vel = [(rnd.uniform(-2, 2), rnd.uniform(-2, 2), 0.0) for _ in rxs] if moving else None
    many = query(model, tx, rxs, vel)
    assert len(rxs) > bellhop.MANY
    for i, rx in enumerate(rxs):
        one = query(model, tx, [rx], [vel[i]] if vel else None)
        for got, want in ((many.per[i], one.per[0]), (many.delay[i], one.delay[0]),
                          (many.level_db[i], one.level_db[0]), (many.doppler[i], one.doppler[0])):
            assert (math.isnan(got) and math.isnan(want)) or got == pytest.approx(want, rel=1e-9, abs=1e-12), i
    assert sum(math.isnan(d) for d in many.delay) > 3 and len({round(v, 3) for v in many.level_db}) > 40


def test_a_flat_bottom_keeps_one_grid_and_its_key(stub):
    flat = SCENE.format(sectors=8, rstep=50, zstep=10).replace("slope 100 0.02 0", "flat 100")
    with pytest.raises(ValueError):      # the stub's grids need a .bty: a flat bottom asks for none
        Network(load_scene_text(flat, "s.xml"))
    assert len(stub) == 1 and stub[0].bty is None


PROGRAM = bellhop.find_program()


@pytest.mark.skipif(PROGRAM is None, reason="Bellhop is not installed (`make bellhop`)")
def test_cached_sector_grids_against_a_direct_bellhop_run_with_the_same_bty(tmp_path, monkeypatch):
    monkeypatch.setenv("UWSIMNET_CACHE", str(tmp_path))
    assert PROGRAM is not None
    sc = load_scene_text(SCENE.format(sectors=4, rstep=25, zstep=2), "s.xml")
    net = Network(sc)
    model = net.modems["buoy-modem"].error
    env = sc.environment
    profile = [tuple(p) for p in env.profile]
    seabed = (env.seabed_speed_mps, env.seabed_density, env.seabed_attenuation)
    rnd = random.Random(37)
    worst = 0.0
    checked = 0
    for _ in range(20):
        k = rnd.randrange(4)
        phi = math.pi / 2 * k
        bty = [(float(r), max(1.0, slope_depth(r * math.cos(phi), r * math.sin(phi))))
               for r in np.arange(0.0, 1000.0 + 2.5 * 25, 25.0)]
        r = rnd.uniform(60.0, 980.0)
        zr = rnd.uniform(2.0, slope_depth(r * math.cos(phi), 0.0) - 4.0)
        bottom = max(slope_depth(r, 0.0) for r, _ in bty)     # the cell's deepest point: east, at the far end
        with tempfile.TemporaryDirectory() as d:
            shd = bellhop.run_bellhop(PROGRAM, bellhop.env_text(model.freq_hz, profile, bottom, seabed, [10.0],
                                                                [zr], [r], "I", bty=True), "shd", d,
                                      bty=bellhop.bty_text(bty))
        _, _, _, p = bellhop.read_shd(shd)
        direct = -20.0 * math.log10(abs(p[0, 0, 0]))
        ans = query(model, (0.0, 0.0, -10.0), [(r * math.cos(phi), r * math.sin(phi), -zr)])
        tl = model.link.sl_db - ans.level_db[0]
        worst = max(worst, abs(tl - direct))
        checked += 1
    print(f"range-dependent: worst TL error {worst:.3f} dB over {checked} geometries")
    assert checked == 20 and worst < 1.0
