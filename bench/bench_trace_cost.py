"""CPU time per transmitted frame inside one process: the bare engine, + the online metrics (`uwsimnet run`),
+ the metrics and the JSONL trace (`uwsimnet run --trace`), on bench_user_path.py's half-duplex ALOHA scene
(issue #19; docs/benchmarks.md, runs 4 and 5b).

The scene is loaded and the Network built outside the timing; `time.process_time()` covers the run, the last
batch and the end-of-run settling of the metrics (`Accumulator.result()`), with the cyclic GC spaced as
`uwsimnet run` spaces it.  Best of `--repeat` runs per configuration, the configurations interleaved.
Works on any checkout of the project (the tracer's batch consumers if it has them, its event listeners
otherwise), so one script measures before and after:

    .venv/bin/python bench/bench_trace_cost.py --nodes 16,256 --frames 20000
"""

from __future__ import annotations

import argparse
import gc
import math
import os
import sys
import tempfile
import time
from pathlib import Path

# the project of the interpreter running this (its venv's install), imported before the scene writer, whose
# imports put this checkout on sys.path: main's .venv/bin/python measures main with this same script
from uwsimnet_zenoh.analysis import Accumulator
from uwsimnet_zenoh.app.checks import build_network
from uwsimnet_zenoh.app.virtual import load_scene_file
from uwsimnet_zenoh.trace.events import JsonlSink, Tracer

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_user_path import FRAME_TIME, scene_xml  # noqa: E402

BATCHED = hasattr(Tracer, "consume")


def _listener(fn):
    """`fn` as a listener of the tracer: a `Callback` where the output port has one (listeners are objects),
    the function itself before."""
    try:
        from uwsimnet_zenoh.trace.tracer import Callback  # noqa: PLC0415 - absent from older checkouts
    except ImportError:
        return fn
    return Callback(fn)


def one(scene, mode: str, trace_path: Path) -> tuple[float, int]:
    """(CPU s, frames transmitted) of one run: mode bare | metrics | trace."""
    net = build_network(scene, seed=1, duration=None)
    acc = fh = jsonl = None
    if mode != "bare":
        acc = Accumulator(net.meta())
        if BATCHED:
            net.tracer.consume(acc.on_batch)
        else:
            net.tracer.listen(_listener(acc.on_event))
    if mode == "trace":
        fh = open(trace_path, "wb")  # noqa: SIM115 - closed below, outside the timing
        jsonl = JsonlSink(fh)
        jsonl.header(net.meta())
        if BATCHED:
            net.tracer.consume(jsonl.write_batch)
        else:
            net.tracer.listen(_listener(jsonl.event))
    old = gc.get_threshold()
    gc.collect()
    gc.set_threshold(50_000, 20, 100)
    try:
        t0 = time.process_time()
        net.run()
        if BATCHED:
            net.tracer.flush()
        if jsonl is not None:
            jsonl.flush()
        if acc is not None:
            acc.result()
        cpu = time.process_time() - t0
    finally:
        gc.set_threshold(*old)
    if fh is not None:
        fh.close()
    return cpu, net.tracer.count("tx")


def replay(scene, trace_path: Path, repeat: int) -> tuple[int, dict[str, float]]:
    """The tracer's part alone: the events of one run recorded (the engine's `emit` arguments, frames
    included), then replayed into a fresh Tracer with nothing / the metrics / the metrics and the JSONL
    writer listening, CPU s of each (emits, last batch, `result()`), best of `repeat`, interleaved."""
    net = build_network(scene, seed=1, duration=None)
    log: list[tuple] = []
    net.tracer.listen(_listener(lambda *a: log.append(a)))
    net.run()
    frames = sum(1 for a in log if a[1] == "tx")
    meta = net.meta()
    best = {"emit": math.inf, "metrics": math.inf, "trace": math.inf}
    old = gc.get_threshold()
    gc.set_threshold(50_000, 20, 100)
    try:
        for _ in range(repeat):
            for mode in best:
                tr = Tracer()
                acc = jsonl = None
                with open(trace_path, "wb") as fh:
                    if mode != "emit":
                        acc = Accumulator(meta)
                        if BATCHED:
                            tr.consume(acc.on_batch)
                        else:
                            tr.listen(_listener(acc.on_event))
                    if mode == "trace":
                        jsonl = JsonlSink(fh)
                        if BATCHED:
                            tr.consume(jsonl.write_batch)
                        else:
                            tr.listen(_listener(jsonl.event))
                    emit = tr.emit
                    gc.collect()
                    t0 = time.process_time()
                    for a in log:
                        emit(*a)
                    if BATCHED:
                        tr.flush()
                    if jsonl is not None:
                        jsonl.flush()
                    if acc is not None:
                        acc.result()
                    best[mode] = min(best[mode], time.process_time() - t0)
    finally:
        gc.set_threshold(*old)
    return frames, best


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--nodes", default="16,256")
    ap.add_argument("--frames", type=int, default=20000, help="about this many frames offered per run")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--modes", default="bare,metrics,trace")
    ap.add_argument("--full", action="store_true", help="full-duplex sensors instead of half duplex")
    ap.add_argument("--replay", action="store_true",
                    help="the tracer's part alone: a run's events replayed into the tracer (emit / + metrics /"
                         " + metrics + JSONL), less noisy than whole runs on a shared machine")
    args = ap.parse_args(argv)
    print(f"# {Path(sys.modules['uwsimnet_zenoh'].__file__).parent.parent}:"
          f" {'batched' if BATCHED else 'listeners'}; load {os.getloadavg()[0]:.2f}", flush=True)
    print("| N | frames | " + " | ".join(args.modes.split(",")) + " |  (us CPU per transmitted frame, best of"
          f" {args.repeat})")
    with tempfile.TemporaryDirectory() as tmp:
        for n in (int(x) for x in args.nodes.split(",")):
            duration = round(args.frames * FRAME_TIME, 3)
            path = Path(tmp) / f"aloha-{n}.xml"
            path.write_text(scene_xml(n, duration, half=not args.full))
            scene = load_scene_file(str(path))
            if args.replay:
                frames, best = replay(scene, Path(tmp) / "t.jsonl", args.repeat)
                print(f"| {n} | {frames} | replay: emit {best['emit'] / frames * 1e6:.1f} | + metrics"
                      f" {best['metrics'] / frames * 1e6:.1f} | + metrics + trace {best['trace'] / frames * 1e6:.1f} |",
                      flush=True)
                continue
            modes = args.modes.split(",")
            best = dict.fromkeys(modes, math.inf)
            frames = 0
            for _ in range(args.repeat):        # the modes interleaved: each sees the same machine
                for mode in modes:
                    cpu, frames = one(scene, mode, Path(tmp) / "t.jsonl")
                    best[mode] = min(best[mode], cpu)
            cells = [f"{best[m] / frames * 1e6:.1f}" for m in modes]
            print(f"| {n} | {frames} | " + " | ".join(cells) + " |", flush=True)
    print(f"# load {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
