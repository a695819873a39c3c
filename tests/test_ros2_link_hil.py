"""The ROS 2 link with robot A's modem swapped for a real one: `uwsimnet driver evologics` serves b-m, its
"hardware" the EvoLogics emulator (AT over TCP) of simulated modem a-m; robot B's link is on c-m. The link
is the same code (uwsimnet_gli.Modem) and the robots see the same topics."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import pytest

pytest.importorskip("rosbags", reason="ROS 2 CDR needs the extra: pip install 'uwsimnet-zenoh[ros2]'")
import zenoh  # noqa: E402
from test_broker_e2e import UWSIMNET, Broker, Proc, device_xml, free_port, scene_xml, stop_all, vehicle_xml  # noqa: E402
from uwsimnet_gli import World  # noqa: E402

from uwsimnet_zenoh.bus.ros2_link import Ros2Link  # noqa: E402
from uwsimnet_zenoh.ros2 import link as L  # noqa: E402
from uwsimnet_zenoh.ros2 import wire as w  # noqa: E402
from uwsimnet_zenoh.ros2.cdr import Codec  # noqa: E402

WORLD = "r2hil"
TWIST = "geometry_msgs/msg/Twist"
IMAGE = "sensor_msgs/msg/CompressedImage"


@pytest.fixture
def parts(tmp_path: Path):
    scene = tmp_path / "hil.xml"
    scene.write_text(scene_xml(world=WORLD, vehicles="".join([
        vehicle_xml("a", (0, 0, 0), device_xml("a-m", 1)),
        vehicle_xml("b", (50, 0, 0), device_xml("b-m", 2)),
        vehicle_xml("c", (100, 0, 0), device_xml("c-m", 3)),
    ])))
    started: list[Proc] = []
    try:
        b = Broker(scene, tmp_path / "trace.jsonl")
        started.append(b)
        port = free_port()
        emu = Proc([*UWSIMNET, "emulate", "evologics", "--port", str(port), "--id", "a-m", "--world", WORLD,
                    "--connect", b.endpoint])
        started.append(emu)
        emu.expect("uwsimnet: emulator evologics ready", 20)
        drv = Proc([*UWSIMNET, "driver", "evologics", "--host", "127.0.0.1", "--port", str(port), "--id", "b-m",
                    "--connect", b.endpoint])
        started.append(drv)
        drv.expect("uwsimnet: driver evologics ready", 20)
        yield b
    finally:
        errors = stop_all(started)
        assert not errors, errors


def test_link_over_the_evologics_driver_and_emulator(parts):
    codec = Codec("jazzy")
    rules = [L.TopicRule("/cmd_vel", TWIST, "both", dst=3, priority=0),
             L.TopicRule("/camera/compressed", IMAGE, "both", dst=3, priority=9, policy="keep_last", depth=1)]
    with World(WORLD, connect=parts.endpoint) as wd:
        assert wd.modem("b-m").wait_kind(("real",), timeout=10) == "real"
    got: list[tuple[str, bytes, bytes]] = []
    cond = threading.Condition()
    diags: list[bytes] = []

    def on(sample: zenoh.Sample) -> None:
        if "/diagnostics/" in str(sample.key_expr):
            diags.append(sample.payload.to_bytes())
            return
        with cond:
            got.append((str(sample.key_expr), sample.payload.to_bytes(), sample.attachment.to_bytes()))
            cond.notify_all()

    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", f'["{parts.endpoint}"]')
    with (Ros2Link([parts.endpoint], WORLD, "b-m", rules, codec=codec, domain=1, mtu=64) as a,
          Ros2Link([parts.endpoint], WORLD, "c-m", rules, codec=codec, domain=2, mtu=64) as b,
          zenoh.open(conf) as robots):
        robots.declare_subscriber("2/**", on)
        time.sleep(1.0)
        tw_a = w.data_key(1, "/cmd_vel", TWIST, codec.key_hash(TWIST))
        im_a = w.data_key(1, "/camera/compressed", IMAGE, codec.key_hash(IMAGE))
        twist = codec.encode(TWIST, {"linear": {"x": 0.5}, "angular": {"z": 0.1}})
        image = codec.encode(IMAGE, {"format": "jpeg", "data": bytes(range(256)) * 6})
        t0 = time.time_ns()
        robots.put(tw_a, twist, attachment=w.encode_attachment(1, t0, bytes(16)))
        robots.put(im_a, image, attachment=w.encode_attachment(1, time.time_ns(), bytes(16)))
        time.sleep(0.3)
        robots.put(tw_a, twist, attachment=w.encode_attachment(2, time.time_ns(), bytes(16)))
        with cond:
            assert cond.wait_for(lambda: len(got) >= 3, 120), (got, a.summary(), b.summary())
        assert [k.split("/")[1] for k, _, _ in got] == ["cmd_vel", "cmd_vel", "camera"]
        assert got[0][1] == twist and got[2][1] == image
        assert w.decode_attachment(got[0][2]).timestamp_ns == t0 // 1000 * 1000
        assert a.problems == {} and b.problems == {}
