"""The channel-model port through its harness (phy.testing) and in real runs: the built-in expression model
against its formula, the default vectorising adapter, the contract check, a model's own delays and the
states (positions, velocities) a model sees, and the SINR rule's refusal of a model without power."""

from __future__ import annotations

import math

import pytest
from conftest import device, scene, vehicle

from uwsimnet_zenoh.engine.build import BuildError
from uwsimnet_zenoh.engine.network import Network
from uwsimnet_zenoh.phy import testing
from uwsimnet_zenoh.phy.models import ChannelModel, Reception
from uwsimnet_zenoh.scene.model import AcousticChannelSpec, Channel, Flow, ModelSpec, Waypoint

SEEN: list = []


class SlowWater(ChannelModel):
    """Per pair only: PER = d / 10 km, delay = d / c + extra (c and extra are parameters)."""

    def __init__(self, params, ctx):
        self.c = float(params.get("c", "1400"))
        self.extra = float(params.get("extra", "0"))

    def reception(self, tx, rx, distance, t, frame):
        SEEN.append((tx, rx, distance, t, frame.size))
        return Reception(min(1.0, distance / 10_000), distance / self.c + self.extra, -distance)


class Broken(ChannelModel):
    def __init__(self, params, ctx):
        pass

    def reception(self, tx, rx, distance, t, frame):
        return Reception(1.5)


def test_expression_model_is_its_formula_through_the_harness():
    h = testing.Harness("expression", expr="1e-6*m", unit="bit")
    xs = [10.0, 250.0, 1000.0, 4000.0]
    a = h.answer([(x, 0.0, 0.0) for x in xs], size=40)
    for x, p in zip(xs, a.per, strict=True):
        assert float(p) == pytest.approx(1 - (1 - 1e-6 * x) ** 320, rel=1e-12)
    assert a.delay is None and h.check() == []


def test_a_per_pair_model_is_vectorised_by_the_default_answer():
    h = testing.Harness(SlowWater, {"c": "1500", "extra": "0.25"})
    rxs = [(300.0, 400.0, 0.0), (0.0, 0.0, -2000.0), (6.0, 8.0, 0.0)]
    a = h.answer(rxs, size=20)
    for r, p, d, lv in zip(rxs, a.per, a.delay, a.level_db, strict=True):
        dist = math.dist((0.0, 0.0, 0.0), r)
        assert p == pytest.approx(dist / 10_000) and d == pytest.approx(dist / 1500 + 0.25) and lv == -dist
    assert h.check() == []


def test_the_model_sees_positions_velocities_time_and_size():
    SEEN.clear()
    h = testing.Harness(SlowWater)
    h.reception((100.0, 0.0, -5.0), tx=(1.0, 2.0, 3.0), t=7.5, size=33, tx_velocity=(1.0, 0.0, 0.0),
           rx_velocities=[(0.0, -2.0, 0.5)])
    tx, rx, dist, t, size = SEEN[-1]
    assert tx.position == (1.0, 2.0, 3.0) and tx.velocity == (1.0, 0.0, 0.0)
    assert rx.position == (100.0, 0.0, -5.0) and rx.velocity == (0.0, -2.0, 0.5)
    assert dist == pytest.approx(math.dist((1, 2, 3), (100, 0, -5))) and t == 7.5 and size == 33


def test_contract_violations_are_reported_and_unknown_parameters_refused():
    assert any("not in [0, 1]" in p for p in testing.Harness(Broken).check())
    with pytest.raises(ValueError, match="unknown parameter"):
        testing.Harness(SlowWater, {"speed": "1"})


def test_delivery_draws_as_the_channel_does():
    h = testing.Harness(SlowWater)
    got = h.delivery((5000.0, 0.0, 0.0), frames=4000, size=10)      # PER 0.5
    assert abs(got - 0.5) < 4 * math.sqrt(0.25 / 4000)


def _net(model: ModelSpec, *, moving: bool = False, dur: float = 20.0) -> tuple[Network, list[dict]]:
    b = vehicle("b", (3000.0, 0.0, 0.0), device("b", 2, max_distance=1e9))
    if moving:     # b sails at 2 m/s along x, then dives at 0.5 m/s
        b = b.model_copy(update={"trajectory": (Waypoint(t=0, x=3000, y=0, z=0), Waypoint(t=10, x=3020, y=0, z=-5)),
                                 "position": (3000.0, 0.0, 0.0)})
    sc = scene([vehicle("a", (0.0, 0.0, 0.0), device("a", 1, max_distance=1e9)), b],
               [Flow(name="f", src="a", dst=2, size=10, interval=1.0, stop=dur)],
               channels=[Channel(id=0, prop_s_per_m=1 / 1500, min_prop_s=0.0, model=model)], duration=dur + 10)
    net = Network(sc)
    rec: list[dict] = []
    net.tracer.add(rec.append)
    net.run()
    return net, rec


def test_a_models_delay_sets_the_arrival_in_a_real_run():
    _, rec = _net(ModelSpec(name=f"{__name__}:SlowWater", params={"c": "1000", "extra": "0.5"}))
    tx = {r["seq"]: r["t"] for r in rec if r["ev"] == "tx" and r["dev"] == "a"}
    done = [r for r in rec if r["ev"] in ("rx", "drop") and r["dev"] == "b"]
    assert len(tx) == 20 and len(done) == 20        # conservation: one outcome per frame
    for r in done:
        # 10 B at 1000 bit/s = 80 ms on air; 3000 m at 1000 m/s + 0.5 s: 3.5 s (the straight path: 2 s)
        assert r["t"] == pytest.approx(tx[r["seq"]] + 3.5 + 0.08, abs=1e-9)
    assert {r["reason"] for r in done if r["ev"] == "drop"} <= {"prop"}


def test_the_model_sees_a_trajectorys_velocity():
    SEEN.clear()
    _net(ModelSpec(name=f"{__name__}:SlowWater"), moving=True, dur=5)
    for tx, rx, _, t, _ in SEEN:
        assert tx.velocity == (0.0, 0.0, 0.0)
        assert rx.velocity == pytest.approx((2.0, 0.0, -0.5)) and rx.position[0] == pytest.approx(3000 + 2 * t)


def test_a_sinr_channel_refuses_a_model_without_received_power():
    ch = Channel(id=0, acoustic=AcousticChannelSpec(interference="sinr"),
                 model=ModelSpec(name=f"{__name__}:SlowWater", line=12))
    sc = scene([vehicle("a", (0.0, 0.0, 0.0), device("a", 1)), vehicle("b", (10.0, 0.0, 0.0), device("b", 2))],
               channels=[ch])
    with pytest.raises(BuildError, match="decides collisions by SINR.*reports none") as e:
        Network(sc)
    assert e.value.line == 12


def test_naming_a_builtin_is_the_default():
    _, rec = _net(ModelSpec(name="expression"))
    assert len([r for r in rec if r["ev"] == "rx"]) == 20
    with pytest.raises(BuildError, match="AcousticCommsDevice"):
        _net(ModelSpec(name="acoustic"))


def test_per_curves_for_the_view_go_through_the_port():
    from uwsimnet_zenoh.phy.models import ModelContext
    from uwsimnet_zenoh.phy.ocean_model import OceanModel

    model = SlowWater({}, None)
    assert list(model.per([100.0, 2500.0, 20_000.0], 10)) == pytest.approx([0.01, 0.25, 1.0])
    ctx = ModelContext(None, Channel(id=0, prop_s_per_m=1 / 1500), 1,
                       {"expression": lambda: testing.RateErrorModel("1e-4*m", "packet")}, "expression")
    assert OceanModel({}, ctx).per(1000.0, 10) == pytest.approx(0.1)
