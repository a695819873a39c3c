"""`uwsimnet driver evologics` -> `uwsimnet emulate evologics` -> simulated channel -> another app, over real
TCP (AT commands) and real Zenoh, every part its own process.

Modem b-m is served by the EvoLogics driver (HIL swap), whose "hardware" is the emulator of simulated
modem a-m; the app talks to b-m's keys and to c-m (simulated) and never notices."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

pytest.importorskip("uwsimnet_gli")
from test_broker_e2e import UWSIMNET, Broker, Proc, device_xml, free_port, scene_xml, stop_all, vehicle_xml  # noqa: E402
from uwsimnet_gli import World  # noqa: E402

WORLD = "hildrv"


@pytest.fixture
def parts(tmp_path: Path):
    scene = tmp_path / "hil.xml"
    scene.write_text(scene_xml(world=WORLD, vehicles="".join([
        vehicle_xml("a", (0, 0, 0), device_xml("a-m", 1)),
        vehicle_xml("b", (50, 0, 0), device_xml("b-m", 2)),
        vehicle_xml("c", (100, 0, 0), device_xml("c-m", 3)),
    ])))
    started: list[Proc] = []
    try:
        b = Broker(scene, tmp_path / "trace.jsonl")
        started.append(b)
        port = free_port()
        emu = Proc([*UWSIMNET, "emulate", "evologics", "--port", str(port), "--id", "a-m", "--world", WORLD,
                    "--connect", b.endpoint])
        started.append(emu)
        emu.expect("uwsimnet: emulator evologics ready", 20)
        drv = Proc([*UWSIMNET, "driver", "evologics", "--host", "127.0.0.1", "--port", str(port), "--id", "b-m",
                    "--connect", b.endpoint])                                 # world discovered
        started.append(drv)
        drv.expect("uwsimnet: driver evologics ready", 20)
        yield b, emu, drv
    finally:
        errors = stop_all(started)
        assert not errors, errors


def test_driver_to_emulator_through_the_simulated_channel(parts):
    broker, emu, drv = parts
    with World(WORLD, connect=broker.endpoint) as w:
        b, c = w.modem("b-m"), w.modem("c-m")
        assert b.wait_kind(("real",), timeout=5) == "real"
        info = b.info()
        assert info is not None and info["kind"] == "real" and info["id"] == "b-m"

        # app -> b-m (driver) -> AT over TCP -> emulator of a-m -> simulated channel -> c-m
        tag = b.send(3, b"hello from hardware")
        f = c.receive(timeout=10)
        assert f is not None and f.data == b"hello from hardware" and f.src == 1 and f.dst == 3
        st = b.wait_status(tag, events=("acked", "failed", "dropped"), timeout=10)
        assert st is not None and st.event == "acked", st          # DELIVEREDIM: the trace said c-m got it

        # c-m -> simulated channel -> a-m -> emulator RECVIM -> driver -> b-m's rx
        c.send(1, b"hello hardware")
        g = None
        deadline = time.monotonic() + 10
        while g is None and time.monotonic() < deadline:
            g = b.receive(timeout=0.5)
        assert g is not None and g.data == b"hello hardware" and g.src == 3
    assert broker.p.poll() is None and emu.p.poll() is None and drv.p.poll() is None


@pytest.mark.parametrize("framing", [None, "SimplePacketBuilder20crc16"])
def test_serial_driver_serves_a_modem_id(tmp_path: Path, framing):
    """`uwsimnet driver serial` on a pty whose other end is a serial-radio emulator of another (in-process)
    simulation: frames put on b-m's keys go out on that radio link, and what it receives comes back."""
    from conftest import device, scene, vehicle

    from uwsimnet_zenoh.drivers.dccomms.emulator import SerialRadioEmulator
    from uwsimnet_zenoh.drivers.sim_backend import SimWorld
    from uwsimnet_zenoh.scene.model import Channel

    radio = SimWorld(scene([vehicle("a", (0, 0, 0), device("radio-a", 1, bitrate=9600)),
                            vehicle("b", (30, 0, 0), device("radio-b", 2, bitrate=9600))],
                           channels=[Channel(id=0, prop_s_per_m=3.333e-9, min_prop_s=0.0)]))
    emu = SerialRadioEmulator(radio.backend("radio-b"), framing=framing)
    got: list = []
    radio.backend("radio-a").on_frame.append(got.append)
    sc = tmp_path / "s.xml"
    sc.write_text(scene_xml(world=WORLD, vehicles="".join([
        vehicle_xml("b", (0, 0, 0), device_xml("b-m", 2)), vehicle_xml("c", (50, 0, 0), device_xml("c-m", 3))])))
    started: list[Proc] = []
    try:
        emu.start()
        radio.start()
        broker = Broker(sc, tmp_path / "trace.jsonl")
        started.append(broker)
        drv = Proc([*UWSIMNET, "driver", "serial", "--device", emu.path, "--id", "b-m", "--world", WORLD,
                    "--connect", broker.endpoint, *(["--framing", framing] if framing else [])])
        started.append(drv)
        drv.expect("uwsimnet: driver serial ready", 20)
        with World(WORLD, connect=broker.endpoint) as w:
            b = w.modem("b-m")
            assert b.wait_kind(("real",), timeout=5) == "real"
            b.send(1, b"over the radio")
            deadline = time.monotonic() + 10
            while not got and time.monotonic() < deadline:
                time.sleep(0.02)
            if framing is None:              # DataLinkFrame: addressed
                assert got and (got[0].src, got[0].dst, got[0].data) == (2, 1, b"over the radio")
                radio.backend("radio-a").send(2, b"radio reply")
                f = b.receive(timeout=10)
                assert f is not None and (f.src, f.dst, f.data) == (1, 2, b"radio reply")
                assert f.msg is None
            else:                            # SimplePacket: no addresses, 20 bytes, its seq the first two
                assert got and got[0].data == b"over the radio".ljust(20, b"\0")
                radio.backend("radio-a").send(2, b"\x01\x02radio reply")
                f = b.receive(timeout=10)
                assert f is not None and f.data == b"\x01\x02radio reply".ljust(20, b"\0")
                assert f.msg == {"aseq": 0x0102}         # the frame's own seq, as the sending app's
    finally:
        errors = stop_all(started)
        emu.close()
        radio.close()
        assert not errors, errors


# -- the driver port: a driver and an emulator from a separately installed package (entry points) -------------
def _doc_blocks() -> tuple[str, str]:
    """The plug-in and its pyproject entry points, as docs/drivers.md shows them (the doc's code is what runs)."""
    import re
    import tomllib

    doc = (Path(__file__).resolve().parents[1] / "docs" / "drivers.md").read_text()
    part = doc[doc.index("## The driver port"):]
    code = re.search(r"```python\n(.*?)```", part, re.S).group(1)
    toml = tomllib.loads(re.search(r"```toml\n(.*?)```", part, re.S).group(1))
    eps = toml["project"]["entry-points"]
    lines = []
    for group, extra in (("uwsimnet.drivers", {"broken": "acme_modems:MISSING", "notaplugin": "acme_modems:_args"}),
                         ("uwsimnet.emulators", {})):
        lines += [f"[{group}]", *(f"{k} = {v}" for k, v in {**eps[group], **extra}.items()), ""]
    return code, "\n".join(lines)


@pytest.fixture
def installed_plugin(tmp_path: Path, monkeypatch):
    """acme_modems installed as a package of its own (its code and its dist-info on the path), as pip would."""
    site = tmp_path / "site"
    (site / "acme_modems").mkdir(parents=True)
    code, entry_points = _doc_blocks()
    (site / "acme_modems" / "__init__.py").write_text(code)
    info = site / "acme_modems-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: acme-modems\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(entry_points)
    import os

    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(p for p in (str(site), os.environ.get("PYTHONPATH")) if p))
    return site


def test_a_driver_and_an_emulator_plugin_serve_through_the_channel(installed_plugin, tmp_path: Path):
    scene = tmp_path / "hil.xml"
    scene.write_text(scene_xml(world=WORLD, vehicles="".join([
        vehicle_xml("a", (0, 0, 0), device_xml("a-m", 1)),
        vehicle_xml("b", (50, 0, 0), device_xml("b-m", 2)),
        vehicle_xml("c", (100, 0, 0), device_xml("c-m", 3)),
    ])))
    started: list[Proc] = []
    try:
        broker = Broker(scene, tmp_path / "trace.jsonl")
        started.append(broker)
        port = free_port()
        emu = Proc([*UWSIMNET, "emulate", "acme", "--tcp", str(port), "--id", "a-m", "--world", WORLD,
                    "--connect", broker.endpoint])
        started.append(emu)
        emu.expect(f"uwsimnet: emulator acme ready for {WORLD}/a-m on 127.0.0.1:{port}", 20)
        drv = Proc([*UWSIMNET, "driver", "acme", "--modem", f"127.0.0.1:{port}", "--id", "b-m",
                    "--connect", broker.endpoint])
        started.append(drv)
        drv.expect("uwsimnet: driver acme ready", 20)
        with World(WORLD, connect=broker.endpoint) as w:
            b, c = w.modem("b-m"), w.modem("c-m")
            assert b.wait_kind(("real",), timeout=5) == "real"
            tag = b.send(3, b"from a plug-in")
            f = c.receive(timeout=10)
            assert f is not None and f.data == b"from a plug-in" and f.src == 1 and f.dst == 3
            st = b.wait_status(tag, events=("acked", "failed", "dropped"), timeout=10)
            assert st is not None and st.event == "acked", st
    finally:
        errors = stop_all(started)
        assert not errors, errors


@pytest.mark.parametrize("argv,line", [
    (["driver", "broken", "--id", "x"], "driver plug-in 'broken' (acme_modems:MISSING) does not load: AttributeError"),
    (["driver", "notaplugin", "--id", "x"],
     "driver plug-in 'notaplugin' (acme_modems:_args) is a function, not a"
     " uwsimnet_zenoh.drivers.registry.DriverPlugin"),
    (["emulate", "nosuch", "--id", "x"], "unknown emulator 'nosuch' (known: evologics, serial, acme;"),
    (["driver", "nosuch", "--id", "x"], "unknown driver 'nosuch' (known: evologics, serial, acme, broken, notaplugin;"),
])
def test_bad_plugins_are_refused_in_one_line(installed_plugin, argv, line):
    import subprocess

    r = subprocess.run([*UWSIMNET, *argv, "--connect", "tcp/127.0.0.1:1"], capture_output=True, text=True, timeout=60)
    assert (r.returncode, r.stdout) == (2, "")
    assert r.stderr.count("\n") == 1 and r.stderr.startswith(line), r.stderr
