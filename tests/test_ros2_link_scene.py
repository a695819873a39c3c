"""The scene's `<ros2Link>`: read and checked like the rest of the scene (file:line, exit 2), the same model as
`uwsimnet ros2-link --topic`, and started by `uwsimnet run --ros2` (a real process, Zenoh over loopback): a
Twist crosses from robot A's graph (ROS domain 1) to robot B's (domain 2), republished with the QoS of A's
publisher as its rmw_zenoh token states it, and the per-topic counters are in the run's summary."""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time

import pytest

pytest.importorskip("rosbags", reason="ROS 2 CDR needs the extra: pip install 'uwsimnet-zenoh[ros2]'")
import zenoh  # noqa: E402
from test_broker_e2e import Proc, device_xml, free_port, scene_xml  # noqa: E402

from uwsimnet_zenoh.errors import UwsimnetError  # noqa: E402
from uwsimnet_zenoh.ros2.cdr import Codec  # noqa: E402
from uwsimnet_zenoh.ros2.link import parse_rule  # noqa: E402
from uwsimnet_zenoh.scene import load_scene_text  # noqa: E402

WORLD = "r2scene"
TWIST = "geometry_msgs/msg/Twist"
IMAGE = "sensor_msgs/msg/CompressedImage"
TOPICS = ('<topic name="/cmd_vel" type="geometry_msgs/msg/Twist" dst="{dst}" prio="0" policy="fifo" rate="20"/>\n'
          '    <topic name="/camera/compressed" type="sensor_msgs/msg/CompressedImage" dir="{cam}" prio="9"'
          ' policy="keep_last" depth="1" budget="400" compress="0"/>')


def link(domain: int, dst: int, cam: str, extra: str = "") -> str:
    return (f"\n  <ros2Link>\n    <rosDomain>{domain}</rosDomain>{extra}\n    "
            f"{TOPICS.format(dst=dst, cam=cam)}\n  </ros2Link>")


def scene(la: str, lb: str) -> str:
    return scene_xml(world=WORLD, vehicles=(
        f"<vehicle><name>alpha</name><position>0 0 0</position>{device_xml('alpha-m', 1)}{la}</vehicle>\n"
        f"<vehicle><name>bravo</name><position>150 0 0</position>{device_xml('bravo-m', 2)}{lb}</vehicle>"))


GOOD = scene(link(1, 2, "out", "<mtu>48</mtu>"), link(2, 1, "in"))


def test_scene_link_is_the_cli_form():
    """Each <topic> builds the rule its --topic text builds; the link's modem, domain and mtu are read."""
    sc = load_scene_text(GOOD, source="s.xml")
    a, b = sc.vehicles[0].ros2_link, sc.vehicles[1].ros2_link
    assert (a.modem, a.domain, a.mtu, a.namespace) == ("alpha-m", 1, 48, "/")
    assert (b.modem, b.domain, b.mtu) == ("bravo-m", 2, 64)
    assert a.topics == (parse_rule(f"topic=/cmd_vel,type={TWIST},dir=both,dst=2,prio=0,policy=fifo,rate=20"),
                        parse_rule("topic=/camera/compressed,type=sensor_msgs/msg/CompressedImage,dir=out,prio=9,"
                                   "policy=keep_last,depth=1,budget=400,compress=0"))
    assert b.topics[1].direction == "in" and b.topics[0].dst == 1


@pytest.mark.parametrize(("la", "lb", "at", "message"), [
    (link(1, 2, "out"), link(1, 1, "in"), ("<ros2Link>", 2), "rosDomain 1 is also alpha's"),
    (link(1, 7, "out"), "", ('dst="7"', 1), "dst 7: no device of the scene has that mac"),
    (link(1, 2, "sideways"), "", ('dir="sideways"', 1), "direction 'sideways'"),
    (link(1, 2, "out").replace('prio="0"', 'prio="first"'), "", ('prio="first"', 1), "prio='first' is not a number"),
    (link(1, 2, "out").replace('rate="20"', 'rte="20"'), "", ("rte=", 1), "unexpected attribute 'rte' on <topic>"),
    (link(1, 2, "out", "<modem>zulu-m</modem>"), "", ("<modem>", 1), "'zulu-m' is not a device of this vehicle"),
    (link(1, 2, "out", "<mtu>4096</mtu>"), "", ("<mtu>", 1), "4096 is larger than alpha-m's maxFrameBytes 2048"),
    (link(1, 2, "out").replace("<rosDomain>1</rosDomain>", ""), "", ("<ros2Link>", 1), "missing <rosDomain>"),
    (link(300, 2, "out"), "", ("<rosDomain>", 1), "ROS domain 300: expected 0..232"),
    (link(1, 2, "out", "<namespace>/robot-1</namespace>"), "", ("<namespace>", 1), "not a ROS 2 namespace"),
    (link(1, 2, "out").replace('name="/cmd_vel"', 'name="/cmd-vel"'), "", ("/cmd-vel", 1), "not a ROS 2 name"),
    (link(1, 2, "out"), link(2, 1, "in").replace("/camera/compressed", "/camera/raw"), ("/camera/raw", 1),
     "position 2 on alpha's link"),
])
def test_bad_link_is_file_line(tmp_path, la, lb, at, message):
    """Checked at load time, one line `file:line: message` at the element at fault; `uwsimnet validate` exits 2
    without a traceback."""
    text = scene(la, lb)
    line = [i for i, ln in enumerate(text.splitlines(), 1) if at[0] in ln][at[1] - 1]
    with pytest.raises(UwsimnetError) as e:
        load_scene_text(text, source="s.xml")
    assert str(e.value).startswith(f"s.xml:{line}: ") and message in str(e.value), (line, str(e.value))
    if at == ("<ros2Link>", 2):
        p = tmp_path / "s.xml"
        p.write_text(text)
        r = subprocess.run([sys.executable, "-m", "uwsimnet_zenoh.cli", "validate", str(p)], capture_output=True,
                           text=True, timeout=60)
        assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
        assert [ln for ln in r.stderr.splitlines() if f"s.xml:{line}: " in ln and message in ln], r.stderr


def _put_token(s: zenoh.Session, key: str) -> zenoh.LivelinessToken:
    return s.liveliness().declare_token(key)


def far_qos(robots: zenoh.Session, topic: str) -> list[str]:
    """The QoS fields `<rel>:<dur>:<hist>,<depth>:...` of the one publisher of `topic` (mangled) in robot B's
    graph (domain 2), split at ':' as rmw_zenoh's keyexpr_to_qos does."""
    far = [str(r.ok.key_expr) for r in robots.liveliness().get("@ros2_lv/2/**", timeout=5) if r.ok]
    mine = [t.split("/") for t in far if t.split("/")[5] == "MP" and t.split("/")[9] == topic]
    assert len(mine) == 1, far
    return mine[0][12].split(":")


def _notify(cond: threading.Condition) -> None:
    with cond:
        cond.notify_all()


def test_run_starts_the_scene_links_copies_qos_and_sums_up(tmp_path):
    """`uwsimnet run --ros2`: the scene's two links carry a Twist from domain 1 to domain 2; a publisher on
    domain 1 whose token says BEST_EFFORT, depth 5 is republished on domain 2 under a token saying the same;
    one saying TRANSIENT_LOCAL, depth 1 (images) too, and a late joiner on domain 2 gets the last image; the
    run's summary has the links' per-topic counters."""
    from ros2_oracle_link import ORACLE, oracle_ready, rclpy

    codec = Codec("jazzy")
    (tmp_path / "scene.xml").write_text(GOOD)
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    trace = tmp_path / "t.jsonl"
    p = Proc([sys.executable, "-m", "uwsimnet_zenoh.cli", "run", str(tmp_path / "scene.xml"), "--ros2",
              "--listen", ep, "--duration", "300", "--trace", str(trace)])
    out: list[str] = []
    try:
        deadline = time.monotonic() + 60
        while "running" not in (line := p.next_line(max(0.1, deadline - time.monotonic()))):
            out.append(line)
        assert any("ros2Link of alpha: alpha-m carries /cmd_vel, /camera/compressed" in ln for ln in out), out
        if oracle_ready():
            cdr = bytes.fromhex(rclpy({"make": {"twist": [0.25, -0.5]}})["twist"])
        else:
            print(f"Twist made by rosbags: no ROS 2 oracle venv at {ORACLE}")
            cdr = codec.encode(TWIST, {"linear": {"x": 0.25}, "angular": {"z": -0.5}})
        h = codec.key_hash(TWIST)
        got: list[bytes] = []
        cond = threading.Condition()

        def on(sample: zenoh.Sample) -> None:
            with cond:
                got.append(sample.payload.to_bytes())
                cond.notify_all()

        conf = zenoh.Config()
        conf.insert_json5("mode", '"client"')
        conf.insert_json5("connect/endpoints", f'["{ep}"]')
        with zenoh.open(conf) as robots:
            zid = str(robots.zid())
            # robot A's talker as rmw_zenoh declares it (docs/design.md's golden token): its publisher's QoS
            # BEST_EFFORT (2), depth 5, the fields equal to rmw_zenoh's defaults left empty
            toks = [_put_token(robots, f"@ros2_lv/1/{zid}/0/0/NN/%/%/talker"),
                    _put_token(robots, f"@ros2_lv/1/{zid}/0/1/MP/%/%/talker/%cmd_vel/"
                                       f"geometry_msgs::msg::dds_::Twist_/{h}/2::,5:,:,:,,")]
            sub = robots.declare_subscriber(f"2/cmd_vel/geometry_msgs::msg::dds_::Twist_/{h}", on)
            key = f"1/cmd_vel/geometry_msgs::msg::dds_::Twist_/{h}"
            seq, qos = 0, None
            deadline = time.monotonic() + 60
            # a Twist at a time until robot B's graph shows the link's publisher with the sender's QoS (the
            # link learns it from the token, asynchronously, and announces it before the next message)
            while qos != ("2", "5") and time.monotonic() < deadline:
                seq += 1
                n = len(got)
                att = seq.to_bytes(8, "little") + time.time_ns().to_bytes(8, "little") + bytes([16]) + bytes(16)
                robots.put(key, cdr, attachment=att)
                with cond:
                    assert cond.wait_for(lambda n=n: len(got) > n, 30), "the Twist did not cross"
                q = far_qos(robots, "%cmd_vel")
                qos = (q[0], q[2].split(",")[1])
            assert qos == ("2", "5"), qos
            assert got[-1] == cdr
            if oracle_ready():
                assert rclpy({"read": [got[-1].hex()]})["read"] == [[0.25, -0.5]]
            sub.undeclare()
            # a TRANSIENT_LOCAL publisher (depth 1) of images: the far side keeps the last one for late joiners
            hi = codec.key_hash(IMAGE)
            toks.append(_put_token(robots, f"@ros2_lv/1/{zid}/0/2/MP/%/%/talker/%camera%compressed/"
                                           f"sensor_msgs::msg::dds_::CompressedImage_/{hi}/:1:,1:,:,:,,"))
            img_key = f"camera/compressed/sensor_msgs::msg::dds_::CompressedImage_/{hi}"
            imgs: list[bytes] = []
            isub = robots.declare_subscriber(f"2/{img_key}", lambda smp: (imgs.append(smp.payload.to_bytes()),
                                                                         _notify(cond)))
            dur, k = None, 0
            deadline = time.monotonic() + 60
            while dur != ("1", "1") and time.monotonic() < deadline:
                k += 1
                img = codec.encode(IMAGE, {"header": {"frame_id": "cam"}, "format": "jpeg", "data": bytes([k]) * 64})
                n = len(imgs)
                att = k.to_bytes(8, "little") + time.time_ns().to_bytes(8, "little") + bytes([16]) + bytes(16)
                robots.put(f"1/{img_key}", img, attachment=att)
                with cond:
                    assert cond.wait_for(lambda n=n: len(imgs) > n, 30), "the image did not cross"
                q = far_qos(robots, "%camera%compressed")
                dur = (q[1], q[2].split(",")[1])
            assert dur == ("1", "1") and imgs[-1] == img
            isub.undeclare()
            import zenoh.ext as zext
            late: list[bytes] = []
            lsub = zext.declare_advanced_subscriber(
                robots, f"2/{img_key}", lambda smp: (late.append(smp.payload.to_bytes()), _notify(cond)),
                history=zext.HistoryConfig(detect_late_publishers=True))
            with cond:
                assert cond.wait_for(lambda: late, 30), "a late joiner got no history (TRANSIENT_LOCAL)"
            assert late == [img]                                     # the last one only: depth 1
            lsub.undeclare()
            for t in toks:
                t.undeclare()
        p.p.send_signal(signal.SIGINT)
        assert p.p.wait(60) == 0, p.output()
        deadline = time.monotonic() + 10
        while p.lines.get(timeout=max(0.1, deadline - time.monotonic())) is not None:   # stdout read to its end
            pass
        lines = [ln.rstrip("\n") for ln in p.out]
        sent = [ln for ln in lines if ln.startswith("ros2 link alpha-m /cmd_vel:")]
        recv = [ln for ln in lines if ln.startswith("ros2 link bravo-m /cmd_vel:")]
        assert sent and f"offered {seq}, sent {seq}" in sent[0], lines
        assert recv and f"received {seq}, latency mean" in recv[0], lines
        cams = [ln for ln in lines if ln.startswith(("ros2 link alpha-m /camera", "ros2 link bravo-m /camera"))]
        assert len(cams) == 2 and f"offered {k}, sent {k}" in cams[0] and f"received {k}," in cams[1], lines
        print("\n".join(sent + recv + cams))
        # the same counters in the trace's end record, with the QoS each side's topic table holds
        import json
        end = json.loads(trace.read_text().splitlines()[-1])
        a, b = end["ros2_link"]["alpha-m"]["topics"], end["ros2_link"]["bravo-m"]["topics"]
        assert end["ev"] == "end" and a["/cmd_vel"]["sent"] == seq and b["/cmd_vel"]["received"] == seq
        assert a["/cmd_vel"]["qos_out"] == b["/cmd_vel"]["qos_in"] == "2:2:1,5:,:,:,,"           # explicit form
        assert a["/camera/compressed"]["qos_out"] == b["/camera/compressed"]["qos_in"] == "1:1:1,1:,:,:,,"
        assert end["ros2_link"]["alpha-m"]["qos_announcements"] >= 2
    finally:
        if p.p.poll() is None:
            p.p.send_signal(signal.SIGINT)
            try:
                p.p.wait(15)
            except subprocess.TimeoutExpired:
                p.p.kill()
                p.p.wait(5)




def test_ros2_link_command_takes_the_scene_link(tmp_path):
    """`uwsimnet ros2-link MODEM --scene FILE` runs the vehicle's <ros2Link>: the same LinkSpec as the options
    spelling it out; mixing both, or a modem no link uses, is one line and exit 2."""
    import argparse

    from uwsimnet_zenoh.cli.ros2_link import add_commands, link_spec

    p = tmp_path / "s.xml"
    p.write_text(GOOD)
    parser = argparse.ArgumentParser()
    add_commands(parser.add_subparsers())
    from_scene = link_spec(parser.parse_args(["ros2-link", "alpha-m", "--scene", str(p)]))
    spelled = link_spec(parser.parse_args([
        "ros2-link", "alpha-m", "--world", WORLD, "--ros-domain", "1", "--mtu", "48",
        "--topic", f"topic=/cmd_vel,type={TWIST},dst=2,prio=0,policy=fifo,rate=20",
        "--topic", "topic=/camera/compressed,type=sensor_msgs/msg/CompressedImage,dir=out,prio=9,policy=keep_last,"
                   "depth=1,budget=400,compress=0"]))
    assert from_scene == spelled and from_scene[1] == WORLD
    for extra in (["alpha-m", "--scene", str(p), "--topic", f"topic=/a,type={TWIST}"], ["zulu-m", "--scene", str(p)]):
        r = subprocess.run([sys.executable, "-m", "uwsimnet_zenoh.cli", "ros2-link", *extra], capture_output=True,
                           text=True, timeout=60)
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr, r.stderr


def test_run_summary_lines_name_drops_and_problems():
    """The run summary's link lines: a topic that moved nothing is left out; drops by reason and the problems
    are said (the counters are the link's own summary)."""
    from uwsimnet_zenoh.app.ros2 import link_lines

    quiet = {"offered": 0, "sent": 0, "frames": 0, "bytes": 0, "received": 0, "dropped": {},
             "latency_mean_s": None, "latency_max_s": None}
    busy = dict(quiet, offered=5, sent=3, frames=9, bytes=400, dropped={"rate": 1, "superseded": 1})
    rx = dict(quiet, received=2, latency_mean_s=0.125, latency_max_s=0.2, dropped={"rx_lost": 1})
    lines = link_lines({"a-m": {"topics": {"/q": quiet, "/cam": busy}, "problems": {"cdr": 2}},
                        "b-m": {"topics": {"/cam": rx}, "problems": {}}})
    assert lines == ["ros2 link a-m /cam: offered 5, sent 3 (9 frames, 400 B), received 0; dropped 1 rate,"
                     " 1 superseded",
                     "ros2 link a-m problems: 2 cdr",
                     "ros2 link b-m /cam: offered 0, sent 0 (0 frames, 0 B), received 2, latency mean 125.0 ms max"
                     " 200.0 ms; dropped 1 rx_lost"]


def test_run_with_a_link_of_an_unknown_type_is_one_line(tmp_path):
    """A type the distro's type store does not know is found when the run starts the link: file:line of the
    <ros2Link>, exit 2, no traceback (the scene alone cannot know the distro)."""
    text = GOOD.replace("geometry_msgs/msg/Twist", "foo_msgs/msg/Bar")
    (tmp_path / "s.xml").write_text(text)
    r = subprocess.run([sys.executable, "-m", "uwsimnet_zenoh.cli", "run", str(tmp_path / "s.xml"), "--ros2",
                        "--listen", f"tcp/127.0.0.1:{free_port()}", "--duration", "30"],
                       capture_output=True, text=True, timeout=120)
    line = [i for i, ln in enumerate(text.splitlines(), 1) if "<ros2Link>" in ln][0]
    err = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert err[-1].startswith(f"{tmp_path / 's.xml'}:{line}: ros2Link of alpha: "), err
    assert "foo_msgs/msg/Bar" in err[-1], err
