"""ns-3 UAN on the capture-on-a-line scenario (docs/acoustic.md, "Capture experiment"), for comparison.

    python -m venv /tmp/ns3venv && /tmp/ns3venv/bin/pip install ns3      # separate venv, never a dependency
    .venv/bin/python bench/ns3_capture.py --ns3 /tmp/ns3venv/lib/python3.11/site-packages/ns3 -o /tmp/ns3_capture.json
    .venv/bin/python bench/capture_line.py -o docs/figures --ns3 /tmp/ns3_capture.json

compiles bench/ns3_capture.cc against the ns3 wheel (headers in <ns3>/include, libraries in <ns3>/lib64),
runs it for each offered load and writes the throughput and per-sensor counts as JSON.  ns-3's UanPhyGen
locks onto the first frame it acquires, which is this simulator's capture "first" rule; the two draw
different random numbers, so they agree when they differ by no more than the statistical error.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
from pathlib import Path

HERE = Path(__file__).resolve().parent
LIBS = ["ns3.44-uan", "ns3.44-energy", "ns3.44-mobility", "ns3.44-network", "ns3.44-core"]
FRAME_TIME = 0.32
LOADS = (0.1, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 4.0)


def build(ns3: Path, out: Path) -> Path:
    src = HERE / "ns3_capture.cc"
    if out.exists() and out.stat().st_mtime > src.stat().st_mtime:
        return out
    cxx = shutil.which("g++") or "c++"
    cmd = [cxx, "-O2", "-std=c++20", "-DNS3_BUILD_PROFILE_RELEASE", "-DNS3_LOG_ENABLE", "-DNS3_ASSERT_ENABLE",
           f"-I{ns3 / 'include'}", str(src), "-o", str(out), f"-L{ns3 / 'lib64'}",
           *[f"-l{lib}" for lib in LIBS], f"-Wl,-rpath,{ns3 / 'lib64'}"]
    subprocess.run(cmd, check=True)
    return out


def run(binary: Path, n: int, load: float, duration: float, seed: int) -> dict:
    lines = subprocess.run([str(binary), str(n), str(load), str(duration), str(seed)], check=True,
                           capture_output=True, text=True).stdout.splitlines()
    offered, sent, received, wall = lines[0].split()
    return {"S": int(received) * FRAME_TIME / duration, "offered": int(offered), "sent_total": int(sent),
            "received_total": int(received), "wall_s": float(wall),
            "received": [int(x) for x in lines[1].split()], "sent": [int(x) for x in lines[2].split()]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ns3", type=Path, default=Path(os.environ.get(
        "NS3_DIR", "/tmp/ns3venv/lib/python3.11/site-packages/ns3")), help="the ns3 wheel's package folder")
    ap.add_argument("--binary", type=Path, default=Path("/tmp/ns3_capture"))
    ap.add_argument("--nodes", type=int, default=16)
    ap.add_argument("--frames", type=float, default=20000.0, help="simulated time in frame-times per point")
    ap.add_argument("--loads", default=",".join(map(str, LOADS)))
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("-o", "--out", type=Path, default=Path("/tmp/ns3_capture.json"))
    a = ap.parse_args(argv)
    binary = build(a.ns3, a.binary)
    duration = a.frames * FRAME_TIME
    points = {}
    for g in (float(x) for x in a.loads.split(",")):
        points[str(g)] = run(binary, a.nodes, g, duration, a.seed)
        print(f"G = {g:g}: S = {points[str(g)]['S']:.4f} ({points[str(g)]['wall_s']:.2f} s)")
    a.out.write_text(json.dumps({"nodes": a.nodes, "duration": duration, "seed": a.seed, "ns3": "3.44",
                                 "points": points}))
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
