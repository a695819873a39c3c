"""`uwsimnet view [TRACE]` (a web page of a trace or of a live world) and `uwsimnet pcap TRACE -o FILE`
(docs/view.md)."""

from __future__ import annotations

import argparse
import contextlib
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import UserError
from ..view import DEFAULT_PORT

if TYPE_CHECKING:
    import subprocess
# the rest is imported by the functions that use it: `uwsimnet run --view` needs one of them (start-up time)


def add_commands(sub: argparse._SubParsersAction) -> None:
    v = sub.add_parser("view", help="a web page of a trace (replay) or of a live world (--connect/--world)",
                       description="A local web page: the map of the vehicles, links coloured by PER, frames in"
                                   " flight with their outcome, per-modem counters and FIFOs, the clock."
                                   " With TRACE: its replay (time slider, speed). Without: the live world.")
    v.add_argument("trace", nargs="?", help="JSONL trace to replay (omit for a live world)")
    v.add_argument("--scene", help="the run's scene: vehicle positions and link PER (replay), PER (live)")
    v.add_argument("--connect", action="append", help="live: Zenoh router to connect to (default"
                                                       " tcp/127.0.0.1:7447, or the --zenoh-config file's)")
    v.add_argument("--world", help="live: world name (default: the only one that answers)")
    v.add_argument("--zenoh-config", metavar="FILE", help="live: Zenoh JSON5 client configuration (TLS,"
                                                          " user/password, e.g. a visitor identity)")
    v.add_argument("--wait", type=float, default=0.0, metavar="S",
                   help="live: keep trying to reach the router for S seconds (default: fail at once)")
    v.add_argument("--host", default="127.0.0.1", help="address the page is served on (default 127.0.0.1)")
    v.add_argument("--port", type=int, default=DEFAULT_PORT, help=f"port (default {DEFAULT_PORT}; 0 = any free)")
    v.add_argument("--open", action="store_true", help="open the page in the default browser")
    v.set_defaults(fn=cmd_view)

    p = sub.add_parser("pcap", help="a trace as pcapng for Wireshark (one packet per frame on air)")
    p.add_argument("trace", nargs="?", metavar="TRACE",
                   help="trace file written by `uwsimnet run --trace` (JSON Lines, or .jsonl.gz)")
    p.add_argument("-o", "--out", help="pcapng file to write")
    p.add_argument("--dissector", action="store_true",
                   help="print the path of the Wireshark Lua dissector shipped with uwsimnet and exit")
    p.set_defaults(fn=cmd_pcap)


def cmd_pcap(args: argparse.Namespace) -> int:
    from ..analysis import TraceError  # noqa: PLC0415 - see the imports
    from ..analysis.pcap import DISSECTOR, trace_to_pcapng  # noqa: PLC0415

    if args.dissector:
        print(DISSECTOR)
        return 0
    if not args.trace or not args.out:
        raise UserError("uwsimnet pcap: usage: uwsimnet pcap TRACE -o FILE.pcapng (or --dissector)")
    _check_trace_file(args.trace)
    try:
        n = trace_to_pcapng(args.trace, args.out)
    except TraceError as e:
        raise UserError(str(e)) from None
    except OSError as e:
        raise UserError(f"{args.out}: cannot write: {e.strerror or e}") from None
    print(f"{args.out}: {n} frames on air (Wireshark: -X lua_script:{DISSECTOR})")
    return 0


def _check_trace_file(path: str) -> None:
    if not Path(path).is_file():
        raise UserError(f"{path}: no such trace file")


def replay_doc(trace: str, scene_path: str | None) -> dict:
    """The replay document of a trace file, or UserError (one line) if it is not a readable trace."""
    from ..analysis import TraceError, read_trace  # noqa: PLC0415 - see the imports
    from ..app.virtual import load_scene_file  # noqa: PLC0415
    from ..view.state import replay_document

    _check_trace_file(trace)
    scene = load_scene_file(scene_path) if scene_path else None
    try:
        meta, events = read_trace(trace)
        doc = replay_document(meta, events, scene, title=Path(trace).name)
    except TraceError as e:
        raise UserError(str(e)) from None
    if not meta and not doc["events"]:
        raise UserError(f"{trace}: not a uwsimnet trace (no meta line, no events)")
    return doc


def _serve(server, args: argparse.Namespace) -> None:
    import asyncio  # noqa: PLC0415 - the page only: `uwsimnet run` imports this module (start-up time)
    import webbrowser  # noqa: PLC0415

    from ..view.server import serve_forever

    if not 0 <= args.port <= 65535:
        raise UserError(f"uwsimnet view: --port {args.port}: a port 0..65535")

    def ready(url: str) -> None:
        print(f"uwsimnet view: {url}", flush=True)
        if args.open:
            webbrowser.open(url)

    try:
        asyncio.run(serve_forever(server, args.host, args.port, ready))
    except OSError as e:
        raise UserError(f"uwsimnet view: cannot serve on {args.host}:{args.port}: {e.strerror or e}") from None


def cmd_view(args: argparse.Namespace) -> int:
    from ..view.server import ViewServer

    if args.trace:
        if args.connect or args.world or args.zenoh_config:
            raise UserError("uwsimnet view: TRACE replays a file; --connect/--world/--zenoh-config are for a"
                            " live world")
        _serve(ViewServer(doc=replay_doc(args.trace, args.scene)), args)
        return 0
    return _live(args)


def _live(args: argparse.Namespace) -> int:
    from ..app.virtual import load_scene_file  # noqa: PLC0415 - see the imports
    from ..bus.session import BusError
    from ..view.links import LiveLinks
    from ..view.live import LiveSource, check_world, client_session, discover_world
    from ..view.server import ViewServer
    from ..view.state import LiveState, scene_parts

    scene = load_scene_file(args.scene) if args.scene else None
    deadline = time.monotonic() + max(0.0, args.wait)
    while True:
        try:
            session = client_session(args.connect, args.zenoh_config)
            break
        except BusError as e:
            if time.monotonic() >= deadline:
                raise UserError(f"uwsimnet view: {e}") from None
            time.sleep(0.5)
    try:
        while True:
            try:
                world = args.world or discover_world(session)
                if args.world:
                    check_world(session, world, restricted=bool(args.zenoh_config))
                break
            except BusError as e:
                if time.monotonic() >= deadline:
                    raise UserError(f"uwsimnet view: {e}") from None
                time.sleep(0.5)
        state = LiveState(world, scene_parts(scene) if scene is not None else None,
                          links=LiveLinks(scene) if scene is not None else None)
        with LiveSource(session, world, state) as source:
            _serve(ViewServer(live=state, control=source.control), args)
    finally:
        with contextlib.suppress(Exception):
            session.close()
    return 0


def start_beside_run(args: argparse.Namespace, world: str, endpoint: str) -> subprocess.Popen | None:
    """`uwsimnet run --view` (realtime): the live page as its own process, a client of the run's router."""
    import subprocess  # noqa: PLC0415 - see the imports

    argv = [sys.executable, "-m", "uwsimnet_zenoh.cli", "view", "--connect", endpoint, "--world", world,
            "--scene", args.scene, "--wait", "30", "--port", str(args.view_port)]
    if args.zenoh_config:
        argv += ["--zenoh-config", args.zenoh_config]
    if args.open:
        argv.append("--open")
    return subprocess.Popen(argv, stdin=subprocess.DEVNULL)


def stop_viewer(p: subprocess.Popen) -> None:
    import subprocess  # noqa: PLC0415 - see the imports

    p.terminate()
    try:
        p.wait(10)
    except subprocess.TimeoutExpired:
        p.kill()
        p.wait(5)


def view_after_run(args: argparse.Namespace, trace: str) -> None:
    """`uwsimnet run --view` (virtual clock): the replay of the run's trace, until Ctrl-C."""
    from ..view.server import ViewServer

    ns = argparse.Namespace(host="127.0.0.1", port=args.view_port, open=args.open)
    _serve(ViewServer(doc=replay_doc(trace, args.scene)), ns)
