"""The rx event carries its channel details (issue #35 item 1, #37): the MAC gets the reception with the frame
and hands it back, and the trace's rx record says the channel model's Doppler factor.

The run is the real `uwsimnet run --trace` process on a scene file with two vehicles moving on straight
waypoint legs under the `ocean` model; each rx record's `doppler` is checked against the classical
moving-source, moving-receiver formula computed here from the scene's waypoints (velocity = leg / time), the
arrival solved by bisection, independently of the model's own code."""

from __future__ import annotations

import json
import math
import pickle
import subprocess
import sys

import pytest

from uwsimnet_zenoh.analysis.read import read_trace
from uwsimnet_zenoh.kernel.rx import Rx, doppler, level_db, with_details
from uwsimnet_zenoh.mac import testing

PER_M_MS = 0.6666666666666666          # propTimeIncPerMeter, ms per m
C = 1.0 / (PER_M_MS / 1000.0)          # the channel's sound speed (no <environment>): 1 / prop_s_per_m
LEGS = {                               # vehicle -> (address, (t, x, y, z) at both ends of its one leg)
    "a": (1, (0.0, 0.0, 0.0, -10.0), (100.0, 300.0, 400.0, -10.0)),
    "b": (2, (0.0, 800.0, 600.0, -60.0), (100.0, -200.0, 600.0, -260.0)),    # passes a at t ~ 62 s
}


def scene_text(mac: str) -> str:
    def vehicle(name: str) -> str:
        addr, (t0, *p0), (t1, *p1) = LEGS[name]
        return (f"<vehicle><name>{name}</name><trajectory>"
                f'<waypoint t="{t0}" x="{p0[0]}" y="{p0[1]}" z="{p0[2]}"/>'
                f'<waypoint t="{t1}" x="{p1[0]}" y="{p1[1]}" z="{p1[2]}"/></trajectory>'
                f"<CustomCommsDevice><dccommsId>{name}</dccommsId><mac>{addr}</mac><txChannelId>0</txChannelId>"
                "<rxChannelId>0</rxChannelId><maxDistance>100000</maxDistance><rateErrorModel><errorUnit>packet"
                "</errorUnit><errorRateExpr>0</errorRateExpr></rateErrorModel>"
                f"<macProtocol><name>{mac}</name></macProtocol></CustomCommsDevice></vehicle>")

    return ('<?xml version="1.0"?><UWSimScene><simulation><duration>90</duration></simulation>'
            f"<CustomCommsChannel><id>0</id><propTimeIncPerMeter>{PER_M_MS!r}</propTimeIncPerMeter>"
            "<minPropTime>0</minPropTime><channelModel><name>ocean</name></channelModel></CustomCommsChannel>"
            + vehicle("a") + vehicle("b") +
            "<flow><name>ab</name><src>a</src><dst>2</dst><size>16</size><interval>9</interval><stop>80</stop></flow>"
            "<flow><name>ba</name><src>b</src><dst>1</dst><size>16</size><interval>11</interval><start>3</start>"
            "<stop>80</stop></flow></UWSimScene>")


def state(name: str, t: float) -> tuple[list[float], list[float]]:
    """Position and velocity of a vehicle at t, from its waypoints (inside its one leg)."""
    _, (t0, *p0), (t1, *p1) = LEGS[name]
    v = [(b - a) / (t1 - t0) for a, b in zip(p0, p1, strict=True)]
    return [a + w * (t - t0) for a, w in zip(p0, v, strict=True)], v


def arrival(ps: list[float], pr: list[float], vr: list[float]) -> float:
    """tau with |pr + vr tau - ps| = C tau, by bisection (the wavefront meets the moving receiver)."""
    lo, hi = 0.0, 100.0
    for _ in range(200):
        mid = (lo + hi) / 2
        gap = math.dist([p + v * mid for p, v in zip(pr, vr, strict=True)], ps) - C * mid
        lo, hi = (mid, hi) if gap > 0 else (lo, mid)
    return (lo + hi) / 2


def classical(sender: str, receiver: str, t0: float) -> float:
    """f_received / f_sent = (c - v_r.u) / (c - v_s.u), u from the sender at emission to the receiver at arrival."""
    ps, vs = state(sender, t0)
    pr, vr = state(receiver, t0)
    tau = arrival(ps, pr, vr)
    at = [p + v * tau for p, v in zip(pr, vr, strict=True)]
    n = math.dist(at, ps)
    u = [(a - b) / n for a, b in zip(at, ps, strict=True)]
    return (C - sum(a * b for a, b in zip(vr, u, strict=True))) / (C - sum(a * b for a, b in zip(vs, u, strict=True)))


def run(tmp_path, mac: str, suffix: str) -> list[dict]:
    sc = tmp_path / "moving.xml"
    sc.write_text(scene_text(mac))
    out = tmp_path / f"moving{suffix}"
    r = subprocess.run([sys.executable, "-m", "uwsimnet_zenoh.cli", "run", str(sc), "--trace", str(out)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    return list(read_trace(out)[1])


@pytest.mark.parametrize("mac", ["none", "aloha"])
def test_rx_records_carry_the_classical_doppler_factor_of_the_moving_ends(tmp_path, mac):
    recs = run(tmp_path, mac, ".jsonl")
    name = {addr: v for v, (addr, *_) in LEGS.items()}
    rx = [r for r in recs if r["ev"] == "rx"]
    kinds = {r["kind"] for r in rx}
    assert len(rx) >= 14 and kinds == ({"data", "ctrl"} if mac == "aloha" else {"data"})    # ACKs too
    for r in rx:
        sender = name[r["src"]]
        sent = [x["t"] for x in recs if x["ev"] == "tx" and x["dev"] == sender and x["seq"] == r["seq"]
                and x["flow"] == r["flow"] and x["kind"] == r["kind"] and x["t"] < r["t"]]
        expect = classical(sender, r["dev"], sent[-1])
        assert abs(r["doppler"] - expect) < 1e-9, (r, expect)
    # they close in at first (D > 1), then part (D < 1): both signs of the convention are in the run
    assert min(r["doppler"] for r in rx) < 1.0 < max(r["doppler"] for r in rx)
    assert all("doppler" not in r for r in recs if "dist" not in r)     # rx and receiver drops only


def test_the_columnar_trace_says_the_same_doppler(tmp_path):
    pytest.importorskip("pyarrow")
    jsonl = run(tmp_path, "aloha", ".jsonl")
    arrow = run(tmp_path, "aloha", ".arrow")
    assert arrow == jsonl and sum("doppler" in r for r in arrow) >= 14


def test_a_distance_only_model_hands_a_plain_distance_and_writes_no_doppler(tmp_path):
    sc = tmp_path / "still.xml"
    sc.write_text(scene_text("none").replace("<channelModel><name>ocean</name></channelModel>", ""))
    out = tmp_path / "still.jsonl"
    r = subprocess.run([sys.executable, "-m", "uwsimnet_zenoh.cli", "run", str(sc), "--trace", str(out)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    recs = [json.loads(line) for line in out.read_text().splitlines()[1:]]
    rx = [r for r in recs if r["ev"] == "rx"]
    assert rx and all("dist" in r and "doppler" not in r for r in rx)


@pytest.mark.parametrize("mac", ["none", "aloha", "sfama", "uwsimnet_zenoh.mac.examples:Tdma"])
def test_every_mac_hands_the_reception_back_unchanged(mac):
    h = testing.Harness(mac, address=1)
    rx = Rx(1234.5, 1.002, -87.5)
    f = h.from_peer(src=2, dst=1, size=20, seq=0)
    if mac == "sfama":
        h.mac.overhear_ends_round = False       # a data frame outside an RTS/CTS round is delivered
    h.receive(f, rx)
    assert ("deliver", f) in h.effects()
    assert h.ctx.delivered_rx == [rx] and h.ctx.delivered_rx[0] is rx


def test_rx_is_its_distance_with_details_and_immutable():
    rx = Rx(12.5, 0.999, -80.0)
    assert rx == 12.5 and float(rx) == 12.5 and rx.distance == 12.5 and round(rx, 1) == 12.5
    assert (doppler(rx), level_db(rx)) == (0.999, -80.0) and (doppler(12.5), level_db(12.5)) == (None, None)
    with pytest.raises(AttributeError):
        rx.doppler = 1.0  # type: ignore[misc]
    back = pickle.loads(pickle.dumps(rx))
    assert (float(back), back.doppler, back.level_db) == (12.5, 0.999, -80.0)
    assert type(with_details(3.0, None, math.nan)) is float and with_details(3.0, 1.0, None).doppler == 1.0
    assert json.dumps({"dist": rx}) == '{"dist": 12.5}'        # goes wherever the distance went

