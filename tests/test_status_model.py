"""The status model (docs/gli-protocol.md, status): every frame a sender offers ends in exactly one final
status - `sent` when nothing acknowledges it, `acked`/`failed` when the MAC does, `dropped` when it is
never sent - and nothing follows the final one.  Checked on contended, lossy networks for every MAC."""

from __future__ import annotations

import re
import subprocess
import sys
from collections import defaultdict

import pytest
from conftest import Recorded
from test_mac import net3
from uwsimnet_gli.wire import FINAL_EVENTS, STATUS_EVENTS, CodecError, decode_status, encode_status

from uwsimnet_zenoh.scene.model import Flow
from uwsimnet_zenoh.trace.tracer import STATUSES, Callback

CASES = [
    ("none", {}, False),
    ("aloha", {"maxDistance": "300", "maxRetries": "2"}, True),
    ("aloha", {"maxDistance": "300", "ack": "0"}, False),
    ("slotted-aloha", {"maxDistance": "300", "maxRetries": "2"}, True),
    ("sfama", {"maxDistance": "300", "maxRetries": "2"}, True),
]


def flows(dst_b: int) -> list[Flow]:
    return [Flow(name="ab", src="a", dst=dst_b, size=40, interval=0.7, arrival="poisson"),
            Flow(name="ba", src="b", dst=1, size=40, interval=0.9, arrival="poisson"),
            Flow(name="cb", src="c", dst=255, size=20, interval=1.3, arrival="poisson")]


def record(rec: Recorded) -> dict[tuple[str, int], list[str]]:
    out: dict[tuple[str, int], list[str]] = defaultdict(list)
    rec.net.tracer.listen(Callback(lambda t, ev, ch, dev, f, *_: out[(dev, f.seq)].append(ev)
                                   if ev in STATUSES else None), statuses=True)
    return out


@pytest.mark.parametrize("mac,params,acks", CASES)
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_every_frame_ends_in_exactly_one_final_status(mac, params, acks, seed):
    rec = net3(mac, params, duration=60.0, seed=seed, b_kw={"error": "0.3"}, flows=flows(2))
    st = record(rec)
    rec.run()
    assert st, "no traffic"
    finals = defaultdict(int)
    for (dev, seq), evs in st.items():
        assert evs[0] == "queued" or evs == ["dropped"], (dev, seq, evs)
        last = evs[-1]
        in_flight = last in ("queued", "transmitted")     # the run ended first
        n_final = sum(e in FINAL_EVENTS for e in evs)
        assert n_final == (0 if in_flight else 1), (dev, seq, evs)
        assert in_flight or last in FINAL_EVENTS, (dev, seq, evs)
        if "transmitted" in evs:                           # an acknowledged frame never says sent
            assert acks and "sent" not in evs and last in ("transmitted", "acked", "failed", "dropped"), evs
        if "sent" in evs:
            assert not acks or dev == "c", (dev, seq, evs)    # only unacknowledged frames (c broadcasts)
        finals[last] += 1
    if acks:
        assert finals["acked"] > 0 and finals["failed"] + finals["acked"] > 0
    else:
        assert finals["sent"] > 0 and finals["acked"] == finals["failed"] == 0


def test_a_frame_given_up_ends_failed_once_not_dropped_too():
    rec = net3("aloha", {"maxDistance": "300", "maxRetries": "1"}, b_kw={"error": "1"})
    st = record(rec)
    rec.net.sched.at(1.0, lambda: rec.net.modems["a"].send(2, 25))
    rec.run()
    assert st[("a", 0)] == ["queued", "transmitted", "transmitted", "failed"]
    (drop,) = [r for r in rec.records if r["ev"] == "drop" and r["dev"] == "a" and r["kind"] == "data"]
    assert drop["reason"] == "retry"           # the trace keeps why


def test_wire_knows_transmitted_as_a_non_final_event():
    assert "transmitted" in STATUS_EVENTS and "transmitted" not in FINAL_EVENTS
    assert set(FINAL_EVENTS) == {"sent", "acked", "failed", "dropped"}
    assert decode_status(encode_status(3, "transmitted", None, 1.0, 0)).event == "transmitted"
    with pytest.raises(CodecError):
        decode_status(encode_status(3, "bogus", None, 1.0))


# -- over Zenoh: the broker, the client library and `gli send --wait` ----------------------------
ACK_SCENE = """<?xml version="1.0"?>
<UWSimScene>
  <simulation><seed>1</seed><clock>realtime</clock><world>acks</world></simulation>
  <CustomCommsChannel><id>0</id><propTimeIncPerMeter>0.6667</propTimeIncPerMeter></CustomCommsChannel>
  {vehicles}
</UWSimScene>"""


def ack_device(dev: str, mac: int) -> str:
    return (f"<CustomCommsDevice><dccommsId>{dev}</dccommsId><mac>{mac}</mac><txChannelId>0</txChannelId>"
            "<rxChannelId>0</rxChannelId><bitrate>10000</bitrate><maxDistance>2000</maxDistance>"
            "<macProtocol><name>aloha</name><maxDistance>400</maxDistance></macProtocol></CustomCommsDevice>")


def gli(endpoint: str, *args: str, timeout: float = 30.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "uwsimnet_gli.cli", "-e", endpoint, "-w", "acks", *args],
                          capture_output=True, text=True, timeout=timeout)


def test_send_wait_and_the_client_wait_for_acked_and_unknown_replies_carry_the_tag(tmp_path):
    from test_broker_e2e import Broker
    from uwsimnet_gli import World
    from uwsimnet_gli.wire import encode_tx

    vehicles = "".join(f"<vehicle><name>{n}</name><position>{x} 0 0</position>{ack_device(f'{n}-m', a)}</vehicle>"
                       for n, x, a in (("alpha", 0, 1), ("bravo", 300, 2)))
    scene = tmp_path / "acks.xml"
    scene.write_text(ACK_SCENE.format(vehicles=vehicles))
    b = Broker(scene, tmp_path / "t.jsonl")
    try:
        g = gli(b.endpoint, "send", "alpha-m", "2", "hello", "--wait")
        assert g.returncode == 0, g.stdout + g.stderr
        assert re.search(r"^  acked at t=\d+\.\d+$", g.stdout, re.M), g.stdout     # not `sent`
        g = gli(b.endpoint, "send", "alpha-m", "255", "all", "--wait")              # broadcast: nobody acks
        assert g.returncode == 0 and re.search(r"^  sent at t=", g.stdout, re.M), g.stdout
        with World("acks", connect=b.endpoint) as w:
            m = w.modem("alpha-m")
            assert m.wait_kind(timeout=10) == "sim"
            tag = m.send(2, b"again")
            st = m.wait_status(tag, timeout=10)
            assert st is not None and st.event == "acked", m.statuses(tag)
            assert [s.event for s in m.statuses(tag)] == ["queued", "transmitted", "acked"]
            ghost = w.modem("ghost-m")                   # a mistyped id: the broker answers, with our tag
            w.session.put("uwsimnet/acks/modem/ghost-m/tx", encode_tx(2, b"x", 4242))
            st = ghost.wait_status(4242, timeout=10)
            assert st is not None and (st.event, st.reason) == ("dropped", "unknown")
        g = gli(b.endpoint, "send", "ghost-m", "2", "x", "--wait", "--timeout", "1")
        assert g.returncode == 1 and "  dropped (unknown)" in g.stdout, g.stdout + g.stderr
    finally:
        assert b.stop() == 0, b.output()
    assert "Traceback" not in b.output()
