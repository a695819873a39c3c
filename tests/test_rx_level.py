"""The rx record says the received level the channel model computed (issue #35, left over): `level`, dB re
1 uPa, to 3 decimals as `dist`.

The run is the real `uwsimnet run --trace` process on a scene file of still acoustic modems (the `acoustic`
model, the default of an `AcousticCommsDevice`); every rx and receiver-side drop record's `level` is checked
against the published passive sonar terms computed here from the scene's positions, independently of the
model's code: RL = SL - TL, TL = k 10 log10(d) + a(f) d / 1000 with Thorp's a(f) in dB/km (Thorp 1967, the
form of Urick, "Principles of Underwater Sound", and ns-3's UanPropModelThorp) for f >= 0.4 kHz."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import pytest

from uwsimnet_zenoh.analysis.read import read_trace

SL, F_KHZ, K = 180.0, 25.0, 1.5
BUOY = (0.0, 0.0, 0.0)
AUVS = {"a1": (2, (300.0, 0.0, -20.0)), "a2": (3, (0.0, 1200.0, -35.0)), "a3": (4, (-2500.0, 1700.0, -60.0))}


def device(name: str, addr: int) -> str:
    return (f"<AcousticCommsDevice><dccommsId>{name}</dccommsId><mac>{addr}</mac><txChannelId>0</txChannelId>"
            f"<rxChannelId>0</rxChannelId><preset>evologics-s2cr-18-34</preset><frequency>{F_KHZ}</frequency>"
            f"<sourceLevel>{SL}</sourceLevel><maxDistance>10000</maxDistance></AcousticCommsDevice>")


def scene_text(channel: str = "<absorption>thorp</absorption>") -> str:
    vehicles = f"<vehicle><name>buoy</name><position>0 0 0</position>{device('buoy', 1)}</vehicle>"
    for name, (addr, p) in AUVS.items():
        vehicles += (f"<vehicle><name>{name}</name><position>{p[0]} {p[1]} {p[2]}</position>"
                     f"{device(name, addr)}</vehicle>")
    flows = "".join(f"<flow><name>{n}</name><src>{n}</src><dst>1</dst><size>64</size><interval>{7 + i}</interval>"
                    f"<start>{i}</start></flow>" for i, n in enumerate(AUVS))
    return ('<?xml version="1.0"?><UWSimScene><simulation><duration>200</duration></simulation>'
            f"<AcousticCommsChannel><id>0</id><spreading>{K}</spreading>{channel}</AcousticCommsChannel>"
            + vehicles + flows +
            "<flow><name>bc</name><src>buoy</src><dst>255</dst><size>32</size><interval>13</interval></flow>"
            "</UWSimScene>")


def thorp_db_per_km(f: float) -> float:
    f2 = f * f
    return 0.11 * f2 / (1 + f2) + 44 * f2 / (4100 + f2) + 2.75e-4 * f2 + 0.003


def received_level(d: float) -> float:
    return SL - (K * 10 * math.log10(d) + thorp_db_per_km(F_KHZ) * d / 1000)


def cli(*args: str) -> str:
    r = subprocess.run([sys.executable, "-m", "uwsimnet_zenoh.cli", *args], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr
    return r.stdout


def run(tmp_path, suffix: str) -> list[dict]:
    sc = tmp_path / "still.xml"
    sc.write_text(scene_text())
    out = tmp_path / f"still{suffix}"
    cli("run", str(sc), "--trace", str(out))
    return list(read_trace(out)[1])


def test_rx_and_drop_records_carry_sl_minus_tl_of_their_distance(tmp_path):
    recs = run(tmp_path, ".jsonl")
    where = {"buoy": BUOY} | {n: p for n, (_, p) in AUVS.items()}
    by_addr = {1: "buoy"} | {addr: n for n, (addr, _) in AUVS.items()}
    heard = [r for r in recs if r["ev"] == "rx" or (r["ev"] == "drop" and "dist" in r)]
    assert sum(r["ev"] == "rx" for r in heard) >= 50
    assert {r["reason"] for r in heard if r["ev"] == "drop"} >= {"prop"}    # a3, 3 km away, loses some
    links = set()
    for r in heard:
        d = math.dist(where[r["dev"]], where[by_addr[r["src"]]])
        assert r["dist"] == round(d, 3)
        assert abs(r["level"] - received_level(d)) <= 0.0005 + 1e-9, (r, received_level(d))
        assert r["level"] == round(r["level"], 3)
        links.add((r["src"], r["dev"]))
    both_ways = {(1, n) for n in AUVS} | {(a, "buoy") for a, _ in AUVS.values()}
    assert links >= both_ways and len({r["level"] for r in heard}) >= 3     # implicit rx at the others too
    assert all("level" not in r for r in recs if r["ev"] in ("enq", "tx"))
    assert all("doppler" not in r for r in recs)        # the acoustic model gives no Doppler factor


def test_the_columnar_trace_says_the_same_levels(tmp_path):
    pytest.importorskip("pyarrow")
    jsonl = run(tmp_path, ".jsonl")
    arrow = run(tmp_path, ".arrow")
    assert arrow == jsonl and sum("level" in r for r in arrow) >= 50


def test_a_model_without_a_level_writes_no_level(tmp_path):
    """The ocean model gives a Doppler factor and no level; a CustomCommsDevice's rateErrorModel gives neither."""
    from tests.test_rx_details import scene_text as moving  # noqa: PLC0415 - the ocean scene of #35

    for text in (moving("none"), moving("none").replace("<channelModel><name>ocean</name></channelModel>", "")):
        sc = tmp_path / "m.xml"
        sc.write_text(text)
        out = tmp_path / "m.jsonl"
        cli("run", str(sc), "--trace", str(out))
        lines = out.read_text().splitlines()[1:]
        assert sum('"ev":"rx"' in ln for ln in lines) >= 14
        assert all("level" not in json.loads(ln) for ln in lines)
        assert "links" not in json.loads(cli("report", "--json", str(out)))   # and the report has no column
        assert "level dB" not in cli("report", str(out))


@pytest.mark.parametrize("suffix", [".jsonl", ".arrow"])
def test_the_report_gives_the_mean_received_level_per_link(tmp_path, suffix):
    if suffix == ".arrow":
        pytest.importorskip("pyarrow")
    sc = tmp_path / "still.xml"
    sc.write_text(scene_text())
    out = tmp_path / f"still{suffix}"
    cli("run", str(sc), "--trace", str(out))
    links = json.loads(cli("report", "--json", str(out)))["links"]
    where = {"buoy": BUOY} | {n: p for n, (_, p) in AUVS.items()}
    rx = [r for r in read_trace(out)[1] if r["ev"] == "rx"]
    assert len(links) >= 6 and sum(x["received"] for x in links) == len(rx)
    for x in links:         # still ends: every frame of a link at one distance, one level
        n = sum(r["dev"] == x["dev"] and r["src"] == AUVS.get(x["src"], (1,))[0] for r in rx)
        expect = received_level(math.dist(where[x["src"]], where[x["dev"]]))
        assert x["received"] == n and abs(x["mean_db"] - expect) <= 0.0005 + 1e-9, (x, expect)
        assert x["min_db"] <= x["mean_db"] <= x["max_db"]
    assert "level dB" in cli("report", str(out))
