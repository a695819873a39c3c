"""Delivery error across emulated hosts vs on one host (not a test; results in docs/benchmarks.md).

Delivery error = wall time at which the receiving app gets a frame on `modem/<id>/rx` minus the frame's
modelled delivery time mapped to wall time (the broker's clock epoch, from `uwsimnet/<world>/clock`,
plus t_rx).  All namespaces share the machine's clock, so the two are comparable.

    one host   `uwsimnet run --listen` (embedded router); sender and receiver apps are its clients
    netns      deploy/netns/hosts.sh: h1 router + broker (client), h2 router + sender, h3 router + receiver;
               routers in a star around h1, plain TCP over veth + bridge: two router hops each way

    sudo .venv/bin/python bench/bench_distributed.py [--seconds 20] [--rate 10]      (root for netns)
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable
HOSTS = ROOT / "deploy" / "netns" / "hosts.sh"
WORLD = "benchdist"
PREFIX = "ubd"
NET = "10.79.0"

SCENE = f"""<?xml version="1.0"?>
<UWSimScene>
  <simulation><seed>1</seed><clock>realtime</clock><world>{WORLD}</world></simulation>
  <CustomCommsChannel><id>0</id><propTimeIncPerMeter>0.6667</propTimeIncPerMeter></CustomCommsChannel>
  <vehicle><name>v0</name><position>0 0 0</position><CustomCommsDevice><dccommsId>m0</dccommsId><mac>1</mac>
    <txChannelId>0</txChannelId><rxChannelId>0</rxChannelId><bitrate>10000</bitrate><txFifoSize>4000</txFifoSize>
    </CustomCommsDevice></vehicle>
  <vehicle><name>v1</name><position>150 0 0</position><CustomCommsDevice><dccommsId>m1</dccommsId><mac>2</mac>
    <txChannelId>0</txChannelId><rxChannelId>0</rxChannelId><bitrate>10000</bitrate><txFifoSize>4000</txFifoSize>
    </CustomCommsDevice></vehicle>
</UWSimScene>
"""


def pct(xs: list[float], q: float) -> float:
    s = sorted(xs)
    return s[min(len(s) - 1, int(q * len(s)))] if s else float("nan")


# -- roles (run inside a host) ----------------------------------------------------------------------------
def client(endpoint: str):
    import zenoh

    c = zenoh.Config()
    c.insert_json5("mode", '"client"')
    c.insert_json5("connect/endpoints", json.dumps([endpoint]))
    c.insert_json5("connect/timeout_ms", "10000")
    c.insert_json5("scouting/multicast/enabled", "false")
    return c


def role_recv(endpoint: str, seconds: float, out: str) -> None:
    import msgpack
    import zenoh

    got: list[tuple[float, float]] = []
    epochs: list[float] = []
    with zenoh.open(client(endpoint)) as s:
        s.declare_subscriber(f"uwsimnet/{WORLD}/modem/m1/rx", zenoh.handlers.Callback(
            lambda smp: got.append((time.time(), msgpack.unpackb(smp.payload.to_bytes())["t_rx"])), indirect=False))
        s.declare_subscriber(f"uwsimnet/{WORLD}/clock",
                             lambda smp: epochs.append(msgpack.unpackb(smp.payload.to_bytes())["epoch"]))
        print("ready", flush=True)
        time.sleep(seconds)
    epoch = sorted(epochs)[len(epochs) // 2]
    Path(out).write_text(json.dumps({"err": [w - (epoch + t) for w, t in got], "epochs": len(epochs)}))


def role_send(endpoint: str, seconds: float, rate: float) -> None:
    import msgpack
    import zenoh

    with zenoh.open(client(endpoint)) as s:
        pub = s.declare_publisher(f"uwsimnet/{WORLD}/modem/m0/tx", express=True)
        time.sleep(1.0)
        t0 = time.monotonic()
        k = 0
        while time.monotonic() - t0 < seconds:
            d = t0 + k / rate - time.monotonic()
            if d > 0:
                time.sleep(d)
            pub.put(msgpack.packb({"dst": 2, "data": bytes(16)}))
            k += 1
        print(f"sent {k}", flush=True)


# -- orchestration ----------------------------------------------------------------------------------------
class Proc:
    def __init__(self, argv: list[str], log: Path, ready: str | None = None, timeout: float = 20) -> None:
        self.log = log
        self.fh = open(log, "w")  # noqa: SIM115
        self.p = subprocess.Popen(argv, stdout=self.fh, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                  cwd=ROOT, env={**os.environ, "PYTHONUNBUFFERED": "1"})
        if ready:
            deadline = time.monotonic() + timeout
            while ready not in log.read_text():
                if self.p.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(f"{argv}: not ready: {log.read_text()[-2000:]}")
                time.sleep(0.05)

    def stop(self, pid_file: Path | None = None) -> None:
        pid = int(pid_file.read_text()) if pid_file and pid_file.exists() else self.p.pid
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, 15)
        try:
            self.p.wait(20)
        except subprocess.TimeoutExpired:
            self.p.kill()
            self.p.wait(5)
        self.fh.close()


def in_host(i: int | None, argv: list[str]) -> list[str]:
    return argv if i is None else ["ip", "netns", "exec", f"{PREFIX}-h{i}", *argv]


def run_setup(name: str, tmp: Path, seconds: float, rate: float) -> dict:
    netns = name == "netns"
    d = tmp / name
    d.mkdir()
    scene = d / "scene.xml"
    scene.write_text(SCENE)
    procs: list[Proc] = []
    env = {**os.environ, "P": PREFIX, "NET": NET, "PY": PY}
    try:
        if netns:
            subprocess.run([str(HOSTS), "up", "3"], env=env, check=True, capture_output=True, timeout=60)
            for i in (1, 2, 3):
                conn = [] if i == 1 else ["--connect", f"tcp/{NET}.1:7447"]
                procs.append(Proc(in_host(i, [PY, "-m", "uwsimnet_zenoh.cli", "router", "--listen",
                                              "tcp/0.0.0.0:7447", *conn]), d / f"router{i}.log", "listening on"))
            ep = "tcp/127.0.0.1:7447"
            broker_argv = in_host(1, ["sh", "-c", 'echo $$ >"$0"; exec "$@"', str(d / "broker.pid"), PY, "-m",
                                      "uwsimnet_zenoh.cli", "run", str(scene), "--connect", ep])
        else:
            import socket

            with socket.socket() as s:
                s.bind(("127.0.0.1", 0))
                ep = f"tcp/127.0.0.1:{s.getsockname()[1]}"
            broker_argv = [PY, "-m", "uwsimnet_zenoh.cli", "run", str(scene), "--listen", ep]
        broker = Proc([*broker_argv, "--trace", str(d / "trace.jsonl")], d / "broker.log", "uwsimnet: running")
        procs.append(broker)
        recv = Proc(in_host(3 if netns else None, [PY, __file__, "--role", "recv", "--endpoint", ep,
                                                   "--seconds", str(seconds + 4), "--out", str(d / "err.json")]),
                    d / "recv.log", "ready")
        procs.append(recv)
        send = subprocess.run(in_host(2 if netns else None, [PY, __file__, "--role", "send", "--endpoint", ep,
                                                             "--seconds", str(seconds), "--rate", str(rate)]),
                              capture_output=True, text=True, timeout=seconds + 60, cwd=ROOT)
        recv.p.wait(seconds + 30)
        broker.stop(d / "broker.pid" if netns else None)
        err = json.loads((d / "err.json").read_text())["err"]
        sent = int(send.stdout.split()[-1]) if send.stdout.strip() else 0
        return {"setup": name, "sent": sent, "delivered": len(err), "median_us": pct(err, 0.5) * 1e6,
                "p99_us": pct(err, 0.99) * 1e6, "max_us": max(err, default=float("nan")) * 1e6}
    finally:
        for p in reversed(procs):
            if p.p.poll() is None:
                p.stop()
        if netns:
            subprocess.run([str(HOSTS), "down"], env=env, capture_output=True, timeout=60)


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--role", choices=["recv", "send"])
    ap.add_argument("--endpoint")
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--rate", type=float, default=10.0, help="frames per second")
    ap.add_argument("--out")
    a = ap.parse_args()
    if a.role == "recv":
        role_recv(a.endpoint, a.seconds, a.out)
        return 0
    if a.role == "send":
        role_send(a.endpoint, a.seconds, a.rate)
        return 0
    setups = ["one-host"] + (["netns"] if os.geteuid() == 0 else [])
    if len(setups) == 1:
        print("not root: netns setup skipped", file=sys.stderr)
    print(f"load average {os.getloadavg()[0]:.2f}; {a.rate:g} frames/s for {a.seconds:g} s, 16 B, 150 m")
    print("| setup | sent | delivered | median us | p99 us | max us |")
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for name in setups:
            r = run_setup(name, Path(tmp), a.seconds, a.rate)
            print(f"| {r['setup']} | {r['sent']} | {r['delivered']} | {r['median_us']:.0f} | {r['p99_us']:.0f}"
                  f" | {r['max_us']:.0f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
