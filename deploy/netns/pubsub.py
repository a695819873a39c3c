"""A publisher and a subscriber that prove two emulated hosts exchange data through their routers.

    python pubsub.py sub CONFIG KEY N          print each of N samples, exit 0 (exit 1 after TIMEOUT s)
    python pubsub.py pub CONFIG KEY N [FILE]   wait until a subscriber matches (and FILE says "ready"),
                                              then put N samples

A matching subscriber is not yet a route: the declaration may reach the publisher's router through a
subscriber elsewhere before the one on the far host, so with FILE the publisher first puts "probe"
samples until the subscriber says "probed" (its route is up end to end), then the N samples.  Routers
may still lose a sample while their links and routes settle (seen once: 2 of 3 after the probe), so
with FILE the publisher puts again the samples the subscriber has not said it got, and says on stderr
how many it put again; the subscriber prints each sample once.

CONFIG is a client configuration rendered by `uwsimnet deploy`.  Every wait is
bounded (TIMEOUT, default 20 s, from the environment); the session is always closed.
"""

from __future__ import annotations

import os
import queue
import sys
import time
from pathlib import Path

import zenoh

TIMEOUT = float(os.environ.get("TIMEOUT", "20"))


def sub(conf: zenoh.Config, key: str, n: int) -> int:
    q: queue.Queue[str] = queue.Queue()
    with zenoh.open(conf) as s:
        _sub = s.declare_subscriber(key, lambda smp: q.put(smp.payload.to_string()))
        print("ready", flush=True)
        deadline = time.monotonic() + TIMEOUT
        seen: set[str] = set()
        probed = False
        while len(seen) < n:
            try:
                msg = q.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                print(f"timeout: {len(seen)}/{n} samples", flush=True)
                return 1
            if msg == "probe":
                if not probed:
                    print("probed", flush=True)
                    probed = True
                continue
            if msg not in seen:
                seen.add(msg)
                print(f"got {msg}", flush=True)
    return 0


def _says(path: str, word: str) -> bool:
    return Path(path).exists() and word in Path(path).read_text().split()


def _got(path: str) -> set[int]:
    """The sample numbers the subscriber says it got ("got sample I from pid P" lines)."""
    lines = Path(path).read_text().splitlines() if Path(path).exists() else []
    return {int(ln.split()[2]) for ln in lines if ln.startswith("got sample ")}


def pub(conf: zenoh.Config, key: str, n: int, ready_file: str | None) -> int:
    deadline = time.monotonic() + TIMEOUT
    if ready_file:
        while not _says(ready_file, "ready"):
            if time.monotonic() > deadline:
                print(f"timeout: {ready_file} never said ready", file=sys.stderr)
                return 1
            time.sleep(0.05)
    with zenoh.open(conf) as s:
        # each put leaves at once (no batching); BLOCK: a router whose queue towards the next hop is full
        # waits instead of dropping the sample
        p = s.declare_publisher(key, express=True, congestion_control=zenoh.CongestionControl.BLOCK)
        while not p.matching_status.matching:
            if time.monotonic() > deadline:
                print("timeout: no subscriber matched", file=sys.stderr)
                return 1
            time.sleep(0.05)
        while ready_file and not _says(ready_file, "probed"):
            if time.monotonic() > deadline:
                print("timeout: the subscriber never heard a probe", file=sys.stderr)
                return 1
            p.put("probe")
            time.sleep(0.1)
        for i in range(n):
            p.put(f"sample {i} from pid {os.getpid()}")
        again = 0
        while ready_file and len(_got(ready_file)) < n:
            time.sleep(0.5)
            missing = set(range(n)) - _got(ready_file)
            if not missing:
                break
            if time.monotonic() > deadline:
                print(f"timeout: the subscriber never got samples {sorted(missing)}", file=sys.stderr)
                return 1
            for i in sorted(missing):
                p.put(f"sample {i} from pid {os.getpid()}")
                again += 1
        if again:
            print(f"put {again} sample(s) again that the subscriber had not got", file=sys.stderr)
        time.sleep(1.0)  # let the samples cross three routers before the session closes (0.2 s lost them once)
    return 0


def main(argv: list[str]) -> int:
    if len(argv) < 4 or argv[0] not in ("pub", "sub"):
        print(__doc__, file=sys.stderr)
        return 2
    zenoh.init_log_from_env_or("error")
    conf = zenoh.Config.from_file(argv[1])
    if argv[0] == "sub":
        return sub(conf, argv[2], int(argv[3]))
    return pub(conf, argv[2], int(argv[3]), argv[4] if len(argv) > 4 else None)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
