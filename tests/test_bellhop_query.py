"""The per-frame query of the channel model "bellhop" on many receivers (numpy, one gather per frame) gives
what the per-receiver path gives, receiver by receiver, on the grid Bellhop made (tests/data/bellhop/): the
same interpolation, reciprocity swap, ISI term, BER and PER, beyond-the-grid losses included."""

from __future__ import annotations

import math
import random
from pathlib import Path

import numpy as np
import pytest

from uwsimnet_zenoh.engine.network import Network
from uwsimnet_zenoh.kernel.frame import Frame
from uwsimnet_zenoh.mobility.trajectory import PoseTable
from uwsimnet_zenoh.phy import bellhop
from uwsimnet_zenoh.phy.models import Query
from uwsimnet_zenoh.phy.ocean import PRESETS
from uwsimnet_zenoh.scene import load_scene

DATA = Path(__file__).resolve().parent / "data"


def _query(tx: tuple[float, float, float], rxs: list[tuple[float, float, float]], size: int = 32,
           vel: dict[int, tuple[float, float, float]] | None = None) -> Query:
    """One transmission at t = 0; `vel`: velocities by vehicle (0 = the sender, i + 1 = receiver i)."""
    vel = vel or {}
    poses = PoseTable(["tx"] + [f"rx{i}" for i in range(len(rxs))])
    for i, (name, p) in enumerate([("tx", tx)] + [(f"rx{i}", p) for i, p in enumerate(rxs)]):
        poses.set_external(name)
        poses.update(name, 0.0, p, vel.get(i, (0.0, 0.0, 0.0)))
    return Query(0.0, Frame(1, 2, 0, size, size), [math.dist(tx, p) for p in rxs], list(range(len(rxs))), poses,
                 0, list(range(1, len(rxs) + 1)))


@pytest.mark.parametrize(("tx_depth", "moving"), [(10.0, False), (60.0, False), (10.0, True)])
def test_many_receivers_at_once_answer_as_one_at_a_time(monkeypatch, tx_depth, moving):
    """On the grid's source depth and off it (the reciprocity swap); still, and with the sender and half of
    the receivers moving at up to 5 m/s (the arrival's fixed point and the Doppler factor)."""
    monkeypatch.setenv("UWSIMNET_CACHE", str(DATA))
    monkeypatch.setenv("UWSIMNET_BELLHOP", "/nonexistent/bellhop")
    model = Network(load_scene(DATA / "ocean-shadow.xml")).modems["buoy-modem"].error
    rnd = random.Random(37)
    tx = (0.0, 0.0, -tx_depth)
    rxs = []
    for _ in range(256):
        r, a = rnd.uniform(0.0, 2200.0), rnd.uniform(0.0, 2 * math.pi)    # some beyond the grid's 2000 m
        rxs.append((r * math.cos(a), r * math.sin(a), -rnd.choice([rnd.uniform(0.0, 210.0), 10.0])))
    vel = {}
    if moving:
        vel[0] = (1.5, -0.5, 0.2)
        for i in range(0, len(rxs), 2):
            vel[i + 1] = (rnd.uniform(-5, 5), rnd.uniform(-5, 5), rnd.uniform(-1, 1))
    many = model.answer(_query(tx, rxs, vel=vel))
    assert len(rxs) > bellhop.MANY and len(many.per) == 256
    lost = delivered = 0
    for i, p in enumerate(rxs):
        one = model.answer(_query(tx, [p], vel={k: v for k, v in ((0, vel.get(0)), (1, vel.get(i + 1))) if v}))
        for got, want in ((many.per[i], one.per[0]), (many.delay[i], one.delay[0]),
                          (many.level_db[i], one.level_db[0]), (many.doppler[i], one.doppler[0])):
            assert (math.isnan(got) and math.isnan(want)) or got == pytest.approx(want, rel=1e-9, abs=1e-12), i
        lost += one.per[0] == 1.0
        delivered += one.per[0] < 0.5
    assert lost > 10 and delivered > 10                    # both outcomes are exercised
    if moving:
        assert sum(abs(d - 1.0) > 1e-4 for d in many.doppler) > 100


def test_the_vectorised_mean_speed_is_the_profiles():
    """`mean_speeds` (the numpy path's Doppler speed) against `SoundSpeedProfile.mean_speed`, on every preset,
    depth pairs inside, across and beyond the profile's points, equal ones included.  To 1e-9: a difference of
    travel times loses digits when the two depths are close (6e-11 seen), which moves a Doppler factor by
    ~1e-13."""
    rnd = random.Random(5)
    for name, (_, prof) in PRESETS.items():
        for z0 in (0.0, 10.0, rnd.uniform(0.0, 300.0), prof.depths[-1] + 50.0):
            z = np.array([rnd.uniform(0.0, 1.2 * prof.depths[-1] + 100.0) for _ in range(200)] + [z0, z0 + 1e-12])
            got = bellhop.mean_speeds(prof, z0, z)
            want = [prof.mean_speed(z0, x) for x in z.tolist()]
            assert got == pytest.approx(want, rel=1e-9, abs=0.0), name


def test_the_devices_of_a_scene_share_one_loaded_grid(monkeypatch):
    monkeypatch.setenv("UWSIMNET_CACHE", str(DATA))
    monkeypatch.setenv("UWSIMNET_BELLHOP", "/nonexistent/bellhop")
    net = Network(load_scene(DATA / "ocean-shadow.xml"))
    a, b = net.modems["buoy-modem"].error, net.modems["auv-modem"].error
    assert a is not b and a.grid is b.grid and a._stack is b._stack
