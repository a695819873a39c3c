"""`uwsimnet view` on a replayed trace, in headless Chromium: labels placed apart, a click on a modem for its
details, stepping event by event, and links coloured by the modelled PER or by the loss measured in the trace.

Every number the page shows is checked against the trace file (counted here from its JSON lines) or the
scene's error expression, never against the page's own code.
"""

from __future__ import annotations

import json
import sys
from collections import Counter
from pathlib import Path

import pytest

from uwsimnet_zenoh.app.virtual import load_scene_file, run_virtual

sys.path.insert(0, str(Path(__file__).parent))
from test_view import UWSIMNET, Proc, needs_browser, shot  # noqa: E402
from test_view import browser as browser  # noqa: E402 - the module's browser fixture

PER_EXPR = "min(1, m / 800)"
"""The scene's packet error rate at distance m (metres)."""
VEHICLES = {"alpha": ((0, 0, -10), 1), "bravo": ((1, 0, -10), 2), "charlie": ((0, 300, -20), 3),
            "delta": ((600, 0, -30), 4)}
"""alpha and bravo are 1 m apart: at the fitted scale (about 700 m across the map) the same pixel."""
FLOWS = (("a-bcast", "alpha-m", 255, 0.9), ("d-to-a", "delta-m", 1, 0.7), ("c-to-d", "charlie-m", 4, 1.3))

SCENE = f"""<?xml version="1.0"?>
<UWSimScene>
  <simulation><seed>5</seed><clock>virtual</clock><world>viewpage</world><duration>120</duration></simulation>
  <CustomCommsChannel><id>0</id><propTimeIncPerMeter>0.6667</propTimeIncPerMeter></CustomCommsChannel>
  {"".join(f'''<vehicle><name>{v}</name><position>{x} {y} {z}</position>
    <CustomCommsDevice><dccommsId>{v}-m</dccommsId><mac>{a}</mac><txChannelId>0</txChannelId>
      <rxChannelId>0</rxChannelId><bitrate>4000</bitrate><txFifoSize>4000</txFifoSize><maxDistance>900</maxDistance>
      <rateErrorModel><errorUnit>packet</errorUnit><errorRateExpr>{PER_EXPR}</errorRateExpr></rateErrorModel>
      <macProtocol><name>aloha</name></macProtocol></CustomCommsDevice></vehicle>'''
          for v, ((x, y, z), a) in VEHICLES.items())}
  {"".join(f'''<flow><name>{n}</name><src>{s}</src><dst>{d}</dst><size>24</size><interval>{i}</interval>
    <arrival>periodic</arrival><start>0.5</start><stop>120</stop></flow>''' for n, s, d, i in FLOWS)}
</UWSimScene>"""


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    d = tmp_path_factory.mktemp("viewpage")
    scene = d / "scene.xml"
    scene.write_text(SCENE)
    trace = d / "trace.jsonl"
    run_virtual(load_scene_file(str(scene)), seed=5, duration=120.0, trace_path=trace, progress=False)
    recs = [r for r in map(json.loads, trace.read_text().splitlines()) if r["ev"] in ("enq", "tx", "rx", "drop")]
    return {"scene": scene, "trace": trace, "recs": recs, "dir": d}


@pytest.fixture()
def page(browser, run, tmp_path):                     # noqa: F811 - the browser fixture of test_view
    """The replay page of the run, with its scene, open in the browser; yields the browser."""
    view = Proc([*UWSIMNET, "view", str(run["trace"]), "--scene", str(run["scene"]), "--port", "0"],
                tmp_path / "view.log")
    try:
        url = view.wait_for("http://").split("uwsimnet view: ")[1].split()[0]
        browser.get(url)
        browser.wait("return window.uwsimnetView && uwsimnetView.ready && document.querySelectorAll("
                     "'#labels g.label').length === 4", what="page ready with 4 labels")
        yield browser
    finally:
        assert view.stop() == 0, view.text()


LABEL_BOXES = """return Object.fromEntries([...document.querySelectorAll('#labels g.label')].map(g => {
  const r = g.querySelector('rect').getBoundingClientRect(), t = g.querySelector('text').getBoundingClientRect();
  return [g.dataset.vehicle, {box: [r.left, r.top, r.right, r.bottom], text: [t.left, t.top, t.right, t.bottom],
          label: g.textContent, leader: g.querySelector('line').getAttribute('visibility') === 'visible'}];
}));"""


def _apart(a: list[float], b: list[float]) -> bool:
    return a[2] <= b[0] or b[2] <= a[0] or a[3] <= b[1] or b[3] <= a[1]


def _client_px(b, vehicle: str) -> tuple[float, float]:
    """Where a vehicle's disc is in the browser's viewport (CSS px), from its canvas pixel."""
    return tuple(b.js(f"""const c = document.getElementById('map').getBoundingClientRect(),
        p = uwsimnetView.pixel('{vehicle}'), m = document.getElementById('map');
        return [c.left + p[0] * c.width / m.width, c.top + p[1] * c.height / m.height];"""))


@needs_browser
def test_labels_of_vehicles_one_metre_apart_do_not_collide(page):
    b = page
    pa, pb = _client_px(b, "alpha"), _client_px(b, "bravo")
    assert abs(pa[0] - pb[0]) < 2 and abs(pa[1] - pb[1]) < 2          # one spot on the map at this scale
    boxes = b.js(LABEL_BOXES)
    assert set(boxes) == set(VEHICLES)
    for v, bx in boxes.items():
        assert bx["label"].startswith(v + " (z ")
        assert bx["box"][0] <= bx["text"][0] and bx["text"][2] <= bx["box"][2] + 2, (v, bx)   # the text in its box
    names = sorted(boxes)
    for i, u in enumerate(names):
        for v in names[i + 1:]:
            assert _apart(boxes[u]["box"], boxes[v]["box"]), (u, v, boxes[u]["box"], boxes[v]["box"])
    # zoomed in 1.5^14 (~290x) about the pair, alpha and bravo are ~290 px apart: both labels beside their own disc
    b.js("""const m = document.getElementById('map'), r = m.getBoundingClientRect(), p = uwsimnetView.pixel('alpha');
        for (let i = 0; i < 14; i++) m.dispatchEvent(new WheelEvent('wheel', {deltaY: -270.3, bubbles: true,
          cancelable: true, clientX: r.left + p[0] * r.width / m.width,
          clientY: r.top + p[1] * r.height / m.height}));""")
    b.wait("return uwsimnetView.zoom > 100", what="zoomed in")
    pa, pb = _client_px(b, "alpha"), _client_px(b, "bravo")
    assert abs(pa[0] - pb[0]) > 100
    boxes = b.wait(LABEL_BOXES.replace("return Object", "const o = Object").replace("}));", "})); "
                   "return !o.alpha.leader && !o.bravo.leader && o;"), what="labels beside their discs")
    assert _apart(boxes["alpha"]["box"], boxes["bravo"]["box"])


def _counts_up_to(recs: list[dict], dev: str, t: float) -> dict:
    mine = [r for r in recs if r["dev"] == dev and r["t"] <= t]
    return {"ev": Counter(r["ev"] for r in mine), "drops": Counter(r["reason"] for r in mine if r["ev"] == "drop")}


@needs_browser
def test_a_click_on_a_modem_shows_its_details_from_the_trace(page, run):
    b = page
    t = 60.0
    b.js(f"uwsimnetView.setTime({t})")
    b.wait(f"return document.getElementById('clock').textContent === 't = {t:.3f} s'", what="the clock at 60 s")
    x, y = _client_px(b, "delta")
    b.click_at(x, y)                                         # a real click on delta's disc in the canvas
    detail = b.wait("const d = document.getElementById('detail').textContent; "
                    "return d.startsWith('modem delta-m') && d", what="delta-m's details")
    c = _counts_up_to(run["recs"], "delta-m", t)
    assert "address 4 · vehicle delta · MAC aloha · 4000 bps · channel tx 0 rx 0" in detail, detail
    assert "(600.00, 0.00, -30.00) m" in detail, detail
    assert f"enq {c['ev']['enq']}, tx {c['ev']['tx']}, rx {c['ev']['rx']}, drop {c['ev']['drop']};" in detail, detail
    assert c["ev"]["tx"] > 20 and c["ev"]["rx"] > 10                  # a run that says something
    drops = ", ".join(f"{k} {n}" for k, n in sorted(c["drops"].items())) or "none"
    assert f"drops here by reason: {drops}" in detail, detail
    assert b.js("return [...document.querySelectorAll('#modems tr.sel')].map(r => r.dataset.dev)") == ["delta-m"]
    # the detail follows the time shown
    b.js("uwsimnetView.setTime(30)")
    c = _counts_up_to(run["recs"], "delta-m", 30.0)
    want = f"enq {c['ev']['enq']}, tx {c['ev']['tx']},"
    b.wait(f"return document.getElementById('detail').textContent.includes('{want}')", what="the counters at 30 s")
    # a click on bravo's label (it sits on alpha's spot: the label is the way to it), then on a table row
    b.click('#labels g.label[data-vehicle="bravo"]')
    b.wait("return document.getElementById('detail').textContent.startsWith('modem bravo-m')", what="bravo-m")
    b.click('#modems tbody tr[data-dev="charlie-m"]')
    b.wait("return document.getElementById('detail').textContent.startsWith('modem charlie-m')", what="charlie-m")


@needs_browser
def test_stepping_event_by_event_follows_the_trace(page, run):
    b = page
    recs = run["recs"]
    t0 = 40.0
    b.js(f"uwsimnetView.setTime({t0})")
    i = next(k for k, r in enumerate(recs) if r["t"] > t0)             # the first event after the time shown
    b.click("#next")
    for k, how in ((i, None), (i + 1, "."), (i + 2, "\ue014"), (i + 1, ","), (i + 2, "\ue014"), (i + 1, "\ue012")):
        if how is not None:
            b.key(how)                                                  # . and → forward, , and ← back
        r = recs[k]
        info = b.wait(f"const s = document.getElementById('stepinfo').textContent; "
                      f"return s.startsWith('event {k + 1} of {len(recs)}:') && s", what=f"event {k + 1}")
        assert f"t = {r['t']:.6f} s {r['dev']} {r['ev']}" in info and f"#{r['seq']} {r['kind']} from {r['src']}" in info
        assert b.js("return uwsimnetView.T") == r["t"]
        b.wait(f"return document.getElementById('clock').textContent === 't = {r['t']:.3f} s'", what="the clock")
    # forward to the next tx: its frame is the newest in the list, and marked
    k = next(k for k in range(i + 2, len(recs)) if recs[k]["ev"] == "tx")
    for _ in range(k - (i + 1)):
        b.click("#next")
    r = recs[k]
    li = b.wait("const l = document.querySelector('#frames li.cur'); return l && [l.dataset.dev, +l.dataset.seq, "
                "l.dataset.kind, l === document.querySelector('#frames li')]", what="the stepped frame in the list")
    assert li == [r["dev"], r["seq"], r["kind"], True]


@needs_browser
def test_links_are_coloured_by_the_modelled_per_or_the_measured_loss(page, run):
    b = page
    t = 100.0
    b.js(f"uwsimnetView.setTime({t})")
    # the default with a scene: the modelled PER at the distance, i.e. the scene's expression min(1, m / 800)
    assert b.js("return document.getElementById('linkby').value") == "model"
    assert "modelled PER" in b.js("return document.getElementById('legend').textContent")
    cd = (600**2 + 300**2 + 10**2) ** 0.5
    for tx, rx, m in (("delta-m", "alpha-m", 600.0), ("alpha-m", "charlie-m", 300.0), ("charlie-m", "delta-m", cd)):
        got = b.js(f"return uwsimnetView.link('{tx}', '{rx}')")
        assert got["by"] == "model" and got["value"] == pytest.approx(min(1.0, m / 800), abs=2e-3), (tx, rx, got)
    # measured: 1 - delivered / outcomes over the link's last 20 outcomes up to t, counted here from the trace
    b.js("const s = document.getElementById('linkby'); s.value = 'measured'; s.dispatchEvent(new Event('change'))")
    b.wait("return document.getElementById('legend').textContent.includes('measured loss')", what="the legend")
    tx_src = {"alpha-m": 1, "delta-m": 4, "charlie-m": 3}
    for tx, rx in (("delta-m", "alpha-m"), ("alpha-m", "charlie-m"), ("alpha-m", "bravo-m")):
        outs = sorted((r["t"], r["ev"] == "rx") for r in run["recs"]
                      if r["dev"] == rx and r["src"] == tx_src[tx] and r["ev"] in ("rx", "drop")
                      and r.get("reason") not in ("range", "nopose", "fifo", "retry") and r["t"] <= t)[-20:]
        want = 1 - sum(d for _, d in outs) / len(outs)
        got = b.js(f"return uwsimnetView.link('{tx}', '{rx}')")
        assert got["by"] == "measured" and got["measured"]["n"] == len(outs) == 20, (tx, rx, got)
        assert got["value"] == pytest.approx(want, abs=1e-12), (tx, rx, got, want)
    # over the whole run the loss measured on the 600 m link is the model's 0.75 (collisions aside)
    outs = [r for r in run["recs"] if r["dev"] == "alpha-m" and r["src"] == 4 and r["ev"] in ("rx", "drop")]
    prop = sum(r.get("reason") == "prop" for r in outs) / sum(r.get("reason") in ("prop", None) for r in outs)
    assert prop == pytest.approx(0.75, abs=0.12)


SHADOW = Path(__file__).resolve().parent / "data" / "ocean-shadow.xml"
LINK_PIXEL = """const m = document.getElementById('map'), c = m.getContext('2d');
const a = uwsimnetView.pixel('buoy'), b = uwsimnetView.pixel('auv'), L = Math.hypot(b[0] - a[0], b[1] - a[1]);
const nx = -(b[1] - a[1]) / L * 2, ny = (b[0] - a[0]) / L * 2, out = [];
for (const f of [0.3, 0.4, 0.6, 0.7]) {
  const x = Math.round(a[0] + (b[0] - a[0]) * f + nx), y = Math.round(a[1] + (b[1] - a[1]) * f + ny);
  const d = c.getImageData(x, y, 1, 1).data;
  out.push([d[0], d[1], d[2]]);
}
return out;"""


def _click_link(b, tmp_path, recs: list[dict], t: float) -> None:
    """A click on the buoy -> AUV line shows the link: Bellhop's level (184 dB source level minus the shipped
    grid's TL at 10 m / 20 m / 1000 m) and the trace's outcomes up to t."""
    from uwsimnet_zenoh.phy import bellhop

    x, y = b.js("""const m = document.getElementById('map'), r = m.getBoundingClientRect();
        const a = uwsimnetView.pixel('buoy'), c = uwsimnetView.pixel('auv'), L = Math.hypot(c[0] - a[0], c[1] - a[1]);
        const px = a[0] + (c[0] - a[0]) * 0.35 - (c[1] - a[1]) / L * 2;
        const py = a[1] + (c[1] - a[1]) * 0.35 + (c[0] - a[0]) / L * 2;
        return [r.left + px * r.width / m.width, r.top + py * r.height / m.height];""")
    b.click_at(x, y)
    detail = b.wait("const d = document.getElementById('detail').textContent; return d.startsWith('link ') && d",
                    what="the link's details")
    assert detail.startswith(f"link buoy-modem → auv-modem at t = {t:.3f} s, 1000.0 m"), detail
    grid = bellhop.Grid.load(next((SHADOW.parent / "bellhop").glob("*.npz")))
    tl = float(grid.lookup([10.0], [20.0], [1000.0])[0][0])
    level = float(detail.split("received level ")[1].split(" dB")[0])
    assert level == pytest.approx(184.0 - tl, abs=0.06), (level, 184.0 - tl)
    assert "modelled PER (frame of " in detail and ": 1.000 at both ends' positions" in detail, detail
    n = sum(r["dev"] == "auv-modem" and r["ev"] in ("rx", "drop") and r["src"] == 1 and r["t"] <= t for r in recs)
    assert f"measured loss: 1.000 (0 of the last {n} delivered)" in detail and f"outcomes up to t: prop {n}" in detail


@needs_browser
def test_a_bellhop_shadow_zone_colours_the_link_red_until_the_dive(browser, tmp_path, monkeypatch):  # noqa: F811
    """tests/data/ocean-shadow.xml with the grid Bellhop made (shipped): the AUV 1000 m away at 20 m depth is in
    the thermocline's shadow until t = 60 s, then dives to 100 m by t = 90 s.  The link's colour is the
    channel model's PER at both ends' positions (not a range curve: the range never changes), and the trace
    of the run agrees: every frame lost while shallow, every frame delivered once deep."""
    monkeypatch.setenv("UWSIMNET_CACHE", str(SHADOW.parent))
    monkeypatch.setenv("UWSIMNET_BELLHOP", "/nonexistent/bellhop")    # the shipped grid, not the program
    trace = tmp_path / "shadow.jsonl"
    run_virtual(load_scene_file(str(SHADOW)), seed=3, duration=200.0, trace_path=trace, progress=False)
    recs = [r for r in map(json.loads, trace.read_text().splitlines()) if r["ev"] in ("enq", "tx", "rx", "drop")]
    tx = {r["seq"]: r["t"] for r in recs if r["ev"] == "tx" and r["dev"] == "buoy-modem"}
    at_auv = {tx[r["seq"]]: r.get("reason", "rx") for r in recs if r["dev"] == "auv-modem" and r["ev"] != "enq"
              and r["src"] == 1}
    assert {o for t, o in at_auv.items() if t < 60} == {"prop"} and {o for t, o in at_auv.items() if t > 90} == {"rx"}
    view = Proc([*UWSIMNET, "view", str(trace), "--scene", str(SHADOW), "--port", "0"], tmp_path / "view.log")
    try:
        url = view.wait_for("http://").split("uwsimnet view: ")[1].split()[0]
        browser.get(url)
        browser.wait("return window.uwsimnetView && uwsimnetView.ready", what="page ready")
        assert browser.js("return document.getElementById('linkby').value") == "model"
        seen = {}
        for t in (30.0, 150.0):
            browser.js(f"uwsimnetView.setTime({t})")
            browser.wait(f"return document.getElementById('clock').textContent === 't = {t:.3f} s'", what=f"t {t}")
            seen[t] = browser.js("return uwsimnetView.link('buoy-modem', 'auv-modem')")
            px = browser.js(LINK_PIXEL)
            red = sum(p[0] > p[1] + 60 for p in px)
            green = sum(p[1] > p[0] + 60 for p in px)
            assert (red, green) == ((len(px), 0) if t < 60 else (0, len(px))), (t, px)
            if t < 60:
                shot(browser, tmp_path, "view-shadow.png")
                _click_link(browser, tmp_path, recs, t)
        assert seen[30.0]["value"] == pytest.approx(1.0, abs=1e-6)
        assert seen[150.0]["value"] == pytest.approx(0.0, abs=1e-6)
        # the loss measured in the trace says the same over the last 20 frames (30 s before and after)
        for t, want in ((58.0, 1.0), (199.0, 0.0)):
            browser.js(f"uwsimnetView.setTime({t})")
            m = browser.js("return uwsimnetView.link('buoy-modem', 'auv-modem').measured")
            assert m["loss"] == want and m["n"] >= 20, (t, m)
    finally:
        assert view.stop() == 0, view.text()


def test_the_document_of_a_geometry_model_has_its_per_along_the_paths_not_a_range_curve(monkeypatch):
    """ocean-shadow with Bellhop: no PER-vs-range curve (the range is 1000 m throughout while the PER goes from
    1 to 0), and the series says what the trace's outcomes are at every frame's send time outside the dive."""
    import bisect

    from uwsimnet_zenoh.engine.network import Network
    from uwsimnet_zenoh.scene import load_scene
    from uwsimnet_zenoh.view.state import replay_document

    monkeypatch.setenv("UWSIMNET_CACHE", str(SHADOW.parent))
    monkeypatch.setenv("UWSIMNET_BELLHOP", "/nonexistent/bellhop")
    scene = load_scene(SHADOW)
    net = Network(scene)
    recs: list[dict] = []
    net.tracer.add(recs.append)
    net.run()
    doc = replay_document({"ev": "meta", "scene": "shadow"}, iter(recs), scene)
    d = doc["devices"]["buoy-modem"]
    assert d["per"] is None and set(d["links"]) == {"auv-modem"}
    series = d["links"]["auv-modem"]
    assert [s[0] for s in series] == sorted(s[0] for s in series) and series[-1][0] == scene.end_time()
    tx = {r["seq"]: r["t"] for r in recs if r["ev"] == "tx" and r["dev"] == "buoy-modem"}
    checked = 0
    for r in recs:
        if r["dev"] == "auv-modem" and r["ev"] in ("rx", "drop") and not 60 <= tx[r["seq"]] <= 90:
            s = series[bisect.bisect_right([x[0] for x in series], tx[r["seq"]]) - 1]
            assert s[1] == (0.0 if r["ev"] == "rx" else 1.0), (r, s)
            checked += 1
    assert checked == 84
    assert 90 < series[-1][2] < 130 and series[0][2] < series[-1][2]       # levels in dB re 1 uPa: shadow lower


DOPPLER = """<?xml version="1.0"?>
<UWSimScene>
  <simulation><seed>2</seed><duration>200</duration></simulation>
  <CustomCommsChannel><id>0</id><propTimeIncPerMeter>0.6667</propTimeIncPerMeter>
    <channelModel><name>ocean</name><dopplerTolerance>1</dopplerTolerance></channelModel></CustomCommsChannel>
  <vehicle><name>alpha</name><position>0 0 -10</position>
    <CustomCommsDevice><dccommsId>alpha-m</dccommsId><mac>1</mac><txChannelId>0</txChannelId><rxChannelId>0</rxChannelId>
      <bitrate>2000</bitrate><txFifoSize>2000</txFifoSize>
      <rateErrorModel><errorUnit>packet</errorUnit><errorRateExpr>0</errorRateExpr></rateErrorModel>
    </CustomCommsDevice></vehicle>
  <vehicle><name>bravo</name>
    <trajectory><waypoint t="0" x="500" y="0" z="-10"/><waypoint t="100" x="200" y="0" z="-10"/></trajectory>
    <CustomCommsDevice><dccommsId>bravo-m</dccommsId><mac>2</mac><txChannelId>0</txChannelId><rxChannelId>0</rxChannelId>
      <bitrate>2000</bitrate><txFifoSize>2000</txFifoSize>
      <rateErrorModel><errorUnit>packet</errorUnit><errorRateExpr>0</errorRateExpr></rateErrorModel>
    </CustomCommsDevice></vehicle>
  <flow><name>f</name><src>alpha-m</src><dst>2</dst><size>16</size><interval>2</interval><start>1</start></flow>
</UWSimScene>"""


def test_the_document_of_a_doppler_tolerance_uses_the_vehicles_velocities(tmp_path):
    """The `ocean` model with dopplerTolerance 1 m/s: bravo closes at 3 m/s until t = 100 s, then holds.  The
    link's modelled PER is 1 while it moves (3 > 1 m/s: lost whatever the distance) and 0 once it is still; the
    view asks the model with the run's velocities, and the trace's outcomes agree at every frame."""
    import bisect

    from uwsimnet_zenoh.engine.network import Network
    from uwsimnet_zenoh.scene import load_scene_text
    from uwsimnet_zenoh.view.state import replay_document

    scene = load_scene_text(DOPPLER, str(tmp_path / "doppler.xml"))
    net = Network(scene)
    recs: list[dict] = []
    net.tracer.add(recs.append)
    net.run()
    doc = replay_document({"ev": "meta"}, iter(recs), scene)
    series = doc["devices"]["alpha-m"]["links"]["bravo-m"]
    assert doc["devices"]["alpha-m"]["per"] is None
    tx = {r["seq"]: r["t"] for r in recs if r["ev"] == "tx" and r["dev"] == "alpha-m" and r["kind"] == "data"}
    outs = {tx[r["seq"]]: r["ev"] for r in recs if r["dev"] == "bravo-m" and r["ev"] in ("rx", "drop")
            and r["kind"] == "data"}
    assert {o for t, o in outs.items() if t < 99} == {"drop"} and {o for t, o in outs.items() if t > 100} == {"rx"}
    times = [s[0] for s in series]
    for t, o in outs.items():
        if not 99 <= t <= 100:
            assert series[bisect.bisect_right(times, t) - 1][1] == (1.0 if o == "drop" else 0.0), (t, o)
    assert len(outs) == 100
