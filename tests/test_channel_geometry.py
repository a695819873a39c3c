"""A channel's geometry (phy.channel): Python lists on a small channel, numpy arrays on a large one, the
same doubles; and small runs, virtual and realtime, that never import numpy (its import was a third of the
start-up, and in a realtime run a stall of the engine thread)."""

from __future__ import annotations

import importlib.util
import random
import socket
import subprocess
import sys
from pathlib import Path

from conftest import device, scene, vehicle

from uwsimnet_zenoh.engine.network import Network
from uwsimnet_zenoh.scene.model import Channel


def _net(rng: random.Random, n: int = 40) -> Network:
    vehicles = []
    for i in range(n):
        pos = (rng.uniform(-3000, 3000), rng.uniform(-3000, 3000), rng.uniform(-300, 0))
        dev = device(f"d{i}", i + 1, 0, rx=rng.choice([0, 0, 1]),
                     max_distance=rng.choice([99_999_999.0, 2500.0]), min_distance=rng.choice([0.0, 0.0, 900.0]))
        vehicles.append(vehicle(f"v{i}", pos, dev))
    return Network(scene(vehicles, channels=[Channel(id=0, prop_s_per_m=1 / 1500, min_prop_s=0.013),
                                             Channel(id=1, prop_s_per_m=1 / 1500, min_prop_s=0.0)]))


def _same(ch, m, t: float) -> None:
    dist, delay, ok, longest = ch._geometry_lists(m, t)
    adist, adelay, aok, alongest = ch._geometry_arrays(m, t)
    assert dist == adist.tolist()
    assert delay == adelay.tolist()
    assert ok == aok.tolist()
    assert longest == alongest


def test_list_and_array_geometry_are_the_same_doubles():
    rng = random.Random(5)
    for _ in range(3):
        net = _net(rng)
        ch = net.channels[0]
        poses = net.poses
        for i, name in enumerate(poses.names):      # some vehicles from outside: sampled, moving, or unknown
            if i % 4 == 1:
                poses.set_external(name)
                if i % 8 != 1:
                    poses.update(name, rng.uniform(0, 5), [rng.uniform(-1e3, 1e3) for _ in range(3)],
                                 [rng.uniform(-2, 2) for _ in range(3)])
        for t in (0.0, 3.3, 17.0):
            for m in net.modems.values():
                _same(ch, m, t)
            # changes after the numpy columns exist (the first array read made them): kept in step
            i = rng.randrange(len(poses.names))
            poses.update(poses.names[i], t, [rng.uniform(-1e3, 1e3) for _ in range(3)], [1.0, -0.5, 0.0])
            poses.set_static(poses.names[(i + 2) % len(poses.names)], (rng.uniform(0, 9), 1.0, -2.0))
            poses.set_external(poses.names[(i + 3) % len(poses.names)])
        assert any(not k for k in poses.known)
        first = next(iter(net.modems.values()))
        assert len({round(d, 6) for d in ch._geometry_lists(first, 1.0)[0]}) > 15     # distinct distances


def test_a_lossless_run_of_a_small_channel_does_not_import_numpy(tmp_path):
    spec = importlib.util.spec_from_file_location(
        "bench_user_path", Path(__file__).resolve().parents[1] / "bench" / "bench_user_path.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    path = tmp_path / "aloha.xml"
    path.write_text(bench.scene_xml(16, 50.0, half=True))
    code = ("import sys; from uwsimnet_zenoh.cli.main import main; "
            f"rc = main(['run', {str(path)!r}, '--trace', {str(tmp_path / 't.jsonl')!r}]); "
            "print(rc, 'numpy' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120)
    assert out.stdout.split()[-2:] == ["0", "False"], out.stdout + out.stderr
    assert len((tmp_path / "t.jsonl").read_text().splitlines()) > 100


def test_a_realtime_run_of_a_small_scene_does_not_import_numpy(tmp_path):
    """The realtime broker publishes the scene vehicles' poses (and answers info and state) from the pose
    table's points: numpy, imported lazily, would be imported by the engine thread in the middle of the run
    (150-300 ms late events)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    dev = ("<CustomCommsDevice><dccommsId>{0}</dccommsId><mac>{1}</mac><txChannelId>0</txChannelId>"
           "<rxChannelId>0</rxChannelId><bitrate>1000</bitrate></CustomCommsDevice>")
    path = tmp_path / "rt.xml"
    path.write_text(
        "<UWSimScene><simulation><duration>1.2</duration><clock>realtime</clock><world>np</world></simulation>"
        "<CustomCommsChannel><id>0</id><propTimeIncPerMeter>0.6666</propTimeIncPerMeter></CustomCommsChannel>"
        f"<vehicle><name>a</name><position>0 0 0</position>{dev.format('a', 1)}</vehicle>"
        f"<vehicle><name>b</name><position>100 0 0</position>{dev.format('b', 2)}</vehicle>"
        "<flow><name>f</name><src>a</src><dst>2</dst><size>20</size><interval>0.2</interval></flow></UWSimScene>")
    code = ("import sys; from uwsimnet_zenoh.cli.main import main; "
            f"rc = main(['run', {str(path)!r}, '--clock', 'realtime', '--listen', 'tcp/127.0.0.1:{port}', "
            f"'--trace', {str(tmp_path / 't.jsonl')!r}]); print(rc, 'numpy' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.stdout.split()[-2:] == ["0", "False"], out.stdout + out.stderr
    assert '"ev":"rx"' in (tmp_path / "t.jsonl").read_text()
