"""Virtual-time runs: a scene file to a Network run to its end, its trace, and the summary table.

Used by `uwsimnet run`, the experiments and the tests; its outputs (trace writer, tracing plug-in, online
metrics) are assembled by assembly/outputs.py, as for the realtime clock (app/realtime.py).  The summary is
computed online, as the run goes (analysis.Accumulator on the output port), so a run without --trace builds
no record at all and a run with one never reads its trace back; `uwsimnet report` on the trace gives the
same numbers."""

from __future__ import annotations

import gc
import signal
import sys
import traceback
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from ..analysis import Analysis, flow_metrics, show_metrics
from ..assembly.outputs import Outputs
from ..engine.network import Network
from ..errors import UserError
from ..kernel.scheduler import Interrupted
from ..scene.load import SceneError, load_scene
from .checks import Interrupt, build_network, tracing_sink


def _warn(msg: str) -> None:
    print(msg, file=sys.stderr)


def summarise_warnings(warnings: list[str]) -> list[str]:
    """One line per kind of warning (same message, any line): the first one, with how many there were.

    `file:12: warning: <file> in <vehicle> ignored (UWSim 3D scene element) [x5, -v lists all]`"""
    kinds: dict[str, list[str]] = {}
    for w in warnings:
        head, sep, msg = w.partition(": warning: ")
        kinds.setdefault(msg if sep else w, []).append(w)
    out = []
    for same in kinds.values():
        out.append(same[0] if len(same) == 1 else f"{same[0]} [x{len(same)}, -v lists all]")
    return out


def load_scene_file(path: str, verbose: bool = False):
    """A scene from a file, or UserError with the one-line `file:line: message`.  Warnings go to stderr,
    one line per kind (`verbose`: every one)."""
    if not Path(path).is_file():
        raise UserError(f"{path}: no such scene file")
    warnings: list[str] = []
    try:
        scene = load_scene(path, on_warning=warnings.append)
    except SceneError as e:
        for w in warnings if verbose else summarise_warnings(warnings):
            _warn(w)
        raise UserError(str(e)) from None
    for w in warnings if verbose else summarise_warnings(warnings):
        _warn(w)
    return scene


@dataclass
class VirtualRun:
    net: Network
    analysis: Analysis | None       # the online metrics (None unless asked for)


def run_virtual(scene, *, seed: int | None, duration: float | None, trace_path: Path | None,
                progress: bool = True):
    """Run a scene in virtual time, writing its trace (if `trace_path`); returns the Network."""
    return simulate(scene, seed=seed, duration=duration, trace_path=trace_path, progress=progress,
                    metrics=False).net


def simulate(scene, *, seed: int | None, duration: float | None, trace_path: Path | None = None,
             progress: bool = True, metrics: bool = True) -> VirtualRun:
    """Run a scene in virtual time: the trace if `trace_path` (JSONL; `.gz` compressed; `.arrow` the
    columnar trace, needs pyarrow), the per-flow metrics online if `metrics`.

    SIGINT/SIGTERM end the run between two events: frames without an outcome are dropped `stopped`,
    the JSONL trace ends with an `end` record (reason `signal`) and is closed whole; `net.end` is that
    record.  An exception of the engine or a plug-in ends it the same way (reason `error`), then
    UserError."""
    net = build_network(scene, seed=seed, duration=duration)
    with Outputs(net, net.meta(), trace_path, metrics=metrics, plugin=tracing_sink(scene)) as out:
        failed = _run_to_end(net, progress)
        out.finish(net.end)
    if failed is not None:
        raise UserError(f"{scene.source}: the run stopped at t={net.now:.6g} s: {type(failed).__name__}:"
                        f" {failed} (traceback above; the trace ends there)")
    return VirtualRun(net, out.result())


def _run_to_end(net: Network, progress: bool) -> BaseException | None:
    """Advance to the duration, or to a signal or an error: then every frame still held is dropped
    `stopped` and `net.end` is set.  Returns the error that cut the run, if one did."""
    with Interrupt(net) as stop:
        try:
            _advance(net, net.duration, progress)
        except Interrupted:
            net.stop("stopped")
            net.end_record("signal", signal=signal.Signals(stop.signum or signal.SIGINT).name)
        except Exception as e:  # noqa: BLE001 - a plug-in or engine error: said once, the trace ends true
            traceback.print_exc(file=sys.stderr)
            try:
                net.stop("stopped")
            finally:
                net.end_record("error", error=f"{type(e).__name__}: {e}")
            return e
    return None


@contextmanager
def _rare_gc():
    """The cyclic garbage collector less often during a run: the metrics keep one small object per frame,
    and with the default threshold (700 allocations) collections that walk them all cost up to a fifth of
    a long run.  The engine makes no reference cycles per frame, so this only spaces the collections."""
    old = gc.get_threshold()
    gc.set_threshold(50_000, 20, 100)
    try:
        yield
    finally:
        gc.set_threshold(*old)


def _advance(net, end: float, progress: bool) -> None:
    """Run to `end` in slices so a long run can show progress (the slicing changes nothing else)."""
    with _rare_gc():
        _slices(net, end, progress)


def _slices(net, end: float, progress: bool) -> None:
    show = progress and sys.stderr.isatty()
    if not show:
        net.run(end)          # the same as the slices below: slicing changes nothing
        return
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn  # noqa: PLC0415 - a tty only

    with Progress(TextColumn("[bold]simulating"), BarColumn(), TextColumn("{task.completed:.0f}/{task.total:.0f} s"),
                  TimeRemainingColumn(), transient=True, disable=not show) as bar:
        task = bar.add_task("sim", total=end)
        steps = 200
        for i in range(1, steps + 1):
            net.run(end * i / steps)
            bar.update(task, completed=net.now)


def print_summary(trace, net) -> None:
    """The per-flow table of a finished run (from its online Analysis, or by reading a trace file), and
    one line on what was simulated (and how it ended, if early)."""
    show_metrics(trace.flows if isinstance(trace, Analysis) else flow_metrics(trace))
    end = net.end
    how = "" if end is None else f" (stopped by {end.get('signal', end['reason'])} of {net.duration:g} s)"
    t = net.duration if end is None else end["t"]
    print(f"{net.scene.name}: {t:g} s simulated{how}, seed {net.seed}, {net.sched.events_run} events")
