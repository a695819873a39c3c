"""What a swarm's pose burst costs a busy engine-like thread: Zenoh callbacks against a ring channel (the
broker's choice; docs/runtime.md "Poses", docs/benchmarks.md "Poses without callbacks").

A router process (this one) subscribes to `bench/pose/*` either with a Python callback per sample (`cb`) or
with a `RingChannel` that the measuring thread drains itself (`ring`), doing the broker's per-sample work
(payload bytes, key, newest per key).  A client process publishes N poses at once every 0.1 s (N = 256: a
swarm's publisher).  The measuring thread wakes every 0.37 ms (sleep, then a short spin, as the engine does)
and records how late it ran: a burst of callbacks takes the interpreter from it.

    .venv/bin/python bench/bench_pose_ingress.py [--n 256] [--seconds 4] [--rounds 2]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import socket
import subprocess
import sys
import threading
import time

import msgpack
import zenoh


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def config(mode: str, endpoint: str) -> zenoh.Config:
    c = zenoh.Config()
    c.insert_json5("mode", json.dumps(mode))
    c.insert_json5("listen/endpoints" if mode == "router" else "connect/endpoints", json.dumps([endpoint]))
    c.insert_json5("scouting/multicast/enabled", "false")
    return c


def publish(endpoint: str, n: int, seconds: float) -> None:
    with zenoh.open(config("client", endpoint)) as s:
        pubs = [s.declare_publisher(f"bench/pose/v{i}") for i in range(n)]
        t0 = time.monotonic()
        k = 0
        while time.monotonic() - t0 < seconds:
            for i, p in enumerate(pubs):
                p.put(msgpack.packb({"p": [100.0 * i + math.sin(k + i), 0.0, 10.0]}))
            k += 1
            d = t0 + k * 0.1 - time.monotonic()
            if d > 0:
                time.sleep(d)


def measure(handler: str, n: int, seconds: float) -> dict:
    sys.setswitchinterval(0.0005)                  # as the broker sets it
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    latest: dict[str, tuple[float, bytes]] = {}
    lock = threading.Lock()
    taken = [0]

    def keep(sample: zenoh.Sample) -> None:
        raw = sample.payload.to_bytes()
        key = str(sample.key_expr)
        with lock:
            latest[key] = (time.perf_counter(), raw)
            taken[0] += 1

    late: list[float] = []
    with zenoh.open(config("router", endpoint)) as s:
        if handler == "cb":
            sub = s.declare_subscriber("bench/pose/*", zenoh.handlers.Callback(keep, indirect=False))
        else:
            sub = s.declare_subscriber("bench/pose/*", zenoh.handlers.RingChannel(16384))
        pub = subprocess.Popen([sys.executable, __file__, "--publish", endpoint, "--n", str(n),
                                "--seconds", str(seconds + 2)])
        try:
            time.sleep(1.0)
            end = time.perf_counter() + seconds

            def engine() -> None:
                period = 0.00037
                nxt = time.perf_counter()
                while nxt < end:
                    nxt += period
                    if handler == "ring":
                        while (smp := sub.try_recv()) is not None:
                            keep(smp)
                    w = nxt - time.perf_counter() - 0.0002
                    if w > 0:
                        time.sleep(w)
                    while time.perf_counter() < nxt:
                        os.sched_yield()
                    late.append(time.perf_counter() - nxt)
            th = threading.Thread(target=engine)
            th.start()
            th.join()
        finally:
            pub.wait(30)
    late.sort()

    def q(f: float) -> float:
        return late[min(len(late) - 1, int(f * len(late)))] * 1e6
    return {"handler": handler, "samples": taken[0], "ticks": len(late), "median": q(0.5), "p99": q(0.99),
            "p999": q(0.999), "max": late[-1] * 1e6}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=256)
    ap.add_argument("--seconds", type=float, default=4.0)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--publish", metavar="ENDPOINT", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.publish:
        publish(a.publish, a.n, a.seconds)
        return
    print("| handler | poses per burst | samples | late median | p99 | p99.9 | max (us) |")
    print("|---|---|---|---|---|---|---|")
    for _ in range(a.rounds):
        for handler in ("cb", "ring"):
            code = (f"import json, sys; sys.path.insert(0, {os.path.dirname(__file__)!r}); import bench_pose_ingress"
                    f" as b; print(json.dumps(b.measure({handler!r}, {a.n}, {a.seconds})))")
            r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
            m = json.loads(r.stdout.strip().splitlines()[-1])
            name = "Python callback per sample" if handler == "cb" else "ring channel, taken by the thread"
            print(f"| {name} | {a.n} | {m['samples']} | {m['median']:.0f} | {m['p99']:.0f} | {m['p999']:.0f} |"
                  f" {m['max']:.0f} |")


if __name__ == "__main__":
    main()
