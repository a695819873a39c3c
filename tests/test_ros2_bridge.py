"""The ROS<->simulator translation (uwsimnet_zenoh/ros2/bridge.py), sans-IO: what a run declares, how ROS
poses and frames become the simulator's, and how bad ROS input is counted and never raises."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from uwsimnet_zenoh.ros2 import wire as w

pytest.importorskip("rosbags", reason="ROS 2 CDR needs the extra: pip install 'uwsimnet-zenoh[ros2]'")
from uwsimnet_zenoh.ros2.bridge import (  # noqa: E402
    ModemInfo,
    Options,
    PoseUpdate,
    Ros2Bridge,
    TxRequest,
    VehicleInfo,
    frame_convention,
    parse_pose_input,
)
from uwsimnet_zenoh.ros2.cdr import Codec  # noqa: E402

GOLDEN = json.loads((Path(__file__).parent / "ros2_golden.json").read_text())["messages"]
ZID = "0123456789abcdef0123456789abcdef"
NOW = 1_700_000_000_000_000_000
MODEMS = [ModemInfo("alpha-m", 1, "alpha"), ModemInfo("bravo-m", 2, "bravo")]
VEHICLES = [VehicleInfo("alpha", "zenoh"), VehicleInfo("bravo", "scene", static=True),
            VehicleInfo("charlie", "scene"), VehicleInfo("delta", "zenoh")]


@pytest.fixture(scope="module")
def codec() -> Codec:
    return Codec("jazzy")


def bridge(codec, **kw) -> Ros2Bridge:
    opts = Options(**{"poses": (parse_pose_input("alpha=odom:/alpha/odom"), parse_pose_input("delta=tf:delta/base")),
                      **kw})
    return Ros2Bridge(opts, ZID, codec, MODEMS, VEHICLES)


def att(seq: int = 1) -> bytes:
    return w.encode_attachment(seq, NOW, bytes(16))


def odom(codec, frame: str, p, q=(0.0, 0.0, 0.0, 1.0), v=(0.0, 0.0, 0.0)) -> bytes:
    return codec.encode("nav_msgs/msg/Odometry", {
        "header": {"frame_id": frame}, "child_frame_id": "alpha/base_link",
        "pose": {"pose": {"position": dict(zip("xyz", p, strict=True)),
                          "orientation": dict(zip("xyzw", q, strict=True))}},
        "twist": {"twist": {"linear": dict(zip("xyz", v, strict=True))}}})


def key_of(b: Ros2Bridge, topic: str) -> str:
    return next(e.key for e in b.subscriptions() if e.topic == topic)


def test_graph_is_numbered_as_rmw_zenoh_numbers_it(codec):
    b = bridge(codec)
    toks = b.tokens()
    nodes = [t for t in toks if "/NN/" in t]
    assert nodes[0] == f"@ros2_lv/0/{ZID}/0/0/NN/%/%/uwsimnet"
    assert f"@ros2_lv/0/{ZID}/6/6/NN/%/%uwsimnet/alpha_m" in nodes
    ids = [int(t.split("/")[4]) for t in toks]
    assert sorted(ids) == list(range(len(toks)))             # one counter for the session, from 0
    assert all(w.parse_token(t) is not None for t in toks)
    pubs = {e.topic: e for e in b.publishers()}
    assert pubs["/uwsimnet/alpha_m/rx"].key == \
        "0/uwsimnet/alpha_m/rx/uwsimnet_msgs::msg::dds_::Frame_/" + GOLDEN["uwsimnet_msgs/msg/Frame"]["rihs01"]
    assert pubs["/tf_static"].qos == w.QoS(w.RELIABLE, w.TRANSIENT_LOCAL, w.KEEP_LAST, 1)
    subs = {e.topic for e in b.subscriptions()}
    assert subs == {"/alpha/odom", "/tf", "/uwsimnet/alpha_m/tx", "/uwsimnet/bravo_m/tx"}
    assert "/clock" not in pubs and "/clock" in {e.topic for e in bridge(codec, clock=True).publishers()}


def test_profiles_add_the_drivers_topics(codec):
    b = bridge(codec, profiles=("dmac2", "stonefish"))
    topics = {(e.kind, e.topic, e.ros_type) for e in b.graph.endpoints}
    assert ("MS", "/alpha_m/send", "dmac2_interfaces/msg/DMACPayload") in topics
    assert ("MP", "/alpha_m/recv", "dmac2_interfaces/msg/DMACPayload") in topics
    assert ("MS", "/bravo_m/data_to_send", "std_msgs/msg/String") in topics
    assert ("MP", "/bravo_m/received_data", "std_msgs/msg/String") in topics
    assert not any(t.startswith("/uwsimnet/") for _, t, _ in topics)


def test_odometry_in_ned_positions_an_enu_scene(codec):
    b = bridge(codec)
    out = b.on_ros_sample(key_of(b, "/alpha/odom"), odom(codec, "world_ned", (10.0, 20.0, 5.0), v=(1.0, 0, 0)),
                          att())
    (u,) = out
    assert u.vehicle == "alpha" and u.p == (20.0, 10.0, -5.0)      # NED (north, east, down) -> ENU
    assert u.v == pytest.approx((0.0, 1.0, 0.0))                   # 1 m/s forward, facing north
    out = b.on_ros_sample(key_of(b, "/alpha/odom"), odom(codec, "world", (10.0, 20.0, -5.0)), att(2))
    assert out == [PoseUpdate("alpha", (10.0, 20.0, -5.0), (0.0, 0.0, 0.0, 1.0), (0.0, 0.0, 0.0))]
    b2 = bridge(codec, scene_frame="ned")
    (u,) = b2.on_ros_sample(key_of(b2, "/alpha/odom"), odom(codec, "odom", (1.0, 2.0, 3.0)), att())
    assert u.p == (2.0, 1.0, -3.0)


def test_a_tf_child_frame_positions_a_vehicle(codec):
    b = bridge(codec)
    tf = codec.encode("tf2_msgs/msg/TFMessage", {"transforms": [
        {"header": {"frame_id": "world"}, "child_frame_id": "other",
         "transform": {"translation": {"x": 9.0}, "rotation": {"w": 1.0}}},
        {"header": {"frame_id": "world"}, "child_frame_id": "delta/base",
         "transform": {"translation": {"x": 1.0, "y": 2.0, "z": -3.0}, "rotation": {"w": 1.0}}}]})
    assert b.on_ros_sample(key_of(b, "/tf"), tf, att()) == \
        [PoseUpdate("delta", (1.0, 2.0, -3.0), (0.0, 0.0, 0.0, 1.0), None)]


def test_frame_conventions():
    assert [frame_convention(f) for f in ("world_ned", "NED", "/map_ned", "ned/odom", "world", "odom", "map",
                                          "kinned")] == ["ned"] * 4 + ["enu"] * 4


def test_transmit_and_driver_topics_become_tx_requests(codec):
    b = bridge(codec, profiles=("native", "dmac2", "stonefish"))
    tx = codec.encode("uwsimnet_msgs/msg/Transmit", {"dst": 2, "data": b"\x00hi\xff", "tag": 7, "has_tag": True})
    assert b.on_ros_sample(key_of(b, "/uwsimnet/alpha_m/tx"), tx, att()) == [TxRequest("alpha-m", 2, b"\x00hi\xff", 7)]
    dm = codec.encode("dmac2_interfaces/msg/DMACPayload", {"destination_address": 2, "payload": "ping", "msg_id": 9,
                                                           "type": 1})
    assert b.on_ros_sample(key_of(b, "/alpha_m/send"), dm, att()) == [TxRequest("alpha-m", 2, b"ping", 9)]
    sf = w.encode_string_cdr(b"hello")
    assert b.on_ros_sample(key_of(b, "/bravo_m/data_to_send"), sf, att()) == [TxRequest("bravo-m", 255, b"hello")]


def test_bad_samples_are_counted_reported_once_and_never_raise(codec, caplog):
    b = bridge(codec)
    k = key_of(b, "/alpha/odom")
    good = odom(codec, "world", (1.0, 2.0, 3.0))
    humble = k.rsplit("/", 1)[0] + "/TypeHashNotSupported"
    other_def = k.rsplit("/", 1)[0] + "/RIHS01_" + "0" * 64
    wrong_type = k.rsplit("/", 2)[0] + "/geometry_msgs::msg::dds_::PoseStamped_/RIHS01_" + "1" * 64
    caplog.set_level("WARNING", logger="uwsimnet.ros2")
    for _ in range(3):
        assert b.on_ros_sample(k, b"\x00\x01\x00\x00garbage", att()) == []         # malformed CDR
        assert b.on_ros_sample(k, good, None) == []                                # no attachment
        assert b.on_ros_sample(k, good, b"\x00" * 77) == []                        # old labelled attachment
        assert b.on_ros_sample(humble, good, att()) == []                          # a Humble publisher
        assert b.on_ros_sample(other_def, good, att()) == []                       # another definition
        assert b.on_ros_sample(wrong_type, good, att()) == []                      # another type
        nan = odom(codec, "world", (math.nan, 0.0, 0.0))
        assert b.on_ros_sample(k, nan, att()) == []                                # NaN pose
        assert b.on_ros_sample("0/unrelated/T/H", good, att()) == []               # not ours: ignored silently
    assert dict(b.problems.counts) == {"cdr": 3, "no-attachment": 3, "attachment": 3, "type_hash": 6, "type": 3,
                                       "invalid": 3}
    warnings = [r for r in caplog.records if r.name == "uwsimnet.ros2"]
    assert len(warnings) == 6                                                      # once per (reason, topic)
    assert any("Humble" in r.getMessage() for r in warnings)
    assert b.on_ros_sample(k, good, att()) != []                                   # and it goes on working


def test_a_humble_bridge_hears_humble_and_counts_jazzy(codec):
    hb = Ros2Bridge(Options(distro="humble", poses=(parse_pose_input("alpha=odom:/alpha/odom"),)), ZID,
                    Codec("humble"), MODEMS, VEHICLES)
    k = key_of(hb, "/alpha/odom")
    assert k.endswith("/TypeHashNotSupported")
    assert hb.on_ros_sample(k, odom(codec, "world", (1.0, 2.0, 3.0)), att()) != []
    jazzy = k.rsplit("/", 1)[0] + "/" + GOLDEN["nav_msgs/msg/Odometry"]["rihs01"]
    assert hb.on_ros_sample(jazzy, odom(codec, "world", (1.0, 2.0, 3.0)), att()) == []
    assert hb.problems.counts["type_hash"] == 1


def test_rx_and_status_become_ros_messages_with_attachments(codec):
    b = bridge(codec, profiles=("native", "dmac2", "stonefish"))
    puts = b.rx("bravo-m", 1, 2, b"ping 4", 4, 11.75, 12.5, 1125.0, NOW)
    assert [p.endpoint.topic for p in puts] == ["/uwsimnet/bravo_m/rx", "/bravo_m/recv", "/bravo_m/received_data"]
    f = codec.decode("uwsimnet_msgs/msg/Frame", puts[0].payload)
    assert (f.src, f.dst, f.seq, bytes(f.data), f.t_tx, f.t_rx, f.distance) == (1, 2, 4, b"ping 4", 11.75, 12.5, 1125.0)
    assert (f.header.stamp.sec, f.header.stamp.nanosec, f.header.frame_id) == (12, 500_000_000, "bravo-m")
    d = codec.decode("dmac2_interfaces/msg/DMACPayload", puts[1].payload)
    assert (d.source_address, d.destination_address, d.payload, d.propagation_time) == (1, 2, "ping 4", 750000)
    assert w.decode_string_cdr(puts[2].payload) == b"ping 4"
    atts = [w.decode_attachment(p.attachment) for p in puts]
    assert [a.seq for a in atts] == [1, 1, 1] and all(a.timestamp_ns == NOW for a in atts)
    assert w.decode_attachment(b.rx("bravo-m", 1, 2, b"x", 5, 1.0, 2.0, None, NOW)[0].attachment).seq == 2
    (st,) = b.status("alpha-m", "dropped", "fifo", 42, None, 3.0, NOW)
    s = codec.decode("uwsimnet_msgs/msg/Status", st.payload)
    assert (s.event, s.reason, s.tag, s.has_tag, s.has_seq) == ("dropped", "fifo", 42, True, False)


def test_scene_vehicles_go_on_tf_and_static_ones_once_on_tf_static(codec):
    b = bridge(codec)
    (p,) = b.vehicle_pose("charlie", (1.0, 2.0, 3.0), None, 1.5, NOW)
    assert p.endpoint.topic == "/tf"
    t = codec.decode("tf2_msgs/msg/TFMessage", p.payload).transforms[0]
    assert (t.header.frame_id, t.child_frame_id, t.transform.translation.x, t.transform.rotation.w) == \
        ("world", "charlie", 1.0, 1.0)
    (s,) = b.vehicle_pose("bravo", (5.0, 0.0, -10.0), None, 0.0, NOW)
    assert s.endpoint.topic == "/tf_static"
    assert b.vehicle_pose("bravo", (5.0, 0.0, -10.0), None, 0.1, NOW) == []        # unchanged: nothing more
    assert b.vehicle_pose("alpha", (0.0, 0.0, 0.0), None, 0.0, NOW) == []         # ROS positions it: not ours


def test_diagnostics_report_modem_kinds_counters_and_bad_samples(codec):
    b = bridge(codec)
    b.on_ros_sample(key_of(b, "/alpha/odom"), b"\x00\x01\x00\x00x", att())
    (p,) = b.diagnostics([{"id": "alpha-m", "kind": "sim", "counters": {"tx": 3, "rx": 1}},
                          {"id": "bravo-m", "kind": "real", "counters": {}}], 2.0, NOW)
    d = codec.decode("diagnostic_msgs/msg/DiagnosticArray", p.payload)
    by = {s.name: s for s in d.status}
    assert by["uwsimnet/alpha-m"].hardware_id == "sim:alpha-m"
    assert {(v.key, v.value) for v in by["uwsimnet/alpha-m"].values} == {("kind", "sim"), ("tx", "3"), ("rx", "1")}
    assert by["uwsimnet/bravo-m"].message == "real modem"
    assert {(v.key, v.value) for v in by["uwsimnet/ros2"].values} == {("cdr", "1")}


@pytest.mark.parametrize("spec", ["alpha", "alpha=odom", "alpha=gps:/x", "alpha=odom:/9x", "alpha=odom:/x@up"])
def test_bad_pose_options_are_refused(spec):
    with pytest.raises(w.Ros2WireError):
        parse_pose_input(spec)


def test_pose_options_must_name_a_ros_positioned_vehicle(codec):
    for spec in ("nobody=odom:/x", "charlie=odom:/x"):
        with pytest.raises(w.Ros2WireError):
            Ros2Bridge(Options(poses=(parse_pose_input(spec),)), ZID, codec, MODEMS, VEHICLES)
    with pytest.raises(w.Ros2WireError):
        Options(profiles=("ros1",))
