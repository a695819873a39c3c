"""Real rclpy for the ROS 2 link tests: runs tests/ros2_oracle/link_samples.py in the oracle venv of
`make ros2-oracle` (or UWSIMNET_ROS2_ORACLE=<venv>) to make and read Twists and CompressedImages."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import pytest

ORACLE = Path(os.environ.get("UWSIMNET_ROS2_ORACLE") or Path(__file__).resolve().parents[1] / ".venv-ros2-jazzy")
NO_ORACLE = f"no ROS 2 oracle venv with sensor_msgs at {ORACLE} (make ros2-oracle)"


def oracle_ready() -> bool:
    """The venv of `make ros2-oracle` with the sensor_msgs wheel (an older one lacks it)."""
    return (ORACLE / "bin" / "python").exists() and (ORACLE / "ros2-install" / "lib").is_dir() \
        and (ORACLE / "share" / "sensor_msgs").is_dir()


def rclpy(req: dict) -> dict:
    """Real rclpy.serialization makes and reads the samples (the calling test skips without the venv)."""
    if not oracle_ready():
        pytest.skip(NO_ORACLE)
    install = ORACLE / "ros2-install"
    env = dict(os.environ, PYTHONPATH=str(next((install / "lib").glob("python3*/site-packages"))),
               LD_LIBRARY_PATH=str(install / "lib"), AMENT_PREFIX_PATH=f"{install}:{ORACLE}")
    r = subprocess.run([str(ORACLE / "bin" / "python"), str(Path(__file__).parent / "ros2_oracle" / "link_samples.py")],
                       input=json.dumps(req), capture_output=True, text=True, env=env, timeout=120)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)
