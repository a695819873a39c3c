"""CPU time per transmitted frame inside one process (docs/benchmarks.md runs 4 and 5): the half-duplex
pure-ALOHA scene of bench_user_path.py, scene loaded and network built outside the timing, then
`time.process_time` around the run; best of `--repeat`.  Three set-ups: the bare engine (no listener),
+ metrics (the online Accumulator, as `uwsimnet run`), + metrics + the JSONL trace (`run --trace`).
Says whether the engine's compiled modules were loaded (uwsimnet_zenoh._native).

    .venv/bin/python bench/bench_frame_cpu.py --nodes 16,256 --frames 20000
"""

from __future__ import annotations

import argparse
import gc
import io
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_user_path import FRAME_TIME, scene_xml  # noqa: E402

try:                                            # absent before the compiled engine (main before run 5)
    from uwsimnet_zenoh import _native  # noqa: E402
except ImportError:
    _native = None
from uwsimnet_zenoh.analysis import Accumulator  # noqa: E402
from uwsimnet_zenoh.app.virtual import load_scene_file  # noqa: E402
from uwsimnet_zenoh.engine.network import Network  # noqa: E402
from uwsimnet_zenoh.trace.events import Callback, JsonlSink  # noqa: E402


def one(path: str, mode: str) -> tuple[float, int]:
    net = Network(load_scene_file(path))
    if mode != "bare":
        acc = Accumulator(net.meta())
        net.tracer.listen(Callback(acc.on_event))
    if mode == "trace":
        sink = JsonlSink(io.BytesIO())
        sink.header(net.meta())
        net.tracer.listen(sink)
    old = gc.get_threshold()
    gc.set_threshold(50_000, 20, 100)          # as uwsimnet run (app.virtual._rare_gc)
    t0 = time.process_time()
    net.run()
    if mode != "bare":
        acc.result()
    if mode == "trace":
        sink.flush()
    dt = time.process_time() - t0
    gc.set_threshold(*old)
    return dt, net.tracer.count("tx")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--nodes", default="16,256")
    ap.add_argument("--frames", type=int, default=20000, help="about this many frames offered")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--modes", default="bare,metrics,trace")
    a = ap.parse_args(argv)
    load = os.getloadavg()
    print(f"# {_native.status() if _native else 'pure Python (no uwsimnet_zenoh._native)'}; load {load[0]:.2f}")
    with tempfile.TemporaryDirectory() as d:
        for n in (int(x) for x in a.nodes.split(",")):
            path = Path(d) / f"aloha-half-{n}.xml"
            path.write_text(scene_xml(n, round(a.frames * FRAME_TIME, 3), half=True))
            cells = []
            for mode in a.modes.split(","):
                best, frames = min(one(str(path), mode) for _ in range(a.repeat))
                cells.append(f"{mode} {best / frames * 1e6:.1f} us")
            print(f"N = {n}: {frames} frames: " + "; ".join(cells), flush=True)
    load = os.getloadavg()
    print(f"# load at the end {load[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
