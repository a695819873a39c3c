"""`uwsimnet emulate serial` on a running broker: a pty speaking dccomms DataLinkFrames, backed by a simulated
modem over real Zenoh; broker and emulator are separate processes, the app is a uwsimnet_gli client.

The test plays the dccomms application on the pty: it decodes what the simulated modem received and writes
frames for it to send, including a corrupted one that must be reported and skipped without stopping it."""

from __future__ import annotations

import os
import select
import signal
import subprocess
import time
from pathlib import Path

import pytest

pytest.importorskip("uwsimnet_gli")
from test_broker_e2e import PY, ROOT, UWSIMNET, Broker, Proc, device_xml, scene_xml, vehicle_xml  # noqa: E402
from uwsimnet_gli import World  # noqa: E402

from uwsimnet_zenoh.drivers.dccomms.driver import set_raw  # noqa: E402
from uwsimnet_zenoh.formats import dccomms as fr  # noqa: E402
from uwsimnet_zenoh.formats import dccomms_stream as ds  # noqa: E402

WORLD = "emuserial"
WAIT = 10.0
# `python -m` runs cli.py as __main__ (a second copy of the module): errors raised by the sub-commands
# must still come out as one line with exit 2 (UserError lives in uwsimnet_zenoh.errors for that)
USER_CLI = [PY, "-m", "uwsimnet_zenoh.cli"]


@pytest.fixture(scope="module")
def broker(tmp_path_factory):
    d = tmp_path_factory.mktemp("emuserial")
    scene = d / "s.xml"
    scene.write_text(scene_xml(world=WORLD, vehicles="".join([
        vehicle_xml("a", (0, 0, 0), device_xml("a-m", 1)),
        vehicle_xml("b", (50, 0, 0), device_xml("b-m", 2)),
    ])))
    b = Broker(scene, d / "trace.jsonl")
    yield b
    assert b.stop() == 0, b.output()


def read_frames(fd: int, dec: ds.FrameDecoder, n: int, timeout: float = WAIT) -> list[ds.Frame]:
    """The next `n` valid frames from the pty (anything else fails the test)."""
    out: list[ds.Frame] = []
    deadline = time.monotonic() + timeout
    while len(out) < n and time.monotonic() < deadline:
        r, _, _ = select.select([fd], [], [], max(0.0, deadline - time.monotonic()))
        if r:
            for ev in dec.feed(os.read(fd, 4096), time.monotonic()):
                assert isinstance(ev, ds.FrameReceived), ev
                out.append(ev.frame)
    assert len(out) == n, f"{len(out)} of {n} frames within {timeout} s"
    return out


def wait_for(cond, timeout: float = WAIT) -> bool:
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.02)
    return True


def test_emulate_serial_frames_both_ways_bad_crc_and_sigterm(broker, tmp_path: Path):
    link = tmp_path / "ttyRADIO"
    emu = Proc([*UWSIMNET, "emulate", "serial", "--id", "a-m", "--link", str(link), "--world", WORLD,
                "--connect", broker.endpoint])
    fd = -1
    try:
        line = emu.expect(f"uwsimnet: emulator serial ready for {WORLD}/a-m on ", 20)
        where = line.split(" on ", 1)[1].split()
        path = where[0]
        assert where[1:] == ["link", str(link)] and os.path.realpath(link) == os.path.realpath(path), line
        fd = os.open(link, os.O_RDWR | os.O_NOCTTY)
        set_raw(fd)
        dec = ds.FrameDecoder()
        with World(WORLD, connect=broker.endpoint) as w:
            b = w.modem("b-m")
            assert b.wait_kind(("sim",), timeout=5) == "sim"

            # app on b-m (2) -> simulated channel -> a-m (1) -> a DataLinkFrame out of the pty
            payload = b"to the radio \x55\x55\x00\xff"
            b.send(1, payload)
            (f,) = read_frames(fd, dec, 1)
            assert (f.dst, f.src, f.payload) == (1, 2, payload)

            # a frame written into the pty -> a-m sends it -> the app gets it from address 1
            os.write(fd, fr.DEFAULT.encode(dst=2, src=1, payload=b"from the radio"))
            g = b.receive(timeout=WAIT)
            assert g is not None and (g.src, g.dst, g.data) == (1, 2, b"from the radio")

            # a corrupted frame is reported and skipped; the next good frame still goes through
            bad = bytearray(fr.DEFAULT.encode(dst=2, src=1, payload=b"corrupted"))
            bad[-1] ^= 0xFF
            os.write(fd, bytes(bad) + fr.DEFAULT.encode(dst=2, src=1, payload=b"after the bad one"))
            g = b.receive(timeout=WAIT)
            assert g is not None and (g.src, g.dst, g.data) == (1, 2, b"after the bad one")
            assert wait_for(lambda: any("a-m: bad CRC (frame 1->2, 9 bytes payload) on the pty, frame skipped"
                                        in x for x in emu.err)), emu.output()
            assert b.receive(timeout=0.3) is None                    # the corrupted frame never went on air
            assert emu.p.poll() is None
        os.close(fd)
        fd = -1

        t0 = time.monotonic()
        emu.p.send_signal(signal.SIGTERM)
        assert emu.p.wait(5) == 0, emu.output()
        assert time.monotonic() - t0 < 5
        emu.drained()                                               # every line it wrote is read
        assert "Traceback" not in emu.output(), emu.output()
        assert not os.path.lexists(link)                            # the symlink goes with the emulator
    finally:
        if fd >= 0:
            os.close(fd)
        emu.stop()


def test_emulate_unknown_id_exits_2_with_one_line_like_evologics(broker):
    """`--id nosuch`: the same one-line error and exit code 2 as `emulate evologics`, no traceback."""
    base = ["--id", "nosuch", "--world", WORLD, "--connect", broker.endpoint]
    procs = [subprocess.Popen([*USER_CLI, "emulate", kind, *extra, *base], cwd=ROOT, text=True,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE)
             for kind, extra in (("serial", []), ("evologics", ["--port", "0"]))]
    results = []
    for p in procs:
        try:
            out, err = p.communicate(timeout=20)
        finally:
            if p.poll() is None:
                p.kill()
                p.wait(5)
        results.append((p.returncode, out, err))
    want = f"modem 'nosuch' of world '{WORLD}' does not answer on uwsimnet/{WORLD}/modem/nosuch/info\n"
    assert results[0] == (2, "", want), results[0]
    assert results[1] == results[0]


def test_emulate_serial_refuses_to_replace_a_file_with_its_link(tmp_path: Path):
    """--link naming a regular file: one line, exit 2, the file untouched (checked before any Zenoh)."""
    victim = tmp_path / "notes.txt"
    victim.write_text("keep me")
    r = subprocess.run([*USER_CLI, "emulate", "serial", "--id", "a-m", "--link", str(victim),
                        "--connect", "tcp/127.0.0.1:1"], cwd=ROOT, capture_output=True, text=True, timeout=30)
    assert (r.returncode, r.stdout) == (2, "")
    assert r.stderr == f"--link {victim}: exists and is not a symlink; not replacing it\n"
    assert victim.read_text() == "keep me"
