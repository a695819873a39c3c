"""Runs INSIDE the ROS 2 oracle venv: real rclpy makes and reads the samples of tests/test_ros2_link_live.py.
stdin {"make": {"twist": [vx, wz]}, "read": [HEX, ...]}; stdout {"twist": HEX, "read": [[vx, wz], ...]}.
(sensor_msgs is not among the oracle's wheels: the image of that test is made by rosbags.)"""

from __future__ import annotations

import json
import sys

from geometry_msgs.msg import Twist
from rclpy.serialization import deserialize_message, serialize_message

req = json.load(sys.stdin)
out: dict = {"read": []}
mk = req.get("make") or {}
if "twist" in mk:
    t = Twist()
    t.linear.x, t.angular.z = mk["twist"]
    out["twist"] = serialize_message(t).hex()
for h in req.get("read", []):
    m = deserialize_message(bytes.fromhex(h), Twist)
    out["read"].append([m.linear.x, m.angular.z])
json.dump(out, sys.stdout)
