"""Kinematic vehicles: the sans-IO model, and `uwsimnet vehicles` driving a broker's vehicle over Zenoh."""

from __future__ import annotations

import math
import time
from pathlib import Path

import msgpack
import pytest

from uwsimnet_zenoh.mobility.kinematic import CommandError, KinematicVehicle

pytest.importorskip("uwsimnet_gli")
from test_broker_e2e import UWSIMNET, Broker, Proc, device_xml, scene_xml, stop_all, vehicle_xml  # noqa: E402
from uwsimnet_gli import World  # noqa: E402

WORLD = "kine"


def test_velocity_is_clipped_and_integrated():
    v = KinematicVehicle("k", (0, 0, 0), max_speed=1.0)
    v.command({"v": [3.0, 4.0, 0.0]})                   # 5 m/s asked: 1 m/s along (0.6, 0.8)
    for _ in range(10):
        v.step(0.1)
    assert v.p == pytest.approx((0.6, 0.8, 0.0))
    v.command({"stop": True})
    v.step(0.1)
    assert v.v == (0.0, 0.0, 0.0) and v.p == pytest.approx((0.6, 0.8, 0.0))


def test_waypoints_reached_in_order_without_overshoot():
    v = KinematicVehicle("k", (0, 0, 0), max_speed=0.5)
    v.command({"waypoints": [[1, 0, 0], [1, 1, 0]], "speed": 2.0})    # speed capped at 0.5
    t, maxd = 0.0, 0.0
    while v.mode != "idle" and t < 10:
        v.step(0.05)
        t += 0.05
        maxd = max(maxd, v.p[0])
        assert math.hypot(*v.v) <= 0.5 + 1e-9
    assert v.mode == "idle" and v.p == pytest.approx((1, 1, 0), abs=0.02)
    assert 3.9 <= t <= 4.2 and maxd <= 1.0 + 1e-9


def test_acceleration_limit_and_bad_commands():
    v = KinematicVehicle("k", max_speed=1.0, max_accel=0.5)
    v.command({"v": [1, 0, 0]})
    v.step(1.0)
    assert v.v == pytest.approx((0.5, 0, 0))
    v.step(1.0)
    assert v.v == pytest.approx((1.0, 0, 0))
    for bad in ([1, 2], {"v": [1, 2]}, {"waypoint": [1, "x", 0]}, {"waypoints": []}, {"speed": -1, "v": [0, 0, 0]},
                {"fly": 1}):
        with pytest.raises(CommandError):
            v.command(bad)


def test_vehicles_command_moves_a_broker_vehicle(tmp_path: Path):
    scene = tmp_path / "k.xml"
    scene.write_text(scene_xml(world=WORLD, vehicles="".join([
        vehicle_xml("base", (0, 0, 0), device_xml("base-m", 1)),
        vehicle_xml("k", None, device_xml("k-m", 2)),
    ])))
    started: list[Proc] = []
    try:
        broker = Broker(scene, tmp_path / "trace.jsonl")
        started.append(broker)
        veh = Proc([*UWSIMNET, "vehicles", "--vehicle", "k=10,0,0", "--max-speed", "2", "--rate", "20",
                    "--connect", broker.endpoint])
        started.append(veh)
        veh.expect("uwsimnet: vehicles ready in kine: k", 20)
        with World(WORLD, connect=broker.endpoint) as w:
            def pos():
                p = w.control("state")["vehicles"]["k"]["p"]
                return None if p is None else tuple(p)

            deadline = time.monotonic() + 5
            while pos() is None and time.monotonic() < deadline:
                time.sleep(0.05)
            assert pos() == pytest.approx((10, 0, 0), abs=0.01)
            w.session.put(f"uwsimnet/{WORLD}/vehicle/k/cmd", msgpack.packb({"waypoint": [12, 0, 0]}))
            w.session.put(f"uwsimnet/{WORLD}/vehicle/k/cmd", b"\xc1garbage")          # ignored
            deadline = time.monotonic() + 5
            while time.monotonic() < deadline and pos()[0] < 11.98:
                time.sleep(0.05)
            assert pos() == pytest.approx((12, 0, 0), abs=0.05)
            # the modem moved with it: propagation delay of a frame follows the new distance
            base, k = w.modem("base-m"), w.modem("k-m")
            # the driver token's answer comes back through the router after it took k's rx subscription
            assert k.wait_kind(("sim",), timeout=10) == "sim" and base.wait_kind(("sim",), timeout=10) == "sim"
            base.send(2, b"ping")
            f = k.receive(timeout=5)
            assert f is not None
            assert f.t_rx - f.t_tx == pytest.approx(12 * 0.6667e-3 + 4 * 8 / 10_000, abs=1e-4)   # 12 m, 4 bytes
    finally:
        errors = stop_all(started)
        assert not errors, errors


def test_vehicles_follow_the_world_clock_speed_and_pause(tmp_path: Path):
    """`uwsimnet vehicles` steps on simulation time: at --speed 4 a vehicle covers 4 s of motion per wall
    second, and while the world is paused it does not move at all."""
    scene = tmp_path / "k.xml"
    scene.write_text(scene_xml(world=WORLD, vehicles="".join([
        vehicle_xml("base", (0, 0, 0), device_xml("base-m", 1)),
        vehicle_xml("k", None, device_xml("k-m", 2)),
    ])))
    started: list[Proc] = []
    try:
        broker = Broker(scene, tmp_path / "trace.jsonl", "--speed", "4")
        started.append(broker)
        veh = Proc([*UWSIMNET, "vehicles", "--vehicle", "k=0,0,0", "--max-speed", "1", "--rate", "20",
                    "--connect", broker.endpoint])
        started.append(veh)
        veh.expect("uwsimnet: vehicles ready in kine: k", 20)
        with World(WORLD, connect=broker.endpoint) as w:
            def x() -> float:
                p = w.control("state")["vehicles"]["k"]["p"]
                return math.nan if p is None else p[0]

            # 1 m/s; a put made before the vehicles' subscription reached the router is routed nowhere, so
            # the command is repeated until k moves (a command is idempotent), then the speed is measured
            deadline = time.monotonic() + 20
            while not x() > 0:
                assert time.monotonic() < deadline, "k never moved on its velocity command"
                w.session.put(f"uwsimnet/{WORLD}/vehicle/k/cmd", msgpack.packb({"v": [1, 0, 0]}))
                time.sleep(0.3)
            x0, t0 = x(), w.sim_time()
            time.sleep(1.0)
            x1, t1 = x(), w.sim_time()
            assert t1 - t0 == pytest.approx(4.0, abs=0.4)            # the world runs 4x
            assert x1 - x0 == pytest.approx(t1 - t0, abs=0.4)        # 1 m per simulated second
            w.control("pause")
            time.sleep(0.3)
            xp = x()
            time.sleep(1.0)
            assert x() == pytest.approx(xp, abs=1e-6)               # paused: the vehicle stands still
            w.control("resume")
            time.sleep(1.0)
            assert x() - xp == pytest.approx(4.0, abs=0.6)
    finally:
        errors = stop_all(started)
        assert not errors, errors
