"""Engine speed: frames simulated per wall second on one channel, against ns-3 UAN's published figures.

The scenario is ns-3's reference pure ALOHA (uwsimnet_zenoh.experiments.aloha): N sensors, G = 1.
Run: .venv/bin/python bench/bench_engine.py [--sim-seconds S] [--markdown]
"""

from __future__ import annotations

import argparse
import datetime
import platform
import time

from uwsimnet_zenoh.engine.network import Network
from uwsimnet_zenoh.experiments import aloha

NS3 = {16: 38_300, 64: 10_000, 256: 2_320, 1024: 438}   # frames sent per wall second, same machine kind


def bench(n: int, sim_seconds: float) -> dict:
    net = Network(aloha.scene(n, 1.0, sim_seconds, seed=1))
    t0 = time.perf_counter()
    net.run()
    wall = time.perf_counter() - t0
    sent = net.tracer.count("tx")
    got = net.tracer.count("rx")
    return {"n": n, "sim_s": sim_seconds, "wall_s": wall, "frames": sent, "fps": sent / wall,
            "events": net.sched.events_run, "S": aloha.measured_throughput(got, sim_seconds),
            "S_theory": aloha.theory(n, 1.0), "ns3_fps": NS3.get(n)}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sim-seconds", type=float, default=2000.0)
    ap.add_argument("--nodes", default="16,64,256,1024")
    ap.add_argument("--markdown", action="store_true")
    a = ap.parse_args()
    rows = [bench(int(n), a.sim_seconds) for n in a.nodes.split(",")]
    print(f"# engine benchmark {datetime.date.today()} on {platform.processor() or platform.machine()},"
          f" Python {platform.python_version()}")
    hdr = "| N | frames | wall s | frames/s | ns-3 frames/s | ratio | events/frame | S | S theory |"
    print(hdr)
    print("|" + "---|" * 9)
    for r in rows:
        ratio = f"{r['fps'] / r['ns3_fps']:.1f}x" if r["ns3_fps"] else "-"
        print(f"| {r['n']} | {r['frames']} | {r['wall_s']:.2f} | {r['fps']:,.0f} | {r['ns3_fps'] or '-'} |"
              f" {ratio} | {r['events'] / max(1, r['frames']):.2f} | {r['S']:.4f} | {r['S_theory']:.4f} |")


if __name__ == "__main__":
    main()
