"""Run the two-app acoustic demo in one command: the simulator and both apps as separate processes.

    .venv/bin/python examples/acoustic_demo.py [--seconds 25] [--port 7447]

Starts `uwsimnet run scenes/examples/acoustic-apps.xml` (realtime, embedded Zenoh router), then
examples/pong_app.py (bravo, drives away and back) and examples/ping_app.py (alpha, pings once a
second), prints their output as it comes, and after `--seconds` stops everything with Ctrl-C (SIGINT)
so the simulator prints its per-flow summary and writes out/acoustic-apps.jsonl.
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def pump(name: str, p: subprocess.Popen) -> None:
    for line in p.stdout:
        print(f"[{name}] {line}", end="", flush=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=25.0)
    ap.add_argument("--port", type=int, default=7447)
    a = ap.parse_args()
    ep = f"tcp/127.0.0.1:{a.port}"
    py = sys.executable
    trace = ROOT / "out" / "acoustic-apps.jsonl"
    procs: list[tuple[str, subprocess.Popen]] = []

    def start(name: str, argv: list[str]) -> subprocess.Popen:
        p = subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                             bufsize=1)
        procs.append((name, p))
        threading.Thread(target=pump, args=(name, p), daemon=True).start()
        return p

    try:
        start("uwsimnet", [py, "-m", "uwsimnet_zenoh.cli", "run", "scenes/examples/acoustic-apps.xml",
                           "--listen", ep, "--trace", str(trace)])
        time.sleep(2.0)                                     # the router is up and the modems declared
        start("pong", [py, "examples/pong_app.py", "-e", ep, "--duration", str(a.seconds)])
        time.sleep(0.5)
        start("ping", [py, "examples/ping_app.py", "-e", ep, "--count", str(int(a.seconds))])
        deadline = time.monotonic() + a.seconds + 5
        while time.monotonic() < deadline and any(p.poll() is None for n, p in procs if n != "uwsimnet"):
            time.sleep(0.2)
    except KeyboardInterrupt:
        pass
    finally:
        for name, p in reversed(procs):                     # apps first, the simulator last
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
                try:
                    p.wait(15)
                except subprocess.TimeoutExpired:
                    print(f"[demo] {name} did not stop, killing it", flush=True)
                    p.kill()
        time.sleep(0.2)
    codes = {n: p.returncode for n, p in procs}
    print(f"[demo] exit codes {codes}; trace {trace.relative_to(ROOT)}", flush=True)
    return 0 if all(c == 0 for c in codes.values()) else 1


if __name__ == "__main__":
    raise SystemExit(main())
