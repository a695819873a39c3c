"""Benches write under out/ only (never over the tracked docs/figures), and the reference data they
compare to is in the repository: the ns-3 UAN capture points (issue #20)."""

from __future__ import annotations

import hashlib
import importlib.util
import json
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "bench"


def load(name: str):
    spec = importlib.util.spec_from_file_location(f"bench_{name}", BENCH / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def sha(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


def test_capture_line_writes_under_out_with_the_ns3_overlay(tmp_path, monkeypatch, capsys):
    tracked = ROOT / "docs" / "figures" / "capture-throughput.png"
    before = sha(tracked)
    monkeypatch.chdir(tmp_path)
    load("capture_line").main(["--frames", "60", "--loads", "0.5,1"])
    out = capsys.readouterr().out
    assert (tmp_path / "out" / "capture" / "capture-throughput.png").stat().st_size > 20_000
    assert sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*") if p.is_file()) == \
        ["out/capture/capture-throughput.png"]
    assert sha(tracked) == before
    rows = {r.split("|")[1].strip(): r.split("|")[7].strip() for r in out.splitlines() if r.startswith("| 0.5 ")
            or r.startswith("| 1 ")}
    assert rows == {"0.5": "0.227", "1": "0.230"}, out            # the ns-3 column, from the repository


def test_the_ns3_reference_is_the_documented_column():
    ref = json.loads((BENCH / "reference" / "ns3_capture.json").read_text())
    assert ref["nodes"] == 16 and ref["seed"] == 1 and ref["ns3"] == "3.44"
    doc = (ROOT / "docs" / "acoustic.md").read_text()
    table = [ln for ln in doc.splitlines() if re.match(r"^\| [0-9.]+ \| 0\.", ln)]
    assert len(table) == 9
    for ln in table:
        cells = [c.strip() for c in ln.strip("|").split("|")]
        assert f"{ref['points'][str(float(cells[0]))]['S']:.3f}" == cells[6], ln
        p = ref["points"][str(float(cells[0]))]
        assert len(p["received"]) == len(p["sent"]) == 16


def test_no_bench_defaults_to_a_tracked_folder():
    for p in BENCH.glob("*.py"):
        code = p.read_text()
        assert not re.search(r"default=[\"'](docs|scenes|tests)/", code), p.name
        assert not re.search(r"\"docs/figures", code.split('"""', 2)[-1]), p.name
