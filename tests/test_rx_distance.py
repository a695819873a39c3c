"""The distance of a received frame travels with it: the broker's `rx` message carries `dist` (the channel's
distance at transmission start, the trace rx record's), applications see it (`uwsimnet_gli.Frame.dist`),
and `ZenohBackend` turns it into the propagation time of the channel's law, so what the device emulators
report (RECV's propagation time, `AT?T`, ranges) is the channel's and not t_rx - t_tx at 1500 m/s (which
would include the modems' 50 ms intrinsic delays here).

Codec checks, then one real broker process (custom channel 3 ms + 0.8 ms/m, modems 500 m apart)."""

from __future__ import annotations

import math
import queue
import socket
import time
from pathlib import Path

import msgpack
import pytest

pytest.importorskip("uwsimnet_gli")
from test_broker_e2e import Broker  # noqa: E402
from uwsimnet_gli import World, records, wire  # noqa: E402
from uwsimnet_gli.wire import Keys  # noqa: E402

from uwsimnet_zenoh.bus.session import make_config, open_session  # noqa: E402
from uwsimnet_zenoh.drivers.backend import BackendFrame, link_metrics  # noqa: E402
from uwsimnet_zenoh.drivers.evologics.emulator import EvoLogicsEmulator  # noqa: E402
from uwsimnet_zenoh.drivers.zenoh_backend import ZenohBackend  # noqa: E402
from uwsimnet_zenoh.engine.network import Network  # noqa: E402
from uwsimnet_zenoh.scene.load import load_scene_text  # noqa: E402

WORLD = "rxdist"
MIN_MS, PER_M_MS = 3.0, 0.8                    # 3 ms + 0.8 ms/m: not 1/1500 s/m
B_POS = (300.0, 400.0, 0.0)
DIST = math.dist((0.0, 0.0, 0.0), B_POS)       # 500 m


def dev_xml(dev: str, mac: int) -> str:
    return (f"<CustomCommsDevice><dccommsId>{dev}</dccommsId><mac>{mac}</mac><txChannelId>0</txChannelId>"
            f"<rxChannelId>0</rxChannelId><bitrate>10000</bitrate><maxDistance>2000</maxDistance>"
            f"<intrinsicDelay><tx>50</tx><rx>50</rx></intrinsicDelay>"
            f"<rateErrorModel><errorUnit>packet</errorUnit><errorRateExpr>0</errorRateExpr></rateErrorModel>"
            f"</CustomCommsDevice>")


SCENE = f"""<?xml version="1.0"?>
<UWSimScene>
  <simulation><seed>1</seed><clock>realtime</clock><world>{WORLD}</world></simulation>
  <CustomCommsChannel><id>0</id><propTimeIncPerMeter>{PER_M_MS}</propTimeIncPerMeter>
    <minPropTime>{MIN_MS}</minPropTime></CustomCommsChannel>
  <vehicle><name>a</name><position>0 0 0</position>{dev_xml("a-m", 1)}</vehicle>
  <vehicle><name>b</name><position>{B_POS[0]} {B_POS[1]} {B_POS[2]}</position>{dev_xml("b-m", 2)}</vehicle>
</UWSimScene>"""


# -- codec -----------------------------------------------------------------------------------------
def test_codec_rx_round_trip_with_and_without_dist():
    f = wire.decode_rx(wire.encode_rx(1, 2, b"abc", 5, 1.25, 1.5, 499.75))
    assert (f.src, f.dst, f.data, f.seq, f.t_tx, f.t_rx, f.dist) == (1, 2, b"abc", 5, 1.25, 1.5, 499.75)
    assert isinstance(wire.decode_rx(wire.encode_rx(1, 2, b"", 0, 0, 0, 7)).dist, float)
    old = wire.encode_rx(1, 2, b"abc", 5, 1.25, 1.5)                   # an older broker: no dist key
    assert "dist" not in msgpack.unpackb(old)
    assert wire.decode_rx(old).dist is None
    assert wire.decode_rx(wire.encode_rx(1, 2, b"", 0, 0, 0, 0.0)).dist == 0.0
    g = records.read_rx(wire.encode_rx(1, 2, b"d", 3, 0.5, 0.75, 12.5), "m")
    assert g is not None and g.dist == 12.5 and g.data == b"d"
    h = records.read_rx(old, "m")
    assert h is not None and h.dist is None


@pytest.mark.parametrize("bad", [-1.0, float("nan"), float("inf"), "500", True, [500.0]])
def test_codec_rx_bad_dist_is_rejected(bad):
    raw = wire.pack({"src": 1, "dst": 2, "data": b"x", "seq": 0, "t_tx": 0.0, "t_rx": 0.1, "dist": bad})
    with pytest.raises(wire.CodecError) as e:
        wire.decode_rx(raw)
    assert e.value.reason == "invalid"
    assert records.read_rx(raw) is None
    nil = wire.pack({"src": 1, "dst": 2, "data": b"x", "seq": 0, "t_tx": 0.0, "t_rx": 0.1, "dist": None})
    assert wire.decode_rx(nil).dist is None and records.read_rx(nil).dist is None


# -- through a broker ------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def law() -> float:
    """The channel's propagation time at DIST, from the same scene's PHY."""
    return Network(load_scene_text(SCENE), flows=False).channels[0].max_prop_delay(DIST)


@pytest.fixture(scope="module")
def broker(tmp_path_factory):
    d: Path = tmp_path_factory.mktemp("rxdist")
    (d / "s.xml").write_text(SCENE)
    b = Broker(d / "s.xml", d / "trace.jsonl")
    try:
        yield b
    finally:
        assert b.stop() == 0, b.output()


@pytest.fixture()
def session(broker):
    with open_session(make_config("client", connect=[broker.endpoint], connect_timeout_ms=3000)) as s:
        yield s


def test_gli_app_gets_the_channels_distance(broker):
    with World(WORLD, connect=broker.endpoint) as w:
        a, b = w.modem("a-m"), w.modem("b-m")
        assert b.wait_kind(timeout=5) == "sim"
        a.send(2, b"how far?")
        f = b.receive(timeout=10)
        assert f is not None and f.data == b"how far?" and f.src == 1
        assert f.dist is not None and abs(f.dist - DIST) < 1e-6, f
        # what t_rx - t_tx would have said at 1500 m/s: off by the intrinsic rx delay and the law
        assert abs((f.t_rx - f.t_tx) * 1500.0 - DIST) > 50.0


def test_zenoh_backend_and_link_metrics_use_the_channel(session, law):
    assert abs(law - (MIN_MS + PER_M_MS * DIST) / 1e3) < 1e-12
    be = ZenohBackend(session, WORLD, "b-m")
    got: queue.Queue[BackendFrame] = queue.Queue()
    be.on_frame.append(got.put)
    try:
        with World(WORLD, session=session) as w:
            w.modem("a-m").send(2, b"range me")
            f = got.get(timeout=10)
        assert f.data == b"range me"
        assert f.distance is not None and abs(f.distance - DIST) < 1e-6
        assert f.prop_time is not None and abs(f.prop_time - law) < 1e-9
        m = link_metrics(f)
        assert abs(m.distance - DIST) < 1e-6 and abs(m.prop_time - law) < 1e-9
        naive = link_metrics(BackendFrame(f.src, f.dst, f.data, f.seq, f.t_tx, f.t_rx, f.size, f.bitrate))
        assert abs(naive.distance - DIST) > 50.0          # the old estimate, visibly wrong here

        # an rx without dist (an older broker, a real driver): the fallback, no error
        session.put(Keys(WORLD).rx("b-m"), wire.encode_rx(1, 2, b"old", 99, 1.0, 1.5))
        g = got.get(timeout=5)
        while g.data != b"old":
            g = got.get(timeout=5)
        assert g.distance is None and g.prop_time is None
    finally:
        be.close()


def _lines(sock: socket.socket, buf: bytearray, prefix: bytes, timeout: float = 10.0) -> bytes:
    deadline = time.monotonic() + timeout
    while True:
        i = buf.find(b"\r\n")
        if i >= 0:
            line = bytes(buf[:i])
            del buf[:i + 2]
            if line.startswith(prefix):
                return line
            continue
        sock.settimeout(max(0.01, deadline - time.monotonic()))
        chunk = sock.recv(4096)
        assert chunk, "emulator closed the connection"
        buf += chunk


def test_evologics_emulator_reports_the_channels_propagation_time(session, law):
    be = ZenohBackend(session, WORLD, "b-m")
    emu = EvoLogicsEmulator(be, port=0)
    try:
        host, port = emu.start()
        with socket.create_connection((host, port), timeout=5) as sock, World(WORLD, session=session) as w:
            deadline = time.monotonic() + 10
            while not emu.clients:                                    # the emulator has the client
                assert time.monotonic() < deadline, "the emulator never took the connection"
                time.sleep(0.01)
            data = b"x" * 100                                         # > 64 bytes: arrives as RECV
            w.modem("a-m").send(2, data)
            buf = bytearray()
            line = _lines(sock, buf, b"RECV,")
            fields = line.split(b",", 9)
            assert fields[9] == data and fields[2] == b"1"
            assert int(fields[7]) == int(round(law * 1e6)), line      # propagation time, us
            sock.sendall(b"AT?T\n")
            assert int(_lines(sock, buf, b"")) == int(round(law * 1e6))
    finally:
        emu.close()
        be.close()
