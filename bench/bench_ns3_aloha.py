"""Side by side with ns-3 UAN: the reference pure-ALOHA scenario run by both simulators and the formula.

    python -m venv /tmp/ns3venv && /tmp/ns3venv/bin/pip install ns3      # separate venv, never a dependency
    .venv/bin/python bench/bench_ns3_aloha.py --ns3 /tmp/ns3venv/lib/python3.11/site-packages/ns3

compiles bench/ns3_aloha.cc against the ns3 wheel (headers in <ns3>/include, libraries in <ns3>/lib64),
runs it and uwsimnet_zenoh on the same scenario (uwsimnet_zenoh/experiments/aloha.py) for a range of
offered loads, and prints a markdown table for docs/benchmarks.md.  The two simulators draw different
random numbers: they agree when their throughputs differ by no more than the statistical error.
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from uwsimnet_zenoh.engine.network import Network  # noqa: E402
from uwsimnet_zenoh.experiments import aloha  # noqa: E402

HERE = Path(__file__).resolve().parent
LIBS = ["ns3.44-uan", "ns3.44-energy", "ns3.44-mobility", "ns3.44-network", "ns3.44-core"]


def build(ns3: Path, out: Path) -> Path:
    src = HERE / "ns3_aloha.cc"
    if out.exists() and out.stat().st_mtime > src.stat().st_mtime:
        return out
    cxx = shutil.which("g++") or "c++"
    cmd = [cxx, "-O2", "-std=c++20", "-DNS3_BUILD_PROFILE_RELEASE", "-DNS3_LOG_ENABLE", "-DNS3_ASSERT_ENABLE",
           f"-I{ns3 / 'include'}", str(src), "-o", str(out), f"-L{ns3 / 'lib64'}",
           *[f"-l{lib}" for lib in LIBS], f"-Wl,-rpath,{ns3 / 'lib64'}"]
    subprocess.run(cmd, check=True)
    return out


def run_ns3(binary: Path, n: int, load: float, duration: float, seed: int) -> tuple[int, float]:
    out = subprocess.run([str(binary), str(n), str(load), str(duration), str(seed)], check=True,
                         capture_output=True, text=True).stdout.split()
    return int(out[2]), float(out[3])


def run_ours(n: int, load: float, duration: float, seed: int) -> tuple[int, float]:
    t0 = time.perf_counter()
    net = Network(aloha.scene(n, load, duration, seed=seed))
    net.run()
    return net.modems["sink"].counters["rx"], time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ns3", type=Path, default=Path(os.environ.get(
        "NS3_DIR", "/tmp/ns3venv/lib/python3.11/site-packages/ns3")), help="the ns3 wheel's package folder")
    ap.add_argument("--binary", type=Path, default=Path("/tmp/ns3_aloha"))
    ap.add_argument("--n", type=int, default=16)
    ap.add_argument("--loads", default="0.1,0.25,0.5,1,2")
    ap.add_argument("--duration", type=float, default=5000.0, help="simulated s per run")
    ap.add_argument("--seeds", type=int, default=4, help="runs per load and simulator")
    a = ap.parse_args(argv)
    binary = build(a.ns3, a.binary)
    T = aloha.FRAME_TIME
    print(f"N = {a.n}, {a.seeds} runs x {a.duration:g} s per load and simulator; S in frames per frame time;"
          " ± = one standard error (sqrt of the received count)\n")
    print("| G | S theory | S ns-3 | S uwsimnet | ns-3 − theory (σ) | uwsimnet − theory (σ) |"
          " uwsimnet − ns-3 (σ) | wall s ns-3 | wall s uwsimnet |")
    print("|---|---|---|---|---|---|---|---|---|")
    for load in (float(x) for x in a.loads.split(",")):
        total = a.duration * a.seeds
        k_ns3 = k_ours = 0
        w_ns3 = w_ours = 0.0
        for seed in range(1, a.seeds + 1):
            k, w = run_ns3(binary, a.n, load, a.duration, seed)
            k_ns3 += k
            w_ns3 += w
            k, w = run_ours(a.n, load, a.duration, seed)
            k_ours += k
            w_ours += w
        theory = aloha.theory(a.n, load)
        expected = theory * total / T
        s_ns3, s_ours = k_ns3 * T / total, k_ours * T / total
        e_ns3, e_ours = math.sqrt(k_ns3) * T / total, math.sqrt(k_ours) * T / total
        sig = math.sqrt(expected) * T / total
        both = math.hypot(e_ns3, e_ours)
        print(f"| {load:g} | {theory:.4f} | {s_ns3:.4f} ± {e_ns3:.4f} | {s_ours:.4f} ± {e_ours:.4f} |"
              f" {(s_ns3 - theory) / sig:+.1f} | {(s_ours - theory) / sig:+.1f} | {(s_ours - s_ns3) / both:+.1f} |"
              f" {w_ns3:.2f} | {w_ours:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
