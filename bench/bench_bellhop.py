"""The channel model "bellhop" (docs/ocean.md, "Bellhop: cost"): what a grid costs to compute with the real
program, and what one frame's query costs from a cached grid.

- grid: the grid of tests/data/ocean-shadow.xml's model (receiver depths every 2 m to 200 m, ranges every
  25 m to 2 km, 25 kHz, summer thermocline), computed by Bellhop for `--sources` source depths with
  `--workers` parallel runs (skipped, said in one line, when Bellhop is absent: `make bellhop`).
- query: the model built from the shipped grid (tests/data/bellhop/), one transmission to N receivers at
  random ranges and depths: `answer()` timed, best of `--repeat` batches, per call and per receiver; the
  straight-path `acoustic` model of the same device beside it.

- run (`--run N`): `uwsimnet run SCENE --trace` as a whole process on N sensors sending to a sink (pure
  ALOHA, acoustic modems in the summer thermocline), with the bellhop model (grid computed first by
  `uwsimnet validate`, into a temporary cache) and with the straight-path model: wall time, tx frames/s.

    .venv/bin/python bench/bench_bellhop.py --receivers 1,16,256 --sources 1,4 --run 256
"""

from __future__ import annotations

import argparse
import math
import os
import random
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "tests" / "data"
SCENE = DATA / "ocean-shadow.xml"
os.environ.setdefault("UWSIMNET_CACHE", str(DATA))        # the shipped grid, before the model is built

from uwsimnet_zenoh.engine.network import Network  # noqa: E402
from uwsimnet_zenoh.kernel.frame import Frame  # noqa: E402
from uwsimnet_zenoh.mobility.trajectory import PoseTable  # noqa: E402
from uwsimnet_zenoh.phy import bellhop  # noqa: E402
from uwsimnet_zenoh.phy.models import Query  # noqa: E402
from uwsimnet_zenoh.scene import load_scene, load_scene_text  # noqa: E402


def query(n: int, seed: int = 1, moving: bool = False) -> Query:
    """One transmission from the buoy (10 m deep) to n receivers at random ranges 30-1990 m, depths 1-199 m;
    `moving`: every receiver at a random velocity of up to 2 m/s per axis (the arrival's fixed point, Doppler)."""
    rnd = random.Random(seed)
    poses = PoseTable(["tx"] + [f"rx{i}" for i in range(n)])
    poses.set_static("tx", (0.0, 0.0, -10.0))
    dist = []
    for i in range(n):
        r, z, a = rnd.uniform(30, 1990), rnd.uniform(1, 199), rnd.uniform(0, 6.283)
        p = (r * math.cos(a), r * math.sin(a), -z)
        if moving:
            poses.set_external(f"rx{i}")
            poses.update(f"rx{i}", 0.0, p, tuple(rnd.uniform(-2, 2) for _ in range(3)))
        else:
            poses.set_static(f"rx{i}", p)
        dist.append(math.dist((0.0, 0.0, -10.0), p))
    return Query(0.0, Frame(1, 2, 0, 32, 32), dist, list(range(n)), poses, 0, list(range(1, n + 1)))


def best_us(fn, q: Query, repeat: int, forget=None) -> float:
    """Best over `repeat` batches of the mean time of one call, microseconds; `forget` (called before each
    call, its own time subtracted) empties the model's kept answers, so that every call interpolates."""
    calls = max(1, 2000 // max(1, len(q.slots)))
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(calls):
            if forget is not None:
                forget()
            fn(q)
        dt = time.perf_counter() - t0
        if forget is not None:
            t1 = time.perf_counter()
            for _ in range(calls):
                forget()
            dt -= time.perf_counter() - t1
        best = min(best, dt / calls)
    return best * 1e6


def bench_query(ns: list[int], repeat: int) -> None:
    net = Network(load_scene(SCENE))
    model = net.modems["buoy-modem"].error
    straight = Network(load_scene_text(_without_model(), str(SCENE))).modems["buoy-modem"].error
    print(f"query: grid {model.grid.tl.shape} (source, receiver depth, range) from {model.path.name}")
    print(f"query: Python floats up to {bellhop.MANY} receivers, numpy above")
    print("query: 'kept': the same transmission again (its answer kept: still, the pose table's version; moving,"
          " each link's two states)")

    def forget() -> None:
        model._memo.clear()
        model._links.clear()

    print(f"{'receivers':>9} {'bellhop us/call':>16} {'us/receiver':>12} {'kept us/call':>13} {'moving us/call':>15}"
          f" {'moving kept':>12} {'straight us/call':>17}")
    for n in ns:
        q, qm = query(n), query(n, moving=True)
        b = best_us(model.answer, q, repeat, forget)
        k = best_us(model.answer, q, repeat)
        m = best_us(model.answer, qm, repeat, forget)
        mk = best_us(model.answer, qm, repeat)
        s = best_us(straight.answer, q, repeat)
        print(f"{n:>9} {b:>16.1f} {b / n:>12.2f} {k:>13.1f} {m:>15.1f} {mk:>12.1f} {s:>17.1f}")


def _without_model() -> str:
    text = SCENE.read_text()
    return text[:text.index("<channelModel>\n")] + text[text.index("</channelModel>") + len("</channelModel>"):]


def _version(program: str) -> str:
    """aubellhop's version when the program is the one its wheel ships, else 'version unknown'."""
    for d in Path(program).resolve().parents:
        found = sorted(d.glob("aubellhop-*.dist-info"))
        if found:
            return found[0].name.removesuffix(".dist-info").replace("-", " ")
    return "version unknown"


def bench_grid(counts: list[int], workers: int) -> None:
    program = bellhop.find_program()
    if program is None:
        print(f"grid: skipped: {bellhop.HOWTO}")
        return
    env = load_scene(SCENE).environment
    assert env is not None
    profile = [tuple(p) for p in env.profile]
    seabed = (env.seabed_speed_mps, env.seabed_density, env.seabed_attenuation)
    rds = [min(max(z, 0.5), env.depth_m - 0.5) for z in range(0, 201, 2)]
    rrs = [25.0 * k for k in range(1, 81)]
    print(f"grid: {program} ({_version(program)}), {len(rds)} depths x {len(rrs)} ranges, "
          f"{workers} workers")
    for ns in counts:
        sds = [10.0 + 40.0 * i for i in range(ns)]
        t0 = time.perf_counter()
        with tempfile.TemporaryDirectory():
            g = bellhop.compute_grid(program, 25_000.0, profile, env.depth_m, seabed, sds, rds, rrs, workers=workers)
        dt = time.perf_counter() - t0
        print(f"  {ns} source depth(s): {dt:.2f} s wall ({dt / ns:.2f} s per source depth), "
              f"{g.tl.size} TL cells")


def run_scene(n: int, duration: float, model: bool) -> str:
    """N sensors on a 500 m circle at 50 m depth sending to a sink at its centre (Poisson, 32-byte frames,
    20 frames/s in all, no MAC, no queue: pure ALOHA), EvoLogics S2CR 18/34 modems in the summer thermocline;
    `model`: with the bellhop channel model (its grid: source depth 50 m, 0-200 m every 2 m, 25-1200 m every
    25 m; the delay-spread loss off, so that both models deliver alike and the runs do the same work: with it,
    the 500 m links at 50 m depth lose most frames to the echoes, f = 0.24 of the energy a bit late), else the
    straight-path acoustic model."""
    dev = ("<AcousticCommsDevice><dccommsId>{id}</dccommsId><mac>{mac}</mac><txChannelId>0</txChannelId>"
           "<rxChannelId>0</rxChannelId><preset>evologics-s2cr-18-34</preset><txFifoSize>0</txFifoSize>"
           "<macProtocol><name>none</name><delivery>addressee</delivery></macProtocol></AcousticCommsDevice>")
    cm = ("<channelModel><name>bellhop</name><sources>50</sources><maxDepth>200</maxDepth><depthStep>2</depthStep>"
          "<maxRange>1200</maxRange><rangeStep>25</rangeStep><isi>off</isi></channelModel>") if model else ""
    out = ["<UWSimScene>", f"<simulation><duration>{duration!r}</duration><seed>1</seed></simulation>",
           "<environment><origin>41.38 2.18</origin><preset>summer-thermocline</preset>"
           "<bathymetry>flat 1000</bathymetry></environment>",
           f"<AcousticCommsChannel><id>0</id>{cm}</AcousticCommsChannel>",
           f"<vehicle><name>sink</name><position>0 0 -50</position>{dev.format(id='sink', mac=0)}</vehicle>"]
    for i in range(n):
        a = 2 * math.pi * i / n
        out.append(f"<vehicle><name>v{i}</name><position>{500 * math.cos(a)!r} {500 * math.sin(a)!r} -50</position>"
                   f"{dev.format(id=f's{i}', mac=i + 1 + (i >= 254))}</vehicle>")
        out.append(f"<flow><name>s{i}</name><src>s{i}</src><dst>0</dst><size>32</size><interval>{n / 20.0!r}"
                   "</interval><arrival>poisson</arrival></flow>")
    return "\n".join(out + ["</UWSimScene>"]) + "\n"


def bench_run(n: int, duration: float, repeat: int) -> None:
    """`uwsimnet run SCENE --trace` as a process, with and without the bellhop model, best of `repeat`."""
    uwsimnet = str(Path(sys.executable).parent / "uwsimnet")
    with tempfile.TemporaryDirectory() as d:
        env = dict(os.environ, UWSIMNET_CACHE=d)
        rows = []
        for model in (True, False):
            scene = Path(d) / f"{'bellhop' if model else 'straight'}-{n}.xml"
            scene.write_text(run_scene(n, duration, model))
            t0 = time.perf_counter()
            v = subprocess.run([uwsimnet, "validate", str(scene)], env=env, capture_output=True, text=True)
            if v.returncode != 0:
                print(f"run: {scene.name}: {v.stderr.strip()}")
                return
            grid = time.perf_counter() - t0
            best = float("inf")
            for _ in range(repeat):
                t0 = time.perf_counter()
                subprocess.run([uwsimnet, "run", str(scene), "--trace", f"{d}/t.jsonl"], env=env, check=True,
                               capture_output=True)
                best = min(best, time.perf_counter() - t0)
            lines = Path(f"{d}/t.jsonl").read_text().splitlines()
            tx = sum('"ev":"tx"' in x.replace(" ", "") for x in lines)
            rx = sum('"ev":"rx"' in x.replace(" ", "") for x in lines)
            rows.append((scene.stem, grid, best, tx, rx))
        print(f"run: N = {n}, {duration:g} s simulated, `uwsimnet run --trace`, best of {repeat} (whole process)")
        for name, grid, wall, tx, rx in rows:
            print(f"  {name:>14}: validate {grid:.2f} s (the grid, when bellhop), run {wall:.2f} s, {tx} tx, "
                  f"{rx} rx, {tx / wall:.0f} tx frames/s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--receivers", default="1,16,256")
    ap.add_argument("--sources", default="1,4", help="source-depth counts of the grids to time ('' = none)")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--run", type=int, default=0, help="N: also time `uwsimnet run --trace` on N sensors")
    ap.add_argument("--duration", type=float, default=250.0, help="simulated s of --run")
    a = ap.parse_args()
    bench_query([int(x) for x in a.receivers.split(",") if x], a.repeat)
    bench_grid([int(x) for x in a.sources.split(",") if x], a.workers)
    if a.run:
        if bellhop.find_program() is None:
            print(f"run: skipped: {bellhop.HOWTO}")
        else:
            bench_run(a.run, a.duration, min(a.repeat, 3))
    sys.stdout.flush()


if __name__ == "__main__":
    main()
