"""The ROS 2 link's sans-IO core against its documented byte layout (docs/ros2-link.md), the fragment
count formula, and CDR made by rosbags (not by this project)."""

from __future__ import annotations

import math
import struct
import zlib

import pytest

from uwsimnet_zenoh.ros2 import link as L

TWIST = "geometry_msgs/msg/Twist"


def _twist_cdr(vx: float, wz: float) -> bytes:
    rosbags = pytest.importorskip("rosbags.typesys")
    ts = rosbags.get_typestore(rosbags.Stores.ROS2_JAZZY)
    t, v = ts.types[TWIST], ts.types["geometry_msgs/msg/Vector3"]
    return bytes(ts.serialize_cdr(t(linear=v(x=vx, y=0.0, z=0.0), angular=v(x=0.0, y=0.0, z=wz)), TWIST))


def test_unfragmented_frame_is_the_documented_layout():
    stamp_ns = 1_733_000_000_123_456_789
    frame = L.fragment(5, 200, b"abc", False, stamp_ns, 64)
    want = bytes([5, 200]) + struct.pack("<I", (stamp_ns // 1000) % 2**32) + b"abc"
    assert frame == [want]
    h, chunk = L.decode_frame(want)
    assert (h.topic, h.seq, h.index, h.count, h.compressed, chunk) == (5, 200, 0, 1, False, b"abc")


def test_fragment_headers_and_count_formula():
    payload = bytes(range(256)) * 80                       # 20480 bytes
    mtu = 128
    frames = L.fragment(3, 7, payload, True, 0, mtu)
    first, rest = mtu - 8, mtu - 4
    assert len(frames) == 1 + math.ceil((len(payload) - first) / rest)
    assert all(len(f) <= mtu for f in frames)
    assert frames[0][:4] == bytes([0x80 | 0x40 | 3, 7, 0, len(frames) - 1])
    assert frames[1][:4] == bytes([0xC3, 7, 1, len(frames) - 1])
    assert b"".join([frames[0][8:]] + [f[4:] for f in frames[1:]]) == payload


def test_oversize_past_256_fragments():
    with pytest.raises(L.LinkError, match="oversize"):
        L.fragment(0, 0, bytes(256 * 60), False, 0, 64)


def test_twist_fits_one_32_byte_frame_with_deflate():
    cdr = _twist_cdr(0.5, 0.1)
    payload, z = L.pack(cdr, True)
    frames = L.fragment(0, 0, payload, z, 0, 32)
    assert len(frames) == 1 and len(frames[0]) <= 32
    # another implementation inflates with plain zlib raw DEFLATE
    assert zlib.decompress(frames[0][6:], -15) == cdr


def test_reassembly_whole_and_lost_fragment_drops_whole():
    payload = bytes(range(256)) * 80
    frames = L.fragment(2, 1, payload, False, 5_000_000, 100)
    r = L.Reassembler()
    out = [r.push(9, f, 0.0) for f in frames]
    assert out[:-1] == [None] * (len(frames) - 1)
    assert out[-1] == (2, payload, 5000)
    frames2 = L.fragment(2, 2, payload, False, 0, 100)
    for f in frames2[:3] + frames2[4:]:                    # fragment 3 lost
        assert r.push(9, f, 1.0) is None
    nxt = L.fragment(2, 3, b"x", False, 0, 100)
    assert r.push(9, nxt[0], 2.0) == (2, b"x", 0)
    assert r.drops == {(2, "lost"): 1}


def test_reassembly_timeout_and_malformed():
    frames = L.fragment(1, 0, bytes(500), False, 0, 100)
    r = L.Reassembler(timeout=5.0)
    r.push(1, frames[0], 0.0)
    r.expire(6.0)
    assert r.drops == {(1, "lost"): 1}
    with pytest.raises(L.LinkError):
        r.push(1, b"\x81", 7.0)
    with pytest.raises(L.LinkError):
        r.push(1, bytes([0x40, 0, 0, 0, 0, 0]) + b"not deflate \xff\xff", 7.0)


def test_stamp_unwrap_nearest_receiver_clock():
    t = 1_733_000_000_000_000_000
    for delay_s in (0.0, 3.7, 600.0):
        now = t + int(delay_s * 1e9)
        assert L.unwrap_stamp((t // 1000) % 2**32, now) == t // 1000 * 1000


def _rules():
    return [L.TopicRule("/cmd_vel", TWIST, "out", dst=2, priority=0, policy="fifo", depth=4),
            L.TopicRule("/image/compressed", "sensor_msgs/msg/CompressedImage", "out", priority=9,
                        policy="keep_last", depth=1, compress=False)]


def test_priority_preempts_at_frame_granularity():
    s = L.Sender(_rules(), mtu=64)
    assert s.offer("/image/compressed", bytes(2000), 0, 0.0) is None
    s.next_frame()                                         # image fragment 0 on air
    assert s.offer("/cmd_vel", b"\x00\x01\x00\x00" + bytes(48), 0, 0.1) is None
    dst, frame = s.next_frame()
    assert dst == 2 and frame[0] & 0x3F == 0               # the control message goes next
    dst, frame = s.next_frame()
    assert dst == L.BROADCAST and frame[2] == 1            # then the image resumes at fragment 1


def test_keep_last_supersedes_fifo_refuses_rate_budget_unknown():
    s = L.Sender(_rules(), mtu=64)
    s.offer("/image/compressed", bytes(100), 0, 0.0)
    s.offer("/image/compressed", bytes(100), 0, 0.0)
    assert s.stats[1].dropped == {"superseded": 1}
    for _ in range(4):
        assert s.offer("/cmd_vel", b"c", 0, 0.0) is None
    assert s.offer("/cmd_vel", b"c", 0, 0.0) == "queue_full"
    assert s.offer("/nope", b"c", 0, 0.0) == "unknown_topic"
    rs = L.Sender([L.TopicRule("/a", TWIST, rate=2.0), L.TopicRule("/b", TWIST, budget=100, compress=False)], 64)
    assert rs.offer("/a", b"x", 0, 0.0) is None
    assert rs.offer("/a", b"x", 0, 0.2) == "rate"
    assert rs.offer("/a", b"x", 0, 0.5) is None
    assert rs.offer("/b", bytes(50), 0, 0.0) is None       # 56 bytes on air of the 100-byte bucket
    assert rs.offer("/b", bytes(50), 0, 0.0) == "budget"
    assert rs.offer("/b", bytes(50), 0, 1.0) is None       # refilled at 100 B/s


def test_parse_rule_cli_form_and_errors():
    r = L.parse_rule("topic=/cmd_vel,type=geometry_msgs/msg/Twist,dir=out,dst=2,prio=0,policy=fifo,rate=5")
    assert (r.name, r.direction, r.dst, r.priority, r.rate) == ("/cmd_vel", "out", 2, 0, 5.0)
    for bad in ("topic=/a", "topic=a,type=x/msg/Y", "topic=/a,type=x/msg/Y,dst=300", "topic=/a,type=x/msg/Y,zz=1",
                "topic=/a,type=x/msg/Y,depth=q"):
        with pytest.raises(L.LinkError):
            L.parse_rule(bad)
    with pytest.raises(L.LinkError, match="twice"):
        L.check_rules([r, r])


def test_pose_from_ros_by_default_for_vehicles_positioned_from_outside():
    """Under --ros2 a poseSource-zenoh vehicle no --ros-pose names follows nav_msgs/Odometry on /<vehicle>/odom
    (rmw_zenoh key by its rules: domain/topic/dds type/hash); a named one keeps its option; a scene-driven one
    gets nothing."""
    from uwsimnet_zenoh.ros2.bridge import ModemInfo, Options, Ros2Bridge, VehicleInfo, parse_pose_input
    from uwsimnet_zenoh.ros2.cdr import Codec

    codec = Codec("jazzy")
    vehicles = [VehicleInfo("alpha-1", "zenoh"), VehicleInfo("bravo", "zenoh"), VehicleInfo("charlie", "scene")]
    opts = Options(poses=(parse_pose_input("bravo=pose:/bravo/pose"),))
    b = Ros2Bridge(opts, "0123456789abcdef0123456789abcdef", codec, [ModemInfo("a-m", 1, "alpha-1")], vehicles)
    subs = {e.topic: e for e in b.graph.endpoints if e.kind == "MS" and e.role == "pose"}
    assert set(subs) == {"/alpha_1/odom", "/bravo/pose"}
    odom = "nav_msgs/msg/Odometry"
    assert subs["/alpha_1/odom"].key == f"0/alpha_1/odom/nav_msgs::msg::dds_::Odometry_/{codec.key_hash(odom)}"
    assert subs["/alpha_1/odom"].arg == "alpha-1"


def test_scene_ros_pose_element():
    """<rosPose> in a vehicle: its pose input under --ros2 (an option still wins); a bad one is file:line."""
    from test_broker_e2e import device_xml, scene_xml

    from uwsimnet_zenoh.app import ros2 as app_ros2
    from uwsimnet_zenoh.errors import UwsimnetError
    from uwsimnet_zenoh.ros2.bridge import Options, default_poses, parse_pose_input
    from uwsimnet_zenoh.scene import load_scene_text

    def scene(pose: str) -> str:
        return scene_xml(vehicles=f"<vehicle><name>bravo</name><poseSource>zenoh</poseSource>{pose}"
                                  f"{device_xml('b-m', 2)}</vehicle>")

    sc = load_scene_text(scene("<rosPose>pose:/bravo/pose@ned</rosPose>"), source="s.xml")
    assert sc.vehicles[0].ros_pose == "pose:/bravo/pose@ned"
    _, vehicles = app_ros2.scene_view(sc)
    assert default_poses(Options(), vehicles) == (parse_pose_input("bravo=pose:/bravo/pose@ned"),)
    opt = parse_pose_input("bravo=odom:/x")
    assert default_poses(Options(poses=(opt,)), vehicles) == (opt,)
    with pytest.raises(UwsimnetError, match=r"s\.xml:\d+: .*rosPose"):
        load_scene_text(scene("<rosPose>gps:/bravo</rosPose>"), source="s.xml")


def test_cli_bad_input_is_one_line_exit_2():
    import subprocess
    import sys
    base = [sys.executable, "-m", "uwsimnet_zenoh.cli", "ros2-link", "a-m", "--world", "w", "--duration", "1"]
    for extra in (["--topic", "topic=/a"], ["--topic", "topic=/a,type=geometry_msgs/msg/Twist,dst=999"],
                  ["--connect", "tcp/127.0.0.1:1", "--topic", "topic=/a,type=geometry_msgs/msg/Twist"]):
        r = subprocess.run(base + extra, capture_output=True, text=True, timeout=60)
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr, r.stderr


def test_qos_announcement_is_the_documented_layout_and_precedes_the_message():
    """`3f 01 <topic> <rel | dur << 2 | hist << 4> <depth u16>` (rmw's enum values), queued ahead of the
    topic's next message, again only after QOS_PERIOD_S; a QoS change is announced at once."""
    from uwsimnet_zenoh.ros2 import wire as w

    qos = w.QoS(reliability=2, durability=1, history=1, depth=5)      # best effort, transient local, keep last
    frame = L.encode_qos(3, qos)
    assert frame == bytes([0x3F, 0x01, 3, 2 | 1 << 2 | 1 << 4, 5, 0]) and L.is_control(frame)
    assert L.decode_qos(frame) == (3, qos)
    for bad in (frame[:5], bytes([0x3F, 2, 3, 0x16, 5, 0]), bytes([0x3F, 1, 3, 0x33, 5, 0])):
        with pytest.raises(L.LinkError):
            L.decode_qos(bad)
    assert not L.is_control(L.fragment(62, 0, b"x", False, 0, 64)[0])
    s = L.Sender(_rules(), mtu=64)
    assert s.set_qos("/cmd_vel", qos) and not s.set_qos("/cmd_vel", qos) and not s.set_qos("/nope", qos)
    cdr = _twist_cdr(0.5, 0.1)
    s.offer("/cmd_vel", cdr, 0, now=100.0)
    frame = bytes([0x3F, 0x01, 0, 0x16, 5, 0])                      # /cmd_vel is topic index 0
    assert s.next_frame() == (2, frame)                              # to the topic's dst, before the message
    assert s.next_frame()[1][0] & 0x3F == 0 and s.next_frame() is None
    s.offer("/cmd_vel", cdr, 0, now=100.0 + L.QOS_PERIOD_S - 1)
    assert s.next_frame()[1][0] & 0x3F == 0 and s.next_frame() is None      # not again within the period
    s.offer("/cmd_vel", cdr, 0, now=100.0 + L.QOS_PERIOD_S)
    assert s.next_frame() == (2, frame) and s.control_frames == 2
    s.next_frame()
    s.set_qos("/cmd_vel", w.QoS(depth=7))                           # changed: announced before the next one
    s.offer("/cmd_vel", cdr, 0, now=100.0 + L.QOS_PERIOD_S + 1)
    assert L.decode_qos(s.next_frame()[1]) == (0, w.QoS(depth=7))


def test_rclpy_image_fragments_and_reassembles_whole():
    """A 20 kB sensor_msgs/CompressedImage made by real rclpy (the oracle venv; skipped, saying so, without
    it): random bytes do not deflate, so it goes raw in 1 + ceil((n - (m - 8)) / (m - 4)) frames at MTU m,
    and the reassembled bytes are what rclpy made and reads back."""
    import hashlib
    import random

    from ros2_oracle_link import rclpy

    img = bytes.fromhex(rclpy({"make": {"image": [20_000, 7]}})["image"])
    payload, z = L.pack(img, True)
    assert (payload, z) == (img, False)
    frames = L.fragment(1, 9, payload, z, 1_733_000_000_000_000_000, 128)
    assert len(frames) == 1 + math.ceil((len(img) - 120) / 124) == 162 and max(map(len, frames)) <= 128
    r = L.Reassembler()
    done = [r.push(3, f, 0.0) for f in frames]
    assert done[:-1] == [None] * 161 and done[-1][:2] == (1, img)
    data = random.Random(7).randbytes(20_000)
    assert rclpy({"read_image": [done[-1][1].hex()]})["read_image"] == [["jpeg", "cam", 20_000,
                                                                          hashlib.sha256(data).hexdigest()]]
