"""`uwsimnet view`: the document (sans-IO), the server's bounded live hand-off, bad input, and the page in a
real headless browser (Debian's chromium + chromium-driver; skipped with the reason when absent) on a
replayed trace and on a live run (`uwsimnet run --view` with its own Zenoh client beside the broker).

Screenshots: every browser test saves one in its tmp folder; with UWSIMNET_VIEW_SHOTS=DIR also in DIR
(docs/view.md's are made so: UWSIMNET_VIEW_SHOTS=docs/figures pytest tests/test_view.py).
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from collections import Counter
from pathlib import Path

import pytest

from uwsimnet_zenoh.analysis import read_trace
from uwsimnet_zenoh.analysis.airframes import air_frames
from uwsimnet_zenoh.app.virtual import load_scene_file, run_virtual
from uwsimnet_zenoh.view.state import LiveState, replay_document

ROOT = Path(__file__).resolve().parents[1]
UWSIMNET = [sys.executable, "-m", "uwsimnet_zenoh.cli"]
REPLAY_SCENE = ROOT / "scenes" / "paper" / "twinbot-sfama.xml"
WORLD = "viewtest"
WAIT = 30.0

sys.path.insert(0, str(Path(__file__).parent))
import view_webdriver  # noqa: E402


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def replay_trace(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("view") / "twinbot.jsonl"
    run_virtual(load_scene_file(str(REPLAY_SCENE)), seed=1, duration=30.0, trace_path=path, progress=False)
    return path


# -- the document ---------------------------------------------------------------------------------
def test_replay_document_holds_every_frame_and_the_counters_of_the_trace(replay_trace):
    scene = load_scene_file(str(REPLAY_SCENE))
    meta, events = read_trace(replay_trace)
    doc = replay_document(meta, events, scene)
    recs = [r for r in map(json.loads, replay_trace.read_text().splitlines()) if r["ev"] != "meta"]
    assert set(doc["vehicles"]) == {v.name for v in scene.vehicles}
    assert set(doc["devices"]) == {d.dccomms_id for _, d in scene.devices()}
    assert doc["t1"] == 30.0 and doc["positions"]
    assert doc["frames"] == [f.to_dict() for f in air_frames(recs)]
    assert len(doc["frames"]) == sum(r["ev"] == "tx" for r in recs)
    counts = Counter((r["dev"], r["ev"]) for r in recs)
    last = {row[1]: row for row in doc["events"]}              # each device's last row: its totals
    for dev, row in last.items():
        assert row[5:9] == [counts[dev, e] for e in ("enq", "tx", "rx", "drop")]
    for dev, d in doc["devices"].items():                      # PER curves from the scene's loss models
        assert d["per"] and all(0.0 <= p <= 1.0 for _, p in d["per"]), dev
    for v in scene.vehicles:                                   # scripted poses: the waypoints themselves
        want = [[w.t, w.x, w.y, w.z] for w in v.trajectory] or [[0.0, *v.position]]
        assert doc["poses"][v.name] == want


def test_replay_document_without_the_scene_places_the_meta_devices():
    meta = {"ev": "meta", "devices": {"a": {"address": 1, "vehicle": "va", "tx_channel": 0, "rx_channel": 0},
                                      "b": {"address": 2, "vehicle": "vb", "tx_channel": 0, "rx_channel": 0}}}
    ev = [{"t": 1.0, "ev": "tx", "ch": 0, "dev": "a", "src": 1, "dst": 2, "seq": 0, "size": 10, "flow": None,
           "kind": "data"},
          {"t": 1.5, "ev": "drop", "ch": 0, "dev": "b", "src": 1, "dst": 2, "seq": 0, "size": 10, "flow": None,
           "kind": "data", "reason": "col", "dist": 3.0}]
    doc = replay_document(meta, iter(ev))
    assert not doc["positions"] and set(doc["vehicles"]) == {"va", "vb"}
    assert doc["frames"][0]["outcomes"] == {"b": {"outcome": "col", "t": 1.5, "dist": 3.0}}


def test_live_state_gives_a_snapshot_to_a_consumer_that_fell_behind():
    st = LiveState("w", log_size=10)
    seq0, _ = st.snapshot()
    for i in range(5):
        st.set_clock({"t": float(i)})
    seq, ups = st.since(seq0)
    assert seq == seq0 + 5 and [u["clock"]["t"] for u in ups] == [0, 1, 2, 3, 4]
    for i in range(20):
        st.set_clock({"t": float(i)})
    assert st.since(seq) is None                       # those updates are gone: take a snapshot
    seq2, doc = st.snapshot()
    assert doc["clock"]["t"] == 19.0 and st.since(seq2) == (seq2, [])
    assert len(st.log) == 10


def _rec(i: int) -> dict:
    return {"t": i * 1e-3, "ev": "tx", "ch": 0, "dev": "a", "src": 1, "dst": 2, "seq": i, "size": 20,
            "flow": None, "kind": "data", "fifo": 0}


def _ws_handshake(port: int, rcvbuf: int | None = None) -> socket.socket:
    s = socket.socket()
    if rcvbuf:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
    s.connect(("127.0.0.1", port))
    key = base64.b64encode(os.urandom(16)).decode()
    s.sendall(f"GET /ws HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
              f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n".encode())
    return s


def test_a_stuck_or_closed_browser_never_holds_up_the_feed():
    """The live hand-off: Zenoh callbacks (here a thread) feed LiveState while one WebSocket client never reads
    and another closes at once; the feed finishes, the log stays bounded, a reading client gets everything."""
    from aiohttp import ClientSession

    from uwsimnet_zenoh.view.server import ViewServer

    n = 30000
    st = LiveState("w", log_size=5000)
    server = ViewServer(live=st)

    async def main() -> None:
        runner, port = await server.start("127.0.0.1", 0)
        try:
            stuck = _ws_handshake(port, rcvbuf=4096)                 # never reads a byte
            closed = _ws_handshake(port)
            await asyncio.sleep(0.2)
            closed.close()                                           # a browser tab closed
            async with ClientSession() as http, http.ws_connect(f"http://127.0.0.1:{port}/ws") as ws:
                first = json.loads(await ws.receive_bytes())
                assert first["type"] == "snapshot"
                feeder = threading.Thread(target=lambda: [st.trace(_rec(i)) for i in range(n)])
                feeder.start()
                while feeder.is_alive():
                    await asyncio.sleep(0.05)
                feeder.join()
                assert len(st.log) == 5000
                last = None
                deadline = time.monotonic() + WAIT
                while last != n - 1 and time.monotonic() < deadline:
                    m = json.loads(await asyncio.wait_for(ws.receive_bytes(), WAIT))
                    if m["type"] == "snapshot":
                        frames = m["doc"]["frames"]
                        last = frames[-1]["seq"] if frames else last
                    else:
                        seqs = [u["f"]["seq"] for u in m["updates"] if u["type"] == "frame"]
                        last = seqs[-1] if seqs else last
                assert last == n - 1
            stuck.close()
            deadline = time.monotonic() + WAIT
            while server.clients and time.monotonic() < deadline:
                await asyncio.sleep(0.1)
            assert server.clients == 0
        finally:
            await runner.cleanup()

    asyncio.run(main())


# -- bad input: one line, exit 2 -------------------------------------------------------------------
def _one_line_exit_2(argv: list[str], timeout: float = 60) -> str:
    r = subprocess.run([*UWSIMNET, *argv], capture_output=True, text=True, cwd=ROOT, timeout=timeout)
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr, r.stderr
    return r.stderr.strip()


def test_view_of_something_that_is_not_a_trace(tmp_path):
    (tmp_path / "a.txt").write_text("not json at all\n")
    (tmp_path / "b.json").write_text('{"name": "a JSON file, not a trace"}\n')
    (tmp_path / "c.jsonl").write_text("")
    (tmp_path / "d.bin").write_bytes(bytes(range(256)) * 4)
    for name in ("a.txt", "b.json", "c.jsonl", "d.bin", "missing.jsonl"):
        msg = _one_line_exit_2(["view", str(tmp_path / name), "--port", "0"])
        assert name in msg


def test_view_on_a_port_in_use(replay_trace):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        msg = _one_line_exit_2(["view", str(replay_trace), "--port", str(port)])
    assert f"127.0.0.1:{port}" in msg


def test_view_of_a_router_that_refuses():
    port = free_port()                                  # nobody listens there: the connection is refused
    msg = _one_line_exit_2(["view", "--connect", f"tcp/127.0.0.1:{port}", "--world", "w", "--port", "0"])
    assert msg.startswith("uwsimnet view:")


# -- the page in a real browser --------------------------------------------------------------------
class Proc:
    def __init__(self, argv: list[str], log: Path) -> None:
        self.log = log
        self.fh = open(log, "w")                        # noqa: SIM115 - closed in stop()
        self.p = subprocess.Popen(argv, cwd=ROOT, stdout=self.fh, stderr=subprocess.STDOUT,
                                  stdin=subprocess.DEVNULL, env=dict(os.environ, PYTHONUNBUFFERED="1"))

    def text(self) -> str:
        return self.log.read_text()

    def wait_for(self, text: str, timeout: float = WAIT) -> str:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            out = self.text()
            if text in out:
                return out
            if self.p.poll() is not None:
                break
            time.sleep(0.1)
        raise AssertionError(f"no {text!r} in the output:\n{self.text()}")

    def stop(self) -> int:
        if self.p.poll() is None:
            self.p.send_signal(signal.SIGINT)
            try:
                self.p.wait(20)
            except subprocess.TimeoutExpired:
                self.p.kill()
                self.p.wait(5)
        self.fh.close()
        return self.p.returncode


def get_json(url: str) -> dict:
    with urllib.request.urlopen(url, timeout=10) as r:
        return json.loads(r.read())


def wait_doc(url: str, pred, timeout: float = WAIT) -> dict:
    deadline = time.monotonic() + timeout
    doc = None
    while time.monotonic() < deadline:
        with contextlib.suppress(OSError):
            doc = get_json(url + "api/doc")
            if pred(doc):
                return doc
        time.sleep(0.2)
    raise AssertionError(f"{url}: document not as expected within {timeout} s: {doc and list(doc)}")


def shot(browser: view_webdriver.Browser, tmp: Path, name: str) -> None:
    browser.screenshot(tmp / name)
    assert (tmp / name).stat().st_size > 10000
    dest = os.environ.get("UWSIMNET_VIEW_SHOTS")
    if dest:
        Path(dest).mkdir(parents=True, exist_ok=True)
        shutil.copy(tmp / name, Path(dest) / name)


needs_browser = pytest.mark.skipif(view_webdriver.unavailable() is not None,
                                   reason=str(view_webdriver.unavailable()))


@pytest.fixture(scope="module")
def browser():
    if view_webdriver.unavailable():
        pytest.skip(view_webdriver.unavailable())
    with view_webdriver.Browser() as b:
        yield b


def outcomes_in_trace(path: Path, dev: str, seq: int, kind: str = "data") -> dict[str, str]:
    recs = [r for r in map(json.loads, path.read_text().splitlines()) if r["ev"] != "meta"]
    tx = next(r for r in recs if r["ev"] == "tx" and r["dev"] == dev and r["seq"] == seq and r["kind"] == kind)
    return {r["dev"]: "rx" if r["ev"] == "rx" else r["reason"] for r in recs
            if r["ev"] in ("rx", "drop") and r["dev"] != dev and r["seq"] == seq and r["src"] == tx["src"]
            and r["ch"] == tx["ch"] and r["kind"] == kind and r["t"] >= tx["t"]}


@needs_browser
def test_page_replays_a_trace(browser, replay_trace, tmp_path):
    scene = load_scene_file(str(REPLAY_SCENE))
    view = Proc([*UWSIMNET, "view", str(replay_trace), "--scene", str(REPLAY_SCENE), "--port", "0"],
                tmp_path / "view.log")
    try:
        url = view.wait_for("http://").split("uwsimnet view: ")[1].split()[0]
        browser.get(url)
        browser.wait("return window.uwsimnetView && uwsimnetView.ready", what="page ready")
        assert browser.js("return [uwsimnetView.mode, uwsimnetView.vehicles(), uwsimnetView.modems()]") == \
            ["replay", len(scene.vehicles), len(list(scene.devices()))]
        assert browser.js("return document.querySelectorAll('#modems tbody tr').length") == len(list(scene.devices()))
        # the slider: a click in its middle moves simulation time to about half the run
        browser.click("#slider")
        t = browser.wait("return uwsimnetView.T > 0 && uwsimnetView.T")
        assert 13.0 < t < 17.0
        # the clock is redrawn on the next animation frame after T moves: wait for it to say T
        want_clock = f"t = {t:.3f} s"
        assert browser.wait(f"const c = document.getElementById('clock').textContent; return c === '{want_clock}' && c",
                            what=f"the clock saying {want_clock!r}") == want_clock
        # a data frame of the trace: on air just after its tx, then its outcome as in the trace
        recs = [r for r in map(json.loads, replay_trace.read_text().splitlines()) if r["ev"] == "tx"]
        tx = next(r for r in recs if r["kind"] == "data" and r["t"] > 10 and r["dev"] == "leader-rf")
        want = outcomes_in_trace(replay_trace, tx["dev"], tx["seq"])
        browser.js(f"uwsimnetView.setTime({tx['t'] + 1e-6})")
        f = browser.wait(f"return uwsimnetView.frame('{tx['dev']}', {tx['seq']}, 'data')")
        assert f["state"] == "air" and f["outs"] == []
        sel = f"#frames li[data-dev=\"{tx['dev']}\"][data-seq=\"{tx['seq']}\"][data-kind=\"data\"]"
        li = browser.wait(f"return document.querySelector('{sel}')?.dataset.state")
        assert li == "air"
        browser.js(f"uwsimnetView.setTime({tx['t'] + 2.0})")
        f = browser.wait(f"return uwsimnetView.frame('{tx['dev']}', {tx['seq']}, 'data')")
        assert f["state"] == "done" and dict(f["outs"]) == want
        browser.wait(f"return document.querySelector('{sel}[data-state=\"done\"]')", what="the frame done")
        browser.click(sel)                                  # its details: the outcomes the trace has
        detail = browser.wait("return document.getElementById('detail').textContent", what="the frame's details")
        assert all(f"  {dev}: {o} at " in detail for dev, o in want.items()), detail
        # the modem filter: only frames sent or heard by that modem stay in the list
        browser.js("const s = document.getElementById('fdev'); s.value = 'buoy-acomm';"
                   " s.dispatchEvent(new Event('change'))")
        buoy = "li.dataset.dev === 'buoy-acomm' || li.dataset.outcomes.includes('buoy-acomm=')"
        rows = "const l = [...document.querySelectorAll('#frames li')]; return l.length && "
        assert browser.wait(rows + f"l.every(li => {buoy}) && l.length", what="only buoy-acomm's frames") >= 1
        browser.js("const s = document.getElementById('fdev'); s.value = ''; s.dispatchEvent(new Event('change'))")
        browser.wait(rows + f"l.some(li => !({buoy}))", what="the others back without the filter")
        # zoom about the centre: the pixel distance between two vehicles grows by the zoom factor (1.5);
        # Fit puts the map back
        a, b = (v.name for v in scene.vehicles[:2])
        dist = (f"const p = uwsimnetView.pixel('{a}'), q = uwsimnetView.pixel('{b}');"
                " return Math.hypot(p[0] - q[0], p[1] - q[1])")
        d0 = browser.js(dist)
        browser.click("#zoomin")
        browser.wait("return uwsimnetView.zoom === 1.5", what="zoomed in")
        assert browser.js(dist) == pytest.approx(1.5 * d0, rel=1e-9)
        browser.click("#fit")
        browser.wait("return uwsimnetView.zoom === 1", what="fitted")
        assert browser.js(dist) == pytest.approx(d0, rel=1e-9)
        # play at 10x: time moves by itself
        browser.js("uwsimnetView.setTime(0); uwsimnetView.play(10)")
        browser.wait("return uwsimnetView.T > 2", what="playing moves time")
        browser.js(f"uwsimnetView.setTime({tx['t'] + 0.05})")
        time.sleep(0.3)
        shot(browser, tmp_path, "view-replay.png")
    finally:
        assert view.stop() == 0, view.text()


LIVE_SCENE = f"""<?xml version="1.0"?>
<UWSimScene>
  <simulation><seed>3</seed><clock>realtime</clock><world>{WORLD}</world><duration>600</duration></simulation>
  <CustomCommsChannel><id>0</id><propTimeIncPerMeter>0.6667</propTimeIncPerMeter></CustomCommsChannel>
  {"".join(f'''<vehicle><name>{v}</name><position>{x} {y} {z}</position><poseRate>5</poseRate>
    <CustomCommsDevice><dccommsId>{v}-m</dccommsId><mac>{a}</mac><txChannelId>0</txChannelId>
      <rxChannelId>0</rxChannelId><bitrate>2000</bitrate><txFifoSize>2000</txFifoSize><maxDistance>900</maxDistance>
      <rateErrorModel><errorUnit>packet</errorUnit><errorRateExpr>min(1, max(0, (m - 300) / 400))</errorRateExpr>
      </rateErrorModel></CustomCommsDevice></vehicle>'''
          for v, a, (x, y, z) in (("alpha", 1, (0, 0, -5)), ("bravo", 2, (450, 0, -20)),
                                  ("charlie", 3, (0, 1000, -40))))}
</UWSimScene>"""


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    """`uwsimnet run --view` of a realtime scene: the broker and, beside it, the page as its own Zenoh client."""
    pytest.importorskip("uwsimnet_gli")
    d = tmp_path_factory.mktemp("live")
    scene = d / "live.xml"
    scene.write_text(LIVE_SCENE)
    zport, vport = free_port(), free_port()
    endpoint = f"tcp/127.0.0.1:{zport}"
    run = Proc([*UWSIMNET, "run", str(scene), "--listen", endpoint, "--trace", str(d / "trace.jsonl"),
                "--view", "--view-port", str(vport)], d / "run.log")
    try:
        url = run.wait_for(f"uwsimnet view: http://127.0.0.1:{vport}/") and f"http://127.0.0.1:{vport}/"
        wait_doc(url, lambda doc: len(doc["devices"]) == 3 and all(v["kind"] == "sim" for v in doc["devices"].values()))
        yield {"url": url, "endpoint": endpoint, "trace": d / "trace.jsonl", "run": run, "dir": d}
    finally:
        rc = run.stop()
        assert rc == 0, run.text()
        assert "Traceback" not in run.text(), run.text()


def test_live_document_from_a_second_viewer_without_the_scene(live, tmp_path):
    """`uwsimnet view --connect --world` alone (what a visitor runs): modems, kinds and poses from the wire."""
    view = Proc([*UWSIMNET, "view", "--connect", live["endpoint"], "--world", WORLD, "--port", "0"],
                tmp_path / "view.log")
    try:
        url = view.wait_for("http://").split("uwsimnet view: ")[1].split()[0]
        doc = wait_doc(url, lambda d: len(d["devices"]) == 3 and all(len(d["poses"].get(v, [])) >= 2
                                                                      for v in ("alpha", "bravo", "charlie")))
        assert doc["mode"] == "live" and doc["control"] is True
        assert {k: (v["vehicle"], v["address"], v["kind"], v["fifo_capacity"]) for k, v in doc["devices"].items()} == \
            {"alpha-m": ("alpha", 1, "sim", 2000), "bravo-m": ("bravo", 2, "sim", 2000),
             "charlie-m": ("charlie", 3, "sim", 2000)}
        assert doc["poses"]["bravo"][-1][1:] == [450.0, 0.0, -20.0]
    finally:
        assert view.stop() == 0, view.text()


def test_a_world_nobody_serves_is_one_line_naming_the_worlds_seen(live):
    """`--world <typo>`: no page that says "connected" over nothing; exit 2, the worlds there are named."""
    err = _one_line_exit_2(["view", "--connect", live["endpoint"], "--world", WORLD + "x", "--port", "0"], 120)
    assert f"no world '{WORLD}x'" in err and f"worlds seen: {WORLD}" in err, err


@needs_browser
def test_page_shows_a_live_run(browser, live, tmp_path):
    from uwsimnet_gli import World

    browser.get(live["url"])
    browser.wait("return window.uwsimnetView && uwsimnetView.ready && uwsimnetView.modems() === 3",
                 what="live page with 3 modems")
    assert browser.js("return [uwsimnetView.mode, uwsimnetView.vehicles()]") == ["live", 3]
    assert browser.js("return uwsimnetView.kinds()") == {"alpha-m": "sim", "bravo-m": "sim", "charlie-m": "sim"}
    t0 = browser.wait("return uwsimnetView.T > 0 && uwsimnetView.T", what="the clock runs")
    browser.wait(f"return uwsimnetView.T > {t0} + 0.3", what="the clock moves")
    with World(WORLD, connect=live["endpoint"]) as w:
        m = w.modem("alpha-m")
        assert m.wait_kind(timeout=10) == "sim"
        tag = m.send(255, b"hello view")                      # broadcast: bravo (450 m) and charlie (1000 m)
        st = m.wait_status(tag, timeout=10)
        assert st is not None and st.event == "sent", st
        seq = st.seq
        f = browser.wait(f"return (f => f && f.state === 'done' && f)(uwsimnetView.frame('alpha-m', {seq}, 'data'))",
                         what="the frame sent during the test, with its outcomes")
        browser.wait(f"return document.querySelector('#frames li[data-dev=\"alpha-m\"][data-seq=\"{seq}\"]"
                     "[data-state=\"done\"]')", what="the frame in the list")
        assert browser.js("return uwsimnetView.counters('alpha-m').tx") >= 1
        shot(browser, tmp_path, "view-live.png")
        # pause and resume through the control API, from the page's buttons
        browser.wait("return !document.getElementById('pause').disabled", what="control allowed")
        browser.click("#pause")
        browser.wait("return /^paused at t = /.test(document.getElementById('ctlmsg').textContent)",
                     what="the confirmation")
        browser.wait("return !document.getElementById('paused').hidden", what="paused")
        browser.wait("return document.getElementById('ctlmsg').textContent.startsWith('paused at t = ')",
                     what="the pause confirmed")
        time.sleep(0.3)                                       # clock samples sent before the pause are in
        t_paused = browser.js("return uwsimnetView.T")
        time.sleep(0.5)
        assert browser.js("return uwsimnetView.T") == t_paused
        # the confirmation outlives the updates that came since (it stays until the next answer)
        assert browser.js("return document.getElementById('ctlmsg').textContent").startswith("paused at t = ")
        assert w.control("state")["paused"] is True
        browser.click("#resume")
        browser.wait("return document.getElementById('paused').hidden", what="resumed")
        browser.wait("return /^resumed at t = /.test(document.getElementById('ctlmsg').textContent)",
                     what="the confirmation")
        time.sleep(0.5)                                       # many update batches later: still there
        assert browser.js("return document.getElementById('ctlmsg').textContent").startswith("resumed at t = ")
        browser.wait(f"return uwsimnetView.T > {t_paused} + 0.2", what="time moves again")
    # the trace (written by the broker, published on the trace keys the page reads) says the same
    deadline = time.monotonic() + WAIT
    want = {}
    while time.monotonic() < deadline and len(want) < 2:
        with contextlib.suppress(StopIteration, json.JSONDecodeError):
            want = outcomes_in_trace(live["trace"], "alpha-m", seq)
        time.sleep(0.2)
    assert dict(f["outs"]) == want and set(want) == {"bravo-m", "charlie-m"}
    assert want["charlie-m"] == "range"


# -- a secured deployment: the page as a visitor (read-only: traces) ------------------------------
@pytest.fixture(scope="module")
def secured(tmp_path_factory):
    """Routers with TLS, user/password and the deployment's ACL (tests/test_security.py's Deployment); the
    broker logs in as `brk`, the page as the visitor `vis`, an app as `app` on the other router."""
    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed")
    pytest.importorskip("uwsimnet_gli")
    from test_security import Deployment

    d = tmp_path_factory.mktemp("secured")
    dep = Deployment(d)
    dep.start()
    started: list[Proc] = []
    try:
        scene = d / "live.xml"
        scene.write_text(LIVE_SCENE)
        cfg = {n: dep.out / dep.inventory.identities[n].host / "clients" / f"{n}.json5" for n in ("brk", "vis", "app")}
        run = Proc([*UWSIMNET, "run", str(scene), "--world", "w", "--zenoh-config", str(cfg["brk"]),
                    "--trace", str(d / "trace.jsonl")], d / "run.log")
        started.append(run)
        run.wait_for("running for")
        view = Proc([*UWSIMNET, "view", "--zenoh-config", str(cfg["vis"]), "--world", "w", "--scene", str(scene),
                     "--port", "0"], d / "view.log")
        started.append(view)
        url = view.wait_for("http://").split("uwsimnet view: ")[1].split()[0]
        yield {"url": url, "app": cfg["app"], "trace": d / "trace.jsonl"}
    finally:
        for p in reversed(started):
            assert p.stop() in (0, 130), p.text()
            assert "Traceback" not in p.text(), p.text()
        dep.stop()


def test_visitor_sees_traced_frames_but_may_not_pause(secured):
    from uwsimnet_gli import World, load_config

    url = secured["url"]
    doc = wait_doc(url, lambda d: len(d["devices"]) == 3)
    assert doc["control"] is False and set(doc["vehicles"]) == {"alpha", "bravo", "charlie"}
    req = urllib.request.Request(url + "api/control/pause", method="POST")
    with pytest.raises(urllib.error.HTTPError) as e:
        urllib.request.urlopen(req, timeout=10)
    assert e.value.code == 403
    with World("w", config=load_config(str(secured["app"]))) as w:
        m = w.modem("alpha-m")
        assert m.wait_kind(timeout=WAIT) == "sim"
        tag = m.send(255, b"seen by a visitor")
        st = m.wait_status(tag, timeout=WAIT)
        assert st is not None and st.event == "sent", st

    def has_frame(d: dict) -> bool:
        return any(f["dev"] == "alpha-m" and f["seq"] == st.seq and len(f["outcomes"]) == 2 for f in d["frames"])

    doc = wait_doc(url, has_frame)
    f = next(f for f in doc["frames"] if f["dev"] == "alpha-m" and f["seq"] == st.seq)
    deadline = time.monotonic() + WAIT
    want: dict[str, str] = {}
    while time.monotonic() < deadline and len(want) < 2:
        with contextlib.suppress(StopIteration, json.JSONDecodeError, FileNotFoundError):
            want = outcomes_in_trace(secured["trace"], "alpha-m", st.seq)
        time.sleep(0.2)
    assert {k: o["outcome"] for k, o in f["outcomes"].items()} == want
    assert doc["clock"]["t"] >= f["t"]                    # time as the trace tells it (no clock for visitors)


def test_documents_are_json_even_with_non_finite_numbers():
    from uwsimnet_zenoh.view.server import _json_bytes

    doc = {"frames": [{"outcomes": {"b": {"dist": float("nan")}}}], "t": float("inf"), "flow": "NaN"}
    assert json.loads(_json_bytes(doc)) == {"frames": [{"outcomes": {"b": {"dist": None}}}], "t": None, "flow": "NaN"}


# -- #41: data is text, the page is its own origin, memory is bounded -------------------------------
XSS = "<img src=x onerror=\"window.pwned=1\">"


def test_a_trace_whose_meta_carries_markup_is_refused_on_read(tmp_path):
    meta = {"ev": "meta", "devices": {"a": {"vehicle": "v", "address": 1, "tx_channel": XSS, "rx_channel": 0}}}
    (tmp_path / "x.jsonl").write_text(json.dumps(meta) + "\n")
    msg = _one_line_exit_2(["view", str(tmp_path / "x.jsonl"), "--port", "0"])
    assert "tx_channel" in msg and "not an integer" in msg, msg


@contextlib.contextmanager
def _served(server):
    """A ViewServer on a free loopback port in a thread of its own; its URL."""
    import asyncio
    import threading

    from uwsimnet_zenoh.view.server import serve_forever

    ready: list[str] = []
    holder: dict = {}

    def run() -> None:
        async def main() -> None:
            holder["stop"], holder["loop"] = asyncio.Event(), asyncio.get_running_loop()
            await serve_forever(server, "127.0.0.1", 0, ready.append, holder["stop"])
        asyncio.run(main())

    th = threading.Thread(target=run, daemon=True)
    th.start()
    deadline = time.monotonic() + WAIT
    while not ready and time.monotonic() < deadline:
        time.sleep(0.05)
    try:
        yield ready[0]
    finally:
        holder["loop"].call_soon_threadsafe(holder["stop"].set)
        th.join(10)


def _forged_live_state() -> LiveState:
    """What a forged `modem/*/info` reply and a forged trace sample on Zenoh feed the page (LiveSource's
    validation lets strings through where the wire allows them)."""
    st = LiveState(XSS)
    st.merge_state({"modems": {XSS: {"vehicle": XSS, "address": XSS, "tx_channel": XSS, "rx_channel": 0}}})
    st.set_control(True)
    st.trace({"ev": "tx", "t": 0.5, "dev": XSS, "src": 1, "dst": 255, "seq": 7, "size": 4, "ch": XSS,
              "kind": XSS, "id": 1})
    return st


@needs_browser
def test_injected_markup_is_shown_as_text(browser):
    from uwsimnet_zenoh.view.server import ViewServer

    with _served(ViewServer(live=_forged_live_state())) as url:
        browser.get(url)
        browser.wait("return window.uwsimnetView && uwsimnetView.ready && uwsimnetView.modems() === 1",
                     what="the forged modem")
        browser.wait("return document.querySelector('#frames li')", what="the forged frame in the list")
        assert browser.js("return document.querySelectorAll('img').length") == 0
        assert browser.js("return window.pwned === undefined")
        assert XSS in browser.js("return document.getElementById('modems').textContent")
        assert XSS in browser.js("return document.getElementById('frames').textContent")


def test_foreign_origin_and_host_are_refused():
    import urllib.error
    import urllib.request

    from uwsimnet_zenoh.view.server import ViewServer

    calls: list[str] = []
    st = LiveState("w")
    st.set_control(True)
    server = ViewServer(live=st, control=lambda op: calls.append(op) or {"ok": True, "t": 1.0})

    def status(url: str, method: str = "GET", **headers: str) -> int:
        req = urllib.request.Request(url, method=method, headers=headers, data=b"" if method == "POST" else None)
        try:
            with urllib.request.urlopen(req, timeout=WAIT) as r:
                return r.status
        except urllib.error.HTTPError as e:
            return e.code

    with _served(server) as url:
        port = url.rstrip("/").rsplit(":", 1)[1]
        assert status(url + "api/doc") == 200
        assert status(url + "api/doc", Host=f"evil.example:{port}") == 403          # DNS rebinding
        assert status(url + "api/control/pause", "POST", Origin="http://evil.example") == 403
        assert calls == []                                                          # the run was not paused
        ws = {"Connection": "Upgrade", "Upgrade": "websocket", "Sec-WebSocket-Version": "13",
              "Sec-WebSocket-Key": "dGhlIHNhbXBsZSBub25jZQ=="}
        assert status(url + "ws", Origin="http://evil.example", **ws) == 403
        assert status(url + "api/control/pause", "POST", Origin=f"http://127.0.0.1:{port}") == 200
        assert calls == ["pause"]
        assert server.refused == 3


def test_a_flood_of_pose_names_is_bounded_and_counted():
    from uwsimnet_zenoh.view.state import MAX_VEHICLES

    st = LiveState("w")
    for i in range(20000):
        st.pose(f"v{i}", (0.0, 0.0, 0.0), float(i))
    assert len(st.poses) == len(st.vehicles) == MAX_VEHICLES
    assert st.refused_vehicles == 20000 - MAX_VEHICLES


def test_half_open_connections_are_closed():
    """A connection that sends nothing, or half a request and then nothing, is closed after the idle timeout."""
    from uwsimnet_zenoh.view.server import ViewServer

    server = ViewServer(doc={"mode": "replay"})
    server.idle_timeout = 1.0
    with _served(server) as url:
        port = int(url.rstrip("/").rsplit(":", 1)[1])
        for first in (b"", b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n"):
            with socket.create_connection(("127.0.0.1", port), timeout=WAIT) as c:
                c.sendall(first)
                t0 = time.monotonic()
                assert c.recv(1) == b""                 # closed by the server (a timeout here raises instead)
                assert time.monotonic() - t0 >= 0.9
