"""`uwsimnet`: run, validate, report and plot.

Every user error ends as one line on stderr and exit code 2 (scene errors as `file:line: message`);
a traceback here is a bug.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path

from .errors import UserError


def _warn(msg: str) -> None:
    print(msg, file=sys.stderr)


def _load(path: str):
    from .scene.load import SceneError, load_scene

    if not Path(path).is_file():
        raise UserError(f"{path}: no such scene file")
    try:
        return load_scene(path, on_warning=_warn)
    except SceneError as e:
        raise UserError(str(e)) from None


def cmd_validate(args: argparse.Namespace) -> int:
    scene = _load(args.scene)
    n_dev = len(scene.devices())
    print(f"{args.scene}: ok ({len(scene.channels)} channels, {len(scene.vehicles)} vehicles, {n_dev} devices,"
          f" {len(scene.flows)} flows)")
    return 0


def run_virtual(scene, *, seed: int | None, duration: float | None, trace_path: Path,
                progress: bool = True):
    """Run a scene in virtual time, writing the JSONL trace; returns the Network."""
    from .engine.network import Network
    from .trace.events import CallbackSink, JsonlSink, load_tracing_class

    try:
        net = Network(scene, seed=seed, duration=duration)
    except ValueError as e:
        raise UserError(f"{scene.source}: {e}") from None
    if scene.tracing.class_name:
        try:
            net.tracer.add(CallbackSink(load_tracing_class(scene.tracing.class_name)))
        except ValueError as e:
            raise UserError(f"{scene.source}:{scene.tracing.line}: {e}") from None
    trace_path.parent.mkdir(parents=True, exist_ok=True)
    with open(trace_path, "w", encoding="utf-8") as fh:
        sink = JsonlSink(fh)
        sink.header(net.meta())
        net.tracer.add(sink)
        _advance(net, net.duration, progress)
    return net


def _advance(net, end: float, progress: bool) -> None:
    """Run to `end` in slices so a long run can show progress (the slicing changes nothing else)."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    show = progress and sys.stderr.isatty()
    with Progress(TextColumn("[bold]simulating"), BarColumn(), TextColumn("{task.completed:.0f}/{task.total:.0f} s"),
                  TimeRemainingColumn(), transient=True, disable=not show) as bar:
        task = bar.add_task("sim", total=end)
        steps = 200
        for i in range(1, steps + 1):
            net.run(end * i / steps)
            bar.update(task, completed=net.now)


def default_clock(scene, args: argparse.Namespace) -> str:
    """The scene's <clock> if it names one, else realtime when something outside drives the run
    (a vehicle with poseSource zenoh, flows run by external apps), else virtual."""
    if "clock" in scene.simulation.model_fields_set:
        return scene.simulation.clock
    if getattr(args, "external_flows", None) or any(v.pose_source == "zenoh" for v in scene.vehicles):
        return "realtime"
    return scene.simulation.clock


def cmd_router(args: argparse.Namespace) -> int:
    from .bus.router import run_router  # noqa: PLC0415 - zenoh only when needed

    return run_router(args)


def cmd_run(args: argparse.Namespace) -> int:
    scene = _load(args.scene)
    if args.world:
        scene = scene.model_copy(update={"simulation": scene.simulation.model_copy(update={"world": args.world})})
    clock = args.clock or default_clock(scene, args)
    if clock == "realtime":
        from .bus.runtime import run_realtime  # noqa: PLC0415 - zenoh only when needed

        return run_realtime(scene, args)
    trace = args.trace or scene.tracing.log_to_file
    if trace:
        net = run_virtual(scene, seed=args.seed, duration=args.duration, trace_path=Path(trace))
        _summary(trace, net)
        print(f"trace: {trace}")
        return 0
    with tempfile.TemporaryDirectory() as tmp:     # the summary is computed from a trace all the same
        path = Path(tmp) / "trace.jsonl"
        net = run_virtual(scene, seed=args.seed, duration=args.duration, trace_path=path)
        _summary(str(path), net)
    return 0


def show_metrics(metrics) -> None:
    """The per-flow table: rich on a terminal, plain aligned text when piped (rich would squeeze it)."""
    from .trace.report import format_report, format_text

    if sys.stdout.isatty():
        from rich.console import Console

        Console().print(format_report(metrics))
    else:
        print(format_text(metrics))


def _summary(trace: str, net) -> None:
    from .trace.report import flow_metrics

    show_metrics(flow_metrics(trace))
    print(f"{net.scene.name}: {net.duration:g} s simulated, seed {net.seed}, {net.sched.events_run} events")


def cmd_report(args: argparse.Namespace) -> int:
    from .trace.report import TraceError, flow_metrics, report_json

    if not Path(args.trace).is_file():
        raise UserError(f"{args.trace}: no such trace file")
    try:
        metrics = flow_metrics(args.trace)
    except TraceError as e:
        raise UserError(str(e)) from None
    if args.json:
        print(json.dumps(report_json(metrics), indent=2))
    else:
        show_metrics(metrics)
    return 0


def cmd_plot(args: argparse.Namespace) -> int:
    from .trace.plot import plot_trace
    from .trace.report import TraceError

    if not Path(args.trace).is_file():
        raise UserError(f"{args.trace}: no such trace file")
    try:
        files = plot_trace(args.trace, Path(args.out))
    except TraceError as e:
        raise UserError(str(e)) from None
    for f in files:
        print(f)
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="uwsimnet", description="Underwater network simulator on Zenoh")
    sub = p.add_subparsers(dest="cmd", required=True)

    r = sub.add_parser("run", help="run a scene")
    r.add_argument("scene")
    r.add_argument("--clock", choices=["virtual", "realtime"])
    r.add_argument("--duration", type=float, help="simulated seconds (default: the scene's)")
    r.add_argument("--speed", type=float, default=1.0,
                   help="realtime: simulated seconds per wall second (default 1; >1 for runs without hardware)")
    r.add_argument("--seed", type=int, help="random seed (default: the scene's)")
    r.add_argument("--trace", help="JSONL trace file to write")
    r.add_argument("--world", help="Zenoh world name (default: the scene's name)")
    r.add_argument("--listen", action="append", help="Zenoh endpoint to listen on (realtime)")
    r.add_argument("--connect", action="append", help="Zenoh router to connect to instead (realtime)")
    r.add_argument("--zenoh-config", metavar="FILE",
                   help="Zenoh JSON5 client/router configuration (TLS, user/password; default $ZENOH_CONFIG);"
                        " --listen/--connect apply on top (realtime)")
    r.add_argument("--channels", help="comma-separated channel ids this broker serves (realtime)")
    r.add_argument("--external-flows", metavar="NAMES",
                   help="flows (comma-separated, or 'all') run by external apps, not by the simulator (realtime)")
    r.set_defaults(fn=cmd_run)

    ro = sub.add_parser("router", help="a standalone Zenoh router for this machine (other machines connect)")
    ro.add_argument("--listen", action="append",
                    help="endpoint to listen on (default: the --config file's, else tcp/[::]:7447)")
    ro.add_argument("--connect", action="append", help="another router to connect to (other machines)")
    ro.add_argument("--config", help="Zenoh JSON5 configuration file (TLS, access control, ...)")
    ro.set_defaults(fn=cmd_router)

    v = sub.add_parser("validate", help="check a scene; exit 2 with file:line: message on errors")
    v.add_argument("scene")
    v.set_defaults(fn=cmd_validate)

    rep = sub.add_parser("report", help="per-flow metrics of a trace")
    rep.add_argument("trace")
    rep.add_argument("--json", action="store_true")
    rep.set_defaults(fn=cmd_report)

    pl = sub.add_parser("plot", help="PNG figures of a trace")
    pl.add_argument("trace")
    pl.add_argument("-o", "--out", default="figures")
    pl.set_defaults(fn=cmd_plot)

    from .drivers.commands import add_commands  # noqa: PLC0415 - driver / emulate / bridge

    add_commands(sub)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.fn(args)
    except UserError as e:
        print(e, file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
