"""`uwsimnet pcap`: every frame on air of a trace as a pcapng packet, read back (1) by a pcapng reader written
here from the pcapng specification and (2) by tshark with the shipped Lua dissector: packet count, interfaces,
timestamps and every header field equal to the trace."""

from __future__ import annotations

import json
import math
import shutil
import struct
import subprocess
import sys
from pathlib import Path

import pytest

from uwsimnet_zenoh.analysis.pcap import DISSECTOR
from uwsimnet_zenoh.app.virtual import load_scene_file, run_virtual

ROOT = Path(__file__).resolve().parents[1]
UWSIMNET = [sys.executable, "-m", "uwsimnet_zenoh.cli"]
SCENES = ("scenes/paper/twinbot-sfama.xml", "scenes/paper/phy-layer-rf.xml")   # MAC ctrl + col; prop + range


@pytest.fixture(scope="module", params=SCENES, ids=lambda s: Path(s).stem)
def trace(request, tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("pcap") / "trace.jsonl"
    run_virtual(load_scene_file(str(ROOT / request.param)), seed=1, duration=30.0, trace_path=path, progress=False)
    return path


def records(path: Path) -> list[dict]:
    return [r for r in map(json.loads, path.read_text().splitlines()) if r["ev"] != "meta"]


def expected(path: Path) -> list[dict]:
    """Per tx record: its fields and, per receiver, the outcome of that transmission (the receiver-side rx or
    drop of the same channel/src/seq/kind after it and before the next transmission of that key)."""
    recs = records(path)
    out = []
    for i, tx in enumerate(recs):
        if tx["ev"] != "tx":
            continue
        key = (tx["ch"], tx["src"], tx["seq"], tx["kind"])
        attempt = sum(1 for r in recs[:i] if r["ev"] == "tx" and (r["ch"], r["src"], r["seq"], r["kind"]) == key) + 1
        outcomes = {}
        for r in recs[i + 1:]:
            if (r["ch"], r["src"], r["seq"], r["kind"]) != key:
                continue
            if r["ev"] == "tx":
                break
            if r["ev"] in ("rx", "drop") and r["dev"] != tx["dev"]:
                outcomes[r["dev"]] = ("rx" if r["ev"] == "rx" else r["reason"], r["t"] - tx["t"], r.get("dist"))
        out.append({**tx, "attempt": attempt, "outcomes": outcomes})
    return out


def read_pcapng(data: bytes) -> tuple[list[dict], list[dict]]:
    """(interfaces, packets) of a little-endian pcapng file."""
    ifaces, pkts, off = [], [], 0
    while off < len(data):
        btype, blen = struct.unpack_from("<II", data, off)
        body = data[off + 8: off + blen - 4]
        assert struct.unpack_from("<I", data, off + blen - 4)[0] == blen
        if btype == 0x0A0D0D0A:
            assert struct.unpack_from("<I", body)[0] == 0x1A2B3C4D
        elif btype == 1:
            link, _, _ = struct.unpack_from("<HHI", body)
            opts, o = {}, 8
            while o < len(body):
                code, n = struct.unpack_from("<HH", body, o)
                if code == 0:
                    break
                opts[code] = body[o + 4: o + 4 + n]
                o += 4 + n + (-n % 4)
            ifaces.append({"link": link, "name": opts[2].decode(), "tsresol": opts[9][0]})
        elif btype == 6:
            iface, hi, lo, cap, orig = struct.unpack_from("<IIIII", body)
            pkts.append({"iface": iface, "ns": (hi << 32) | lo, "data": body[20: 20 + cap], "orig": orig})
        off += blen
    return ifaces, pkts


def parse_header(b: bytes) -> dict:
    """The link-layer header as docs/view.md lays it out."""
    assert b[:4] == b"UWSN"
    version, kind, hlen, ch, src, dst, attempt, seq, size = struct.unpack_from(">BBHHHHHII", b, 4)

    def s(o: int) -> tuple[str, int]:
        n = b[o]
        return b[o + 1: o + 1 + n].decode(), o + 1 + n

    txdev, o = s(24)
    flow, o = s(o)
    n, o = b[o], o + 1
    outs = {}
    for _ in range(n):
        dev, o = s(o)
        code = b[o]
        text, o = s(o + 1)
        delay, dist = struct.unpack_from(">df", b, o)
        o += 12
        outs[dev] = (code, text, delay, dist)
    assert o == hlen == len(b)
    return {"version": version, "kind": {0: "data", 1: "ctrl"}[kind], "ch": ch, "src": src, "dst": dst,
            "attempt": attempt, "seq": seq, "size": size, "dev": txdev, "flow": flow or None, "outcomes": outs}


CODES = {"rx": 0, "prop": 1, "col": 2, "mult": 3, "range": 4, "nopose": 5}


def test_every_frame_on_air_is_one_packet_with_the_traces_fields(trace, tmp_path):
    out = tmp_path / "run.pcapng"
    r = subprocess.run([*UWSIMNET, "pcap", str(trace), "-o", str(out)], capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    want = expected(trace)
    ifaces, pkts = read_pcapng(out.read_bytes())
    assert f"{len(want)} frames on air" in r.stdout
    assert len(pkts) == len(want) > 100
    chans = sorted({w["ch"] for w in want})
    assert sorted(i["name"] for i in ifaces) == [f"ch{c}" for c in chans]
    assert {i["link"] for i in ifaces} == {147} and {i["tsresol"] for i in ifaces} == {9}
    reasons = set()
    for w, p in zip(want, pkts, strict=True):
        h = parse_header(p["data"])
        assert ifaces[p["iface"]]["name"] == f"ch{w['ch']}"
        assert p["ns"] == round(w["t"] * 1e9)
        assert p["orig"] == len(p["data"]) + w["size"]
        assert {k: h[k] for k in ("kind", "ch", "src", "dst", "seq", "size", "dev", "flow", "attempt")} == \
            {k: w[k] for k in ("kind", "ch", "src", "dst", "seq", "size", "dev", "flow", "attempt")}
        assert set(h["outcomes"]) == set(w["outcomes"])
        for dev, (text, delay, dist) in w["outcomes"].items():
            code, text2, delay2, dist2 = h["outcomes"][dev]
            assert (text2, code) == (text, CODES.get(text, 255))
            assert delay2 == pytest.approx(delay, abs=1e-9)
            assert (math.isnan(dist2) if dist is None else dist2 == pytest.approx(dist, rel=1e-6))
            reasons.add(text)
    assert "rx" in reasons and reasons & {"col", "prop", "range", "mult"}


@pytest.mark.skipif(shutil.which("tshark") is None, reason="no tshark (apt-get install tshark)")
def test_tshark_decodes_the_capture_with_the_shipped_dissector(trace, tmp_path):
    out = tmp_path / "run.pcapng"
    subprocess.run([*UWSIMNET, "pcap", str(trace), "-o", str(out)], check=True, capture_output=True, cwd=ROOT)
    fields = ["frame.interface_name", "frame.time_epoch", "uwsimnet.kind", "uwsimnet.channel", "uwsimnet.src",
              "uwsimnet.dst", "uwsimnet.seq", "uwsimnet.size", "uwsimnet.attempt", "uwsimnet.txdev", "uwsimnet.flow",
              "uwsimnet.rx.dev", "uwsimnet.rx.outcome"]
    r = subprocess.run(["tshark", "-n", "-X", f"lua_script:{DISSECTOR}", "-r", str(out), "-T", "fields",
                        *[a for f in fields for a in ("-e", f)], "-E", "separator=|", "-E", "aggregator=,",
                        "-E", "occurrence=a"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    want = expected(trace)
    assert len(lines) == len(want)
    for w, line in zip(want, lines, strict=True):
        iface, t, kind, ch, src, dst, seq, size, attempt, dev, flow, rx_dev, rx_out = line.split("|")
        assert iface == f"ch{w['ch']}"
        assert round(float(t) * 1e9) == round(w["t"] * 1e9)
        assert (int(kind), int(ch), int(src), int(dst), int(seq), int(size), int(attempt)) == \
            ({"data": 0, "ctrl": 1}[w["kind"]], w["ch"], w["src"], w["dst"], w["seq"], w["size"], w["attempt"])
        assert (dev, flow or None) == (w["dev"], w["flow"])
        got = dict(zip(rx_dev.split(","), rx_out.split(","), strict=True)) if rx_dev else {}
        assert got == {d: o[0] for d, o in w["outcomes"].items()}


def test_pcap_of_something_that_is_not_a_trace_is_one_line_and_exit_2(tmp_path):
    bad = tmp_path / "notes.txt"
    bad.write_text("hello, I am not a trace\n")
    for argv in ([str(bad), "-o", str(tmp_path / "x.pcapng")], [str(tmp_path / "missing.jsonl"), "-o", "x"]):
        r = subprocess.run([*UWSIMNET, "pcap", *argv], capture_output=True, text=True, cwd=ROOT)
        assert r.returncode == 2, r
        assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr, r.stderr
    assert not (tmp_path / "x.pcapng").exists()


def test_the_dissector_ships_with_the_package():
    r = subprocess.run([*UWSIMNET, "pcap", "--dissector"], capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 0 and Path(r.stdout.strip()) == DISSECTOR and DISSECTOR.is_file()


def test_pcap_help_says_what_the_trace_argument_is():
    r = subprocess.run([*UWSIMNET, "pcap", "--help"], capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 0
    line = next(ln for ln in r.stdout.splitlines() if ln.strip().startswith("TRACE"))
    assert "uwsimnet run --trace" in r.stdout and len(line.split()) > 1, r.stdout
