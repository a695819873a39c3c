"""Runs INSIDE the ROS 2 oracle venv: real rclpy makes and reads the samples of tests/test_ros2_link_*.py.
stdin {"make": {"twist": [vx, wz], "image": [n, seed]}, "read": [HEX, ...], "read_image": [HEX, ...]};
stdout {"twist": HEX, "image": HEX, "read": [[vx, wz], ...], "read_image": [[format, frame_id, n, sha256], ...]}.
The image is a sensor_msgs/CompressedImage of n random bytes (random.Random(seed)), frame "cam", format "jpeg"."""

from __future__ import annotations

import hashlib
import json
import random
import sys

from geometry_msgs.msg import Twist
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import CompressedImage

req = json.load(sys.stdin)
out: dict = {"read": [], "read_image": []}
mk = req.get("make") or {}
if "twist" in mk:
    t = Twist()
    t.linear.x, t.angular.z = mk["twist"]
    out["twist"] = serialize_message(t).hex()
if "image" in mk:
    n, seed = mk["image"]
    img = CompressedImage()
    img.header.frame_id, img.format = "cam", "jpeg"
    img.data = random.Random(seed).randbytes(n)
    out["image"] = serialize_message(img).hex()
for h in req.get("read", []):
    m = deserialize_message(bytes.fromhex(h), Twist)
    out["read"].append([m.linear.x, m.angular.z])
for h in req.get("read_image", []):
    m = deserialize_message(bytes.fromhex(h), CompressedImage)
    data = bytes(m.data)
    out["read_image"].append([m.format, m.header.frame_id, len(data), hashlib.sha256(data).hexdigest()])
json.dump(out, sys.stdout)
