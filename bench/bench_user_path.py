"""The user's path against ns-3 UAN: `uwsimnet run SCENE [--trace t.jsonl]` as a process, side by side with the
compiled ns-3.44 program on ns-3's reference pure-ALOHA scenario (issue #19; docs/benchmarks.md).

Scenario (../shared/notes/ns3-reference.md, uwsimnet_zenoh/experiments/aloha.py): a sink at the centre of a
500 m circle of N sensors, 1000 bps, 40-byte frames (37 B payload + 3 B header), Poisson traffic of G = 1 frame
time in total, no MAC (NOMAC with `delivery addressee`: a frame is handed up only at its addressee, as ns-3's
UanMacAloha does), no queue.  Two variants of the sensors: half duplex (they listen on the channel they
send on, as ns-3's UanPhyGen does) and full duplex (they listen on another channel: the textbook model of
bench_engine.py).  For each N the benchmark writes both scenes as XML files and runs, one after the other on
the same machine:

- ns-3: bench/ns3_aloha.cc compiled against the ns3 wheel (bench_ns3_aloha.build), same N, G, duration;
- bare engine: a process that loads the scene, builds the Network and runs it with no listener at all (with
  the start-up of the command: pydantic's plugin scan off, as cli/__init__.py sets it);
- `uwsimnet run SCENE` (online summary, no trace) and `uwsimnet run SCENE --trace t.jsonl`.

Every figure is a whole process (start-up, imports and scene loading included) timed with wait4, which also
gives its peak RSS (`--repeat R`: the fastest of R runs of each process, the processes of one N taken in
turn); ns-3's own Simulator::Run time is shown too.  frames = transmissions (tx), counted by the bare engine
(the runs are deterministic: the same frames in all three of ours).

    python -m venv /tmp/ns3venv && /tmp/ns3venv/bin/pip install --no-deps ns3    # outside the repo (headers, libs)
    .venv/bin/python bench/bench_user_path.py --ns3 /tmp/ns3venv/lib/python3.11/site-packages/ns3
    .venv/bin/python bench/bench_user_path.py --big          # N = 10 000, 100 000 frames: wall and peak RSS
    .venv/bin/python bench/bench_user_path.py --nodes 256 --modes half,half-bellhop --repeat 3   # issue #37
"""

from __future__ import annotations

import argparse
import datetime
import math
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_ns3_aloha import build  # noqa: E402

PAYLOAD, HEADER, BITRATE, RADIUS = 37, 3, 1000, 500.0
FRAME_TIME = (PAYLOAD + HEADER) * 8 / BITRATE
UWSIMNET = [str(Path(sys.executable).parent / "uwsimnet")]


BELLHOP_DEPTH = 50.0
"""Depth of every modem in the `bellhop` variant (m): under the summer thermocline's layer, so that the
500 m links are lit and both models deliver alike."""


def scene_xml(n: int, duration: float, *, half: bool, load: float = 1.0, seed: int = 1,
              model: str = "straight") -> str:
    """The reference ALOHA scene as a scene file (the same as experiments.aloha.scene, sensors' rx channel
    0 for half duplex, 1 for full duplex).  `model` "bellhop": the same sensors, traffic and MAC as acoustic
    modems (EvoLogics S2CR 18/34's carrier and source level, 1000 bps, 3-byte header) at 50 m depth in the
    summer-thermocline preset, the channel answered by the ray-traced `bellhop` model from a grid computed
    before the timed runs (`uwsimnet validate`; delay-spread loss off, docs/ocean.md)."""
    interval = n * FRAME_TIME / load
    if model == "bellhop":
        dev = ("<AcousticCommsDevice><dccommsId>{id}</dccommsId><mac>{mac}</mac><txChannelId>0</txChannelId>"
               "<rxChannelId>{rx}</rxChannelId><preset>evologics-s2cr-18-34</preset><bitrate>1000</bitrate>"
               "<txFifoSize>0</txFifoSize><headerBytes>3</headerBytes>"
               "<macProtocol><name>none</name><delivery>addressee</delivery></macProtocol></AcousticCommsDevice>")
        cm = (f"<channelModel><name>bellhop</name><sources>{BELLHOP_DEPTH!r}</sources><maxDepth>100</maxDepth>"
              "<depthStep>2</depthStep><maxRange>600</maxRange><rangeStep>25</rangeStep><isi>off</isi>"
              "</channelModel>")
        channels = ["<environment><origin>41.38 2.18</origin><preset>summer-thermocline</preset>"
                    "<bathymetry>flat 1000</bathymetry></environment>",
                    f"<AcousticCommsChannel><id>0</id>{cm}</AcousticCommsChannel>",
                    f"<AcousticCommsChannel><id>1</id>{cm}</AcousticCommsChannel>"]
        z = -BELLHOP_DEPTH
    else:
        dev = ("<CustomCommsDevice><dccommsId>{id}</dccommsId><mac>{mac}</mac><txChannelId>0</txChannelId>"
               "<rxChannelId>{rx}</rxChannelId><bitrate>1000</bitrate><txFifoSize>0</txFifoSize>"
               "<headerBytes>3</headerBytes><rateErrorModel><errorUnit>packet</errorUnit>"
               "<errorRateExpr>0</errorRateExpr></rateErrorModel>"
               "<macProtocol><name>none</name><delivery>addressee</delivery></macProtocol></CustomCommsDevice>")
        channels = ["<CustomCommsChannel><id>0</id><propTimeIncPerMeter>0.6666666666666666</propTimeIncPerMeter>"
                    "<minPropTime>0</minPropTime></CustomCommsChannel>",
                    "<CustomCommsChannel><id>1</id><propTimeIncPerMeter>0.6666666666666666</propTimeIncPerMeter>"
                    "<minPropTime>0</minPropTime></CustomCommsChannel>"]
        z = 0.0
    out = ["<UWSimScene>",
           f"<simulation><duration>{duration!r}</duration><seed>{seed}</seed><clock>virtual</clock>"
           f"<world>aloha-{'half' if half else 'full'}-{n}</world></simulation>", *channels,
           f"<vehicle><name>sink</name><position>0 0 {z!r}</position>{dev.format(id='sink', mac=0, rx=0)}</vehicle>"]
    for i in range(n):
        a = 2 * math.pi * i / n
        mac = i + 1 + (i >= 254)
        out.append(f"<vehicle><name>sensor{i}</name><position>{RADIUS * math.cos(a)!r} {RADIUS * math.sin(a)!r}"
                   f" {z!r}</position>{dev.format(id=f's{i}', mac=mac, rx=0 if half else 1)}</vehicle>")
        out.append(f"<flow><name>s{i}</name><src>s{i}</src><dst>0</dst><size>{PAYLOAD}</size>"
                   f"<interval>{interval!r}</interval><arrival>poisson</arrival></flow>")
    out.append("</UWSimScene>")
    return "\n".join(out) + "\n"


def timed(cmd: list[str]) -> tuple[float, int, str]:
    """(wall s, peak RSS bytes, stdout) of one process."""
    with tempfile.TemporaryFile() as out:
        t0 = time.perf_counter()
        p = subprocess.Popen(cmd, stdout=out, stderr=subprocess.DEVNULL)
        _, status, ru = os.wait4(p.pid, 0)
        wall = time.perf_counter() - t0
        p.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        text = out.read().decode()
    if p.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)}: exit {p.returncode}")
    return wall, ru.ru_maxrss * 1024, text


BARE = """
import os, sys, time
os.environ.setdefault("PYDANTIC_DISABLE_PLUGINS", "__all__")     # the start-up of the command (cli/__init__.py)
from uwsimnet_zenoh.app.virtual import load_scene_file
from uwsimnet_zenoh.engine.network import Network
net = Network(load_scene_file(sys.argv[1]))
t0 = time.perf_counter()
net.run()
print(net.tracer.count("tx"), net.modems["sink"].counters["rx"], time.perf_counter() - t0)
"""


def bests(cmds: list[list[str]], repeat: int) -> list[tuple[float, int, str]]:
    """`timed(cmd)` of the fastest of `repeat` runs of each command, the commands taken in turn (one run of
    each, then the next round): the VM's speed drifts over minutes, and interleaved runs see the same drift,
    so their ratios hold better than those of runs timed one command after the other.  (The same output
    every time: the runs are deterministic.)"""
    out: list[tuple[float, int, str] | None] = [None] * len(cmds)
    for _ in range(repeat):
        for i, cmd in enumerate(cmds):
            r = timed(cmd)
            if out[i] is None or r[0] < out[i][0]:  # type: ignore[index]
                out[i] = r
    return out  # type: ignore[return-value]


def bench_n(n: int, frames: int, binary: Path | None, modes: list[str], tmp: Path, repeat: int = 1) -> list[dict]:
    """`modes`: half, full, or either with "-bellhop" (the `bellhop` channel model: its grid is computed here,
    before any timed run, into the cache of $UWSIMNET_CACHE)."""
    duration = round(frames / (1 / FRAME_TIME), 3)     # G = 1: one frame time of offered traffic per T
    rows = []
    cmds: list[list[str]] = []
    if binary is not None:
        cmds.append([str(binary), str(n), "1", str(duration), "1"])
    for mode in modes:
        path = tmp / f"aloha-{mode}-{n}.xml"
        half, _, model = mode.partition("-")
        path.write_text(scene_xml(n, duration, half=half == "half", model=model or "straight"))
        if model:
            v = subprocess.run([*UWSIMNET, "validate", str(path)], capture_output=True, text=True)
            if v.returncode != 0:
                raise SystemExit(f"{path.name}: {v.stderr.strip()}")
        cmds += [[sys.executable, "-c", BARE, str(path)], [*UWSIMNET, "run", str(path)],
                 [*UWSIMNET, "run", str(path), "--trace", str(tmp / f"t-{mode}.jsonl")]]
    got = bests(cmds, repeat)
    ns3 = None
    if binary is not None:
        wall, rss, text = got.pop(0)
        _, sent, rx, run_s = text.split()
        ns3 = {"wall": wall, "rss": rss, "frames": int(sent), "run_s": float(run_s), "rx": int(rx)}
    for k, mode in enumerate(modes):
        (bare_wall, bare_rss, text), (run_wall, run_rss, _), (tr_wall, tr_rss, _) = got[3 * k:3 * k + 3]
        sent, rx, bare_run = text.split()
        rows.append({"n": n, "mode": mode, "sim_s": duration, "frames": int(sent), "rx": int(rx),
                     "bare": bare_wall, "bare_run": float(bare_run), "bare_rss": bare_rss,
                     "run": run_wall, "run_rss": run_rss, "trace": tr_wall, "trace_rss": tr_rss,
                     "trace_bytes": (tmp / f"t-{mode}.jsonl").stat().st_size, "ns3": ns3})
    return rows


def fmt(rows: list[dict]) -> str:
    lines = ["| N | sensors | frames | ns-3 frames/s (process; Run only) | bare engine frames/s | `uwsimnet run`"
             " frames/s | `run --trace` frames/s | run / bare | --trace / ns-3 | run / ns-3 | peak RSS run, --trace,"
             " ns-3 MB |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        f = r["frames"]
        ns3 = r["ns3"]
        ns3_fps = ns3["frames"] / ns3["wall"] if ns3 else None
        ns3_cell = f"{ns3_fps:,.0f}; {ns3['frames'] / ns3['run_s']:,.0f}" if ns3 else "-"
        run_fps, tr_fps, bare_fps = f / r["run"], f / r["trace"], f / r["bare"]

        def ratio(x: float, ns3_fps: float | None = ns3_fps) -> str:
            return f"{x / ns3_fps:.1f}x" if ns3_fps else "-"
        mb = f"{r['run_rss'] / 2**20:.0f}, {r['trace_rss'] / 2**20:.0f}, " + (
            f"{ns3['rss'] / 2**20:.0f}" if ns3 else "-")
        lines.append(f"| {r['n']} | {r['mode']} | {f} | {ns3_cell} | {bare_fps:,.0f} | {run_fps:,.0f} | {tr_fps:,.0f} |"
                     f" {bare_fps / run_fps:.2f} slower | {ratio(tr_fps)} | {ratio(run_fps)} | {mb} |")
    return "\n".join(lines)


def big(n: int, frames: int, tmp: Path) -> str:
    duration = round(frames / (1 / FRAME_TIME), 3)
    lines = ["| N | sensors | sim s | frames | command | wall s | peak RSS MB |", "|---|---|---|---|---|---|---|"]
    for mode in ("half", "full"):
        path = tmp / f"aloha-{mode}-{n}.xml"
        path.write_text(scene_xml(n, duration, half=mode == "half"))
        wall, rss, text = timed([sys.executable, "-c", BARE, str(path)])
        sent = int(text.split()[0])
        lines.append(f"| {n} | {mode} | {duration:g} | {sent} | bare engine | {wall:.1f} | {rss / 2**20:.0f} |")
        for extra in ([], ["--trace", str(tmp / "t.jsonl")]):
            wall, rss, _ = timed([*UWSIMNET, "run", str(path), *extra])
            label = "`uwsimnet run" + (" --trace`" if extra else "`")
            lines.append(f"| {n} | {mode} | {duration:g} | {sent} | {label} | {wall:.1f} | {rss / 2**20:.0f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ns3", type=Path, default=Path(os.environ.get(
        "NS3_DIR", "/tmp/ns3venv/lib/python3.11/site-packages/ns3")), help="the ns3 wheel's package folder")
    ap.add_argument("--binary", type=Path, default=Path("/tmp/ns3_aloha"))
    ap.add_argument("--no-ns3", action="store_true", help="our side only")
    ap.add_argument("--nodes", default="16,64,256,1024")
    ap.add_argument("--modes", default="half,full",
                    help="half, full, half-bellhop, full-bellhop (the ray-traced channel model; needs Bellhop"
                         " or a cached grid)")
    ap.add_argument("--frames", type=int, default=20000, help="about this many frames offered per run")
    ap.add_argument("--big", action="store_true", help="only the N = 10 000, 100 000 frames run (memory)")
    ap.add_argument("--repeat", type=int, default=1, help="each process this many times, the fastest kept")
    a = ap.parse_args(argv)
    load = os.getloadavg()
    print(f"# uwsimnet run vs ns-3 UAN, {datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M} UTC,"
          f" {platform.machine()} x {os.cpu_count()} cores, Python {platform.python_version()},"
          f" load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}\n")
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        if a.big:
            print(big(10_000, 100_000, tmp))
            return 0
        binary = None if a.no_ns3 else build(a.ns3, a.binary)
        rows = []
        for n in (int(x) for x in a.nodes.split(",")):
            rows += bench_n(n, a.frames, binary, a.modes.split(","), tmp, a.repeat)
            print(f"N = {n} done", file=sys.stderr, flush=True)
    print(fmt(rows))
    load = os.getloadavg()
    print(f"\nload average at the end {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
