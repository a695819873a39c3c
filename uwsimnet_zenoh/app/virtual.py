"""Virtual-time runs: a scene file to a Network run to its end, its JSONL trace, and the summary table.

The one assembly of Network + trace sinks for the virtual clock, used by `uwsimnet run`, the experiments and
the tests (app/realtime.py is its realtime twin)."""

from __future__ import annotations

import signal
import sys
import traceback
from pathlib import Path

from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

from ..analysis import flow_metrics, format_report, format_text
from ..errors import UserError
from ..kernel.scheduler import Interrupted
from ..scene.load import SceneError, load_scene
from ..trace.events import JsonlSink
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


def run_virtual(scene, *, seed: int | None, duration: float | None, trace_path: Path,
                progress: bool = True):
    """Run a scene in virtual time, writing the JSONL trace; returns the Network.

    SIGINT/SIGTERM end the run between two events: frames without an outcome are dropped `stopped`,
    the trace ends with an `end` record (reason `signal`) and is closed whole; `net.end` is that record.
    An exception of the engine or a plug-in ends it the same way (reason `error`), then UserError."""
    net = build_network(scene, seed=seed, duration=duration)
    plugin = tracing_sink(scene)
    if plugin is not None:
        net.tracer.add(plugin)
    trace_path.parent.mkdir(parents=True, exist_ok=True)
    failed: BaseException | None = None
    with open(trace_path, "w", encoding="utf-8") as fh:
        sink = JsonlSink(fh)
        sink.header(net.meta())
        net.tracer.add(sink)
        with Interrupt(net) as stop:
            try:
                _advance(net, net.duration, progress)
            except Interrupted:
                net.stop("stopped")
                sink(net.end_record("signal", signal=signal.Signals(stop.signum or signal.SIGINT).name))
            except Exception as e:  # noqa: BLE001 - a plug-in or engine error: said once, the trace ends true
                failed = e
                traceback.print_exc(file=sys.stderr)
                try:
                    net.stop("stopped")
                finally:
                    sink(net.end_record("error", error=f"{type(e).__name__}: {e}"))
    if failed is not None:
        raise UserError(f"{scene.source}: the run stopped at t={net.now:.6g} s: {type(failed).__name__}:"
                        f" {failed} (traceback above; the trace ends there)")
    return net


def _advance(net, end: float, progress: bool) -> None:
    """Run to `end` in slices so a long run can show progress (the slicing changes nothing else)."""
    show = progress and sys.stderr.isatty()
    with Progress(TextColumn("[bold]simulating"), BarColumn(), TextColumn("{task.completed:.0f}/{task.total:.0f} s"),
                  TimeRemainingColumn(), transient=True, disable=not show) as bar:
        task = bar.add_task("sim", total=end)
        steps = 200
        for i in range(1, steps + 1):
            net.run(end * i / steps)
            bar.update(task, completed=net.now)


def show_metrics(metrics) -> None:
    """The per-flow table: rich on a terminal, plain aligned text when piped (rich would squeeze it)."""
    if sys.stdout.isatty():
        Console().print(format_report(metrics))
    else:
        print(format_text(metrics))


def print_summary(trace: str, net) -> None:
    """The per-flow table of a finished run, and one line on what was simulated."""
    show_metrics(flow_metrics(trace))
    end = net.end
    how = "" if end is None else f" (stopped by {end.get('signal', end['reason'])} of {net.duration:g} s)"
    t = net.duration if end is None else end["t"]
    print(f"{net.scene.name}: {t:g} s simulated{how}, seed {net.seed}, {net.sched.events_run} events")


