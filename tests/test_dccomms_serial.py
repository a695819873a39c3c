"""dccomms DataLinkFrame framing, CRC16 XMODEM, and the serial radio driver against the pty emulator."""

from __future__ import annotations

import contextlib
import os
import random
import time

import pytest
from conftest import device, scene, vehicle

from uwsimnet_zenoh.drivers.dccomms.driver import SerialRadioDriver, open_raw_tty, set_raw
from uwsimnet_zenoh.drivers.dccomms.emulator import SerialRadioEmulator
from uwsimnet_zenoh.drivers.sim_backend import SimWorld
from uwsimnet_zenoh.formats import dccomms as fr
from uwsimnet_zenoh.formats import dccomms_stream as ds
from uwsimnet_zenoh.scene.model import Channel

WAIT = 5.0


def until(cond, timeout: float = WAIT, step: float = 0.01) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(step)
    return cond()


def encode_frame(dst: int, src: int, payload: bytes) -> bytes:
    return fr.DEFAULT.encode(payload, dst=dst, src=src)


def crc_bitwise(data: bytes) -> int:
    """CRC-16/XMODEM the slow way, as dccomms' Checksum::crc_xmodem_update does it."""
    crc = 0
    for b in data:
        crc ^= b << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
            crc &= 0xFFFF
    return crc


# =================================================================================================
# framing
# =================================================================================================
def test_crc16_xmodem_check_value_and_agreement_with_the_bitwise_form():
    assert fr.crc16(b"123456789") == 0x31C3
    assert fr.crc16(b"") == 0
    rnd = random.Random(3)
    for n in (1, 2, 7, 100, 2048):
        data = bytes(rnd.randrange(256) for _ in range(n))
        assert fr.crc16(data) == crc_bitwise(data)
        assert fr.crc16(data[n // 2:], fr.crc16(data[:n // 2])) == crc_bitwise(data)


def test_frame_layout():
    f = encode_frame(2, 1, b"hello")
    body = bytes([2, 1, 0, 5]) + b"hello"
    assert f == b"\x55\x55" + body + crc_bitwise(body).to_bytes(2, "big")
    assert f.hex() == "5555020100056865" "6c6c6f" + f"{crc_bitwise(body):04x}"
    assert fr.crc16(f[2:]) == 0                     # dccomms' check: CRC over dst..FCS is 0
    p = fr.DEFAULT.parse(f)
    assert (p.dst, p.src, p.payload, p.size) == (2, 1, b"hello", len(f))
    empty = b"\xff\x03\x00\x00"
    assert encode_frame(255, 3, b"") == b"\x55\x55" + empty + crc_bitwise(empty).to_bytes(2, "big")
    big = encode_frame(9, 8, bytes(2048))
    assert len(big) == fr.DEFAULT.max_frame and big[4:6] == b"\x08\x00"         # length big-endian
    with pytest.raises(ValueError):
        encode_frame(2, 1, bytes(2049))
    with pytest.raises(ValueError):
        encode_frame(256, 1, b"")


@pytest.mark.parametrize("buf,why", [
    (b"\x55\x55\x02\x01\x00", "needs"),
    (b"\x55\x55\x02\x01\x08\x01" + bytes(2049 + 2), "exceeds"),
    (encode_frame(2, 1, b"abc")[:-1], "needs"),
    (encode_frame(2, 1, b"abc")[:-1] + b"\x00", "FCS"),
])
def test_parsing_errors(buf, why):
    with pytest.raises(fr.FramingError, match=why):
        fr.DEFAULT.parse(buf)


def frames_of(events):
    return [e.frame for e in events if isinstance(e, ds.FrameReceived)]


def test_stream_decoder_bytewise_and_with_garbage_between_frames():
    a, b, c = encode_frame(2, 1, b"first"), encode_frame(1, 2, b"\x55\x55 inside"), encode_frame(255, 3, b"")
    stream = b"noise" + a + b"\x00\x13\x37" + b + c
    d = ds.FrameDecoder()
    events = [e for i in range(len(stream)) for e in d.feed(stream[i:i + 1])]
    assert frames_of(events) == [ds.Frame(2, 1, b"first"), ds.Frame(1, 2, b"\x55\x55 inside"),
                                 ds.Frame(255, 3, b"")]
    assert b"".join(e.data for e in events if isinstance(e, ds.Garbage)) == b"noise\x00\x13\x37"
    assert d.pending == 0 and d.counters["frames"] == 3


def test_bad_crc_and_bad_length_are_reported_and_the_next_frame_is_found():
    good = encode_frame(2, 1, b"good")
    bad = bytearray(encode_frame(2, 1, b"xxxx"))
    bad[8] ^= 0x40                                          # one flipped bit in the payload
    badlen = b"\x55\x55\x02\x01\xff\xff"                    # 65535 > 2048
    d = ds.FrameDecoder()
    events = d.feed(bytes(bad) + badlen + good)
    assert frames_of(events) == [ds.Frame(2, 1, b"good")]
    kinds = [type(e).__name__ for e in events]
    assert "BadCrc" in kinds and "BadLength" in kinds
    bc = next(e for e in events if isinstance(e, ds.BadCrc))
    assert (bc.dst, bc.src, bc.length) == (2, 1, 4)
    assert d.counters["bad_crc"] == 1 and d.counters["bad_length"] == 1


def test_a_truncated_frame_does_not_hold_back_the_next_one():
    cut = encode_frame(2, 1, b"0123456789")[:9]           # header says 10 bytes, 3 came
    good = encode_frame(2, 1, b"ok")
    d = ds.FrameDecoder(stall_timeout=0.5)
    events = d.feed(cut + good, now=0.0)                     # a whole valid frame after a false start
    assert frames_of(events) == [ds.Frame(2, 1, b"ok")]
    # a truncated frame alone is reported when nothing more comes
    events = d.feed(cut, now=1.0)
    assert events == [] and d.pending == len(cut)
    assert d.expire(1.2) == []
    events = d.expire(1.6)
    assert [type(e).__name__ for e in events][0] == "Truncated" and d.pending == 0
    assert frames_of(d.feed(good, now=2.0)) == [ds.Frame(2, 1, b"ok")]


def test_random_garbage_never_raises_and_frames_survive_it():
    rnd = random.Random(11)
    for _ in range(200):
        d = ds.FrameDecoder(stall_timeout=0.1)
        frames = [ds.Frame(rnd.randrange(256), rnd.randrange(256), bytes(rnd.randrange(256) for _ in
                                                                                  range(rnd.randrange(40))))
                  for _ in range(3)]
        # garbage free of 0x55 cannot fake a preamble: every frame must come out
        stream = b"".join(bytes(rnd.choice([x for x in range(256) if x != 0x55]) for _ in range(rnd.randrange(30)))
                          + encode_frame(f.dst, f.src, f.payload) for f in frames)
        out = []
        pos = 0
        while pos < len(stream):
            n = rnd.randrange(1, 20)
            out += d.feed(stream[pos:pos + n], now=0.0)
            pos += n
        assert frames_of(out) == frames
        # arbitrary garbage (preambles included): no exception, and a frame sent after it is found
        junk = bytes(rnd.randrange(256) for _ in range(rnd.randrange(200)))
        d.feed(junk, now=1.0)
        d.expire(5.0)
        d.expire(10.0)
        assert frames_of(d.feed(encode_frame(frames[0].dst, frames[0].src, frames[0].payload) * 2,
                                now=11.0))[-1] == frames[0]


def test_gli_messages():
    f = encode_frame(2, 1, b"x")
    assert fr.req_state_message() == b"\x01" and fr.state_message(fr.PHY_READY) == b"\x02\x01"
    m = fr.parse_gli(b"\x02\x00")
    assert m.type == fr.MSG_CMD_STATE and m.state == fr.PHY_BUSY
    assert fr.parse_gli(b"\x00" + f).body == f
    for bad in (b"", b"\x07abc", b"\x02"):
        with pytest.raises(fr.FramingError):
            fr.parse_gli(bad)
    assert fr.tx_queue_name("bluerov0-dev") == "/bluerov0-dev_tx_dlnk_phy"
    assert fr.rx_queue_name("bluerov0-dev") == "/bluerov0-dev_rx_dlnk_phy"


# =================================================================================================
# serial radio driver <-> pty emulator, on a simulated RF link
# =================================================================================================
def radio_scene():
    rf = Channel(id=0, prop_s_per_m=3.333e-9, min_prop_s=0.0)            # speed of light
    return scene([vehicle("a", (0, 0, 0), device("radio-a", 1, bitrate=9600, intrinsic_tx_s=0.001)),
                  vehicle("b", (30, 0, 0), device("radio-b", 2, bitrate=9600))], channels=[rf])


@pytest.fixture
def radios(tmp_path):
    w = SimWorld(radio_scene())
    emus = {"a": SerialRadioEmulator(w.backend("radio-a"), link=str(tmp_path / "ttyA")),
            "b": SerialRadioEmulator(w.backend("radio-b"))}
    for e in emus.values():
        e.start()
    w.start()
    drivers = []
    yield w, emus, drivers
    for d in drivers:
        d.close()
    for e in emus.values():
        e.close()
    w.close()


def test_serial_round_trip_through_ptys(radios, tmp_path):
    w, emus, drivers = radios
    assert os.path.islink(tmp_path / "ttyA") and emus["b"].path.startswith("/dev/pts/")
    rx_a, rx_b, st = [], [], []
    da = SerialRadioDriver(str(tmp_path / "ttyA"), 1, "radio-a", on_frame=rx_a.append, on_status=st.append)
    db = SerialRadioDriver(emus["b"].path, 2, "radio-b", on_frame=rx_b.append, baud=115200)
    drivers += [da, db]
    assert da.open(WAIT) and db.open(WAIT)
    payload = b"\x55\x55 binary \r\n\x00 " * 3
    t0 = time.monotonic()
    da.send(2, payload, tag=9)
    assert until(lambda: rx_b)
    assert time.monotonic() - t0 >= len(payload) * 8 / 9600         # its time on air at 9600 bps
    assert (rx_b[0].src, rx_b[0].dst, rx_b[0].data) == (1, 2, payload)
    assert [s.event for s in st] == ["queued", "sent"] and st[0].tag == 9
    db.send(1, b"pong")
    db.send(255, b"to all")
    db.send(7, b"not for a")                                # a's driver filters it out
    assert until(lambda: len(rx_a) == 2 and da.counters["rx_not_for_us"] == 1)    # all three decoded
    assert [(f.src, f.dst, f.data) for f in rx_a] == [(2, 1, b"pong"), (2, 255, b"to all")]
    # without a MAC the simulated modem a hands up all three (implicit broadcast); a's driver filters
    assert emus["a"].counters["rx"] == 3 and emus["b"].counters["tx"] == 3
    assert da.info()["decoder"]["frames"] == 3 and da.info()["kind"] == "real"
    assert da.counters["rx_not_for_us"] == 1


def test_malformed_device_output_is_reported_and_survived(tmp_path):
    """The test plays the radio: it owns the pty master and writes junk, then a good frame."""
    master, slave = os.openpty()
    set_raw(slave)
    path = os.ttyname(slave)
    rx, evs = [], []
    d = SerialRadioDriver(path, 1, "fake", on_frame=rx.append, on_event=evs.append, stall_timeout=0.3)
    try:
        assert d.open(WAIT)
        bad = bytearray(encode_frame(1, 5, b"corrupted"))
        bad[-1] ^= 0xFF
        os.write(master, b"+++AT:garbage\r\n" + bytes(bad) + b"\x55\x55\x01\x05\x7f\xff")
        os.write(master, encode_frame(1, 5, b"cut short")[:8])           # then nothing for a while
        assert until(lambda: any("truncated" in e.detail for e in evs))      # after stall_timeout
        os.write(master, encode_frame(1, 5, b"fine") + encode_frame(3, 5, b"for 3"))
        assert until(lambda: rx and d.counters["rx_not_for_us"] == 1)       # "for 3" decoded and filtered
        assert [(f.src, f.dst, f.data) for f in rx] == [(5, 1, b"fine")]
        details = " | ".join(e.detail for e in evs if e.kind == "protocol-error")
        assert "garbage" in details and "bad CRC" in details and "bad length" in details and "truncated" in details
        assert d.state == "open"
        # and the driver writes proper frames
        d.send(5, b"reply")
        assert until(lambda: encode_frame(5, 1, b"reply") in _read_all(master))
    finally:
        d.close()
        os.close(master)
        os.close(slave)


_seen = bytearray()


def _read_all(fd: int) -> bytes:
    os.set_blocking(fd, False)
    with contextlib.suppress(BlockingIOError):
        _seen.extend(os.read(fd, 4096))
    return bytes(_seen)


def test_emulator_survives_junk_written_to_its_pty(radios):
    w, emus, drivers = radios
    rx_b = []
    db = SerialRadioDriver(emus["b"].path, 2, "radio-b", on_frame=rx_b.append)
    drivers.append(db)
    assert db.open(WAIT)
    fd = open_raw_tty(emus["a"].path, 9600)
    try:
        bad = bytearray(encode_frame(2, 1, b"bad"))
        bad[7] ^= 1
        os.write(fd, b"\xde\xad" + bytes(bad) + b"\x55\x55\x02\x01\x99\x99" + encode_frame(2, 1, b"good"))
        assert until(lambda: rx_b)
        assert [f.data for f in rx_b] == [b"good"]
        c = emus["a"].counters
        assert c["BadCrc"] == 1 and c["BadLength"] == 1 and c["Garbage"] >= 1 and c["tx"] == 1
    finally:
        os.close(fd)


def test_driver_reports_connect_failures_and_reconnects_to_a_new_pty(tmp_path):
    link = str(tmp_path / "ttyRadio")
    evs = []
    d = SerialRadioDriver(link, 1, "late", on_event=evs.append, backoff_initial=0.05, backoff_max=0.1)
    w = SimWorld(radio_scene())
    emu = SerialRadioEmulator(w.backend("radio-a"), link=link)
    try:
        assert not d.open(0.3)                                        # nothing there yet
        assert any(e.kind == "connect-failed" for e in evs)
        emu.start()
        w.start()
        assert d.wait_open(WAIT)
        emu.close()                                                   # the radio goes away
        assert until(lambda: d.state in ("reconnecting", "connecting"))
        emu = SerialRadioEmulator(w.backend("radio-a"), link=link)
        emu.start()
        assert until(lambda: d.state == "open")
        assert d.counters["connects"] == 2
    finally:
        d.close()
        emu.close()
        w.close()


@pytest.mark.parametrize("name", ["VariableLength2BPacketBuilder", "VariableLengthPacketBuilder",
                                  "SimplePacketBuilder20crc16", "DataLinkFrameBuilderCRC32"])
def test_stream_decoder_in_every_framing(name):
    """Frames the real dccomms builders made (tests/data), on a noisy line, in another framing than CRC16."""
    import json
    from pathlib import Path


    key = {"VariableLength2BPacketBuilder": "vl2b", "VariableLengthPacketBuilder": "vlp",
           "SimplePacketBuilder20crc16": "sp20", "DataLinkFrameBuilderCRC32": "dlf32"}[name]
    vectors = json.loads((Path(__file__).parent / "data" / "dccomms_vectors.json").read_text())
    frames = [bytes.fromhex(v["frame_hex"]) for v in vectors["frames"] if v["framing"] == key]
    f = fr.builder(name)
    bad = bytearray(frames[-1])
    bad[-1] ^= 0x01
    d = ds.FrameDecoder(framing=f)
    events = d.feed(b"\x00junk\r\n" + frames[0] + bytes(bad) + b"".join(frames[1:]))
    got = [e.frame.payload for e in events if isinstance(e, ds.FrameReceived)]
    assert got == [f.parse(x).payload for x in frames]
    assert d.counters["bad_crc"] >= 1 and d.counters["garbage_bytes"] >= 7
    if not f.addressed:
        assert all(e.frame.dst == fr.BROADCAST for e in events if isinstance(e, ds.FrameReceived))
