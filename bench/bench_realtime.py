"""Realtime fidelity of the Zenoh runtime (issue #4), with real processes over loopback TCP.

1. Delivery error with N modems (default 2, 16, 64), each vehicle's pose published at 50 Hz by a
   separate process (`--pose-phase spread`, the default: vehicle i at phase i/N of the period, as
   vehicles with clocks of their own publish; `burst`: all N poses at once each period, the broker's
   worst case): `uwsimnet run --clock realtime` (embedded router) in one process, the poses in a
   second, the applications in this one (every modem sends to its neighbour; one wildcard subscriber on
   `modem/*/rx`).  Delivery error = wall time at which the app gets a frame on `rx` minus the frame's
   modelled delivery time mapped to wall time (the broker's clock epoch + t_rx).  Also: the engine's own
   lateness (how late events ran on the engine thread, from the broker's summary) and the broker
   process's CPU use while the apps send (user + system, % of one core).
2. Broker overhead: app -> broker -> app with a zero modelled delay, against a bare Zenoh round trip
   through an echo process that is also a Python router (the same topology: app -> router+echo -> app).

Run: .venv/bin/python bench/bench_realtime.py [--modems 2,16,64] [--seconds 20] [--markdown]
"""

from __future__ import annotations

import argparse
import datetime
import importlib.metadata
import json
import math
import os
import platform
import re
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import msgpack
import zenoh

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def client(endpoint: str) -> zenoh.Config:
    c = zenoh.Config()
    c.insert_json5("mode", '"client"')
    c.insert_json5("connect/endpoints", json.dumps([endpoint]))
    c.insert_json5("connect/timeout_ms", "5000")
    c.insert_json5("scouting/multicast/enabled", "false")
    return c


def direct(fn):
    """Callbacks on Zenoh's network thread (no Python thread hop): the measuring side adds nothing."""
    return zenoh.handlers.Callback(fn, indirect=False)


def pct(xs: list[float], q: float) -> float:
    if not xs:
        return math.nan
    s = sorted(xs)
    return s[min(len(s) - 1, int(q * len(s)))]


# -- scenes ---------------------------------------------------------------------------------------
FLOOD = ("<flow><name>flood</name><src>fsrc</src><dst>254</dst><size>64000</size><interval>0.016</interval>"
         "</flow>")
"""4 MB/s of frames from fsrc to fbusy on channel 1 (its own air): what a stalled subscriber of fbusy's rx
stops reading (the stall rows).  Few big frames (62.5/s): the bytes fill the stalled consumer's buffers
while the broker's per-frame work stays small next to the line's (500 frames/s of 2 kB took the broker
to 70-90 % of a core: those rows measured a saturated broker, not the stall)."""


CHANNEL_MODEL = ""
"""`--channel-model bellhop`: the line's channel is acoustic (EvoLogics S2CR 18/34 presets) in the summer-thermocline
environment, its model Bellhop on a cached grid (computed by `uwsimnet validate` before the broker starts).
`acoustic`: the same modems and environment on the straight-path acoustic model (what Bellhop adds)."""
BELLHOP_ENV = """<environment><preset>summer-thermocline</preset><bathymetry>flat 100</bathymetry></environment>"""
BELLHOP_CHANNEL = """<AcousticCommsChannel><id>0</id><channelModel><name>bellhop</name><sources>0.5</sources>
<maxDepth>20</maxDepth><depthStep>1</depthStep><maxRange>400</maxRange><rangeStep>5</rangeStep></channelModel>
</AcousticCommsChannel>"""


def scene_xml(n: int, world: str, *, zero_delay: bool = False, flood: bool = False) -> str:
    """n vehicles (poseSource zenoh) 100 m apart on a line, one modem each, each hearing only its
    neighbours (150 m range; 16 B frames take 1.3 ms: no collisions with the staggered sends below);
    or 2 co-located modems with no modelled delay at all (zero_delay).  `flood`: plus two fast modems
    on a second channel, fsrc flooding fbusy (FLOOD)."""
    prop, bitrate = ("0", "1000000000") if zero_delay else ("0.6667", "100000")
    reach = 5000 if zero_delay else 150
    vs = []
    for i in range(n):
        src = "<position>0 0 0</position>" if zero_delay else "<poseSource>zenoh</poseSource>"
        vs.append(f"""<vehicle><name>v{i}</name>{src}<CustomCommsDevice><dccommsId>m{i}</dccommsId><mac>{addr(i)}</mac>
<txChannelId>0</txChannelId><rxChannelId>0</rxChannelId><bitrate>{bitrate}</bitrate><txFifoSize>100000</txFifoSize>
<intrinsicDelay>0</intrinsicDelay><maxDistance>{reach}</maxDistance><rateErrorModel><errorUnit>packet</errorUnit>
<errorRateExpr>0</errorRateExpr></rateErrorModel></CustomCommsDevice></vehicle>""")
    chans = f"<CustomCommsChannel><id>0</id><propTimeIncPerMeter>{prop}</propTimeIncPerMeter></CustomCommsChannel>"
    if CHANNEL_MODEL in ("bellhop", "acoustic") and not zero_delay and not flood:
        chans = BELLHOP_ENV + (BELLHOP_CHANNEL if CHANNEL_MODEL == "bellhop" else
                               "<AcousticCommsChannel><id>0</id></AcousticCommsChannel>")
        vs = [f"""<vehicle><name>v{i}</name><poseSource>zenoh</poseSource><AcousticCommsDevice>
<dccommsId>m{i}</dccommsId><mac>{addr(i)}</mac><txChannelId>0</txChannelId><rxChannelId>0</rxChannelId><preset>evologics-s2cr-18-34</preset>
<txFifoSize>100000</txFifoSize><maxDistance>{reach}</maxDistance></AcousticCommsDevice></vehicle>""" for i in range(n)]
    if flood:
        chans += "<CustomCommsChannel><id>1</id><propTimeIncPerMeter>0.6667</propTimeIncPerMeter></CustomCommsChannel>"
        for name, a, y in (("fsrc", 253, 10), ("fbusy", 254, 20)):
            vs.append(f"""<vehicle><name>{name}</name><position>0 {y} 10</position><CustomCommsDevice>
<dccommsId>{name}</dccommsId><mac>{a}</mac><txChannelId>1</txChannelId><rxChannelId>1</rxChannelId>
<bitrate>200000000</bitrate><txFifoSize>1000000</txFifoSize><maxDistance>2000</maxDistance><maxFrameBytes>65536</maxFrameBytes>
</CustomCommsDevice></vehicle>""")
    return f"""<?xml version="1.0"?><UWSimScene><simulation><seed>1</seed><clock>realtime</clock>
<world>{world}</world></simulation>{chans}{''.join(vs)}{FLOOD if flood else ''}</UWSimScene>"""


def addr(i: int) -> int:
    """Modem i's address: i + 1, skipping 255 (the broadcast address) for the swarm of 256."""
    return i + 1 if i + 1 < 255 else i + 2


def where(i: int, t: float) -> tuple[float, float, float]:
    return (100.0 * i + 2.0 * math.sin(t + i), 0.0, 10.0)     # a wobble: every sample is a real change


# -- helper processes -------------------------------------------------------------------------------
def role_poses(endpoint: str, world: str, n: int, hz: float, seconds: float, phase: str = "spread") -> None:
    """Every vehicle's pose at `hz`.  `phase` "spread": vehicle i at its own phase i/n of the period, as
    vehicles with clocks of their own publish; "burst": all n at once each period (one process for a
    swarm, the worst case for the broker: n samples arrive together)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    with zenoh.open(client(endpoint)) as s:
        pubs = [s.declare_publisher(f"uwsimnet/{world}/pose/v{i}") for i in range(n)]
        period = 1.0 / hz
        t0 = time.monotonic()
        k = 0
        while time.monotonic() - t0 < seconds:
            t = k * period
            for i, p in enumerate(pubs):
                if phase == "spread":
                    d = t0 + (k + i / n) * period - time.monotonic()
                    if d > 0:
                        time.sleep(d)
                p.put(msgpack.packb({"p": list(where(i, t))}))
            k += 1
            d = t0 + k * period - time.monotonic()
            if d > 0:
                time.sleep(d)


def role_listen(endpoint: str, key: str) -> None:
    """A subscriber of `key` that counts what it gets (the bench SIGSTOPs it: a stalled consumer)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    n = [0]
    with zenoh.open(client(endpoint)) as s:
        s.declare_subscriber(key, lambda smp: n.__setitem__(0, n[0] + 1))
        print("ready", flush=True)
        while True:
            time.sleep(0.2)
            print(n[0], flush=True)


def role_echo(endpoint: str) -> None:
    c = zenoh.Config()
    c.insert_json5("mode", '"router"')
    c.insert_json5("listen/endpoints", json.dumps([endpoint]))
    c.insert_json5("scouting/multicast/enabled", "false")
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *a: stop.set())
    signal.signal(signal.SIGTERM, lambda *a: stop.set())
    with zenoh.open(c) as s:
        pub = s.declare_publisher("bench/pong", express=True)
        s.declare_subscriber("bench/ping", direct(lambda smp: pub.put(smp.payload.to_bytes())))
        print("ready", flush=True)
        while not stop.wait(0.2):
            pass


def role_ticker(endpoint: str, rate: float) -> None:
    """The floor: the same realtime clock and an embedded router, but no simulation: events at
    scheduled times put {t, epoch} on `bench/tick` (what a broker does at a frame's delivery time)."""
    sys.path.insert(0, str(ROOT))
    from uwsimnet_zenoh.kernel.realtime import RealtimeClock
    from uwsimnet_zenoh.kernel.scheduler import Scheduler

    sys.setswitchinterval(0.0005)
    c = zenoh.Config()
    c.insert_json5("mode", '"router"')
    c.insert_json5("listen/endpoints", json.dumps([endpoint]))
    c.insert_json5("scouting/multicast/enabled", "false")
    sched = Scheduler()
    clock = RealtimeClock(sched)
    signal.signal(signal.SIGINT, lambda *a: clock.stop())
    signal.signal(signal.SIGTERM, lambda *a: clock.stop())
    with zenoh.open(c) as s:
        pub = s.declare_publisher("bench/tick", express=True)

        def tick(k: int) -> None:
            pub.put(msgpack.packb({"t": sched.now, "epoch": clock.wall_epoch()}))
            sched.at(1.0 + (k + 1) / rate + 0.0037 * (k % 7), tick, k + 1)
        sched.at(1.0, tick, 0)
        clock.start()
        print("ready", flush=True)
        clock.done.wait()
        clock.join(2)


def bench_floor(seconds: float, rate: float) -> dict:
    ep = f"tcp/127.0.0.1:{free_port()}"
    t = Sub([PY, __file__, "--role", "ticker", "--endpoint", ep, "--hz", str(rate)], "ready")
    got: list[tuple[float, bytes]] = []
    try:
        with zenoh.open(client(ep)) as s:
            s.declare_subscriber("bench/tick", direct(lambda smp: got.append((time.time(), smp.payload.to_bytes()))))
            time.sleep(seconds)
    finally:
        t.stop()
    err = [w - (m["epoch"] + m["t"]) for w, m in ((w, msgpack.unpackb(r)) for w, r in got)]
    return {"n": len(err), "err_median": pct(err, 0.5), "err_p99": pct(err, 0.99),
            "err_max": max(err, default=math.nan)}


class Sub:
    def __init__(self, argv: list[str], ready: str) -> None:
        err = None if os.environ.get("BENCH_DEBUG") else subprocess.DEVNULL
        self.p = subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.PIPE, stderr=err, text=True, bufsize=1)
        self.out: list[str] = []
        self.ready = threading.Event()
        threading.Thread(target=self._read, args=(ready,), daemon=True).start()
        if not self.ready.wait(30):
            self.stop()
            raise RuntimeError(f"{argv[:4]} did not start:\n{''.join(self.out)}")

    def _read(self, ready: str) -> None:
        for line in self.p.stdout:
            self.out.append(line)
            if line.startswith(ready):
                self.ready.set()

    def cpu_s(self) -> float:
        """CPU seconds (user + system) the process has used so far (Linux /proc), NaN if unknown."""
        try:
            f = Path(f"/proc/{self.p.pid}/stat").read_text().rsplit(")", 1)[1].split()
            return (int(f[11]) + int(f[12])) / os.sysconf("SC_CLK_TCK")
        except (OSError, ValueError, IndexError):
            return math.nan

    def stop(self) -> str:
        if self.p.poll() is None:
            self.p.send_signal(signal.SIGINT)
            try:
                self.p.wait(20)
            except subprocess.TimeoutExpired:
                self.p.kill()
                self.p.wait()
        time.sleep(0.1)
        return "".join(self.out)


BROKER_ZENOH_CONFIG: str | None = None
"""--broker-zenoh-config: a Zenoh configuration file for the broker (e.g. another wait_before_close)."""


def broker(scene: str, endpoint: str, tmp: Path, name: str) -> Sub:
    path = tmp / f"{name}.xml"
    path.write_text(scene)
    if CHANNEL_MODEL:                     # its grid is computed (once, then cached) before the run starts
        subprocess.run([PY, "-m", "uwsimnet_zenoh.cli", "validate", str(path)], check=True, cwd=ROOT)
    return Sub([PY, "-m", "uwsimnet_zenoh.cli", "run", str(path), "--clock", "realtime", "--listen", endpoint,
                "--trace", str(tmp / f"{name}.jsonl"),
                *(["--zenoh-config", BROKER_ZENOH_CONFIG] if BROKER_ZENOH_CONFIG else [])],
               "uwsimnet: running")


def engine_late(out: str) -> tuple[float, float]:
    m = re.search(r"late mean (\d+) us, max ([\d.]+) ms", out)
    return (float(m.group(1)) * 1e-6, float(m.group(2)) * 1e-3) if m else (math.nan, math.nan)


# -- 1. delivery error --------------------------------------------------------------------------------
def bench_delivery(n: int, seconds: float, pose_hz: float, tmp: Path, stall: str = "",
                   phase: str = "spread") -> dict:
    """`stall` "": the plain row; "flood": plus 4 MB/s of frames to fbusy on a second channel, read by a
    subscriber of fbusy's rx; "stalled": the same with that subscriber SIGSTOPped (its buffers fill and
    the broker's puts to it block): the delivery error of the line's modems should not move."""
    world = f"rt{n}{stall}"
    ep = f"tcp/127.0.0.1:{free_port()}"
    b = broker(scene_xml(n, world, flood=bool(stall)), ep, tmp, world)
    listener = None
    if stall:
        listener = Sub([PY, __file__, "--role", "listen", "--endpoint", ep, "--world",
                        f"uwsimnet/{world}/modem/fbusy/rx"], "ready")
    poses = subprocess.Popen([PY, __file__, "--role", "poses", "--endpoint", ep, "--world", world, "--n", str(n),
                              "--hz", str(pose_hz), "--seconds", str(seconds + 4), "--pose-phase", phase],
                             cwd=ROOT)
    got: list[tuple[float, bytes]] = []
    epochs: list[float] = []
    try:
        with zenoh.open(client(ep)) as s:
            s.declare_subscriber(f"uwsimnet/{world}/modem/m$*/rx", direct(lambda smp: got.append(
                (time.time(), smp.payload.to_bytes()))))
            s.declare_subscriber(f"uwsimnet/{world}/clock",
                                 lambda smp: epochs.append(msgpack.unpackb(smp.payload.to_bytes())["epoch"]))
            pubs = [s.declare_publisher(f"uwsimnet/{world}/modem/m{i}/tx", express=True) for i in range(n)]
            time.sleep(1.5)                              # poses known everywhere
            if listener is not None and stall == "stalled":
                listener.p.send_signal(signal.SIGSTOP)
                time.sleep(4.0)                          # its buffers fill (16 MB): the broker's puts to it back up
            cpu0, wall0 = b.cpu_s(), time.monotonic()
            rate = {2: 10.0, 16: 2.0}.get(n, 1.0)        # frames per second per modem
            period = 1.0 / rate
            t0 = time.monotonic()
            wall_t0 = time.time()
            k = 0
            sent = 0
            while time.monotonic() - t0 < seconds:
                for i, p in enumerate(pubs):             # staggered: modem i at t0 + (k + i/n) period
                    d = t0 + (k + i / n) * period - time.monotonic()
                    if d > 0:
                        time.sleep(d)
                    dst = addr(i + 1 if i + 1 < n else i - 1)   # the next one on the line (the last: the previous)
                    p.put(msgpack.packb({"dst": dst, "data": struct.pack("<d", time.time()) * 2}))
                    sent += 1
                k += 1
            time.sleep(1.0)
            cpu = (b.cpu_s() - cpu0) / (time.monotonic() - wall0)
            for p in pubs:
                p.undeclare()
    finally:
        poses.send_signal(signal.SIGINT)
        poses.wait(10)
        if listener is not None:
            listener.p.send_signal(signal.SIGCONT)
            listener.p.kill()
            listener.p.wait()
        out = b.stop()
    epoch = sorted(epochs)[len(epochs) // 2]
    err, e2e, late = [], [], []
    for wall, raw in got:
        m = msgpack.unpackb(raw)
        err.append(wall - (epoch + m["t_rx"]))
        if err[-1] > 0.05:
            late.append((round(wall - wall_t0, 3), round(err[-1], 3), m.get("src")))
        w_send = struct.unpack("<d", m["data"][:8])[0]
        e2e.append((wall - w_send) - (m["t_rx"] - m["t_tx"]))
    late_mean, late_max = engine_late(out)
    if late:
        print(f"{len(late)} frames > 50 ms late (s after the start, error s, src): {late[:20]}", file=sys.stderr)
    return {"n": n, "stall": stall, "lost_at_edge": "lost at the edge: fbusy" in out,
            "sent": sent, "delivered": len(got), "pose_msgs_per_s": n * pose_hz,
            "err_median": pct(err, 0.5), "err_p99": pct(err, 0.99), "err_max": max(err, default=math.nan),
            "e2e_median": pct(e2e, 0.5), "e2e_p99": pct(e2e, 0.99),
            "engine_late_mean": late_mean, "engine_late_max": late_max, "broker_cpu": cpu}


# -- 2. broker overhead vs bare round trip ---------------------------------------------------------------
def round_trips(s: zenoh.Session, put, arrived: threading.Event, stamps: list[float], count: int) -> list[float]:
    rtts = []
    for _ in range(count):
        arrived.clear()
        t = time.perf_counter()
        put()
        if not arrived.wait(2.0):
            continue
        rtts.append(stamps[-1] - t)
        time.sleep(0.002)
    return rtts


def bench_overhead(count: int, tmp: Path) -> dict:
    sys.setswitchinterval(0.0005)
    payload = msgpack.packb({"dst": 2, "data": bytes(16)})
    arrived = threading.Event()
    stamps: list[float] = []

    def hit(_smp) -> None:
        stamps.append(time.perf_counter())
        arrived.set()

    ep = f"tcp/127.0.0.1:{free_port()}"
    echo = Sub([PY, __file__, "--role", "echo", "--endpoint", ep], "ready")
    try:
        with zenoh.open(client(ep)) as s:
            s.declare_subscriber("bench/pong", direct(hit))
            pub = s.declare_publisher("bench/ping", express=True)
            time.sleep(0.5)
            round_trips(s, lambda: pub.put(payload), arrived, stamps, 100)
            bare = round_trips(s, lambda: pub.put(payload), arrived, stamps, count)
    finally:
        echo.stop()

    ep = f"tcp/127.0.0.1:{free_port()}"
    b = broker(scene_xml(2, "zero", zero_delay=True), ep, tmp, "zero")
    try:
        with zenoh.open(client(ep)) as s:
            s.declare_subscriber("uwsimnet/zero/modem/m1/rx", direct(hit))
            pub = s.declare_publisher("uwsimnet/zero/modem/m0/tx", express=True)
            time.sleep(0.5)
            round_trips(s, lambda: pub.put(payload), arrived, stamps, 100)
            via = round_trips(s, lambda: pub.put(payload), arrived, stamps, count)
    finally:
        b.stop()
    return {"count": count, "bare_median": pct(bare, 0.5), "bare_p99": pct(bare, 0.99),
            "broker_median": pct(via, 0.5), "broker_p99": pct(via, 0.99),
            "overhead_median": pct(via, 0.5) - pct(bare, 0.5), "overhead_p99": pct(via, 0.99) - pct(bare, 0.99)}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--role", choices=["main", "poses", "echo", "ticker", "listen"], default="main")
    ap.add_argument("--endpoint")
    ap.add_argument("--world")
    ap.add_argument("--n", type=int)
    ap.add_argument("--hz", type=float, default=50.0)
    ap.add_argument("--pose-phase", choices=["spread", "burst"], default="spread",
                    help="spread: each vehicle's poses at a phase of its own (vehicles with their own clocks);"
                         " burst: all vehicles' at once (one process for the swarm: the broker's worst case)")
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--modems", default="2,16,64")
    ap.add_argument("--round-trips", type=int, default=2000)
    ap.add_argument("--markdown", action="store_true")
    ap.add_argument("--channel-model", choices=["", "bellhop", "acoustic"], default="",
                    help="bellhop: the line's modems acoustic, the channel model Bellhop on a cached grid;"
                         " acoustic: the same modems and water on the straight path (Bellhop's share)")
    ap.add_argument("--broker-zenoh-config", metavar="FILE", help="the broker's Zenoh configuration file")
    ap.add_argument("--rt", type=int, default=0, help="SCHED_RR priority for broker and apps (0: normal)")
    ap.add_argument("--stall", type=int, default=0, metavar="N",
                    help="also N modems + a 4 MB/s flood on a 2nd channel, its rx subscriber running, then"
                         " SIGSTOPped (0: not measured)")
    a = ap.parse_args()
    global BROKER_ZENOH_CONFIG, CHANNEL_MODEL
    BROKER_ZENOH_CONFIG = a.broker_zenoh_config
    CHANNEL_MODEL = a.channel_model
    if a.role == "poses":
        role_poses(a.endpoint, a.world, a.n, a.hz, a.seconds, a.pose_phase)
        return
    if a.role == "listen":
        role_listen(a.endpoint, a.world)
        return
    if a.role == "echo":
        role_echo(a.endpoint)
        return
    if a.role == "ticker":
        role_ticker(a.endpoint, a.hz)
        return
    sys.setswitchinterval(0.0005)
    if a.rt:                 # the broker (env) and this process (the apps) under SCHED_RR
        os.environ["UWSIMNET_RT_PRIORITY"] = str(a.rt)
        os.sched_setscheduler(0, os.SCHED_RR, os.sched_param(a.rt))
    load = os.getloadavg()
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        floor = bench_floor(a.seconds, 50.0)
        rows = [bench_delivery(int(n), a.seconds, a.hz, tmp, phase=a.pose_phase) for n in a.modems.split(",") if n]
        if a.stall:
            rows += [bench_delivery(a.stall, a.seconds, a.hz, tmp, stall) for stall in ("flood", "stalled")]
        ov = bench_overhead(a.round_trips, tmp)
    load2 = os.getloadavg()
    us = 1e6
    zv = importlib.metadata.version("eclipse-zenoh")
    print(f"# realtime benchmark {datetime.date.today()} on {platform.machine()}, {os.cpu_count()} cores,"
          f" Python {platform.python_version()}, zenoh {zv}; load average before/after {load[0]:.2f}/{load2[0]:.2f}"
          + (f"; broker and apps SCHED_RR {a.rt}" if a.rt else ""))
    print()
    print(f"Delivery error ({a.seconds:g} s per row, poses {a.hz:g} Hz per vehicle, {a.pose_phase}), microseconds:")
    print()
    print("| modems | pose msgs/s | frames delivered | error median | error p99 | error max |"
          " app-to-app excess median | p99 | engine late mean | max | broker CPU |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    print(f"| floor: clock + router, no simulation | - | {floor['n']} | {floor['err_median'] * us:.0f} |"
          f" {floor['err_p99'] * us:.0f} | {floor['err_max'] * us:.0f} | - | - | - | - | - |")
    for r in rows:
        label = {"": str(r["n"]), "flood": f"{r['n']} + flood on ch 1, its subscriber reading",
                 "stalled": f"{r['n']} + flood on ch 1, its subscriber SIGSTOPped"
                            + (" (lost at its edge)" if r["lost_at_edge"] else "")}[r["stall"]]
        cells = [label, f"{r['pose_msgs_per_s']:.0f}", f"{r['delivered']}/{r['sent']}"]
        cells += [f"{r[k] * us:.0f}" for k in ("err_median", "err_p99", "err_max", "e2e_median", "e2e_p99",
                                               "engine_late_mean", "engine_late_max")]
        cells.append(f"{r['broker_cpu'] * 100:.0f} %")
        print("| " + " | ".join(str(c) for c in cells) + " |")
    print()
    print(f"Broker overhead ({ov['count']} sequential round trips, 16 B payload, zero modelled delay), microseconds:")
    print()
    print("| path | median | p99 |")
    print("|---|---|---|")
    for label, k in (("bare Zenoh: app -> router+echo (Python) -> app", "bare"),
                     ("app -> broker (tx -> engine -> rx) -> app", "broker"), ("overhead of the broker", "overhead")):
        print(f"| {label} | {ov[k + '_median'] * us:.0f} | {ov[k + '_p99'] * us:.0f} |")
    if not a.markdown:
        print()
        print(json.dumps({"floor": floor, "delivery": rows, "overhead": ov}, indent=1))


if __name__ == "__main__":
    main()
