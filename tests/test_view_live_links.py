"""#37 in the loop: a live run of the shadow scene (tests/data/ocean-shadow.xml, Bellhop's shipped grid) whose
AUV is positioned from Zenoh (HIL), `uwsimnet run --view` beside it.  The page colours the buoy -> AUV link by
Bellhop's PER at the poses the test publishes: 1 while the AUV is at 20 m (the thermocline's shadow), 0 at
100 m, with received levels of 184 dB minus the grid's TL at those depths; the broker's trace agrees: the
frames sent while shallow are lost, the ones sent once deep are delivered.
"""

from __future__ import annotations

import json
import sys
import threading
import time
import urllib.request
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))
from test_view import UWSIMNET, WAIT, Proc, free_port, needs_browser, wait_doc  # noqa: E402
from test_view import browser as browser  # noqa: E402 - the module's browser fixture

zenoh = pytest.importorskip("zenoh")
wire = pytest.importorskip("uwsimnet_gli.wire")

DATA = Path(__file__).resolve().parent / "data"
WORLD = "hilshadow"


def _scene() -> str:
    text = (DATA / "ocean-shadow.xml").read_text()
    a, b = text.index("    <trajectory>"), text.index("</trajectory>") + len("</trajectory>")
    text = text[:a] + "    <poseSource>zenoh</poseSource>" + text[b:]
    return text.replace("<seed>3</seed>", f"<seed>3</seed><clock>realtime</clock><world>{WORLD}</world>") \
               .replace("<duration>200</duration>", "<duration>600</duration>")


class Poser:
    """Publishes the AUV's pose five times a second from a Zenoh client (what a vehicle in the loop does)."""

    def __init__(self, endpoint: str) -> None:
        conf = zenoh.Config()
        conf.insert_json5("mode", '"client"')
        conf.insert_json5("connect/endpoints", f'["{endpoint}"]')
        self.s = zenoh.open(conf)
        self.z = -20.0
        self.stop = threading.Event()
        self.th = threading.Thread(target=self._run, daemon=True)
        self.th.start()

    def _run(self) -> None:
        key = wire.Keys(WORLD).pose("auv")
        while not self.stop.wait(0.2):
            self.s.put(key, wire.encode_pose((1000.0, 0.0, self.z)))

    def close(self) -> None:
        self.stop.set()
        self.th.join(5)
        self.s.close()


@needs_browser
def test_a_vehicle_in_the_loop_gets_its_link_coloured_by_bellhop(browser, tmp_path, monkeypatch):
    from uwsimnet_zenoh.phy import bellhop

    monkeypatch.setenv("UWSIMNET_CACHE", str(DATA))
    monkeypatch.setenv("UWSIMNET_BELLHOP", "/nonexistent/bellhop")    # the shipped grid, not the program
    scene = tmp_path / "hil-shadow.xml"
    scene.write_text(_scene())
    endpoint, vport = f"tcp/127.0.0.1:{free_port()}", free_port()
    trace = tmp_path / "trace.jsonl"
    run = Proc([*UWSIMNET, "run", str(scene), "--listen", endpoint, "--trace", str(trace), "--view",
                "--view-port", str(vport)], tmp_path / "run.log")
    poser = None
    grid = bellhop.Grid.load(next((DATA / "bellhop").glob("*.npz")))
    level = {z: 184.0 - float(grid.lookup([10.0], [z], [1000.0])[0][0]) for z in (20.0, 100.0)}
    try:
        run.wait_for(f"uwsimnet view: http://127.0.0.1:{vport}/")
        url = f"http://127.0.0.1:{vport}/"
        wait_doc(url, lambda d: len(d["devices"]) == 2)
        poser = Poser(endpoint)
        browser.get(url)
        browser.wait("return window.uwsimnetView && uwsimnetView.ready && uwsimnetView.position('auv')",
                     timeout=WAIT, what="the AUV's pose on the page")
        assert browser.js("return document.getElementById('linkby').value") == "model"
        seen = {}
        for z, per in ((20.0, 1.0), (100.0, 0.0)):
            poser.z = -z
            seen[z] = browser.wait(f"return (l => l.value === {per} && uwsimnetView.position('auv')[2] === {-z} && l)"
                                   "(uwsimnetView.link('buoy-modem', 'auv-modem'))", timeout=WAIT,
                                   what=f"the link at PER {per} with the AUV at {z} m")
            with urllib.request.urlopen(url + "api/doc", timeout=10) as r:
                doc = json.loads(r.read())
            last = doc["devices"]["buoy-modem"]["links"]["auv-modem"][-1]
            assert last[1] == per and last[2] == pytest.approx(level[z], abs=0.06), (z, last, level)
            t_z = browser.js("return uwsimnetView.T")
            browser.wait(f"return uwsimnetView.T > {t_z} + 6", timeout=WAIT, what="three frames' time")
            seen[z] = t_z
        # the broker's trace: frames sent at 20 m (after the first pose) lost, frames sent at 100 m delivered
        deadline = time.monotonic() + WAIT
        outs: dict[float, str] = {}
        while time.monotonic() < deadline:
            recs = [json.loads(x) for x in trace.read_text().splitlines() if x.strip()] if trace.exists() else []
            tx = {r["seq"]: r["t"] for r in recs if r.get("ev") == "tx" and r["dev"] == "buoy-modem"}
            outs = {tx[r["seq"]]: r.get("reason", "rx") for r in recs if r.get("dev") == "auv-modem"
                    and r.get("ev") in ("rx", "drop") and r["seq"] in tx}
            if any(t > seen[100.0] + 2 for t in outs):
                break
            time.sleep(0.2)
        shallow = [o for t, o in outs.items() if seen[20.0] + 1 < t < seen[100.0] - 1]
        deep = [o for t, o in outs.items() if t > seen[100.0] + 1]
        assert shallow and set(shallow) == {"prop"}, outs
        assert deep and set(deep) == {"rx"}, outs
    finally:
        if poser is not None:
            poser.close()
        assert run.stop() == 0, run.text()
        assert "Traceback" not in run.text(), run.text()
