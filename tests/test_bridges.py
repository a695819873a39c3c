"""Bridges: the socket bridge (with the C client built by cc) and the dccomms POSIX message-queue bridge."""

from __future__ import annotations

import itertools
import json
import os
import shutil
import socket
import struct
import subprocess
import time
from pathlib import Path

import pytest
from conftest import device, scene, vehicle

from uwsimnet_zenoh.bridges import posix_mq
from uwsimnet_zenoh.bridges import socket_wire as sw
from uwsimnet_zenoh.bridges.mq_bridge import GliQueueClient, MqBridge
from uwsimnet_zenoh.bridges.socket_bridge import SocketBridge
from uwsimnet_zenoh.bridges.socket_client import SocketBridgeClient
from uwsimnet_zenoh.drivers.backend import BackendFrame
from uwsimnet_zenoh.drivers.sim_backend import SimWorld
from uwsimnet_zenoh.formats import dccomms as fr

WAIT = 15.0  # an upper bound only: until() returns as soon as the condition holds
C_SOURCE = Path(__file__).resolve().parent.parent / "gli_clients" / "c" / "gli_socket_client.c"
_names = itertools.count()


def until(cond, timeout: float = WAIT, step: float = 0.01) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(step)
    return cond()


def three_modems():
    """A (the C program, socket bridge), B (a Python client, socket bridge), C (a dccomms application,
    message queues), on one half-duplex channel: the tests keep traffic sequential, since frames sent at
    the same time would collide (the simulator being right, not the bridges being wrong)."""
    kw = {"bitrate": 4800, "intrinsic_tx_s": 0.001}    # 1 ms between back-to-back frames, as UWSim-NET scenes
    return scene([vehicle("va", (0, 0, 0), device("dev-a", 1, **kw)),
                  vehicle("vb", (60, 0, 0), device("dev-b", 2, **kw)),
                  vehicle("vc", (0, 60, 0), device("dev-c", 3, **kw))])


@pytest.fixture
def world():
    w = SimWorld(three_modems())
    yield w
    w.close()


@pytest.fixture
def closing():
    things = []
    yield things
    for t in reversed(things):
        t.close()


# =================================================================================================
# socket bridge wire format
# =================================================================================================
def test_wire_format_vectors():
    assert sw.encode_tx(2, b"hi", 7) == b"\x00\x00\x00\x09\x02\x00\x02\x00\x00\x00\x07hi"
    assert sw.encode_hello(1, 2048, "dev-a") == b"\x00\x00\x00\x0a\x01\x00\x01\x08\x00dev-a"
    rx = sw.encode_rx(1, 2, b"x", 5, 1.5, 2.0)
    assert rx[:4] == (26).to_bytes(4, "big") and rx[4] == 3
    assert sw.decode_body(rx[4:]) == sw.Rx(1, 2, 5, 1.5, 2.0, b"x")
    st = sw.encode_status(7, "acked", 3.25, None)
    assert sw.decode_body(st[4:]) == sw.Status(7, "acked", 3.25, "")
    assert sw.decode_body(sw.encode_status(1, "dropped", 0.0, "fifo")[4:]).reason == "fifo"
    assert sw.decode_datagram(sw.encode_subscribe()) == sw.Subscribe()


def test_stream_decoder_partial_and_malformed_input():
    d = sw.StreamDecoder()
    wire = sw.encode_tx(2, b"a\r\nb", 1) + sw.encode_tx(3, b"", 0)
    msgs = [m for i in range(len(wire)) for m in d.feed(wire[i:i + 1])[0]]
    assert msgs == [sw.Tx(2, 1, b"a\r\nb"), sw.Tx(3, 0, b"")]
    msgs, errs = d.feed(b"\x00\x00\x00\x02\x09\x00" + b"\x00\x00\x00\x03\x02\x00\x01" + sw.encode_tx(4, b"ok"))
    assert msgs == [sw.Tx(4, 0, b"ok")] and len(errs) == 2 and "unknown message type 9" in errs[0]
    msgs, errs = d.feed(b"\xff\xff\xff\xff")
    assert d.broken and "out of range" in errs[0]
    for bad in (b"\x00\x00", b"\x00\x00\x00\x05\x02", sw.encode_tx(1, bytes(sw.MAX_DATA + 1))):
        with pytest.raises(sw.WireError):
            sw.decode_datagram(bad)


# =================================================================================================
# the C program and a Python client, through the simulator
# =================================================================================================
@pytest.fixture(scope="module")
def c_client(tmp_path_factory):
    cc = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
    if cc is None:
        pytest.skip("no C compiler (cc) on this machine: the C client cannot be built")
    exe = tmp_path_factory.mktemp("c") / "gli_socket_client"
    subprocess.run([cc, "-std=c99", "-Wall", "-Wextra", "-Werror", "-O2", "-o", str(exe), str(C_SOURCE)],
                   check=True, timeout=60)
    return exe


def test_c_program_and_python_client_exchange_frames(world, closing, c_client):
    bra = SocketBridge(world.backend("dev-a")).start()
    brb = SocketBridge(world.backend("dev-b")).start()
    closing += [bra, brb]
    world.start()
    py = SocketBridgeClient("127.0.0.1", brb.tcp_port)
    closing.append(py)
    assert (py.address, py.id) == (2, "dev-b")
    # the C program sends 3 frames to B, then waits for 2 frames
    proc = subprocess.Popen([str(c_client), "127.0.0.1", str(bra.tcp_port), "2", "3", "2", "8", "hi from C"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        got = [py.receive(WAIT) for _ in range(3)]
        assert [(m.src, m.dst, m.data) for m in got if m] == [(1, 2, f"hi from C #{i}".encode()) for i in (1, 2, 3)]
        assert all(m.t_rx > m.t_tx >= 0 for m in got)
        py.send(1, b"hello C \x00\xff", tag=11)
        py.send(1, b"second", tag=12)
        assert py.wait_status(12, "delivered", WAIT) is not None
        out, err = proc.communicate(timeout=WAIT + 5)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, (out, err)
    lines = out.splitlines()
    assert lines[0] == "HELLO address=1 max_payload=2048 id=dev-a"
    rx = [x for x in lines if x.startswith("RX ")]
    assert len(rx) == 2 and rx[0].startswith("RX src=2 dst=1 ") and rx[0].endswith("data=hello C \\x00\\xff")
    statuses = [x for x in lines if x.startswith("STATUS ")]
    for tag in (1, 2, 3):
        assert any(f"tag={tag} event=sent" in x for x in statuses)
        assert any(f"tag={tag} event=delivered" in x for x in statuses)
    assert lines[-1] == "DONE rx=2 finals=3"
    assert [s.event for s in py.statuses if s.tag == 11][:2] == ["queued", "sent"]


def test_socket_bridge_errors_and_udp(world, closing):
    br = SocketBridge(world.backend("dev-a"), udp_port=0).start()
    py_b = SocketBridge(world.backend("dev-b")).start()
    closing += [br, py_b]
    world.start()
    b = SocketBridgeClient("127.0.0.1", py_b.tcp_port)
    closing.append(b)
    # UDP: subscribe, get HELLO, send, receive
    u = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    closing.append(u)
    u.settimeout(WAIT)
    u.sendto(sw.encode_subscribe(), ("127.0.0.1", br.udp_port))
    assert sw.decode_datagram(u.recv(4096)) == sw.Hello(1, 2048, "dev-a")
    u.sendto(b"\x00\x00\x00\x05\x02\x00", ("127.0.0.1", br.udp_port))          # length lies
    assert isinstance(sw.decode_datagram(u.recv(4096)), sw.Error)
    u.sendto(sw.encode_tx(2, b"by udp", 5), ("127.0.0.1", br.udp_port))
    m = b.receive(WAIT)
    assert m is not None and (m.src, m.data) == (1, b"by udp")
    statuses = [sw.decode_datagram(u.recv(4096)) for _ in range(2)]
    assert [(s.tag, s.event) for s in statuses] == [(5, "queued"), (5, "sent")]
    b.send(1, b"back")
    while True:                                   # statuses of frame 5 may come first
        msg = sw.decode_datagram(u.recv(4096))
        if isinstance(msg, sw.Rx):
            break
    assert (msg.src, msg.dst, msg.data) == (2, 1, b"back")
    # TCP: a bad message is answered with ERROR and the connection lives; a bad length closes it
    t = SocketBridgeClient("127.0.0.1", br.tcp_port)
    closing.append(t)
    t.send_raw(b"\x00\x00\x00\x01\x03")                               # an RX with no fields
    t.send(2, b"still fine", tag=1)
    assert t.wait_status(1, "sent", WAIT) and any("too short" in e for e in t.errors)
    t.send_raw(b"\x7f\xff\xff\xff")
    assert until(lambda: t._read(0.1) is False)                           # closed by the bridge
    assert any("out of range" in e for e in t.errors)
    assert br.counters["bad_messages"] >= 3


# =================================================================================================
# dccomms POSIX message queues
# =================================================================================================
@pytest.fixture
def qname():
    names = []

    def make() -> str:
        n = f"uwt{os.getpid()}x{next(_names)}"
        names.append(n)
        return n
    yield make
    for n in names:
        for q in (fr.tx_queue_name(n), fr.rx_queue_name(n)):
            posix_mq.MessageQueue.unlink(q)


pytestmark_mq = pytest.mark.skipif(not posix_mq.available(), reason="POSIX message queues need Linux librt")


@pytestmark_mq
def test_message_queue_basics(qname):
    name = "/" + qname()
    q = posix_mq.MessageQueue.open(name, maxmsg=2, msgsize=64, nonblock=True)
    try:
        assert q.getattr()["maxmsg"] == 2 and q.msgsize == 64
        q.send(b"one")
        q.send(b"two")
        with pytest.raises(BlockingIOError):
            q.send(b"three")
        assert q.receive(0) == b"one" and q.receive(0.1) == b"two" and q.receive(0) is None
        with pytest.raises(posix_mq.MqError):
            q.send(bytes(65))
    finally:
        q.close()
        assert posix_mq.MessageQueue.unlink(name) and not posix_mq.MessageQueue.unlink(name)


VECTORS = json.loads((Path(__file__).parent / "data" / "dccomms_vectors.json").read_text())


def _vector(framing: str, payload_name: str) -> dict:
    return next(v for v in VECTORS["frames"] if v["framing"] == framing and v["payload_name"] == payload_name)


@pytestmark_mq
def test_dccomms_queue_client_exchanges_frames_with_a_python_client(world, closing, qname):
    cid = qname()
    mq = MqBridge(world.backend("dev-c"), cid)          # no framing in the scene: DataLinkFrame CRC16
    brb = SocketBridge(world.backend("dev-b")).start()
    closing += [brb]
    app = GliQueueClient(cid, address=3)        # the application may start first: queues are created
    closing.append(app)
    assert app.tx.getattr()["msgsize"] == 8192 and app.tx.getattr()["maxmsg"] == 10
    mq.start()
    closing.append(mq)
    world.start()
    assert app.wait_ready(WAIT)                 # the PHY side announces READY (dccomms Start())
    py = SocketBridgeClient("127.0.0.1", brb.tcp_port)
    closing.append(py)
    # dccomms app -> Python: a 2069-byte FRAME message (frame, padding, virtual area)
    assert len(app.message(2, b"x")) == 2069
    app.send(2, b"from dccomms \x55\x55\r\n")
    m = py.receive(WAIT)
    assert m is not None and (m.src, m.dst, m.data) == (3, 2, b"from dccomms \x55\x55\r\n")
    # Python -> dccomms app: the whole packet buffer, the virtual area filled (src = the sender)
    py.send(3, b"to dccomms", tag=4)
    f = app.receive(WAIT)
    assert f is not None and (f.src, f.dst, f.payload) == (2, 3, b"to dccomms")
    assert app.phy_state == fr.PHY_READY       # every frame the app wrote was answered READY
    # a corrupted frame and a garbage message are refused (WARNING, counted); REQ_STATE is answered
    bad = bytearray(app.message(2, b"broken"))
    bad[1 + 6 + 6] ^= 0xFF                      # the FCS
    app.send_raw(bytes(bad))
    app.tx.send(b"\x09junk")
    app.tx.send(fr.req_state_message())
    app.send(2, b"after the junk")
    m = py.receive(WAIT)
    assert m is not None and m.data == b"after the junk"
    assert until(lambda: mq.info()["refused"] == {"frame": 1, "type": 1})
    assert "unknown message type 9" in mq.info()["last_refusal"]
    # (the app's first REQ_STATE, sent before the bridge started, was cleared with the stale input)
    assert mq.counters["req_state"] == 1 and mq.counters["cleared"] == 1 and mq.counters["tx"] == 2
    assert py.receive(0.3) is None              # nothing else got through


@pytestmark_mq
def test_refusals_are_warnings_with_the_reason(world, closing, qname, caplog):
    cid = qname()
    mq = MqBridge(world.backend("dev-c"), cid, framing="VariableLength2BPacketBuilder")
    mq.start()
    closing.append(mq)
    world.start()
    for q in (mq._txq, mq._rxq):                # the bridge created them: as dccomms does
        assert (q.getattr()["maxmsg"], q.getattr()["msgsize"]) == (10, 8192)
        assert os.fstat(q.fileno()).st_mode & 0o777 == 0o777
    app = GliQueueClient(cid, address=3, framing="VariableLength2BPacketBuilder")
    closing.append(app)
    bad = bytearray(app.message(2, b"hello"))
    bad[4] ^= 0x01                              # a payload bit
    with caplog.at_level("WARNING", logger="uwsimnet.bridges.mq"):
        app.send_raw(bytes(bad))
        assert until(lambda: mq.counters["refused"] == 1)
    assert any(r.levelname == "WARNING" and "bad CRC16" in r.getMessage() for r in caplog.records)
    info = mq.info()
    assert info["refused"] == {"frame": 1} and "bad CRC16" in info["last_refusal"]
    assert info["framing"] == "VariableLength2BPacketBuilder" and info["message_size"] == 2066


@pytestmark_mq
@pytest.mark.parametrize("framing, builder", [("vl2b", "VariableLength2BPacketBuilder"),
                                              ("dlf16", "DataLinkFrameBuilderCRC16")])
def test_messages_in_the_real_layout_go_through_both_ways(world, closing, qname, framing, builder):
    """A client that writes the bytes the real dccomms app wrote (tests/data, captured from its queue)
    and checks what the bridge writes back against the real library's layout."""
    cid = qname()
    mq = MqBridge(world.backend("dev-c"), cid, framing=builder)
    brb = SocketBridge(world.backend("dev-b")).start()
    closing += [brb]
    mq.start()
    closing.append(mq)
    world.start()
    tx = posix_mq.MessageQueue.open(fr.tx_queue_name(cid), read=False, write=True)
    rx = posix_mq.MessageQueue.open(fr.rx_queue_name(cid), read=True, write=False)
    closing += [tx, rx]
    py = SocketBridgeClient("127.0.0.1", brb.tcp_port)
    closing.append(py)
    v = _vector(framing, "hello")
    # the captured message: padding = the real library's uninitialised memory; virtual area seq 7 src 1 dst 2
    tx.send(bytes.fromhex(v["message_hex_as_captured"]))
    m = py.receive(WAIT)
    assert m is not None and (m.src, m.dst, m.data) == (3, 2, b"Hello World!")
    py.send(3, b"Hello World!")
    while True:
        msg = rx.receive(WAIT)
        assert msg is not None
        if msg[0] == fr.MSG_FRAME:
            break
    assert len(msg) == v["message_size"]
    frame_len = v["packet_size"]
    if framing == "dlf16":     # header dst 3 src 2 (the real frame had dst 2 src 1): same length and payload
        real = bytes.fromhex(v["frame_hex"])
        assert msg[1:3] == real[:2] and msg[3:5] == b"\x03\x02" and msg[5:1 + frame_len - 2] == real[4:-2]
        assert fr.DataLinkFrame("crc16").parse(msg[1:]).payload == b"Hello World!"      # its FCS checks
    else:
        assert msg[1:1 + frame_len] == bytes.fromhex(v["frame_hex"])
    assert msg[1 + frame_len:-12] == bytes(len(msg) - 13 - frame_len)
    seq, src, dst = struct.unpack("<III", msg[-12:])
    assert (src, dst) == (2, 3) and seq == 0       # the sender's address and sequence number


@pytestmark_mq
def test_mq_bridge_keeps_frames_while_the_application_is_slow(world, closing, qname):
    cid = qname()
    mq = MqBridge(world.backend("dev-c"), cid)
    brb = SocketBridge(world.backend("dev-b")).start()
    closing += [brb]
    mq.start()
    closing.append(mq)
    world.start()
    py = SocketBridgeClient("127.0.0.1", brb.tcp_port)
    closing.append(py)
    for i in range(14):                         # more than the queue's 10 messages
        py.send(3, b"n%d" % i)
    assert until(lambda: mq.counters["rx"] == 14, timeout=WAIT)
    assert mq.info()["backlog"] > 0             # the queue is full: the rest waits in the bridge
    app = GliQueueClient(cid, address=3)
    closing.append(app)
    # a dccomms app cannot clear 8192-byte queues (ClearInputQueue reads with a 4000-byte buffer): it
    # gets everything, in order
    got = []
    while (f := app.receive(1.0)) is not None:
        got.append(f.payload)
    assert got == [b"n%d" % i for i in range(14)]
    assert mq.info()["backlog"] == 0


@pytestmark_mq
@pytest.mark.xfail(not hasattr(BackendFrame, "aseq"), strict=True,
                   reason="the backends pass the wire's aseq once BackendFrame carries it (docs/bridges.md)")
def test_the_sending_applications_seq_reaches_the_receivers(world, closing, qname):
    """dccomms apps number their packets (SetVirtualSeq); the receiver reads that number in its virtual area
    (GetSeq), as the original simulator passed it (dccomms_by_examples 003/004 print it), not the modem's."""
    ca, cc = qname(), qname()
    vl2b = "VariableLength2BPacketBuilder"
    mqa = MqBridge(world.backend("dev-a"), ca, framing=vl2b)
    mqc = MqBridge(world.backend("dev-c"), cc, framing=vl2b)
    brb = SocketBridge(world.backend("dev-b")).start()
    closing += [brb]
    a, c = GliQueueClient(ca, address=1, framing=vl2b), GliQueueClient(cc, address=3, framing=vl2b)
    closing += [a, c]
    for m in (mqa, mqc):
        m.start()
        closing.append(m)
    world.start()
    assert a.wait_ready(WAIT) and c.wait_ready(WAIT)
    py = SocketBridgeClient("127.0.0.1", brb.tcp_port)
    closing.append(py)
    for seq in (4_000_000_000, 7, 0):
        a.send(3, f"seq {seq}".encode(), seq=seq)
        f = c.receive(WAIT)
        assert f is not None and (f.payload, f.src, f.dst, f.seq) == (f"seq {seq}".encode(), 1, 3, seq)
        m = py.receive(WAIT)                     # the frame reaches B too (no MAC: no dst filter)
        assert m is not None and m.seq == seq    # the socket bridge's rx seq: the sender's as well


@pytestmark_mq
def test_dcmac_frames_through_the_queues(world, closing, qname):
    """DcMacPacketBuilder on the queues: data packets go through with their four-bit addresses; rts, cts and
    sync packets are DcMac's own control frames (run DcMac as the scene's MAC) and are refused with why."""
    ca, cc = qname(), qname()
    dcmac = fr.builder("DcMacPacketBuilder")
    mqa, mqc = MqBridge(world.backend("dev-a"), ca, framing=dcmac), MqBridge(world.backend("dev-c"), cc, framing=dcmac)
    a, c = GliQueueClient(ca, address=1, framing=dcmac), GliQueueClient(cc, address=3, framing=dcmac)
    closing += [a, c]
    for m in (mqa, mqc):
        m.start()
        closing.append(m)
    world.start()
    assert a.wait_ready(WAIT) and c.wait_ready(WAIT)
    assert len(a.message(3, b"x")) == 1 + 2056 + 12
    a.send(3, b"dcmac data")
    f = c.receive(WAIT)
    assert f is not None and (f.payload, f.src, f.dst, f.packet.kind) == (b"dcmac data", 1, 3, "data")
    assert f.packet.size == len(b"dcmac data") + 6
    rts = dcmac.control("rts", dst=3, src=1, rts_size=100)
    a.send_raw(fr.frame_message(dcmac, rts, fr.VirtualArea(0, 1, 3)))
    assert until(lambda: mqa.info()["refused"] == {"control": 1})
    assert "rts packet is DcMac's own control frame" in mqa.info()["last_refusal"]


def test_the_wire_carries_the_applications_seq():
    """`aseq` on the tx and rx maps (msgpack read back with msgpack itself, not with the codec under test)."""
    import msgpack
    from uwsimnet_gli import wire

    raw = wire.encode_tx(3, b"x", 9, msg={"aseq": 4_294_967_295})
    assert msgpack.unpackb(raw) == {"dst": 3, "data": b"x", "tag": 9, "aseq": 4_294_967_295}
    assert wire.decode_tx(raw).msg == {"aseq": 4_294_967_295}
    both = {"kind": "im", "flag": "ack", "aseq": 0}
    assert wire.decode_tx(wire.encode_tx(3, b"x", msg=both)).msg == both
    rx = wire.encode_rx(1, 3, b"x", 17, 0.0, 1.0, msg={"aseq": 5})
    assert msgpack.unpackb(rx)["aseq"] == 5 and msgpack.unpackb(rx)["seq"] == 17
    assert wire.decode_rx(rx).msg == {"aseq": 5}
    assert wire.decode_rx(wire.encode_rx(1, 3, b"x", 17, 0.0, 1.0)).msg is None
    for bad in ({"aseq": -1}, {"aseq": 1 << 32}, {"aseq": "7"}, {"aseq": 1, "flag": "ack"}):
        with pytest.raises(ValueError):
            wire.encode_tx(3, b"x", msg=bad)
    with pytest.raises(wire.CodecError):
        wire.decode_tx(msgpack.packb({"dst": 3, "data": b"x", "aseq": -2}))
