"""`uwsimnet`: the one command (run, validate, report, plot, router, and the driver/bridge/deploy/experiment
sub-commands registered by their modules in this package).

Every user error ends as one line on stderr and exit code 2 (scene errors as `file:line: message`);
a traceback here is a bug.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
from collections.abc import Sequence
from pathlib import Path

from ..app import ros2
from ..errors import UserError, UwsimnetError
from ..view import DEFAULT_PORT as VIEW_PORT
from .limits import DURATION_MAX, REALTIME_ONLY, SPEED_RANGE, check_numbers
from .startup import importing
from .zenoh_flags import add_zenoh_flags

# What a command runs is imported by its function (in `importing()`): `uwsimnet report` or `router` never
# imports the engine, pydantic or the scene models (start-up time)

DEFAULT_VIEW_ROUTER = "tcp/127.0.0.1:7447"
"""Where the page of `run --view` connects when the run says nothing (the run's default listen endpoint)."""


def cmd_validate(args: argparse.Namespace) -> int:
    with importing():
        from ..app.checks import check  # noqa: PLC0415 - see the imports
        from ..app.virtual import load_scene_file  # noqa: PLC0415

    scene = load_scene_file(args.scene, verbose=args.verbose)
    check(scene)                        # the build step and the tracing plug-in, as a run makes them
    n_dev = len(scene.devices())
    print(f"{args.scene}: ok ({len(scene.channels)} channels, {len(scene.vehicles)} vehicles, {n_dev} devices,"
          f" {len(scene.flows)} flows)")
    return 0


def default_clock(scene, args: argparse.Namespace) -> str:
    """The scene's <clock> if it names one, else realtime when something outside drives the run
    (a vehicle with poseSource zenoh, flows run by external apps, ROS 2 nodes), else virtual; --ros2 always
    runs realtime."""
    if getattr(args, "ros2", False):
        return "realtime"
    if "clock" in scene.simulation.model_fields_set:
        return scene.simulation.clock
    if getattr(args, "external_flows", None) or any(v.pose_source == "zenoh" for v in scene.vehicles):
        return "realtime"
    return scene.simulation.clock


def cmd_router(args: argparse.Namespace) -> int:
    from ..bus.router import run_router  # noqa: PLC0415 - zenoh only when needed

    return run_router(args)


def check_applies(args: argparse.Namespace, clock: str) -> None:
    """Real-time-only options on a virtual-clock run are an error, not silently ignored."""
    if clock == "realtime":
        return
    given = [o for o in REALTIME_ONLY if getattr(args, o, None) not in (None, [])]
    if given:
        opts = ", ".join("--" + o.replace("_", "-") for o in given)
        raise UserError(f"{opts}: {'apply' if len(given) > 1 else 'applies'} to a real-time run only, and"
                        f" {args.scene} runs on the virtual clock (add --clock realtime)")


def cmd_run(args: argparse.Namespace) -> int:
    with importing():
        from ..app.checks import failed_plugin  # noqa: PLC0415 - see the imports
        from ..app.virtual import load_scene_file, print_summary, simulate  # noqa: PLC0415
        if args.view:
            from . import view  # noqa: PLC0415 - the page only

    check_numbers(args)
    scene = load_scene_file(args.scene, verbose=args.verbose)
    clock = args.clock or default_clock(scene, args)
    check_applies(args, clock)
    if args.world:
        scene = scene.model_copy(update={"simulation": scene.simulation.model_copy(update={"world": args.world})})
    if getattr(args, "ros2", False) and clock != "realtime":
        raise UserError("--ros2 runs on the realtime clock (ROS 2 nodes live in wall time): drop --clock virtual")
    if args.speed is None:
        args.speed = 1.0
    if clock == "realtime":
        with importing():
            from ..app.realtime import run_realtime  # noqa: PLC0415 - zenoh only when needed

        viewer = view.start_beside_run(args, scene.world, (args.connect or args.listen or [DEFAULT_VIEW_ROUTER])[0]) \
            if args.view else None
        try:
            return run_realtime(scene, args)
        finally:
            if viewer is not None:
                view.stop_viewer(viewer)
    trace = args.trace or scene.tracing.log_to_file
    if args.view and not trace:                     # the page replays the run's trace after it
        import tempfile  # noqa: PLC0415 - only here (start-up time)

        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "trace.jsonl"
            run = simulate(scene, seed=args.seed, duration=args.duration, trace_path=path)
            print_summary(run.analysis, run.net)
            view.view_after_run(args, str(path))
    else:
        run = simulate(scene, seed=args.seed, duration=args.duration, trace_path=Path(trace) if trace else None)
        print_summary(run.analysis, run.net)        # online: the trace is not read back
        if trace:
            print(f"trace: {trace}")
            if args.view:
                view.view_after_run(args, trace)
    bad = failed_plugin(run.net)
    if bad:
        raise UserError(f"{scene.source}:{scene.tracing.line}: {bad}")
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    with importing():
        from ..analysis import TraceError, analyse, report_json, show_metrics  # noqa: PLC0415

    if not Path(args.trace).is_file():
        raise UserError(f"{args.trace}: no such trace file")
    try:
        a = analyse(args.trace)
    except TraceError as e:
        raise UserError(str(e)) from None
    if args.json:
        print(json.dumps(report_json(a.flows, a.links), indent=2, allow_nan=False))
    else:
        show_metrics(a.flows, a.links)
    return 0


def cmd_plot(args: argparse.Namespace) -> int:
    with importing():
        from ..analysis import TraceError  # noqa: PLC0415
        from ..analysis.figures import plot_trace  # noqa: PLC0415

    if not Path(args.trace).is_file():
        raise UserError(f"{args.trace}: no such trace file")
    try:
        files = plot_trace(args.trace, Path(args.out))
    except TraceError as e:
        raise UserError(str(e)) from None
    if args.scene:                  # the TL field of links whose model is bellhop (docs/ocean.md)
        from ..analysis.tl_field import plot_tl_field  # noqa: PLC0415
        from ..app.checks import build_network  # noqa: PLC0415
        from ..scene import SceneError, load_scene  # noqa: PLC0415

        try:
            net = build_network(load_scene(args.scene, on_warning=lambda _msg: None), flows=False)
            files += plot_tl_field(net, args.trace, Path(args.out))
        except (SceneError, OSError) as e:
            raise UserError(str(e)) from None
    for f in files:
        print(f)
    return 0


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors (the usage is one `-h` away), exit 2 as before."""

    def error(self, message: str):  # type: ignore[override]
        self.exit(2, f"{self.prog}: {message} (see {self.prog} -h)\n")


CORE = ("run", "router", "validate", "report", "plot")
"""The commands defined here: `uwsimnet run ...` builds only these parsers (the other commands' modules,
with zenoh, asyncio and msgpack among their imports, are not loaded: a virtual run starts sooner)."""


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The whole command line; `command` one of CORE: only the parsers of CORE (for that command)."""
    p = Parser(prog="uwsimnet", description="Underwater network simulator on Zenoh")
    sub = p.add_subparsers(dest="cmd", required=True)

    r = sub.add_parser("run", help="run a scene")
    r.add_argument("scene")
    r.add_argument("-v", "--verbose", action="store_true", help="list every scene warning (default: one per kind)")
    r.add_argument("--clock", choices=["virtual", "realtime"])
    r.add_argument("--duration", type=float,
                   help=f"simulated seconds, > 0 and <= {DURATION_MAX:g} (default: the scene's)")
    r.add_argument("--speed", type=float,
                   help=f"realtime: simulated seconds per wall second, {SPEED_RANGE[0]:g} to {SPEED_RANGE[1]:g}"
                        " (default 1; >1 for runs without hardware)")
    r.add_argument("--seed", type=int, help="random seed (default: the scene's)")
    r.add_argument("--trace", help="JSONL trace file to write")
    add_zenoh_flags(r, listen=True, world="Zenoh world name (default: the scene's name)",
                    listen_help="Zenoh endpoint to listen on (realtime; default: the --zenoh-config file's,"
                                " else tcp/127.0.0.1:7447)",
                    connect_help="Zenoh router to connect to instead (realtime)",
                    config_help="Zenoh JSON5 client/router configuration (TLS, user/password; default"
                                " $ZENOH_CONFIG): its mode and endpoints unless --listen/--connect (realtime)")
    r.add_argument("--channels", help="comma-separated channel ids this broker serves (realtime)")
    r.add_argument("--external-flows", metavar="NAMES",
                   help="flows (comma-separated, or 'all') run by external apps, not by the simulator (realtime)")
    ros2.add_arguments(r)
    r.add_argument("--view", action="store_true",
                   help="the web page of the run (uwsimnet view): live beside a realtime run, else the replay"
                        " of its trace once it ends")
    r.add_argument("--view-port", type=int, default=VIEW_PORT, help="port of that page")
    r.set_defaults(fn=cmd_run, open=False)

    ro = sub.add_parser("router", help="a standalone Zenoh router for this machine (other machines connect)")
    add_zenoh_flags(ro, listen=True, config_aliases=("--config",),
                    listen_help="endpoint to listen on (default: the --config file's, else tcp/[::]:7447)",
                    connect_help="another router to connect to (other machines; replaces the file's)",
                    config_help="Zenoh JSON5 router configuration (TLS, access control, ...; not"
                                " $ZENOH_CONFIG, which names clients' files)")
    ro.set_defaults(fn=cmd_router)

    v = sub.add_parser("validate", help="check a scene; exit 2 with file:line: message on errors")
    v.add_argument("scene")
    v.add_argument("-v", "--verbose", action="store_true", help="list every warning (default: one per kind)")
    v.set_defaults(fn=cmd_validate)

    rep = sub.add_parser("report", help="per-flow metrics of a trace")
    rep.add_argument("trace", help="JSONL trace of a run (run --trace)")
    rep.add_argument("--json", action="store_true")
    rep.set_defaults(fn=cmd_report)

    pl = sub.add_parser("plot", help="PNG figures of a trace")
    pl.add_argument("trace", help="JSONL trace of a run (run --trace)")
    pl.add_argument("-o", "--out", default="figures", help="folder for the PNGs (default figures)")
    pl.add_argument("--scene", help="the run's scene: adds the TL field of its bellhop links (docs/ocean.md)")
    pl.set_defaults(fn=cmd_plot)

    if command not in CORE:
        from . import deploy, drivers, experiment, ros2_link, sweep, view  # noqa: PLC0415 - only for their commands

        for add_commands in (drivers.add_commands, experiment.add_commands, sweep.add_commands,
                             deploy.add_commands, view.add_commands, ros2_link.add_commands):
            add_commands(sub)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    _interruptible()
    parser = build_parser(argv[0] if argv else None)
    args = parser.parse_args(argv)
    try:
        return args.fn(args)
    except UwsimnetError as e:
        print(e, file=sys.stderr)
        return 2
    except OSError as e:
        if e.filename is None:          # not about a path: a bug or the machine's, shown whole
            raise
        # a path the user named (or one made from it) that cannot be written or read: one line, as bad input
        target = e.filename if e.filename2 is None else f"{e.filename} -> {e.filename2}"
        print(f"uwsimnet: {target}: {e.strerror or e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


def _interruptible() -> None:
    """SIGINT stops every command, however it was started.  A script's background job (`uwsimnet sweep ... &`,
    no job control) inherits SIGINT ignored (POSIX), and Python then never raises KeyboardInterrupt: a sweep
    stopped with `kill -INT` ran to its end instead of saying what it kept.  (`run` has its own handlers.)"""
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN and threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.default_int_handler)

