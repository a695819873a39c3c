"""`uwsimnet run --ros2` options and topology choice (app/ros2.py): one-line errors, exit 2."""

from __future__ import annotations

import socket

import pytest

from uwsimnet_zenoh.app import ros2
from uwsimnet_zenoh.cli.main import build_parser, main
from uwsimnet_zenoh.errors import UserError


def args(*argv: str):
    return build_parser().parse_args(["run", "scene.xml", "--ros2", *argv])


def test_options_from_flags_and_environment(monkeypatch):
    monkeypatch.setenv("ROS_DOMAIN_ID", "7")
    monkeypatch.setenv("ROS_DISTRO", "humble")
    o = ros2.options(args("--ros-pose", "auv=odom:/auv/odom@ned", "--ros-profile", "dmac2", "--ros-clock"))
    assert (o.domain, o.distro, o.profiles, o.clock) == (7, "humble", ("dmac2",), True)
    assert (o.poses[0].vehicle, o.poses[0].source, o.poses[0].topic, o.poses[0].frame) == \
        ("auv", "odom", "/auv/odom", "ned")
    o = ros2.options(args("--ros-domain", "2", "--ros-distro", "kilted", "--ros-frame", "ned"))
    assert (o.domain, o.distro, o.profiles, o.scene_frame, o.world_frame) == (2, "kilted", ("native",), "ned",
                                                                             "world_ned")
    monkeypatch.setenv("ROS_DISTRO", "iron")
    with pytest.raises(UserError, match="ROS_DISTRO=iron"):
        ros2.options(args())


@pytest.mark.parametrize("argv,msg", [
    (["--ros-pose", "auv"], "--ros-pose 'auv'"),
    (["--ros-domain", "400"], "domain"),
    (["--ros-namespace", "bad name"], "namespace"),
])
def test_bad_options_are_one_line_errors(argv, msg):
    with pytest.raises(UserError, match=msg):
        ros2.options(args(*argv))


def test_topology_stands_in_for_rmw_zenohd_or_joins_it(monkeypatch):
    monkeypatch.setattr(ros2, "router_running", lambda *a, **k: False)
    assert ros2.topology([], []) == (["tcp/127.0.0.1:7447", "tcp/[::1]:7447"], [], None)
    monkeypatch.setattr(ros2, "router_running", lambda *a, **k: True)
    listen, connect, note = ros2.topology([], [])
    assert (listen, connect) == ([], ["tcp/localhost:7447"]) and "joining it as a client" in note
    assert ros2.topology(["tcp/127.0.0.1:9"], []) == (["tcp/127.0.0.1:9"], [], None)   # explicit wins


def test_router_running_sees_a_listener():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        assert ros2.router_running(port=port)
    assert not ros2.router_running(port=port)


def test_the_adapter_connects_to_a_loopback_locator():
    assert ros2.adapter_endpoint("router", [], ["tcp/0.0.0.0:7447"], []) == ["tcp/127.0.0.1:7447"]
    assert ros2.adapter_endpoint("router", [], ["tcp/[::]:7000"], ["tcp/10.0.0.5:7000", "tcp/[::1]:7000"]) == \
        ["tcp/[::1]:7000"]
    assert ros2.adapter_endpoint("client", ["tcp/localhost:7447"], [], []) == ["tcp/localhost:7447"]
    with pytest.raises(UserError):
        ros2.adapter_endpoint("router", [], ["tcp/127.0.0.1:0"], [])


def test_ros2_refuses_the_virtual_clock(tmp_path, capsys):
    scene = tmp_path / "s.xml"
    scene.write_text('<?xml version="1.0"?><UWSimScene><simulation><clock>virtual</clock></simulation>'
                     "<CustomCommsChannel><id>0</id></CustomCommsChannel></UWSimScene>")
    assert main(["run", str(scene), "--ros2", "--clock", "virtual"]) == 2
    assert capsys.readouterr().err.strip().endswith("drop --clock virtual")


def test_a_pose_for_a_vehicle_the_scene_drives_is_refused_before_any_session(tmp_path, capsys):
    scene = tmp_path / "s.xml"
    scene.write_text('<?xml version="1.0"?><UWSimScene><CustomCommsChannel><id>0</id></CustomCommsChannel>'
                     "<vehicle><name>a</name><position>0 0 0</position></vehicle></UWSimScene>")
    assert main(["run", str(scene), "--ros2", "--listen", "tcp/127.0.0.1:0", "--ros-pose", "a=odom:/a/odom"]) == 2
    assert "the scene drives this vehicle" in capsys.readouterr().err.strip().splitlines()[-1]
    assert main(["run", str(scene), "--ros2", "--ros-pose", "b=odom:/b/odom"]) == 2
    assert "the scene has no vehicle 'b' (it has a)" in capsys.readouterr().err
