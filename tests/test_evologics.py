"""EvoLogics S2C: the AT codec (both ends), the emulator and the driver over real TCP.

The transcripts below are written from the reply formats in public code of the device's users and
maker (EvoLogics evins role_at.erl and dmac parser.h, LSTS DUNE Transports/Evologics, DESERT
evologics-drivers, the dmac2 README); they are reconstructions, not captures from a modem.
"""

from __future__ import annotations

import contextlib
import random
import socket
import threading
import time

import pytest
from conftest import device, scene, vehicle

from uwsimnet_zenoh.drivers.evologics.driver import EvoLogicsDriver
from uwsimnet_zenoh.drivers.evologics.emulator import ERRORS, EvoLogicsEmulator, im_duration_us
from uwsimnet_zenoh.drivers.sim_backend import SimWorld
from uwsimnet_zenoh.formats import evologics_at as at

WAIT = 5.0       # s: every wait in this file gives up after this


def until(cond, timeout: float = WAIT, step: float = 0.01) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(step)
    return cond()


# =================================================================================================
# codec: host side
# =================================================================================================
def test_commands_are_built_as_the_modem_expects():
    c = at.DriverCodec()
    assert c.im(2, b"hello") == b"AT*SENDIM,5,2,ack,hello\n"
    assert c.im(255, b"hi", "noack") == b"AT*SENDIM,2,255,noack,hi\n"
    assert c.burst(3, b"a\r\nb") == b"AT*SEND,4,3,a\r\nb\n"
    assert c.pbm(4, b"x") == b"AT*SENDPBM,1,4,x\n"
    assert c.im(2, b"q", pid=1) == b"AT*SENDIM,p1,1,2,ack,q\n"
    assert c.command("?AL") == b"AT?AL\n"
    assert c.command("AT!L3") == b"AT!L3\n"
    assert c.waiting == ("*SENDIM", "*SENDIM", "*SEND", "*SENDPBM", "*SENDIM", "?AL", "!L")
    assert at.DriverCodec(eol="\r").command("?T") == b"AT?T\r"      # serial line terminator
    with pytest.raises(ValueError):
        c.im(2, b"x" * 65)
    with pytest.raises(ValueError):
        c.im(2, b"x", "maybe")


# (host sends, modem answers, events the driver must see)
TRANSCRIPTS = [
    # an acknowledged instant message (DUNE sendIM + expectOK, evins deliveredim)
    ("im", [b"AT*SENDIM,5,2,ack,hello\n"], b"OK\r\nDELIVEREDIM,2\r\n",
     [at.Ok("*SENDIM"), at.Delivered("im", 2)]),
    ("im failed", [b"AT*SENDIM,5,7,ack,hello\n"], b"OK\r\nFAILEDIM,7\r\n",
     [at.Ok("*SENDIM"), at.Failed("im", 7)]),
    ("busy", [b"AT*SENDIM,5,2,ack,hello\n"], b"BUSY DELIVERING INSTANT MESSAGE TO 2\r\n",
     [at.Busy("*SENDIM", "DELIVERING INSTANT MESSAGE TO 2")]),
    ("deferred", [b"AT!L3\n", b"AT?L\n"], b"[*]OK\r\n[*]3\r\n", [at.Ok("!L"), at.Reply("?L", "3")]),
    ("async never answers", [b"AT?AL\n"], b"RECVPROBE,1,2,3,4,5,0.0\r\n%KEY,v\r\n1\r\n",
     [at.Notification("RECVPROBE", ("1", "2", "3", "4", "5", "0.0")), at.Notification("%KEY", ("v",)),
      at.Reply("?AL", "1")]),
    ("burst", [b"AT*SEND,10,2,0123456789\n"], b"OK\r\nDELIVERED,10,2\r\n",
     [at.Ok("*SEND"), at.Delivered("burst", 2, 10)]),
    ("burst failed", [b"AT*SEND,3,2,abc\n"], b"OK\r\nFAILED,3,2\r\n", [at.Ok("*SEND"), at.Failed("burst", 2, 3)]),
    ("settings", [b"AT?AL\n", b"AT!L3\n", b"AT?T\n"], b"1\r\nOK\r\n1875\r\n",
     [at.Reply("?AL", "1"), at.Ok("!L"), at.Reply("?T", "1875")]),
    ("error", [b"AT!ZZ\n"], b"ERROR WRONG FORMAT\r\n", [at.Error("!ZZ", "WRONG FORMAT")]),
    ("multi-line", [b"AT&V\n"], b"Source Level: 3\r\nGain: 0\r\n\r\n",
     [at.Reply("&V", "Source Level: 3\nGain: 0")]),
    # receptions (evins recv_extract_helper field order; DUNE sscanf formats)
    ("recvim", [], b"RECVIM,5,1,2,ack,1875,-45,198,0.0000,hello\r\n",
     [at.Received("im", 1, 2, b"hello", rssi=-45, integrity=198, velocity=0.0, duration_us=1875, flag="ack")]),
    ("recv", [], b"RECV,10,1,2,976,-48,201,66000,0.1200,0123456789\r\n",
     [at.Received("burst", 1, 2, b"0123456789", rssi=-48, integrity=201, velocity=0.12, bitrate=976,
                  prop_time_us=66000)]),
    ("recvpbm", [], b"RECVPBM,3,4,2,1200,-60,150,-0.5,xyz\r\n",
     [at.Received("pbm", 4, 2, b"xyz", rssi=-60, integrity=150, velocity=-0.5, duration_us=1200)]),
    ("recvims", [], b"RECVIMS,2,4,2,123456,1200,-60,150,0.0,ok\r\n",
     [at.Received("ims", 4, 2, b"ok", rssi=-60, integrity=150, velocity=0.0, duration_us=1200,
                  timestamp_us=123456)]),
    ("extended pid", [], b"RECVIM,p0,2,1,2,noack,1875,-45,198,0.0,hi\r\n",
     [at.Received("im", 1, 2, b"hi", rssi=-45, integrity=198, velocity=0.0, duration_us=1875, flag="noack",
                  pid=0)]),
    ("binary with CRLF", [], b"RECVIM,6,1,2,ack,1875,-45,198,0.0,a\r\nb\r\n\r\nDELIVEREDIM,1\r\n",
     [at.Received("im", 1, 2, b"a\r\nb\r\n", rssi=-45, integrity=198, velocity=0.0, duration_us=1875,
                  flag="ack"), at.Delivered("im", 1)]),
    ("notifications", [], b"SENDSTART,2,im,1875,0\r\nSENDEND,2,im,3528177,1875\r\nRECVSTART\r\n"
     b"RECVEND,3528277,1875,-45,198\r\nBITRATE,local,976\r\nCANCELEDIM,2\r\nERROR EFAULT\r\n",
     [at.Notification("SENDSTART", ("2", "im", "1875", "0")),
      at.Notification("SENDEND", ("2", "im", "3528177", "1875")), at.Notification("RECVSTART"),
      at.Notification("RECVEND", ("3528277", "1875", "-45", "198")), at.Notification("BITRATE", ("local", "976")),
      at.Canceled("im", 2), at.Error(None, "EFAULT")]),
    ("usbl", [], b"USBLLONG,1.5,1.4,2,1.0,2.0,3.0,1.1,2.1,3.1,0.1,0.2,0.3,66000,-50,200,0.5\r\n",
     [at.Notification("USBLLONG", ("1.5", "1.4", "2", "1.0", "2.0", "3.0", "1.1", "2.1", "3.1", "0.1", "0.2",
                                   "0.3", "66000", "-50", "200", "0.5"))]),
]


@pytest.mark.parametrize("name,sent,reply,expected", TRANSCRIPTS, ids=[t[0] for t in TRANSCRIPTS])
def test_transcripts(name, sent, reply, expected):
    for chunking in ("whole", "bytewise"):
        c = at.DriverCodec()
        for s in sent:
            c.expect(at.request_name(s.decode("latin-1")))
        if chunking == "whole":
            events = c.feed(reply)
        else:
            events = [e for i in range(len(reply)) for e in c.feed(reply[i:i + 1])]
        assert events == expected, chunking
        assert c.waiting == ()


def test_recvim_fields_may_carry_decimals_in_rssi():
    ev = at.DriverCodec().feed(b"RECVIM,2,1,2,ack,1875,-45.4,198,0.0,hi\r\n")
    assert ev[0].rssi == -45


def test_garbage_wrong_lengths_and_bad_fields_are_reported_and_skipped():
    c = at.DriverCodec()
    c.command("?AL")
    out = c.feed(b"\x00\xff\xfe junk\r\n"                                # non-ASCII
                 b"RECVIM,9,1,2,ack,1875,-45,198,0.0,short\r\n"          # length says 9, 5 follow
                 b"RECVIM,x,1,2,ack,1,1,1,0,abc\r\n"                     # not a number
                 b"RECVIM,3,1,2,maybe,1,1,1,0,abc\r\n"                   # unknown flag
                 b"RECV,1,2\r\n"                                         # too few fields
                 b"DELIVEREDIM\r\n"                                      # no address
                 b"7\r\n"                                                 # the answer to ?AL
                 b"stray\r\n"                                            # nothing waits for it
                 b"RECVIM,2,1,2,ack,1875,-45,198,0.0,ok\r\n")
    kinds = [(type(e).__name__, getattr(e, "kind", "")) for e in out]
    assert kinds == [("ProtocolError", "garbage"), ("ProtocolError", "length"), ("ProtocolError", "format"),
                     ("ProtocolError", "format"), ("ProtocolError", "format"), ("ProtocolError", "format"),
                     ("Reply", ""), ("ProtocolError", "unexpected"), ("Received", "im")]
    assert out[-1].data == b"ok"
    assert c.counters["errors"] == 7


def test_a_too_long_length_field_does_not_swallow_what_follows():
    c = at.DriverCodec()
    out = c.feed(b"RECVIM,20,1,2,ack,1875,-45,198,0.0,abc\r\nDELIVEREDIM,2\r\nRECVIM,1,1,2,ack,1,-4,1,0.0,z\r\n")
    assert [type(e).__name__ for e in out] == ["ProtocolError", "Delivered", "Received"]
    assert out[0].kind == "length" and out[2].data == b"z"


def test_timeouts_for_missing_answers_and_stalled_payloads():
    c = at.DriverCodec(reply_timeout=1.0, payload_timeout=0.5)
    c.command("?AL", now=0.0)
    assert c.feed(b"RECVIM,10,1,2,ack,1875,-45,198,0.0,abc", now=0.1) == []
    assert c.expire(0.5) == []
    out = c.expire(1.2)
    assert [(e.kind, e.request) for e in out] == [("timeout", "?AL"), ("timeout", None)]
    assert c.waiting == ()
    assert c.feed(b"DELIVEREDIM,2\r\n", now=1.3) == [at.Delivered("im", 2)]


def test_random_garbage_never_raises_and_the_parser_resynchronises():
    rnd = random.Random(6)
    alphabet = b"RECVIMSDLAT*,0123456789\r\n-.ackno" + bytes(range(256))
    for _ in range(300):
        c = at.DriverCodec()
        junk = bytes(rnd.choice(alphabet) for _ in range(rnd.randrange(1, 120)))
        for i in range(0, len(junk), 7):
            c.feed(junk[i:i + 7])
        c.expire(0.0)
        c.expire(100.0)             # whatever was held is dropped
        out = c.feed(b"\r\nRECVIM,2,1,2,ack,1875,-45,198,0.0,ok\r\n")
        assert at.Received("im", 1, 2, b"ok", rssi=-45, integrity=198, velocity=0.0, duration_us=1875,
                           flag="ack") in out


# =================================================================================================
# codec: modem side
# =================================================================================================
def test_device_parses_commands_with_binary_payloads():
    d = at.DeviceCodec()
    out = d.feed(b"AT*SENDIM,6,2,ack,he\r\nlo\nAT?AL\r\nATZ1\rAT!L3\nat*send,3,4,a\nb\r\nAT&V\nAT@ZX1\n"
                 b"AT*SENDIM,p3,2,255,noack,hi\n")
    assert out == [
        at.SendCommand("*SENDIM", 2, b"he\r\nlo", "ack"),
        at.Command("?AL", "", b"AT?AL"), at.Command("Z", "1", b"ATZ1"), at.Command("!L", "3", b"AT!L3"),
        at.SendCommand("*SEND", 4, b"a\nb"), at.Command("&V", "", b"AT&V"), at.Command("@ZX", "1", b"AT@ZX1"),
        at.SendCommand("*SENDIM", 255, b"hi", "noack", pid=3),
    ]


def test_device_split_input_and_wrong_lengths():
    d = at.DeviceCodec(payload_timeout=1.0)
    wire = b"AT*SENDIM,5,2,ack,hello\r\nAT?T\r\n"
    out = [e for i in range(len(wire)) for e in d.feed(wire[i:i + 1], now=0.0)]
    assert out == [at.SendCommand("*SENDIM", 2, b"hello", "ack"), at.Command("?T", "", b"AT?T")]
    # data longer than the length field: refused, the next command survives
    out = d.feed(b"AT*SENDIM,2,2,ack,hello\nAT?AL\n")
    assert [type(e).__name__ for e in out] == ["BadCommand", "Command"] and out[0].kind == "length"
    # too long for an instant message
    out = d.feed(b"AT*SENDIM,65," + b"2,ack," + b"x" * 65 + b"\nAT?AL\n")
    assert out[0].reply == "ERROR OUT OF RANGE" and out[1] == at.Command("?AL", "", b"AT?AL")
    # data shorter than the length field, nothing more comes: refused at the timeout, what followed survives
    assert d.feed(b"AT*SENDIM,12,2,ack,abc\nAT?AL\n", now=5.0) == []
    out = d.expire(6.5)
    assert [type(e).__name__ for e in out] == ["BadCommand", "Command"] and out[0].kind == "timeout"
    # garbage
    assert d.feed(b"hello\n")[0].kind == "garbage"


# =================================================================================================
# emulator + driver over TCP, on a simulated acoustic link
# =================================================================================================
def two_modems(distance: float = 150.0, **kw):
    return scene([vehicle("a", (0, 0, 0), device("a-dev", 1, bitrate=2000, **kw)),
                  vehicle("b", (distance, 0, 0), device("b-dev", 2, bitrate=2000, **kw))])


@pytest.fixture
def world():
    made = []

    def make(sc, **emu_kw):
        w = SimWorld(sc)
        emus = {d: EvoLogicsEmulator(w.backend(d), **emu_kw) for d in w.net.modems}
        for e in emus.values():
            e.start()
        w.start()
        made.append((w, emus))
        return w, emus
    yield make
    for w, emus in made:
        for e in emus.values():
            e.close()
        w.close()


@pytest.fixture
def drivers():
    made = []

    def make(*a, **kw):
        d = EvoLogicsDriver(*a, **kw)
        made.append(d)
        return d
    yield make
    for d in made:
        d.close()


class Raw:
    """A bare TCP client of an emulator, reading CRLF lines."""

    def __init__(self, port: int) -> None:
        self.s = socket.create_connection(("127.0.0.1", port), WAIT)
        self.buf = b""

    def send(self, b: bytes) -> None:
        self.s.sendall(b)

    def lines(self, n: int, timeout: float = WAIT) -> list[bytes]:
        deadline = time.monotonic() + timeout
        while self.buf.count(b"\r\n") < n and time.monotonic() < deadline:
            self.s.settimeout(max(0.01, deadline - time.monotonic()))
            try:
                chunk = self.s.recv(4096)
            except TimeoutError:
                break
            if not chunk:
                break
            self.buf += chunk
        parts = self.buf.split(b"\r\n")
        got, self.buf = parts[:n], b"\r\n".join(parts[n:])
        return got

    def close(self) -> None:
        self.s.close()


def test_instant_message_round_trip_with_modelled_delay(world, drivers):
    w, emus = world(two_modems(150.0))
    rx, st = [], []
    da = drivers("127.0.0.1", emus["a-dev"].port, "a-dev", on_status=lambda s: st.append((time.monotonic(), s)))
    db = drivers("127.0.0.1", emus["b-dev"].port, "b-dev", on_frame=lambda f: rx.append((time.monotonic(), f)))
    assert da.open(WAIT) and db.open(WAIT)
    assert until(lambda: da.address == 1 and db.address == 2)        # learnt from AT?AL at connect
    payload = b"hi\r\nthere\x00"                                      # binary, CRLF inside
    t0 = time.monotonic()
    da.send(2, payload, tag=41)
    assert until(lambda: rx and any(s.event == "acked" for _, s in st))
    t_rx, f = rx[0]
    # 10 bytes at 2000 bps = 40 ms in the simulator + 150 m at 1500 m/s = 100 ms, then the modem reports
    # it once demodulated: an IM of 10 bytes takes im_duration_us(10) = 235520 us at the S2C IM rate
    dur = im_duration_us(len(payload))
    assert dur == 235520
    assert 0.14 + dur / 1e6 <= t_rx - t0 < 1.0
    assert (f.src, f.dst, f.data) == (1, 2, payload)
    assert f.meta["kind"] == "im" and f.meta["flag"] == "ack" and f.meta["duration_us"] == dur
    assert -120 <= f.rssi < -20 and 100 < f.integrity <= 255
    events = [s.event for _, s in st]
    assert events == ["queued", "transmitted", "acked"] and all(s.tag == 41 for _, s in st)
    t_ack = next(t for t, s in st if s.event == "acked")
    assert t_ack - t_rx >= 0.1 + 0.14                                 # it travels back, 147 ms on air
    assert db.query("?T") == "100000"                                # propagation time, us
    assert int(db.query("?E")) == f.rssi


def test_burst_data_and_two_way_traffic(world, drivers):
    w, emus = world(two_modems(300.0))
    rx_a, rx_b, st = [], [], []
    da = drivers("127.0.0.1", emus["a-dev"].port, "a-dev", on_frame=rx_a.append, on_status=st.append)
    db = drivers("127.0.0.1", emus["b-dev"].port, "b-dev", on_frame=rx_b.append, mode="im")
    assert da.open(WAIT) and db.open(WAIT)
    big = bytes(range(256)) + b"\r\n"                                # 258 bytes: burst mode (1.03 s on air)
    da.send(2, big, tag=1)
    assert until(lambda: rx_b and any(s.event == "acked" for s in st))
    db.send(1, b"pong", tag=2)          # after, not during: both modems are half duplex (it would collide)
    db.send(1, b"x" * 65, tag=3)                                     # too long for mode="im"
    assert until(lambda: rx_a)
    f = rx_b[0]
    assert f.data == big and f.meta["kind"] == "burst" and f.meta["bitrate"] == 2000
    assert f.meta["prop_time_us"] == 200000
    assert rx_a[0].data == b"pong"
    assert [s.event for s in st if s.tag == 1] == ["queued", "transmitted", "acked"]
    assert db.counters["status_dropped"] == 1


def test_busy_while_an_instant_message_is_on_air_and_the_driver_retries(world, drivers):
    w, emus = world(two_modems(300.0))
    raw = Raw(emus["a-dev"].port)
    raw.send(b"AT*SENDIM,4,2,ack,one!\nAT*SENDIM,4,2,ack,two!\nAT?DI\n")
    assert raw.lines(3) == [b"OK", b"BUSY DELIVERING INSTANT MESSAGE TO 2", b"DELIVERING,im,0"]
    # the driver on the same modem meets the same refusal: it polls AT?DI and sends again, nothing is lost
    st, evs = [], []
    da = drivers("127.0.0.1", emus["a-dev"].port, "a-dev", on_status=st.append, on_event=evs.append, init=(),
                 im_ack=False)
    assert da.open(WAIT)
    da.send(2, b"three", tag=3)
    assert until(lambda: any(s.event == "sent" for s in st), 2 * WAIT)
    assert not any(s.event in ("dropped", "failed") for s in st)
    assert any(e.kind == "busy" for e in evs) and da.counters["busy_resent"] >= 1
    lines = raw.lines(2, timeout=2 * WAIT)                            # the first one got through, then
    assert lines[0] == b"DELIVEREDIM,2" or lines[1] == b"DELIVEREDIM,2"   # was the driver's noack IM
    raw.send(b"AT?DI\n")
    assert until(lambda: raw.lines(1, 0.2) == [b"EMPTY"] or (raw.send(b"AT?DI\n") and False), WAIT)
    raw.close()


def test_a_new_message_cancels_an_acknowledged_one_still_waiting(world):
    """Messages are not queued (manual 1.7 section 5.5.4): sent before the acknowledgement came, the next
    message cancels the first (CANCELEDIM) and AT?DI follows the new one."""
    w, emus = world(two_modems(150.0), ack_time=30.0)            # an acknowledgement that takes its time
    raw = Raw(emus["a-dev"].port)
    raw.send(b"AT*SENDIM,5,2,ack,first\n")
    assert raw.lines(1) == [b"OK"]
    answer = b"BUSY"
    while answer.startswith(b"BUSY"):                             # on air: busy; then waiting for the ack
        raw.send(b"AT*SENDIM,6,2,noack,second\n")
        answer = raw.lines(1)[0]
    assert answer == b"OK"
    assert raw.lines(1) == [b"CANCELEDIM,2"]
    raw.send(b"AT?DI\n")
    assert raw.lines(1) in ([b"DELIVERING,im,0"], [b"EMPTY"])
    raw.close()


def test_the_net_interpreter_for_dune(world):
    """interpreter="net": AT?MODE answers NET (DUNE's sendInitialization requires it), no data mode."""
    w, emus = world(two_modems(150.0), interpreter="net")
    raw = Raw(emus["a-dev"].port)
    raw.send(b"AT?MODE\nATO\n+++AT?AL\nAT?AL\n")
    assert raw.lines(4) == [b"NET", b"ERROR WRONG FORMAT", b"ERROR WRONG FORMAT", b"1"]
    # AT?S is a multi-line answer on the net interpreter: evins' role_at.erl (from_term_helper, 3b5c6c0) waits
    # with `{"?S", net} -> multiline` until "\n\r\n", i.e. the block's lines and then an empty line
    raw.send(b"AT?S\nAT?AL\n")
    assert raw.lines(3) == [b"INITIATION LISTEN 16384", b"", b"1"]
    raw.close()
    at_side = Raw(world(two_modems(150.0))[1]["a-dev"].port)
    at_side.send(b"AT?S\nAT?AL\n")                  # the at interpreter: one line (role_at: singleline)
    assert at_side.lines(2) == [b"INITIATION LISTEN 16384", b"1"]
    at_side.close()


def test_data_mode_framing_and_burst_data(world):
    """ATO: no answer; +++AT<cmd> answered +++AT<cmd>:<len>:<answer>, notifications +++AT:<len>:<line>, raw
    bytes are burst data to AT!AR and come out raw at a data-mode peer; +++ATC: OK in command mode."""
    w, emus = world(two_modems(150.0))
    a, b = Raw(emus["a-dev"].port), Raw(emus["b-dev"].port)
    a.send(b"ATO\n+++AT?AL\n+++AT!AR2\n+++AT&V\n")
    assert a.lines(2) == [b"+++AT?AL:1:1", b"+++AT!AR:2:OK"]
    head = a.lines(1)[0]
    assert head.startswith(b"+++AT&V:") and head.endswith(b"Source Level: 0")
    assert a.lines(18)[-1] == b""                     # the block's lines, then the frame's own CRLF
    b.send(b"ATO\n")
    a.send(b"raw \r\n bytes +++ not a command")
    got = b""
    end = time.monotonic() + WAIT
    while len(got) < 30 and time.monotonic() < end:
        b.s.settimeout(0.2)
        with contextlib.suppress(TimeoutError):
            got += b.s.recv(4096)
    assert got == b"raw \r\n bytes +++ not a command"
    assert a.lines(1) == [b"+++AT:14:DELIVERED,30,2"]
    a.send(b"+++ATC\nAT?AL\n")
    assert a.lines(2) == [b"OK", b"1"]
    a.close()
    b.close()


def test_the_ack_timeout_counts_simulated_time_too(world):
    """A broker or machine running late brings the outcome late: FAILEDIM waits for `ack_timeout` of simulated
    time as well as of wall time.  With the simulation paused, 3 s of wall time (6 timeouts) give no FAILEDIM;
    once it runs again, it comes."""
    w, emus = world(two_modems(150.0), ack_timeout=0.5)
    raw = Raw(emus["a-dev"].port)
    raw.send(b"AT*SENDIM,2,9,ack,hi\n")                              # nobody has address 9
    assert raw.lines(1, timeout=WAIT) == [b"OK"]
    w.clock.pause()
    assert raw.lines(1, timeout=3.0) == [b""]                       # nothing within 3 s
    w.clock.resume()
    assert raw.lines(1, timeout=WAIT) == [b"FAILEDIM,9"]
    raw.close()


def test_no_addressee_means_failedim_and_emulator_answers_like_the_device(world, drivers):
    w, emus = world(two_modems(150.0), ack_timeout=0.5)
    raw = Raw(emus["a-dev"].port)
    raw.send(b"AT*SENDIM,2,9,ack,hi\n")                              # nobody has address 9
    assert raw.lines(2, timeout=WAIT) == [b"OK", b"FAILEDIM,9"]
    raw.send(b"AT?AL\nAT!AL1\nAT!AL5\nAT?L\nAT!L2\nAT?L\nATI7\nATA\nAT!ZZ9\nnonsense\n"
             b"AT*SENDIM,99,2,ack,x\nAT*SEND,3,2,abcdef\nAT*SENDIM,1,1,noack,x\nAT*SENDIM,1,255,ack,x\nATI5\n")
    got = raw.lines(15)
    assert got == [b"1", b"OK", b"ERROR NOT ACCEPTED", b"0", b"OK", b"2", b"EvoLogics GmbH",
                   b"INITIATION LISTEN", b"ERROR WRONG FORMAT", b"ERROR WRONG FORMAT",
                   b"ERROR OUT OF RANGE", b"ERROR WRONG FORMAT", b"ERROR WRONG DESTINATION ADDRESS",
                   b"ERROR WRONG FORMAT", b"ERROR OUT OF RANGE"]
    assert all(x.split(b" ")[0] != b"ERROR" or x.decode() in ERRORS for x in got)   # the modem's own list
    raw.send(b"AT&V\n")
    block = raw.lines(19)
    assert block[-1] == b"" and block[0] == b"Source Level: 2" and b"Local Address: 1" in block
    # extended notifications around a reception
    raw_b = Raw(emus["b-dev"].port)
    raw_b.send(b"AT@ZX1\n")
    assert raw_b.lines(1) == [b"OK"]
    raw.send(b"AT*SENDIM,2,2,noack,ok\n")
    assert raw.lines(1) == [b"OK"]
    got = raw_b.lines(3)
    assert got[0] == b"RECVSTART" and got[1].startswith(b"RECVEND,")
    assert got[2].startswith(f"RECVIM,2,1,2,noack,{im_duration_us(2)},".encode()) and got[2].endswith(b",ok")
    raw.close()
    raw_b.close()


# =================================================================================================
# malformed device output, reconnection
# =================================================================================================
class FakeModem:
    """A TCP server playing a misbehaving modem: each accepted connection gets the next script."""

    def __init__(self, scripts: list[bytes]) -> None:
        self.scripts = list(scripts)
        self.srv = socket.socket()
        self.srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.srv.bind(("127.0.0.1", 0))
        self.srv.listen()
        self.port = self.srv.getsockname()[1]
        self.received = b""
        self.t = threading.Thread(target=self.run, daemon=True)
        self.t.start()

    def run(self) -> None:
        self.srv.settimeout(WAIT)
        while self.scripts:
            try:
                conn, _ = self.srv.accept()
            except OSError:
                return
            script = self.scripts.pop(0)
            conn.settimeout(0.3)
            for i in range(0, len(script), 5):      # dribble it out in small pieces
                conn.sendall(script[i:i + 5])
            try:
                while True:
                    data = conn.recv(4096)
                    if not data:
                        break
                    self.received += data
            except OSError:
                pass
            conn.close()
        self.srv.close()


def test_malformed_device_output_is_reported_and_survived(drivers):
    good = b"RECVIM,5,3,1,noack,1875,-45,198,0.0,hello\r\n"
    fake = FakeModem([
        b"\x00\x01garbage\xff\r\nRECVIM,40,3,1,ack,1875,-45,198,0.0,short\r\nOK\r\nRECV,zz\r\n"
        b"DELIVEREDIM,2\r\nRECVIM,5,3,1,ack,1,2,3,4,hel",          # then the connection drops mid-frame
        b"FAILED,x,2\r\n" + good,
    ])
    rx, evs = [], []
    d = drivers("127.0.0.1", fake.port, "fake", init=(), on_frame=rx.append, on_event=evs.append,
                backoff_initial=0.05)
    assert d.open(WAIT)
    assert until(lambda: len(rx) == 1 and d.counters["connects"] == 2)
    assert rx[0].data == b"hello" and rx[0].src == 3
    errors = [e.detail for e in evs if e.kind == "protocol-error"]
    assert len(errors) >= 6
    assert any("garbage" in e for e in errors) and any("length" in e for e in errors)
    assert any("unexpected" in e for e in errors) and any("format" in e for e in errors)
    assert [e.detail for e in evs if e.kind == "state"][:4] == ["connecting", "open", "reconnecting", "open"]
    assert d.state == "open" and d.info()["last_error"]


def test_driver_reconnects_with_backoff_and_keeps_queued_frames(drivers):
    sc = two_modems(150.0)
    w = SimWorld(sc)
    w.start()
    emu = EvoLogicsEmulator(w.backend("a-dev"))
    emu.start()
    port = emu.port
    st = []
    d = drivers("127.0.0.1", port, "a-dev", on_status=st.append, backoff_initial=0.05, backoff_max=0.2)
    try:
        assert d.open(WAIT)
        emu.close()
        assert until(lambda: d.state in ("reconnecting", "connecting"))
        d.send(2, b"later", tag=5)                                   # queued while the link is down
        assert until(lambda: d.counters["connect_failures"] >= 1)    # a reconnection failed meanwhile
        emu = EvoLogicsEmulator(w.backend("a-dev"), port=port)
        emu.start()
        assert until(lambda: d.state == "open" and any(s.event == "transmitted" for s in st))
        assert [s.event for s in st][:2] == ["queued", "transmitted"]
    finally:
        emu.close()
        w.close()
