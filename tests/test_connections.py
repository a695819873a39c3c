"""bus/connections.py: the broker knows when Zenoh cut an app off and let it back in (#36, docs/runtime.md)."""

from __future__ import annotations

import logging
import signal
import sys
import time

from test_broker_e2e import Proc, free_port, procs  # noqa: F401 - procs is a fixture

from uwsimnet_zenoh.bus.connections import KEEP, Connections
from uwsimnet_zenoh.bus.session import make_config, open_raw

CLIENT = """
import json, sys, time
import zenoh
conf = zenoh.Config()
conf.insert_json5("mode", '"client"')
conf.insert_json5("connect/endpoints", json.dumps([sys.argv[1]]))
conf.insert_json5("transport/link/tx/lease", "1000")    # the router drops it 1 s after it stops
with zenoh.open(conf) as s:
    print("ready", s.zid(), flush=True)
    for _ in sys.stdin:
        pass
"""


def test_a_close_then_an_open_of_the_same_zid_is_a_cut_off_and_a_close_alone_is_not(caplog):
    t = [0.0]
    c = Connections(lambda: t[0])
    with caplog.at_level(logging.INFO, logger="uwsimnet.bus.connections"):
        c.note("aa", "client", False, 0.5, 100.0)          # opened: nothing to say
        c.note("aa", "client", True, 2.0, 101.5)           # closed ...
        c.note("bb", "client", True, 2.5, 102.0)           # (another one leaves for good)
        c.note("aa", "client", False, 6.25, 105.75)        # ... and back
    assert c.summary() == [{"zid": "aa", "whatami": "client", "t": 2.0, "back": 6.25, "s": 4.25},
                           {"zid": "bb", "whatami": "client", "t": 2.5}]
    assert c.cut_off() == [c.summary()[0]]
    warned = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert warned == ["client aa was cut off for 4.2 s (t=2.000..6.250 s) and is back: Zenoh closed its"
                      " connection (it did not read for the router's wait_before_close, or its lease ran out);"
                      " what was put for it in that time is lost"]
    c.note("aa", "client", True, 7.0, 106.0)               # a second cut is a second entry
    c.note("aa", "client", False, 8.0, 107.0)
    assert [e.get("back") for e in c.summary()] == [6.25, None, 8.0]


def test_the_list_is_bounded_and_what_is_past_it_counted():
    c = Connections(lambda: 0.0)
    for i in range(KEEP + 5):
        c.note(f"z{i}", "client", True, float(i), float(i))
    assert len(c.summary()) == KEEP and c.dropped == 5
    c.note("z3", "client", False, 9.0, 9.0)                # listed: its return is noted
    c.note(f"z{KEEP + 2}", "client", False, 9.0, 9.0)      # not listed: nothing to update, no error
    assert c.summary()[3]["back"] == 9.0


def test_a_router_sees_a_stopped_client_cut_off_by_its_lease_and_back_after_it_resumes(procs, tmp_path):  # noqa: F811
    """Real Zenoh: a client with a 1 s lease, SIGSTOPped, is closed by the router; resumed, it connects again
    with the same ZenohId: one `disconnected` entry, with `back`."""
    ep = f"tcp/127.0.0.1:{free_port()}"
    t0 = time.monotonic()
    c = Connections(lambda: time.monotonic() - t0)
    with open_raw(make_config("router", listen=[ep])) as router:
        c.start(router)
        (tmp_path / "client.py").write_text(CLIENT)
        client = Proc([sys.executable, str(tmp_path / "client.py"), ep], stdin=True)
        procs.append(client)
        word, zid = client.next_line(20).split()
        assert word == "ready"
        client.p.send_signal(signal.SIGSTOP)
        try:
            deadline = time.monotonic() + 20
            while not any(e["zid"] == zid for e in c.summary()):      # its lease runs out at the router
                time.sleep(0.05)
                assert time.monotonic() < deadline, c.summary()
            assert c.cut_off() == []                                    # gone, not (yet) back
        finally:
            client.p.send_signal(signal.SIGCONT)
        while not c.cut_off():                                          # it connects again
            time.sleep(0.05)
            assert time.monotonic() < deadline, c.summary()
        c.close()
    [cut] = [e for e in c.cut_off() if e["zid"] == zid]
    assert cut["whatami"] == "client"
    assert 0.0 < cut["t"] < cut["back"] and 0.0 < cut["s"] < 20, cut
