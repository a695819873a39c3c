"""Virtual-time runs: a scene file to a Network run to its end, its trace, and the summary table.

The one assembly of Network + trace sinks for the virtual clock, used by `uwsimnet run`, the experiments and
the tests (app/realtime.py is its realtime twin).  The summary is computed online, as the run goes
(analysis.Accumulator listening on the tracer), so a run without --trace builds no record at all and a run
with one never reads its trace back; `uwsimnet report` on the trace gives the same numbers."""

from __future__ import annotations

import gc
import gzip
import sys
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from ..analysis import Accumulator, Analysis, flow_metrics, format_report, format_text
from ..engine.network import Network
from ..errors import UserError
from ..scene.load import SceneError, load_scene
from ..trace.events import ArrowSink, CallbackSink, JsonlSink, load_tracing_class


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
    columnar trace, needs pyarrow), the per-flow metrics online if `metrics`."""
    try:
        net = Network(scene, seed=seed, duration=duration)
    except ValueError as e:
        raise UserError(f"{scene.source}: {e}") from None
    if scene.tracing.class_name:
        try:
            net.tracer.add(CallbackSink(load_tracing_class(scene.tracing.class_name)))
        except ValueError as e:
            raise UserError(f"{scene.source}:{scene.tracing.line}: {e}") from None
    meta = net.meta()
    acc = None
    if metrics:
        acc = Accumulator(meta)
        net.tracer.listen(acc.on_event)
    if trace_path is None:
        _advance(net, net.duration, progress)
    else:
        trace_path.parent.mkdir(parents=True, exist_ok=True)
        if trace_path.suffix == ".arrow":
            try:
                sink = ArrowSink(trace_path, meta)
            except ValueError as e:
                raise UserError(f"{trace_path}: {e}") from None
            net.tracer.listen(sink.event)
            try:
                _advance(net, net.duration, progress)
            finally:
                sink.close()
        else:
            opener = gzip.open if trace_path.suffix == ".gz" else open
            with opener(trace_path, "wb") as fh:
                jsonl = JsonlSink(fh)
                jsonl.header(meta)
                net.tracer.listen(jsonl.event)
                try:
                    _advance(net, net.duration, progress)
                finally:
                    jsonl.flush()
    return VirtualRun(net, acc.result() if acc is not None else None)


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


def show_metrics(metrics) -> None:
    """The per-flow table: rich on a terminal, plain aligned text when piped (rich would squeeze it)."""
    if sys.stdout.isatty():
        from rich.console import Console  # noqa: PLC0415 - a terminal only (start-up time)

        Console().print(format_report(metrics))
    else:
        print(format_text(metrics))


def print_summary(trace, net) -> None:
    """The per-flow table of a finished run (from its online Analysis, or by reading a trace file), and
    one line on what was simulated."""
    show_metrics(trace.flows if isinstance(trace, Analysis) else flow_metrics(trace))
    print(f"{net.scene.name}: {net.duration:g} s simulated, seed {net.seed}, {net.sched.events_run} events")
