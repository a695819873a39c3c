"""Run the two-app acoustic demo in one command: the simulator and both apps as separate processes.

    .venv/bin/python examples/acoustic_demo.py [--seconds 25] [--port 0]

Starts `uwsimnet run scenes/examples/acoustic-apps.xml` (realtime, embedded Zenoh router) on a free port
(`--port 0`, the default: it never clashes with a simulator you already run on 7447; `--port N` takes N
and says so if it is busy), then examples/pong_app.py (bravo, drives away and back) and
examples/ping_app.py (alpha, pings once a second) connected to that port, prints their output as it
comes, and after `--seconds` stops everything with Ctrl-C (SIGINT) so the simulator prints its per-flow
summary and writes out/acoustic-apps.jsonl.  Exit code 0 when every process ended cleanly, 2 when the
simulator could not start (its one-line reason is printed), 1 otherwise.
"""

from __future__ import annotations

import argparse
import queue
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCENE = "scenes/examples/acoustic-apps.xml"


def pump(name: str, p: subprocess.Popen, lines: queue.Queue | None = None) -> None:
    for line in p.stdout:
        print(f"[{name}] {line}", end="", flush=True)
        if lines is not None:
            lines.put(line)
    if lines is not None:
        lines.put(None)


def wait_ready(p: subprocess.Popen, lines: queue.Queue, timeout: float = 30.0) -> tuple[str | None, str]:
    """The endpoint the simulator listens on once it runs, or (None, its last line) if it exits first."""
    endpoint, last = None, ""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            line = lines.get(timeout=max(0.01, deadline - time.monotonic()))
        except queue.Empty:
            break
        if line is None:
            p.wait(10)
            return None, last
        last = line.strip() or last
        m = re.search(r"listening on .*?(tcp/127\.0\.0\.1:\d+)", line)
        if m:
            endpoint = m.group(1)
        if line.startswith("uwsimnet: running") and endpoint:
            return endpoint, last
    return None, f"no 'uwsimnet: running' within {timeout:g} s (last: {last})"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=25.0)
    ap.add_argument("--port", type=int, default=0, help="the simulator's Zenoh port (default 0: a free one)")
    a = ap.parse_args()
    py = sys.executable
    trace = Path.cwd() / "out" / "acoustic-apps.jsonl"    # out/ where the command runs (the README: the top)
    procs: list[tuple[str, subprocess.Popen]] = []

    def start(name: str, argv: list[str], lines: queue.Queue | None = None) -> subprocess.Popen:
        p = subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                             bufsize=1)
        procs.append((name, p))
        threading.Thread(target=pump, args=(name, p, lines), daemon=True).start()
        return p

    sim_lines: queue.Queue = queue.Queue()
    try:
        trace.unlink(missing_ok=True)
        sim = start("uwsimnet", [py, "-m", "uwsimnet_zenoh.cli", "run", SCENE, "--clock", "realtime",
                                 "--duration", f"{a.seconds + 10:g}",   # the demo's length, not the scene's 600 s
                                 "--listen", f"tcp/127.0.0.1:{a.port}", "--trace", str(trace)], sim_lines)
        ep, why = wait_ready(sim, sim_lines)
        if ep is None:
            print(f"[demo] the simulator did not start: {why}", flush=True)
            return 2
        print(f"[demo] simulator on {ep}; starting the apps", flush=True)
        start("pong", [py, "examples/pong_app.py", "-e", ep, "--duration", str(a.seconds)])
        time.sleep(0.5)
        start("ping", [py, "examples/ping_app.py", "-e", ep, "--count", str(int(a.seconds))])
        deadline = time.monotonic() + a.seconds + 5
        while time.monotonic() < deadline and any(p.poll() is None for n, p in procs if n != "uwsimnet"):
            if sim.poll() is not None:
                print("[demo] the simulator stopped early", flush=True)
                break
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
                    p.wait(5)
        time.sleep(0.2)
    codes = {n: p.returncode for n, p in procs}
    wrote = f"; trace {trace.relative_to(Path.cwd())}" if trace.is_file() else "; no trace written"
    print(f"[demo] exit codes {codes}{wrote}", flush=True)
    return 0 if all(c == 0 for c in codes.values()) else 1


if __name__ == "__main__":
    raise SystemExit(main())
