"""Faults over real Zenoh on loopback (separate processes): a broker killed and restarted, the router
restarted, a robot running a real driver killed.  What an application sees (liveliness kind changes,
frames again after reconnection) and that the surviving broker's trace stays complete (parses,
conservation holds).  docs/deployment.md, "What you see when..."."""

from __future__ import annotations

import signal
import time

from test_broker_e2e import (  # noqa: F401 - procs is a fixture
    UWSIMNET,
    App,
    Broker,
    Proc,
    device_xml,
    free_port,
    procs,
    scene_xml,
    vehicle_xml,
)

from uwsimnet_zenoh.analysis import analyse, read_trace

WAIT = 10.0


def _kind_becomes(app: App, dev: str, want: str | None, timeout: float = WAIT) -> list:
    deadline = time.monotonic() + timeout
    while True:
        r = app.call(cmd="kind", id=dev)
        if r["kind"] == want:
            return r["changes"]
        assert time.monotonic() < deadline, f"{dev}: kind {r['kind']!r}, wanted {want!r}: {r}"
        time.sleep(0.1)


def _delivers(app: App, src: str, dst_dev: str, dst: int, timeout: float = WAIT) -> int:
    """Send until one frame arrives (puts made while a link is down are lost); returns the attempts."""
    deadline = time.monotonic() + timeout
    n = 0
    while time.monotonic() < deadline:
        n += 1
        app.call(cmd="send", id=src, dst=dst, size=8)
        if app.call(cmd="recv", id=dst_dev, n=1, timeout=1.0)["frames"]:
            return n
    raise AssertionError(f"{src} -> {dst_dev}: nothing delivered within {timeout} s")


def test_broker_killed_and_restarted_router_restarted(tmp_path, procs):  # noqa: F811
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    router = Proc([*UWSIMNET, "router", "--listen", endpoint])
    procs.append(router)
    router.expect("zenoh router", 15)
    scene = tmp_path / "faults.xml"
    scene.write_text(scene_xml(world="faults", channels=(0, 1), vehicles=(
        vehicle_xml("a", (0, 0, 0), device_xml("a-m", 1, 0), device_xml("a-m1", 1, 1))
        + vehicle_xml("b", (150, 0, 0), device_xml("b-m", 2, 0), device_xml("b-m1", 2, 1)))))
    b0 = Broker(scene, tmp_path / "t0.jsonl", "--connect", endpoint, "--channels", "0", listen=False)
    procs.append(b0)
    b1 = Broker(scene, tmp_path / "t1.jsonl", "--connect", endpoint, "--channels", "1", listen=False)
    procs.append(b1)
    app = App(endpoint, "faults")
    procs.append(app)
    for m in ("a-m", "b-m", "a-m1", "b-m1"):
        assert app.call(cmd="modem", id=m)["kind"] == "sim", m
    assert _delivers(app, "a-m", "b-m", 2) == 1
    assert _delivers(app, "a-m1", "b-m1", 2) == 1

    # 1. broker of channel 1 killed: its modems' kind goes to None at once (liveliness), channel 0 serves on
    b1.p.kill()
    b1.p.wait(10)
    t0 = time.monotonic()
    _kind_becomes(app, "a-m1", None, timeout=5.0)
    assert time.monotonic() - t0 < 5.0
    assert app.call(cmd="kind", id="a-m")["kind"] == "sim"
    assert _delivers(app, "a-m", "b-m", 2) == 1
    # a tx to a modem nobody serves: no status at all (only a broker of the whole scene answers "unknown")

    # 2. restarted: kind back to sim, frames again (a new trace: the killed one ends where it was cut)
    b1r = Broker(scene, tmp_path / "t1r.jsonl", "--connect", endpoint, "--channels", "1", listen=False)
    procs.append(b1r)
    _kind_becomes(app, "a-m1", "sim")
    assert _delivers(app, "a-m1", "b-m1", 2) == 1

    # 3. the router restarted on the same port: brokers and app reconnect alone, tokens come back
    assert router.stop(signal.SIGTERM) == 0, router.output()
    router2 = Proc([*UWSIMNET, "router", "--listen", endpoint])
    procs.append(router2)
    router2.expect("zenoh router", 15)
    t_restart = time.monotonic()
    _kind_becomes(app, "a-m", "sim", timeout=15.0)
    _kind_becomes(app, "a-m1", "sim", timeout=15.0)
    _delivers(app, "a-m", "b-m", 2, timeout=15.0)
    _delivers(app, "a-m1", "b-m1", 2, timeout=15.0)
    print(f"router restart: frames on both channels again {time.monotonic() - t_restart:.2f} s after it was up")

    # 4. a robot host dies (SIGKILL) while it runs a real driver for b-m: its driver/real token goes at
    # once, the broker serves b-m again (kind real -> sim) and the other apps go on
    robot = App(endpoint, "faults")
    try:
        robot.call(cmd="token", key="uwsimnet/faults/modem/b-m/driver/real")
        _kind_becomes(app, "b-m", "real")
    finally:
        robot.p.kill()
        robot.p.wait(10)
    _kind_becomes(app, "b-m", "sim", timeout=5.0)
    _delivers(app, "a-m", "b-m", 2)

    # the surviving broker's trace is complete: parses, conservation holds for every frame it served
    for p in (b0, b1r):
        assert p.stop(signal.SIGTERM) == 0, p.output()
    for trace in (b0.trace, b1r.trace):
        events = list(read_trace(trace)[1])
        assert any(e["ev"] == "rx" for e in events), trace
        a = analyse(trace, horizon=5.0)
        assert a.conservation.ok, a.conservation.violations[:5]
        assert a.conservation.frames == sum(e["ev"] == "enq" for e in events)
