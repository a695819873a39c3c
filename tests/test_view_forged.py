"""#41 live: a forger on the Zenoh wire (a real router session in this test) answers the world's control
`state`, `modem/*/info` and `pause`, declares a modem's driver token and puts clock, pose and trace samples
whose every string field is markup with script in it.  `uwsimnet view --connect` (a real process, its own
Zenoh client) serves the page and headless Chromium shows it: every forged string appears as text, no
script runs (no `window.__pwned`), no element or inline handler is added, and the page keeps working.
"""

from __future__ import annotations

import json
import socket
import sys
import threading
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))
from test_view import UWSIMNET, WAIT, Proc, needs_browser  # noqa: E402
from test_view import browser as browser  # noqa: E402 - the module's browser fixture

zenoh = pytest.importorskip("zenoh")
wire = pytest.importorskip("uwsimnet_gli.wire")

WORLD = "forged"


def xss(field: str) -> str:
    """Markup that would run script (setting window.__pwned to the field's name) if inserted as HTML."""
    return f"<img src=x onerror=\"window.__pwned='{field}'\"><script>window.__pwned='{field}'</script>"


DEV, VEH = xss("dev"), xss("vehicle")
KEY_DEV = "<b>key-dev<b>"
"""A modem id in a key (a key chunk has no whitespace or '/': markup, but no script)."""
KEY_VEH = "<i>key-vehicle<i>"
PAGE_TAGS = {"html", "head", "meta", "title", "link", "body", "header", "span", "main", "section", "div", "canvas",
             "svg", "g", "line", "rect", "text", "label", "select", "option", "button", "input", "aside", "h2",
             "table", "thead", "tbody", "tr", "th", "td", "ol", "li", "pre", "script"}
"""Every element the page itself makes: anything else came from data."""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Forger:
    """A router session that plays a world with forged answers and samples (what an attacker's process on
    the network can do without any access control)."""

    def __init__(self, endpoint: str) -> None:
        conf = zenoh.Config()
        conf.insert_json5("mode", '"router"')
        conf.insert_json5("listen/endpoints", f'["{endpoint}"]')
        conf.insert_json5("scouting/multicast/enabled", "false")
        self.s = zenoh.open(conf)
        self.keys = wire.Keys(WORLD)
        self.stop = threading.Event()
        self.t = 0.0
        self.seq = 0
        self.benign: int | None = None
        modem = {"vehicle": VEH, "address": xss("address"), "tx_channel": xss("tx_channel"),
                 "rx_channel": xss("rx_channel"), "kind": xss("kind"), "mac": xss("mac"), "bitrate": xss("bitrate"),
                 "fifo_capacity": xss("fifo_capacity")}
        state = {"ok": True, "paused": False, "modems": {DEV: modem, "ok-m": {"vehicle": "okv", "address": 9,
                                                                             "tx_channel": 0, "rx_channel": 0}},
                 "vehicles": {VEH: {"source": xss("source")}, "okv": {"source": "zenoh"}}}
        self._held = [
            self.s.liveliness().declare_token(self.keys.driver(KEY_DEV, "sim")),
            self.s.declare_queryable(self.keys.control("state"),
                                     lambda q: self._reply(q, state, self.keys.control("state"))),
            self.s.declare_queryable(self.keys.control("pause"), lambda q: self._reply(
                q, {"ok": False, "error": xss("control error")}, self.keys.control("pause"))),
            self.s.declare_queryable(self.keys.info_all, lambda q: self._reply(
                q, {"id": DEV, **modem}, self.keys.info(KEY_DEV))),
        ]
        self.thread = threading.Thread(target=self._feed, daemon=True)
        self.thread.start()

    @staticmethod
    def _reply(q: zenoh.Query, m: dict, key: str) -> None:
        with q:
            q.reply(key, wire.pack(m))

    def _trace(self, **rec: object) -> None:
        self.s.put(self.keys.trace(0), wire.pack(rec))

    def _feed(self) -> None:
        """Every 0.1 s: the clock, poses, and a forged frame with its outcomes; a benign frame when asked."""
        while not self.stop.wait(0.1):
            self.t += 0.1
            t, n = round(self.t, 3), self.seq
            self.seq += 1
            self.s.put(self.keys.clock, wire.pack({"t": t, "paused": False, "speed": 1.0, "epoch": xss("epoch")}))
            self.s.put(self.keys.pose(KEY_VEH), wire.encode_pose((n % 7, 1.0, -2.0), t=t))
            common = {"src": 7, "dst": xss("dst"), "seq": n, "size": 12, "flow": xss("flow"), "kind": xss("kind ev"),
                      "ch": xss("ch")}
            self._trace(t=t, ev="tx", dev=DEV, fifo=0, **common)
            self._trace(t=t + 0.01, ev="drop", dev="ok-m", reason=xss("reason"), dist=xss("dist"), **common)
            self._trace(t=t + 0.02, ev="rx", dev=KEY_DEV, **common)
            if self.benign is not None:
                b = {"src": 9, "dst": 255, "seq": self.benign, "size": 10, "flow": None, "kind": "data", "ch": 0}
                self._trace(t=t, ev="tx", dev="ok-m", **b)
                self._trace(t=t + 0.03, ev="rx", dev=KEY_DEV, **b)
                self.benign += 1

    def close(self) -> None:
        self.stop.set()
        self.thread.join(5)
        for h in self._held:
            h.undeclare()
        self.s.close()


SHOWN = ("return [...document.querySelectorAll('body *')].filter(e => e.id !== 'detail')"
         ".map(e => e.textContent).join('\\n')")
NOT_PAGE = """const tags = new Set(arguments[0]);
return [...document.querySelectorAll('*')].filter(e => !tags.has(e.localName)).map(e => e.outerHTML.slice(0, 80))
  .concat([...document.querySelectorAll('*')].flatMap(e => [...e.attributes].filter(a => a.name.startsWith('on'))
  .map(a => e.localName + ' ' + a.name)))
  .concat([...document.scripts].map(s => s.getAttribute('src'))
  .filter(s => !/^static\\/(lib|labels|view)\\.js$/.test(s)));"""


@needs_browser
def test_forged_live_samples_are_shown_as_text_and_run_nothing(browser, tmp_path):
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    forger = Forger(endpoint)
    view = None
    try:
        view = Proc([*UWSIMNET, "view", "--connect", endpoint, "--world", WORLD, "--port", "0", "--wait", "20"],
                    tmp_path / "view.log")
        url = view.wait_for("http://").split("uwsimnet view: ")[1].split()[0]
        browser.get(url)
        browser.js("window.__errors = []; "
                   "window.addEventListener('error', e => window.__errors.push(String(e.message)))")
        browser.wait("return window.uwsimnetView && uwsimnetView.ready && uwsimnetView.modems() >= 3 && "
                     "document.querySelector('#frames li')", timeout=WAIT, what="the forged modems and frames")
        browser.wait(f"return document.getElementById('modems').textContent.includes({xss('kind')!r})",
                     what="the forged kind in the table")
        # the forged modem's details (a click on its row), a step to an event, Pause (a forged refusal)
        browser.js("[...document.querySelectorAll('#modems tbody tr')].find(r => r.dataset.dev === arguments[0])"
                   ".click()", DEV)
        detail = browser.wait("const d = document.getElementById('detail').textContent; "
                              "return d.includes('address') && d", what="the forged modem's details")
        for f in ("dev", "vehicle", "address", "mac", "bitrate", "tx_channel", "rx_channel", "kind"):
            assert xss(f) in detail, (f, detail)
        browser.wait("return !document.getElementById('pause').disabled", what="control (forged) allowed")
        browser.click("#pause")
        browser.wait(f"return document.getElementById('ctlmsg').textContent === {xss('control error')!r}",
                     what="the forged refusal as text")
        browser.js("uwsimnetView.setTime(Math.max(0, uwsimnetView.T - 0.05))")
        browser.click("#next")
        step = browser.wait("return document.getElementById('stepinfo').textContent", what="a stepped event")
        assert any(x in step for x in (DEV, KEY_DEV, "ok-m")), step
        shown = browser.wait(f"const s = (() => {{ {SHOWN} }})(); return s.includes({xss('reason')!r}) && s",
                             what="the forged outcome in the list")
        for f in ("dev", "dst", "kind ev", "reason"):
            assert xss(f) in shown, f
        assert KEY_DEV in shown and KEY_VEH in shown
        # the frames filter offers the forged id as an option (text), and filtering by it works
        browser.js("const s = document.getElementById('fdev'); s.value = arguments[0]; "
                   "s.dispatchEvent(new Event('change'))", DEV)
        assert browser.js("return document.getElementById('fdev').value") == DEV
        other = browser.wait(f"const l = [...document.querySelectorAll('#frames li')]; return l.length && "
                             f"l.every(li => li.dataset.dev === {json.dumps(DEV)}) && l.length",
                             what="only the forged modem's frames")
        assert other >= 1
        # nothing ran, nothing was added
        assert browser.js("return window.__pwned === undefined")
        assert browser.js(NOT_PAGE, sorted(PAGE_TAGS)) == []
        assert browser.js("return document.querySelectorAll('img, iframe, object, embed, b, i').length") == 0
        # and the page keeps working: a benign frame sent now shows, done, and time moves
        browser.js("const s = document.getElementById('fdev'); s.value = ''; s.dispatchEvent(new Event('change'))")
        browser.click("#follow")                     # back to now (the step above left the time behind)
        forger.benign = 1000
        browser.wait("return (f => f && f.state === 'done')(uwsimnetView.frame('ok-m', 1002, 'data'))",
                     what="a benign frame after the forged ones")
        t0 = browser.js("return uwsimnetView.T")
        browser.wait(f"return uwsimnetView.T > {t0} + 0.3", what="time moves")
        assert browser.js("return window.__errors") == []
        assert browser.js("return window.__pwned === undefined")
    finally:
        if view is not None:
            assert view.stop() == 0, view.text()
            assert "Traceback" not in view.text(), view.text()
        forger.close()
