"""The project's CDR and type hashes judged by real ROS 2 code: rclpy.serialization (ros-jazzy-rclpy from
PyPI, rmw_fastrtps_cpp) and rosidl's type-hash generator, in the venv `make ros2-oracle` builds
(tests/ros2_oracle/setup.sh; or UWSIMNET_ROS2_ORACLE=<venv>). Without it this module skips, saying so;
tests/ros2_golden.json keeps the same checks for fixed values in every run.

For each of ~130 messages with seeded random field values the project encodes (rosbags), the oracle
encodes (rclpy), and the two must be byte-equal except at alignment padding that rclpy ignores when reading
(fastcdr leaves it uninitialised); rclpy must read the project's bytes as the same message. The RIHS01 of
every type must equal rosidl's: for the project's .msg files, rosidl's generator run on them.
"""

from __future__ import annotations

import json
import os
import random
import subprocess
from pathlib import Path

import pytest

pytest.importorskip("rosbags", reason="ROS 2 CDR needs the extra: pip install 'uwsimnet-zenoh[ros2]'")
from uwsimnet_zenoh.ros2.cdr import SHIPPED, Codec  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
ORACLE = Path(os.environ.get("UWSIMNET_ROS2_ORACLE") or ROOT / ".venv-ros2-jazzy")
PY = ORACLE / "bin" / "python"
INSTALL = ORACLE / "ros2-install"

if not (PY.exists() and (INSTALL / "lib").is_dir()):
    pytest.skip(f"no ROS 2 oracle venv at {ORACLE} (make ros2-oracle builds it: PyPI ros-jazzy wheels + local"
                " builds of tf2_msgs, uwsimnet_msgs, dmac2_interfaces)", allow_module_level=True)

R = random.Random(14)


def f64() -> float:
    return R.choice([0.0, -0.0, 1.0, R.uniform(-1e4, 1e4), R.uniform(-1, 1) * 1e-9, 1e300])


def f32() -> float:
    return R.randint(-2**20, 2**20) / 8.0          # exactly representable in float32


def text(n: int = 12) -> str:
    return "".join(R.choice("abcdefghijklmnopqrstuvwxyz_/ 0123456789") for _ in range(R.randint(0, n)))


def stamp() -> dict:
    return {"sec": R.randint(0, 2**31 - 1), "nanosec": R.randint(0, 999_999_999)}


def header() -> dict:
    return {"stamp": stamp(), "frame_id": text()}


def vec() -> dict:
    return {"x": f64(), "y": f64(), "z": f64()}


def quat() -> dict:
    return {"x": f64(), "y": f64(), "z": f64(), "w": f64()}


def transform_stamped() -> dict:
    return {"header": header(), "child_frame_id": text(), "transform": {"translation": vec(), "rotation": quat()}}


MAKERS = {
    "nav_msgs/msg/Odometry": lambda: {
        "header": header(), "child_frame_id": text(),
        "pose": {"pose": {"position": vec(), "orientation": quat()}, "covariance": [f64() for _ in range(36)]},
        "twist": {"twist": {"linear": vec(), "angular": vec()}, "covariance": [f64() for _ in range(36)]}},
    "geometry_msgs/msg/PoseStamped": lambda: {"header": header(), "pose": {"position": vec(), "orientation": quat()}},
    "tf2_msgs/msg/TFMessage": lambda: {"transforms": [transform_stamped() for _ in range(R.randint(0, 3))]},
    "rosgraph_msgs/msg/Clock": lambda: {"clock": stamp()},
    "sensor_msgs/msg/CompressedImage": lambda: {    # what the ROS 2 link carries as images (docs/ros2-link.md)
        "header": header(), "format": text(8), "data": [R.randint(0, 255) for _ in range(R.randint(0, 300))]},
    "std_msgs/msg/String": lambda: {"data": text(40)},
    "diagnostic_msgs/msg/DiagnosticArray": lambda: {"header": header(), "status": [
        {"level": R.randint(0, 3), "name": text(), "message": text(), "hardware_id": text(),
         "values": [{"key": text(), "value": text()} for _ in range(R.randint(0, 3))]}
        for _ in range(R.randint(0, 3))]},
    "uwsimnet_msgs/msg/Frame": lambda: {
        "header": header(), "src": R.randint(0, 65535), "dst": R.randint(0, 65535), "seq": R.randint(0, 2**32 - 1),
        "t_tx": f64(), "t_rx": f64(), "distance": f64(), "data": [R.randint(0, 255) for _ in range(R.randint(0, 40))]},
    "uwsimnet_msgs/msg/Transmit": lambda: {
        "dst": R.randint(0, 65535), "data": [R.randint(0, 255) for _ in range(R.randint(0, 40))],
        "tag": R.randint(-2**63, 2**63 - 1), "has_tag": R.random() < 0.5},
    "uwsimnet_msgs/msg/Status": lambda: {
        "header": header(), "event": R.choice(["queued", "sent", "dropped", "acked", "failed"]), "reason": text(),
        "tag": R.randint(-2**63, 2**63 - 1), "has_tag": R.random() < 0.5, "seq": R.randint(0, 2**32 - 1),
        "has_seq": R.random() < 0.5},
    "dmac2_interfaces/msg/DMACPayload": lambda: {
        "header": header(), "msg_id": R.randint(0, 2**32 - 1), "source_address": R.randint(0, 255),
        "destination_address": R.randint(0, 255), "source_name": text(), "destination_name": text(),
        "type": R.randint(0, 3), "ack": R.random() < 0.5, "force": R.random() < 0.5,
        "bitrate": R.randint(0, 2**32 - 1), "rssi": f32(), "integrity": f32(),
        "propagation_time": R.randint(0, 2**32 - 1), "duration": R.randint(0, 2**32 - 1),
        "timestamp": R.randint(0, 2**32 - 1), "timestamp_undefined": R.random() < 0.5, "relative_velocity": f32(),
        "payload": text(60), "info": [{"key": text(), "value": text()} for _ in range(R.randint(0, 2))]},
}
PER_TYPE = 11


@pytest.fixture(scope="module")
def verdict() -> tuple[list[dict], dict, dict]:
    codec = Codec("jazzy")
    cases = []
    for t, make in MAKERS.items():
        for _ in range(PER_TYPE):
            fields = make()
            cases.append({"type": t, "fields": fields, "ours": codec.encode(t, fields).hex()})
    msg_dirs = {pkg: str(ROOT / "uwsimnet_zenoh" / "ros2" / "interfaces" / pkg / "msg") for pkg in SHIPPED}
    env = dict(os.environ, PYTHONPATH=str(next((INSTALL / "lib").glob("python3*/site-packages"))),
               LD_LIBRARY_PATH=str(INSTALL / "lib"), AMENT_PREFIX_PATH=f"{INSTALL}:{ORACLE}")
    r = subprocess.run([str(PY), str(ROOT / "tests" / "ros2_oracle" / "rclpy_check.py")], input=json.dumps(
        {"cases": cases, "msg_dirs": msg_dirs}), capture_output=True, text=True, env=env, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    out = json.loads(r.stdout)
    ours = {t: codec.rihs01(t) for t in MAKERS}
    return [dict(c, **o) for c, o in zip(cases, out["cases"], strict=True)], out["hashes"], ours


def test_every_message_is_rclpys_bytes(verdict):
    cases, _, _ = verdict
    bad = [(c["type"], c["ours"], c["rclpy"]) for c in cases if not (c["equal_but_padding"] and c["same_message"])]
    assert not bad, bad[:3]
    assert len(cases) == len(MAKERS) * PER_TYPE


def test_every_type_hash_is_rosidls(verdict):
    _, theirs, ours = verdict
    assert set(theirs) >= set(ours)
    assert {t: ours[t] for t in ours} == {t: theirs[t] for t in ours}
