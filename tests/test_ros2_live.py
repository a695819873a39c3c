"""`uwsimnet run --ros2` over real Zenoh (loopback) with ROS 2 peers configured as rmw_zenoh configures a
node's session (tests/ros2_peer.py: peer mode, connect tcp/localhost:PORT, timestamping).

What a ROS 2 node would do, checked against rmw_zenoh's facts: it finds the simulator's nodes with a
liveliness query, publishes nav_msgs/Odometry (rclpy's own bytes, tests/ros2_golden.json) that moves a
vehicle so the next frame's delay follows the channel's law, sends a Transmit (rclpy's bytes) and receives
the Frame on the exact key a ROS subscriber declares (with the rosidl hash), with a valid 33-byte
attachment; a late joiner gets /tf_static from the publication cache; bad samples are counted, reported
once, and the adapter goes on. Peers on eclipse-zenoh 1.4.0 and 1.6.2 (the versions rmw_zenoh ships) run
the same checks when their venvs exist (`make ros2-peers`), else those tests skip saying so.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import msgpack
import pytest

from uwsimnet_zenoh.ros2 import wire as w

pytest.importorskip("rosbags", reason="ROS 2 CDR needs the extra: pip install 'uwsimnet-zenoh[ros2]'")
from test_broker_e2e import BITRATE, PROP, Proc, device_xml, free_port, scene_xml, vehicle_xml  # noqa: E402

from uwsimnet_zenoh.ros2.cdr import Codec  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
PEER = str(ROOT / "tests" / "ros2_peer.py")
GOLDEN = json.loads((ROOT / "tests" / "ros2_golden.json").read_text())["messages"]
WORLD = "r2"
H = {t: g["rihs01"] for t, g in GOLDEN.items()}
ODOM_KEY = "0/bravo/odom/nav_msgs::msg::dds_::Odometry_/" + H["nav_msgs/msg/Odometry"]
TX_KEY = "0/uwsimnet/alpha_m/tx/uwsimnet_msgs::msg::dds_::Transmit_/" + H["uwsimnet_msgs/msg/Transmit"]
RX_KEY = "0/uwsimnet/bravo_m/rx/uwsimnet_msgs::msg::dds_::Frame_/" + H["uwsimnet_msgs/msg/Frame"]
STATUS_KEY = "0/uwsimnet/alpha_m/status/uwsimnet_msgs::msg::dds_::Status_/" + H["uwsimnet_msgs/msg/Status"]
TF_STATIC_KEY = "0/tf_static/tf2_msgs::msg::dds_::TFMessage_/" + H["tf2_msgs/msg/TFMessage"]
DIAG_KEY = "0/diagnostics/diagnostic_msgs::msg::dds_::DiagnosticArray_/" + H["diagnostic_msgs/msg/DiagnosticArray"]
SCENE = scene_xml(world=WORLD, vehicles=vehicle_xml("alpha", (0, 0, 0), device_xml("alpha-m", 1))
                  + vehicle_xml("bravo", None, device_xml("bravo-m", 2)))


def old_pythons() -> dict[str, str]:
    """eclipse-zenoh versions rmw_zenoh ships -> a python that has it (`make ros2-peers`, or
    UWSIMNET_ZENOH_PEERS="1.4.0=/path/python,1.6.2=/path/python")."""
    found = {}
    for v in ("1.4.0", "1.6.2"):
        p = ROOT / f".venv-zenoh-{v}" / "bin" / "python"
        if p.exists():
            found[v] = str(p)
    for item in filter(None, os.environ.get("UWSIMNET_ZENOH_PEERS", "").split(",")):
        v, _, p = item.partition("=")
        found[v.strip()] = p.strip()
    return found


class Peer:
    """tests/ros2_peer.py under some python: one JSON request, one JSON answer."""

    def __init__(self, python: str, connect: str) -> None:
        self.p = subprocess.Popen([python, PEER], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                  stderr=subprocess.PIPE, text=True, bufsize=1)
        self.info = self.call(cmd="open", connect=connect)

    def call(self, **req) -> dict:
        self.p.stdin.write(json.dumps(req) + "\n")
        self.p.stdin.flush()
        line = self.p.stdout.readline()
        if not line:
            raise AssertionError(f"peer exited: {self.p.stderr.read()[-2000:]}")
        res = json.loads(line)
        assert res.get("ok"), res
        return res

    def close(self) -> None:
        if self.p.poll() is None:
            try:
                self.call(cmd="close")
                self.p.wait(10)
            except (AssertionError, BrokenPipeError, subprocess.TimeoutExpired, OSError):
                self.p.kill()
                self.p.wait(5)


@pytest.fixture(scope="module")
def codec() -> Codec:
    return Codec("jazzy")


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    d = tmp_path_factory.mktemp("ros2")
    (d / "scene.xml").write_text(SCENE)
    port = free_port()
    p = Proc([sys.executable, "-m", "uwsimnet_zenoh.cli", "run", str(d / "scene.xml"), "--ros2",
              "--listen", f"tcp/127.0.0.1:{port}", "--listen", f"tcp/[::1]:{port}",
              "--ros-pose", "bravo=odom:/bravo/odom", "--ros-clock", "--duration", "120"])
    try:
        deadline = time.monotonic() + 20
        while "running" not in p.next_line(max(0.1, deadline - time.monotonic())):
            pass
        yield port, p
    finally:
        if p.p.poll() is None:
            p.p.send_signal(signal.SIGINT)
            try:
                p.p.wait(15)
            except subprocess.TimeoutExpired:
                p.p.kill()
                p.p.wait(5)


def att(seq: int) -> str:
    return w.encode_attachment(seq, time.time_ns(), bytes(range(16))).hex()


def odometry(codec: Codec, frame: str, xyz: tuple[float, float, float]) -> str:
    return codec.encode("nav_msgs/msg/Odometry", {"header": {"frame_id": frame}, "child_frame_id": "bravo",
                                                  "pose": {"pose": {"position": dict(zip("xyz", xyz, strict=True)),
                                                                    "orientation": {"w": 1.0}}}}).hex()


def info(peer: Peer, dev: str) -> dict:
    (r,) = peer.call(cmd="get", key=f"uwsimnet/{WORLD}/modem/{dev}/info")["replies"]
    return msgpack.unpackb(bytes.fromhex(r[1]), raw=False)


def move(peer: Peer, payload_hex: str, seq: int, expect: tuple[float, float, float]) -> None:
    peer.call(cmd="put", key=ODOM_KEY, payload=payload_hex, attachment=att(seq))
    deadline = time.monotonic() + 5
    while info(peer, "bravo-m")["position"] != pytest.approx(list(expect)):
        assert time.monotonic() < deadline, f"pose never applied: {info(peer, 'bravo-m')['position']}"
        time.sleep(0.05)


def send_and_receive(peer: Peer, codec: Codec, seq: int) -> list:
    """One Transmit (rclpy's bytes) from alpha-m to bravo-m; the Frame bravo-m's rx topic delivers."""
    peer.call(cmd="put", key=TX_KEY, payload=GOLDEN["uwsimnet_msgs/msg/Transmit"]["cdr_hex"], attachment=att(seq))
    (s,) = peer.call(cmd="take", name="rx", n=1, timeout=5)["samples"]
    assert s["key"] == RX_KEY
    a = w.decode_attachment(bytes.fromhex(s["att"]))                       # 33 bytes, rmw_zenoh's layout
    f = codec.decode("uwsimnet_msgs/msg/Frame", bytes.fromhex(s["payload"]))
    return [a, f]


def modelled(dist: float, size: int, inf: dict) -> float:
    return dist * PROP + size * 8 / BITRATE + inf["config"]["intrinsic_rx_s"]


def check_a_ros_node_can_use_the_simulator(port: int, python: str, codec: Codec, pose_seq: int,
                                           far: float) -> None:
    peer = Peer(python, f"tcp/localhost:{port}")
    try:
        # the ROS graph: a liveliness query, as rmw_zenoh's graph cache does at start
        keys = peer.call(cmd="lget", key="@ros2_lv/0/**")["keys"]
        toks = [w.parse_token(k) for k in keys]
        assert all(t is not None for t in toks), keys
        nodes = {(t.namespace, t.node) for t in toks if t.kind == "NN"}
        assert {("/", "uwsimnet"), ("/uwsimnet", "alpha_m"), ("/uwsimnet", "bravo_m")} <= nodes
        ents = {(t.kind, t.topic, t.dds_type, t.type_hash) for t in toks if t.kind != "NN"}
        assert ("MP", "/uwsimnet/bravo_m/rx", "uwsimnet_msgs::msg::dds_::Frame_", H["uwsimnet_msgs/msg/Frame"]) in ents
        assert ("MS", "/bravo/odom", "nav_msgs::msg::dds_::Odometry_", H["nav_msgs/msg/Odometry"]) in ents
        assert ("MP", "/tf_static", "tf2_msgs::msg::dds_::TFMessage_", H["tf2_msgs/msg/TFMessage"]) in ents

        peer.call(cmd="sub", name="rx", key=RX_KEY)
        peer.call(cmd="sub", name="status", key=STATUS_KEY)
        time.sleep(0.3)                                   # declarations reach the router
        inf = info(peer, "bravo-m")
        # rclpy's Odometry: frame world_ned, position (1.5, -2.25, 10) NED = (-2.25, 1.5, -10) in the ENU scene
        move(peer, GOLDEN["nav_msgs/msg/Odometry"]["cdr_hex"], pose_seq, (-2.25, 1.5, -10.0))
        near = math.dist((0, 0, 0), (-2.25, 1.5, -10.0))
        a1, f1 = send_and_receive(peer, codec, 1)
        assert f1.t_rx - f1.t_tx == pytest.approx(modelled(near, 10, inf), abs=1e-6)
        assert (f1.src, f1.dst, bytes(f1.data)) == (1, 2, b"\x00\x01payload\xff")
        assert f1.distance == pytest.approx(near)
        # an ENU Odometry (frame "odom") moves it `far` m away: the delay grows by far - near times the law
        move(peer, odometry(codec, "odom", (far, 0.0, 0.0)), pose_seq + 1, (far, 0.0, 0.0))
        a2, f2 = send_and_receive(peer, codec, 2)
        assert f2.t_rx - f2.t_tx == pytest.approx(modelled(far, 10, inf), abs=1e-6)
        assert (f2.t_rx - f2.t_tx) - (f1.t_rx - f1.t_tx) == pytest.approx((far - near) * PROP, abs=1e-6)
        assert a2.seq > a1.seq >= 1 and a1.gid == a2.gid and abs(a2.timestamp_ns - time.time_ns()) < 30e9
        sts = peer.call(cmd="take", name="status", n=2, timeout=3)["samples"]
        st = [codec.decode("uwsimnet_msgs/msg/Status", bytes.fromhex(s["payload"])) for s in sts]
        assert [(s.tag, s.has_tag) for s in st] and all(s.tag == 42 and s.has_tag for s in st)
        assert {s.event for s in st} <= {"queued", "sent"}
        if peer.info["version"] >= "1.6":
            # a late joiner (this peer subscribed after the static pose was published) gets /tf_static
            peer.call(cmd="adv_sub", name="tfs", key=TF_STATIC_KEY)
            (s,) = peer.call(cmd="take", name="tfs", n=1, timeout=5)["samples"]
            tf = codec.decode("tf2_msgs/msg/TFMessage", bytes.fromhex(s["payload"]))
            assert [(t.child_frame_id, t.header.frame_id, t.transform.translation.x) for t in tf.transforms] == \
                [("alpha", "world", 0.0)]
            w.decode_attachment(bytes.fromhex(s["att"]))
    finally:
        peer.close()


def test_a_ros_node_on_the_projects_zenoh(sim, codec):
    port, _ = sim
    check_a_ros_node_can_use_the_simulator(port, sys.executable, codec, 1, 450.0)


@pytest.mark.parametrize("version", ["1.4.0", "1.6.2"])
def test_a_ros_node_on_the_zenoh_rmw_zenoh_ships(sim, codec, version):
    python = old_pythons().get(version)
    if not python:
        pytest.skip(f"no python with eclipse-zenoh=={version} (make ros2-peers, or UWSIMNET_ZENOH_PEERS)")
    port, _ = sim
    check_a_ros_node_can_use_the_simulator(port, python, codec, 10 + int(version[2]), 300.0 + 10 * int(version[2]))


def test_bad_samples_are_counted_reported_once_and_the_adapter_goes_on(sim, codec):
    port, proc = sim
    peer = Peer(sys.executable, f"tcp/localhost:{port}")
    try:
        peer.call(cmd="sub", name="diag", key=DIAG_KEY)
        good = odometry(codec, "odom", (100.0, 0.0, 0.0))
        humble_key = ODOM_KEY.rsplit("/", 1)[0] + "/TypeHashNotSupported"
        for i in range(2):
            peer.call(cmd="put", key=ODOM_KEY, payload="00010000deadbeef", attachment=att(100 + i))   # bad CDR
            peer.call(cmd="put", key=ODOM_KEY, payload=good, attachment=None)                        # no attachment
            peer.call(cmd="put", key=humble_key, payload=good, attachment=att(200 + i))               # Humble hash
        deadline = time.monotonic() + 6
        while True:
            assert time.monotonic() < deadline, "no /diagnostics with the counts"
            samples = peer.call(cmd="take", name="diag", n=1, timeout=3)["samples"]
            if not samples:
                continue
            d = codec.decode("diagnostic_msgs/msg/DiagnosticArray", bytes.fromhex(samples[0]["payload"]))
            ros = next(s for s in d.status if s.name == "uwsimnet/ros2")
            counts = {v.key: int(v.value) for v in ros.values}
            kinds = {s.name: s.hardware_id for s in d.status}
            if counts.get("cdr", 0) >= 2 and counts.get("no-attachment", 0) >= 2 and counts.get("type_hash", 0) >= 2:
                break
        assert kinds["uwsimnet/alpha-m"] == "sim:alpha-m"
        move(peer, good, 300, (100.0, 0.0, 0.0))             # the adapter still serves
        err = "".join(proc.err)
        for what in ("cdr on /bravo/odom", "no-attachment on /bravo/odom", "type_hash on /bravo/odom"):
            assert err.count(f"ROS 2: {what}") == 1, err[-3000:]
    finally:
        peer.close()


def test_joined_router_sees_the_tokens_go_when_the_run_stops(tmp_path):
    """With a router already there (rmw_zenohd's place), the run joins it as a client; on exit its nodes
    leave the ROS graph at once (tokens undeclared), the router staying up."""
    (tmp_path / "scene.xml").write_text(SCENE)
    port = free_port()
    router = Proc([sys.executable, "-m", "uwsimnet_zenoh.cli", "router", "--listen", f"tcp/127.0.0.1:{port}"])
    run = None
    peer = None
    try:
        while "listening" not in router.next_line(10):
            pass
        run = Proc([sys.executable, "-m", "uwsimnet_zenoh.cli", "run", str(tmp_path / "scene.xml"), "--ros2",
                    "--connect", f"tcp/127.0.0.1:{port}", "--ros-domain", "3", "--duration", "60"])
        while "running" not in run.next_line(20):
            pass
        peer = Peer(sys.executable, f"tcp/localhost:{port}")
        assert any("/NN/%/%uwsimnet/bravo_m" in k for k in peer.call(cmd="lget", key="@ros2_lv/3/**")["keys"])
        run.p.send_signal(signal.SIGINT)
        run.p.wait(15)
        assert run.p.returncode == 0, run.output()
        assert peer.call(cmd="lget", key="@ros2_lv/3/**")["keys"] == []
    finally:
        if peer is not None:
            peer.close()
        for p in (run, router):
            if p is not None and p.p.poll() is None:
                p.p.send_signal(signal.SIGINT)
                try:
                    p.p.wait(10)
                except subprocess.TimeoutExpired:
                    p.p.kill()
