"""EvoLogics S2C as public host software sees it: two `uwsimnet emulate evologics` processes on one broker,
driven over TCP by a host written from the public grammar (tests/s2c_host.py: evins role_at.erl, the vendor
AT manual 1.7, DUNE's sscanf formats, DESERT's and Rock's AT&V readers), in command mode and in data mode.

Every message kind crosses Zenoh (the wire's tx/rx `kind`/`flag`/`ts`/`pid`), so the far emulator reports
what the sender chose; every line the emulators write must parse by that grammar (`Host.errors` stays
empty).  Time checks are lower bounds only (a timer never fires early), never a speed assumption."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

pytest.importorskip("uwsimnet_gli")
from s2c_host import Host, atv_ok, dune_ati1, dune_recvim  # noqa: E402
from test_broker_e2e import UWSIMNET, Broker, Proc, device_xml, free_port, scene_xml, stop_all, vehicle_xml  # noqa: E402

WORLD = "s2chosts"
IM_1 = 155648           # µs: the manual's 1-byte instant message (SENDSTART,2,im,155648,0)
IM_4 = 182272           # µs: its 4-byte one


def im_us(n: int) -> int:
    """The two manual points, linear in between (13 units of 2048 µs per 3 bytes): a lower bound check."""
    return IM_1 + (IM_4 - IM_1) * (n - 1) // 3


@pytest.fixture(scope="module")
def modems(tmp_path_factory):
    tmp: Path = tmp_path_factory.mktemp("s2c")
    scene = tmp / "s2c.xml"
    scene.write_text(scene_xml(world=WORLD, vehicles="".join([
        vehicle_xml("a", (0, 0, 0), device_xml("a-m", 1)),
        vehicle_xml("b", (150, 0, 0), device_xml("b-m", 2)),
    ])))
    started: list[Proc] = []
    try:
        b = Broker(scene, tmp / "trace.jsonl")
        started.append(b)
        ports = {}
        for dev in ("a-m", "b-m"):
            ports[dev] = free_port()
            # every frame here has an addressee: its outcome is the simulation's, never the fallback timeout (a
            # saturated machine once took over 5 s to bring a delivered burst's outcome)
            emu = Proc([*UWSIMNET, "emulate", "evologics", "--port", str(ports[dev]), "--id", dev, "--world",
                        WORLD, "--connect", b.endpoint, "--ack-timeout", "60"])
            started.append(emu)
            emu.expect("uwsimnet: emulator evologics ready", 20)
        ports["endpoint"] = b.endpoint
        yield ports
    finally:
        errors = stop_all(started)
        assert not errors, errors


def pair(ports, data_mode: bool = False, zx: bool = True) -> tuple[Host, Host]:
    a, b = Host("127.0.0.1", ports["a-m"]).__enter__(), Host("127.0.0.1", ports["b-m"]).__enter__()
    for h in (a, b):
        if data_mode:
            h.to_data_mode()
        if zx:
            assert h.command("@ZX1") == "OK"
    return a, b


def done(*hosts: Host) -> None:
    for h in hosts:
        h.pump(0.1)
        assert h.errors == [], h.errors          # every line parsed by the public grammar
        h.__exit__()


def recv(h: Host, name: str, data: bytes, seconds: float = 10.0):
    return h.wait_for(lambda t: t.kind == "recv" and t.name == name and t.data == data, seconds)


def note(h: Host, name: str, seconds: float = 10.0):
    return h.wait_for(lambda t: t.kind == "async" and t.name == name, seconds)


# =================================================================================================
# what hosts ask at connect
# =================================================================================================
def test_answers_as_hosts_read_them(modems):
    with Host("127.0.0.1", modems["a-m"]) as h:
        assert h.command("?MODE") == "AT"                      # evins fsm_conf / dmac initializer
        assert dune_ati1(h.command("I1")) is not None          # DUNE sendInitialization sscanf
        assert h.command("I0") and h.command("I7") == "EvoLogics GmbH"
        assert atv_ok(h.command("&V")) is None                 # DESERT positional, Rock key names
        assert h.command("?PID") == "0" and h.command("?AL") == "1" and h.command("?DI") == "EMPTY"
        assert h.command("@CTRL") == "OK" and h.command("I5") == "ERROR OUT OF RANGE"
        assert h.command("!NONSENSE1") == "ERROR WRONG FORMAT"
        assert h.send("im", 1, b"me", "noack") == "ERROR WRONG DESTINATION ADDRESS"
        assert h.send("im", 255, b"x", "ack") == "ERROR WRONG FORMAT"      # ack to broadcast: syntax error
        h.split.mode = "command"
        h.write(b"+++AT?AL\n")                                  # data-mode escape while in command mode
        h.split.expect("?")
        assert h.pump(0.5) and h.command("?AL") == "1"
        done(h)


def test_evins_handshake_in_data_mode(modems):
    """fsm_conf.erl: +++AT?MODE (in command mode: ERROR WRONG FORMAT), AT?MODE -> AT, ATO (no answer), then
    +++AT?AL ?AM ?PID @ZF1 @ZX1 @ZU1 @ZA1, each answered in +++AT<cmd>:<len>:<answer> form."""
    with Host("127.0.0.1", modems["a-m"]) as h:
        h.write(b"+++AT?MODE\n")
        h.split.expect("?MODE")
        t = h.pump(0.5)
        assert any(x.kind == "sync" and x.value == "ERROR WRONG FORMAT" for x in t)
        h.to_data_mode()
        assert h.pump(0.3) == []                                 # ATO: silent
        assert h.command("?MODE") == "AT"                        # +++AT?MODE:2:AT, as a real modem (dmac2)
        assert h.command("?AL") == "1" and h.command("?AM").isdigit() and h.command("?PID") == "0"
        for c in ("@ZF1", "@ZX1", "@ZU1", "@ZA1"):
            assert h.command(c) == "OK", c
        assert atv_ok(h.command("&V")) is None                   # multi-line answer in one +++AT&V frame
        assert h.command("?DI") == "EMPTY"
        h.split.mode = "command"                                 # +++ATC: OK, in command mode
        assert h.request(b"+++ATC\n", "C") == "OK"
        assert h.command("?AL") == "1"
        done(h)


# =================================================================================================
# every message kind, both modes, across two emulator processes
# =================================================================================================
@pytest.mark.parametrize("data_mode", [False, True], ids=["command", "data"])
def test_instant_messages_of_every_kind_cross_zenoh(modems, data_mode):
    a, b = pair(modems, data_mode)
    if data_mode:
        assert a.command("@ZF1") == "OK" and b.command("@ZF1") == "OK"   # evins: RECV*,p<pid>, forms
    # IM with ack: RECVIM flagged ack at b; at a SENDSTART..SENDEND, then the acknowledgement's
    # RECVSTART..RECVEND, then DELIVEREDIM
    t0 = time.monotonic()
    assert a.send("im", 2, b"ack me", "ack", pid=0 if data_mode else None) == "OK"
    r = recv(b, "recvim", b"ack me")
    assert r.fields[1:4] == (1, 2, "ack") and r.fields[4] >= im_us(6)
    assert (r.pid == 0) if data_mode else (r.pid is None)
    s0, s1 = note(a, "SENDSTART"), note(a, "SENDEND")
    assert s0.fields[:2] == (2, "im") and s0.fields[2] >= im_us(6) and s1.fields[3] == s0.fields[2]
    note(a, "RECVSTART")
    r1 = note(a, "RECVEND")
    d = note(a, "DELIVEREDIM")
    assert d.fields == (2,) and r1.fields[1] > 0
    assert time.monotonic() - t0 >= 2 * 0.1 + (im_us(6) + r1.fields[1]) / 1e6   # two crossings of 150 m
    # in this order, each step no earlier than the time on air says (timers never fire early).  Measured
    # from t0: the host may read a line late (it was pumping b), never early, so these bounds hold under load
    order = [(t, x.name) for t, x in a.seen if x.kind == "async"
             and x.name in ("SENDSTART", "SENDEND", "RECVSTART", "RECVEND", "DELIVEREDIM")][:5]
    assert [n for _, n in order] == ["SENDSTART", "SENDEND", "RECVSTART", "RECVEND", "DELIVEREDIM"], order
    at_ = {n: t - t0 for t, n in order}
    assert at_["SENDEND"] >= s0.fields[2] / 1e6 - 0.01
    assert at_["RECVSTART"] >= s0.fields[2] / 1e6 + 2 * 0.1 - 0.01                    # there and back, 150 m
    assert at_["RECVEND"] >= (s0.fields[2] + r1.fields[1]) / 1e6 + 2 * 0.1 - 0.01
    # IM without ack: flagged noack, no report
    assert a.send("im", 2, b"no ack", "noack") == "OK"
    assert recv(b, "recvim", b"no ack").fields[3] == "noack"
    # IMS, at once and at a time of a's clock: RECVIMS with the timestamp of b's reception start
    a.pump(1.0)
    assert a.send("ims", 2, b"now") == "OK"
    ims = recv(b, "recvims", b"now")
    assert ims.fields[1:3] == (1, 2)
    assert a.wait_for(lambda t: t.name == "SENDEND" and t.fields[1] == "ims").fields[0] == 2
    clock = int(a.command("?CLOCK"))
    assert a.send("ims", 2, b"later", ts=(clock + 600_000) % (1 << 32)) == "OK"
    assert a.command("?DI") == "DELIVERING,ims,0"
    recv(b, "recvims", b"later")
    # PBM: RECVPBM at b
    a.pump(0.5)
    assert a.send("pbm", 2, b"piggy") == "OK"
    p = recv(b, "recvpbm", b"piggy")
    assert p.fields[1:3] == (1, 2)
    # and back: b -> a, ack
    b.pump(0.5)
    assert b.send("im", 1, b"back", "ack") == "OK"
    assert recv(a, "recvim", b"back").fields[3] == "ack"
    assert note(b, "DELIVEREDIM").fields == (1,)
    # broadcast
    b.pump(0.5)
    assert b.send("im", 255, b"all", "noack") == "OK"
    assert recv(a, "recvim", b"all").fields[1:4] == (2, 255, "noack")
    done(a, b)


@pytest.mark.parametrize("data_mode", [False, True], ids=["command", "data"])
def test_bursts_of_1_64_65_1024_bytes_both_ways(modems, data_mode):
    a, b = pair(modems, data_mode, zx=False)
    sizes = (1, 64, 65, 1024)
    for src, dst, addr in ((a, b, 2), (b, a, 1)):
        blobs = [bytes((i * 7 + n) % 256 for i in range(n)) for n in sizes]
        if data_mode:
            assert src.command(f"!AR{addr}") == "OK"
            for blob in blobs:                  # data mode: raw bytes are burst data to AT!AR
                src.write(blob)
                src.pump(0.05)
            want = b"".join(blobs)
            end = time.monotonic() + 30
            while len(dst.raw) < len(want) and time.monotonic() < end:
                dst.pump(0.1)
            assert bytes(dst.raw) == want       # received burst data comes out as it is
            dst.raw.clear()
        else:
            for blob in blobs:
                assert src.send("burst", addr, blob) == "OK"
            for blob in blobs:
                r = recv(dst, "recv", blob, 30)
                assert r.fields[1] == (1 if addr == 2 else 2) and r.fields[2] == addr
            for n in sizes:
                src.wait_for(lambda t, n=n, addr=addr: t.name == "DELIVERED" and t.fields == (n, addr), 30)
    done(a, b)


def test_busy_then_retry_after_di_empty(modems):
    """A second message while the first is on air: BUSY (the modem's own words); AT?DI says DELIVERING
    until it is out, then EMPTY, and the same message is accepted (DESERT's loop)."""
    a, b = pair(modems, zx=False)
    assert a.send("im", 2, b"first", "noack") == "OK"
    busy = a.send("im", 2, b"second", "noack")
    assert busy == "BUSY DELIVERING INSTANT MESSAGE TO 2"
    polls = 0
    while (di := a.command("?DI")) != "EMPTY":
        assert di == "DELIVERING,im,0"
        polls += 1
        a.pump(0.05)
    assert polls >= 1
    assert a.send("im", 2, b"second", "noack") == "OK"
    recv(b, "recvim", b"first")
    recv(b, "recvim", b"second")
    done(a, b)


def test_an_app_on_the_bus_chooses_the_kind_too(modems):
    """A GLI application puts kind/flag on modem a-m's tx: b-m's emulator reports it as such, and an app
    reading b-m's rx gets the same fields (docs/gli-protocol.md)."""
    from uwsimnet_gli import World

    with Host("127.0.0.1", modems["b-m"]) as b, World(WORLD, connect=modems["endpoint"]) as w:
        rx_b = w.modem("b-m")
        w.modem("a-m").send(2, b"from an app", msg={"kind": "im", "flag": "ack", "pid": 0})
        assert recv(b, "recvim", b"from an app").fields[3] == "ack"
        f = rx_b.receive(timeout=10)
        while f is not None and f.data != b"from an app":
            f = rx_b.receive(timeout=10)
        assert f is not None and f.msg == {"kind": "im", "flag": "ack", "pid": 0}
        w.modem("a-m").send(2, b"no kind")
        assert recv(b, "recvim", b"no kind").fields[3] == "noack"     # not said: a short frame is an IM
        done(b)


def test_every_line_parses_by_dune_formats(modems):
    """The RECVIM lines DUNE reads (Driver.hpp sscanf, firmware >= 1.7) and the AT&V that DESERT reads."""
    with Host("127.0.0.1", modems["a-m"]) as a, Host("127.0.0.1", modems["b-m"]) as b:
        got = []
        orig = b.split.feed

        def tap(chunk: bytes):
            got.append(chunk)
            return orig(chunk)
        b.split.feed = tap
        assert a.send("im", 2, b"dune", "ack") == "OK"
        recv(b, "recvim", b"dune")
        line = next(x for x in b"".join(got).split(b"\r\n") if x.startswith(b"RECVIM"))
        assert dune_recvim(line), line
        assert note(a, "DELIVEREDIM").fields == (2,)
        done(a, b)


# =================================================================================================
# the project's driver against the emulator: no frame lost under back-to-back sends
# =================================================================================================
@pytest.mark.parametrize("link_mode", ["command", "data"])
def test_driver_loses_no_frame_back_to_back(modems, link_mode):
    from uwsimnet_zenoh.drivers.evologics.driver import EvoLogicsDriver

    st: list = []
    with Host("127.0.0.1", modems["b-m"]) as b:
        drv = EvoLogicsDriver("127.0.0.1", modems["a-m"], "a-m", on_status=st.append, link_mode=link_mode)
        try:
            assert drv.open(10)
            frames = [(255 if i % 3 == 0 else 2, f"frame {i}".encode()) for i in range(9)]
            for i, (dst, data) in enumerate(frames):
                drv.send(dst, data, tag=i)
            for _, data in frames:
                recv(b, "recvim", data, 30)
            end = time.monotonic() + 30
            while time.monotonic() < end and not all(
                    any(s.tag == i and s.event == ("acked" if dst == 2 else "sent") for s in st)
                    for i, (dst, _) in enumerate(frames)):
                time.sleep(0.05)
            assert not [s for s in st if s.event in ("dropped", "failed")], st
            for i, (dst, _) in enumerate(frames):
                assert any(s.tag == i and s.event == ("acked" if dst == 2 else "sent") for s in st), (i, st)
        finally:
            drv.close()
        done(b)
