"""HIL swap end to end (docs/gli-protocol.md, "Driver liveliness tokens"): a real driver (another process)
declares `driver/real` for a modem; the broker's simulated modem leaves the channel, every frame it still
held ends with a `dropped` status (reason `swapped`), and when the driver goes (cleanly, or killed -9)
the simulated modem is back on the channel.  Real Zenoh over loopback TCP, the broker a subprocess."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

pytest.importorskip("uwsimnet_gli")
from test_broker_e2e import Broker, device_xml, scene_xml, vehicle_xml  # noqa: E402
from uwsimnet_gli import World  # noqa: E402

WORLD = "hilswap"
FINAL = ("sent", "acked", "failed", "dropped")


DRIVER = r"""
import sys, json, zenoh
key, endpoint = sys.argv[1], sys.argv[2]
conf = zenoh.Config()
conf.insert_json5("mode", '"client"')
conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
conf.insert_json5("scouting/multicast/enabled", "false")
with zenoh.open(conf) as s:
    n = [0]
    sub = s.declare_subscriber(key.rsplit("/driver/", 1)[0] + "/tx", lambda smp: n.__setitem__(0, n[0] + 1))
    tok = s.liveliness().declare_token(key)
    print("ready", flush=True)
    for line in sys.stdin:
        if line.strip() == "count":
            print(n[0], flush=True)
        elif line.strip() == "quit":
            break
    tok.undeclare()
    sub.undeclare()
"""


def slow_device(dev: str, mac: int) -> str:
    """Slow (1 kbit/s) so that b-m's FIFO holds frames when the driver comes; addressee-only delivery, so
    that a frame for a modem that left the channel is refused (`noaddr`) instead of going on air for
    whoever is in range (the original's implicit broadcast without a MAC)."""
    only = "<macProtocol><name>none</name><delivery>addressee</delivery></macProtocol>"
    return device_xml(dev, mac, extra=only).replace("<bitrate>10000</bitrate>", "<bitrate>1000</bitrate>")


class Driver:
    def __init__(self, endpoint: str, dev: str) -> None:
        key = f"uwsimnet/{WORLD}/modem/{dev}/driver/real"
        self.p = subprocess.Popen([sys.executable, "-c", DRIVER, key, endpoint], text=True,
                                  stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                  env=dict(os.environ, PYTHONUNBUFFERED="1"))
        self._line("ready", 15)

    def _line(self, want: str | None, timeout: float) -> str:
        out: list[str] = []
        t = threading.Thread(target=lambda: out.append(self.p.stdout.readline()), daemon=True)
        t.start()
        t.join(timeout)
        assert out and out[0], "driver gave no answer"
        if want is not None:
            assert out[0].strip() == want
        return out[0].strip()

    def count(self) -> int:
        self.p.stdin.write("count\n")
        self.p.stdin.flush()
        return int(self._line(None, 5))

    def quit(self) -> None:
        self.p.stdin.write("quit\n")
        self.p.stdin.flush()
        self.p.wait(10)

    def kill9(self) -> None:
        self.p.send_signal(signal.SIGKILL)
        self.p.wait(10)

    def cleanup(self) -> None:
        if self.p.poll() is None:
            self.p.kill()
            self.p.wait(5)


def wait_for(pred, timeout: float, what: str):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        v = pred()
        if v:
            return v
        time.sleep(0.02)
    raise AssertionError(f"timed out waiting for {what}")


def final(modem, tag: int):
    return next((s for s in modem.statuses(tag) if s.event in FINAL), None)


def sim_token(world: World, dev: str) -> bool:
    return bool(list(world.session.liveliness().get(world.keys.modem(dev, "driver/sim"), timeout=1.0)))


@pytest.fixture
def broker(tmp_path: Path):
    scene = tmp_path / "hil.xml"
    scene.write_text(scene_xml(world=WORLD, vehicles="".join([
        vehicle_xml("a", (0, 0, 0), slow_device("a-m", 1)),
        vehicle_xml("b", (100, 0, 0), slow_device("b-m", 2)),
    ])))
    b = Broker(scene, tmp_path / "trace.jsonl")
    try:
        yield b
    finally:
        b.stop()


def test_swap_in_out_and_kill9(broker):
    drivers: list[Driver] = []
    try:
        with World(WORLD, connect=broker.endpoint) as w:
            a, b = w.modem("a-m"), w.modem("b-m")
            kinds: list[str | None] = []
            b.on_kind(kinds.append)
            assert b.wait_kind(timeout=5) == "sim" and a.wait_kind(timeout=5) == "sim"
            b.send(1, b"warm")                                  # the link works before any swap
            assert a.receive(timeout=5) is not None

            # 1. b-m holds a queue of 50-byte frames (0.4 s each at 1 kbit/s) when a real driver comes
            tags = [b.send(1, bytes(50)) for _ in range(8)]
            wait_for(lambda: all(any(s.event == "queued" for s in b.statuses(t)) for t in tags), 5, "queued")
            drv = Driver(broker.endpoint, "b-m")
            drivers.append(drv)
            assert b.wait_kind(("real",), timeout=5) == "real"
            wait_for(lambda: not sim_token(w, "b-m"), 5, "the sim token to go")
            # nothing is lost silently: every frame ends sent, or dropped `swapped` (with its seq)
            outcomes = wait_for(lambda: all(final(b, t) for t in tags) and [final(b, t) for t in tags],
                                5, "a final status for every queued frame")
            swapped = [s for s in outcomes if s.event == "dropped"]
            assert swapped and all(s.reason == "swapped" for s in swapped)
            assert all(isinstance(s.seq, int) for s in outcomes)
            assert len({s.seq for s in outcomes}) == len(outcomes)
            # the simulated modem left the channel: a frame for address 2 has nobody to reach
            t = a.send(2, b"to-b")
            st = wait_for(lambda: final(a, t), 5, "a's status")
            assert (st.event, st.reason) == ("dropped", "noaddr")
            # b-m's tx now goes to the driver only: the simulator no longer answers for it
            t = b.send(1, b"real")
            wait_for(lambda: drv.count() >= 1, 5, "the driver to get the frame")
            time.sleep(0.3)
            assert b.statuses(t) == []
            assert all(f.data != b"real" for f in a.frames(timeout=0.2))   # (frames sent before: fine)
            state = w.control("state")
            assert state["modems"]["b-m"]["kind"] == "real"

            # 2. the driver stops cleanly: the simulated modem is back on the channel
            drv.quit()
            assert b.wait_kind(("sim",), timeout=5) == "sim"
            t = b.send(1, b"back")
            f = a.receive(timeout=5)
            assert f is not None and f.data == b"back"
            assert wait_for(lambda: final(b, t), 5, "status").event == "sent"

            # 3. again, and the driver is killed -9 while traffic flows both ways
            stop = threading.Event()
            sent: list[tuple[object, int]] = []

            def traffic() -> None:
                i = 0
                while not stop.is_set():
                    for m, dst in ((a, 2), (b, 1)):
                        sent.append((m, m.send(dst, b"x%d" % i)))
                    i += 1
                    time.sleep(0.05)

            th = threading.Thread(target=traffic, daemon=True)
            th.start()
            try:
                wait_for(lambda: any(m is b and final(b, t) for m, t in list(sent)), 10,
                         "traffic answered by the simulated b-m")
                drv2 = Driver(broker.endpoint, "b-m")
                drivers.append(drv2)
                assert b.wait_kind(("real",), timeout=5) == "real"
                wait_for(lambda: drv2.count() >= 3, 5, "the driver to get frames")
                drv2.kill9()
                assert b.wait_kind(("sim",), timeout=5) == "sim"
                wait_for(lambda: sim_token(w, "b-m"), 5, "the sim token back")
                n_back = len(sent)
                wait_for(lambda: len(sent) >= n_back + 6, 10, "traffic going on after the swap back")
            finally:
                stop.set()
                th.join(5)
            # after the kill the simulated modem serves b-m again: new frames flow and are answered
            t = b.send(1, b"after-kill")
            wait_for(lambda: final(b, t), 5, "a status after the kill")
            got = []
            wait_for(lambda: got.extend(a.frames(timeout=0.1)) or any(f.data == b"after-kill" for f in got),
                     8, "the frame after the kill")
            # every frame a-m (always simulated) was offered ended with a status
            a_tags = [tag for m, tag in sent if m is a]
            wait_for(lambda: all(final(a, tag) for tag in a_tags), 10, "a's statuses")
            reasons = {final(a, tag).reason for tag in a_tags} - {None}
            assert reasons <= {"noaddr", "fifo"}, reasons
            assert kinds.count("real") == 2 and kinds[-1] == "sim"
    finally:
        for d in drivers:
            with contextlib.suppress(Exception):
                d.cleanup()


def test_status_seq_round_trip():
    from uwsimnet_gli import wire
    from uwsimnet_gli.records import read_status as gli_decode

    raw = wire.encode_status(7, "dropped", "swapped", 1.5, seq=42)
    assert wire.decode_status(raw) == wire.Status(7, "dropped", "swapped", 1.5, 42)
    assert gli_decode(raw).seq == 42
    old = wire.encode_status(7, "sent", None, 1.5)                    # no seq: still valid, seq None
    assert wire.decode_status(old).seq is None and gli_decode(old).seq is None
