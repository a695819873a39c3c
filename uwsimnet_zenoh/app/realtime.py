"""`uwsimnet run --clock realtime`: a scene's channels on Zenoh, in wall time, until duration or Ctrl-C.

    session  router listening on --listen (default tcp/127.0.0.1:7447), or a client of --connect
    network  the scene (restricted to --channels), flows of the scene except --external-flows
    clock    kernel/realtime.RealtimeClock: the engine on its own thread
    broker   bus/broker.Broker: the modems on their keys, poses, trace, clock, control
    outputs  the same trace and metrics as a virtual run (assembly/outputs.py), the trace on disk every second

SIGINT/SIGTERM (or the duration) stop the engine after the event it is running; then every frame
without an outcome is dropped `stopped` (its application hears `dropped stopped` if the modem still
held it), the trace ends with an `end` record (the actual end time, reason `duration`, `signal` or
`error`), the broker's outboxes drain (2 s at most), it undeclares, the trace is closed and the
session too; the summary is printed.  Exit code 0 when the run reached its duration or was stopped on
request; 2 when an event, a MAC or a tracing plug-in raised (reported once with its traceback; a
tracing plug-in is disabled and the run goes on, anything else stops it) or the engine thread died.
"""

from __future__ import annotations

import faulthandler
import logging
import math
import os
import signal
import sys
import threading
import time
from typing import Any

from ..assembly.outputs import Outputs
from ..bus import flush
from ..bus.connections import Connections
from ..bus.router import StopOnSignal
from ..bus.session import (
    DEFAULT_ENDPOINT,
    WAIT_BEFORE_CLOSE_US,
    BusError,
    locators,
    make_config,
    open_raw,
    tune_threads,
)
from ..errors import UserError
from ..phy.channel import LIST_SLOTS
from ..scene.model import Scene
from . import ros2
from .checks import build_network, plugin_failure, tracing_sink

log = logging.getLogger("uwsimnet.bus.runtime")


def parse_channels(spec: str | None, scene: Scene) -> set[int] | None:
    if not spec:
        return None
    out: set[int] = set()
    ids = {c.id for c in scene.channels}
    for part in spec.split(","):
        part = part.strip()
        if not part:
            continue
        try:
            cid = int(part)
        except ValueError:
            raise UserError(f"--channels: {part!r} is not a channel id") from None
        if cid not in ids:
            raise UserError(f"--channels: the scene has no channel {cid} (it has {sorted(ids)})")
        out.add(cid)
    return out or None


def select_channels(scene: Scene, channels: set[int] | None) -> tuple[Scene, set[str]]:
    """The part of `scene` a broker for `channels` hosts, and the dccommsIds it leaves to others.

    Vehicles all stay (their poses are needed for geometry); a device stays if both its channels are
    served; flows stay if their source does.  A device that transmits on one channel and receives on
    another is one modem (one FIFO, one MAC, duplex), so one broker serves both channels: a selection
    that splits it is refused (UserError, one line)."""
    if channels is None:
        return scene, set()
    foreign: set[str] = set()
    vehicles = []
    for v in scene.vehicles:
        keep = []
        for d in v.devices:
            if d.tx_channel in channels and d.rx_channel in channels:
                keep.append(d)
            elif (d.tx_channel in channels) != (d.rx_channel in channels):
                both = ",".join(str(c) for c in sorted(channels | {d.tx_channel, d.rx_channel}))
                raise UserError(f"--channels {','.join(str(c) for c in sorted(channels))}: device"
                                  f" {d.dccomms_id} transmits on channel {d.tx_channel} and receives on channel"
                                  f" {d.rx_channel}; one broker must serve both (e.g. --channels {both})")
            else:
                foreign.add(d.dccomms_id)
        vehicles.append(v.model_copy(update={"devices": tuple(keep)}))
    kept = {d.dccomms_id for v in vehicles for d in v.devices}
    return scene.model_copy(update={
        "channels": tuple(c for c in scene.channels if c.id in channels),
        "vehicles": tuple(vehicles),
        "flows": tuple(f for f in scene.flows if f.src in kept),
    }), foreign


def parse_external(spec: str | None, scene: Scene) -> set[str]:
    if not spec:
        return set()
    names = {f.name for f in scene.flows}
    if spec.strip() == "all":
        return names
    out = {p.strip() for p in spec.split(",") if p.strip()}
    unknown = out - names
    if unknown:
        raise UserError(f"--external-flows: no flow {', '.join(sorted(unknown))} in the scene"
                          f" (flows: {', '.join(sorted(names)) or 'none'})")
    return out


def _file_endpoints(path: str) -> tuple[str, list[str], list[str]]:
    """(mode, connect, listen) of a Zenoh configuration file: what `uwsimnet run --zenoh-config FILE`
    (or ZENOH_CONFIG) uses when neither --listen nor --connect is given."""
    import json  # noqa: PLC0415

    import zenoh  # noqa: PLC0415

    try:
        conf = zenoh.Config.from_file(path)
        mode = json.loads(conf.get_json("mode")) or "client"
        eps = {k: json.loads(conf.get_json(f"{k}/endpoints")) for k in ("connect", "listen")}
    except (zenoh.ZError, ValueError) as e:
        raise UserError(f"{path}: {' '.join(str(e).split())}") from None
    if mode not in ("client", "router"):
        raise UserError(f"{path}: mode {mode!r}: uwsimnet run is a client or a router")
    for k, v in eps.items():                        # Zenoh's defaults are per mode: {"router": [...], ...}
        eps[k] = [str(e) for e in (v.get(mode) or [] if isinstance(v, dict) else v or [])]
    return mode, eps["connect"], eps["listen"] if mode == "router" else []


def realtime_priority() -> None:
    """UWSIMNET_RT_PRIORITY=N: run this process (the engine and Zenoh's threads, created later, inherit
    it) under SCHED_RR priority N, so a loaded machine does not delay deliveries (needs CAP_SYS_NICE)."""
    prio = os.environ.get("UWSIMNET_RT_PRIORITY")
    if not prio:
        return
    try:
        os.sched_setscheduler(0, os.SCHED_RR, os.sched_param(int(prio)))
        log.info("realtime scheduling: SCHED_RR priority %s", prio)
    except (AttributeError, OSError, ValueError) as e:
        log.warning("UWSIMNET_RT_PRIORITY=%s ignored: %s", prio, e)


def python_cpu() -> int | None:
    """The one CPU of the threads that run Python (the engine, the outboxes: kernel.realtime.pin_thread),
    or None (not pinned, the default).

    UWSIMNET_PYTHON_CPU=auto: the last CPU this process may use (if it may use more than one); =N: CPU N.
    Opt-in: it trims the broker's overhead (docs/benchmarks.md, "One core for Python"), but a pinned thread
    cannot leave its CPU, and under SCHED_RR another busy thread of the same priority there holds it for a
    whole 100 ms time slice (seen).  Zenoh's threads are never pinned."""
    want = os.environ.get("UWSIMNET_PYTHON_CPU", "").strip().lower()
    if want in ("", "any"):
        return None
    try:
        allowed = os.sched_getaffinity(0)
    except (AttributeError, OSError):
        return None
    if want == "auto":
        return max(allowed) if len(allowed) > 1 else None
    if want.isdigit() and int(want) in allowed:
        return int(want)
    log.warning("UWSIMNET_PYTHON_CPU=%s ignored: this process may use CPUs %s (or say auto, any)", want,
                ",".join(map(str, sorted(allowed))))
    return None


class _Stderr(logging.StreamHandler):
    """A handler on whatever sys.stderr is when it writes (run in-process, e.g. by a test that has
    swapped and closed stderr since, a handler bound to the old stream would fail)."""

    @property
    def stream(self) -> Any:
        return sys.stderr

    @stream.setter
    def stream(self, _: Any) -> None:
        pass


def _setup_logging() -> None:
    root = logging.getLogger("uwsimnet")
    if not root.handlers:
        h = _Stderr()
        h.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
        root.addHandler(h)
        root.setLevel(logging.INFO)


def run_realtime(scene: Scene, args: Any) -> int:
    """Run `scene` on the realtime clock, serving its modems on Zenoh (see module docstring)."""
    _setup_logging()
    duration = args.duration if args.duration is not None else scene.simulation.duration
    if duration is not None and not duration > 0:
        raise UserError("--duration must be > 0")
    speed = getattr(args, "speed", 1.0)
    if not (math.isfinite(speed) and speed > 0):
        raise UserError("--speed must be a number > 0")
    channels = parse_channels(getattr(args, "channels", None), scene)
    external = parse_external(getattr(args, "external_flows", None), scene)
    hosted, foreign = select_channels(scene, channels)
    trace = args.trace or scene.tracing.log_to_file or None
    return _run(scene, args, duration, channels, external, hosted, foreign, trace)


def _run(scene: Scene, args: Any, duration: float | None, channels: set[int] | None, external: set[str],
         hosted: Scene, foreign: set[str], trace: str | None) -> int:
    """The realtime run; `trace` None: no trace file (the summary's metrics are online either way)."""
    from ..bus.broker import Broker
    from ..kernel.realtime import SPIN, RealtimeClock
    from ..traffic.flow import FlowSource

    world = scene.world
    listen = list(args.listen or ())
    connect = list(args.connect or ())
    if connect and listen:
        raise UserError("give --listen (embedded router) or --connect (existing router), not both")
    zconf = getattr(args, "zenoh_config", None) or os.environ.get("ZENOH_CONFIG") or None
    mode = "client" if connect else "router"
    if zconf and not listen and not connect:        # the file says it all: its mode and its endpoints
        mode, connect, listen = _file_endpoints(zconf)
        if mode == "client" and not connect:
            raise UserError(f"{zconf}: a client configuration without connect/endpoints; give --connect")
    ros_opts = ros_codec = ros_note = None
    if ros2.enabled(args):
        ros_opts = ros2.options(args)
        ros_view = ros2.check(ros_opts, hosted)
        ros_codec = ros2.codec(ros_opts.distro)
        if not zconf:
            listen, connect, ros_note = ros2.topology(listen, connect)
            mode = "client" if connect else "router"
    if not connect and not listen:
        listen = [DEFAULT_ENDPOINT]

    tune_threads()
    realtime_priority()
    net = build_network(hosted, seed=args.seed, duration=duration if duration is not None else math.inf,
                        flows=False)
    plugin = tracing_sink(scene)
    for f in hosted.flows:
        if f.name not in external:
            net.flows.append(FlowSource(f, net.modems[f.src], net.sched, net.seeds("flow", f.name),
                                        net.duration))
    if len(net.modems) > LIST_SLOTS:
        import numpy  # noqa: F401 - a channel this large computes with arrays: imported now, not by the
        #               engine thread at its first transmission (a 150-300 ms stall in the middle of a run)
    failed = threading.Event()          # an event, a MAC or the engine raised: the run stops (exit 2)
    clock = RealtimeClock(net.sched, until=duration, speed=getattr(args, "speed", 1.0),
                          spin=float(os.environ.get("UWSIMNET_SPIN") or SPIN),
                          on_error=lambda e: failed.set(), cpu=python_cpu())
    try:
        conf = (make_config("client", connect=connect, connect_timeout_ms=3000, config_file=zconf)
                if mode == "client" else make_config("router", listen=listen, config_file=zconf))
    except (BusError, ValueError) as e:
        raise UserError(str(e)) from None

    summary: dict[str, Any] = {}
    with StopOnSignal() as stop:
        try:
            session = open_raw(conf)
        except BusError as e:
            if connect:
                raise UserError(f"cannot connect to {', '.join(connect)}: {e}") from None
            raise UserError(f"cannot listen on {', '.join(listen)} ({e}); is another uwsimnet or router"
                              f" running there? use --connect {listen[0]} to join it, or --listen"
                              " another endpoint") from None
        broker = None
        ros = None
        links: list[Any] = []
        connections = Connections(clock.now)
        meta = net.meta()
        meta.update(clock="realtime", world=world, duration=duration,
                    channels=sorted(net.channels), external_flows=sorted(external))
        # the trace file, the tracing plug-in and the summary's metrics (online, on the engine thread; read at
        # the end), as a virtual run has them (assembly/outputs.py); closed in finally, after the engine
        out = Outputs(net, meta, trace, plugin=plugin)
        try:
            out.__enter__()
            if trace is not None:
                last_flush = [time.monotonic()]

                def write_trace() -> None:      # the trace when the engine is idle, not between an event
                    net.tracer.flush()          # and its rx; on disk every second (tail -f works)
                    if time.monotonic() - last_flush[0] > 1.0:
                        out.flush()
                        last_flush[0] = time.monotonic()
                clock.idle_hooks.append(write_trace)
            connections.start(session)          # who Zenoh cuts off, for the end record (docs/runtime.md)
            try:
                broker = Broker(session, net, clock, world=world, channels=channels, foreign=foreign)
                broker.start()
            except ValueError as e:
                raise UserError(f"{scene.source}: {e} (names become Zenoh keys; --world NAME sets the"
                                  " world)") from None

            if ros_opts is not None:
                from ..bus.ros2 import Ros2Adapter
                try:
                    ros = Ros2Adapter(ros2.adapter_endpoint(mode, connect, listen, locators(session)), world,
                                      ros_opts, *ros_view, ros_codec)
                    ros.start()
                except (BusError, ValueError) as e:
                    raise UserError(f"--ros2: {e}") from None
                if ros_note:
                    print(f"uwsimnet: {ros_note}", flush=True)
                b = ros.bridge
                print(f"uwsimnet: ROS 2 {ros_opts.distro}, domain {ros_opts.domain}: {len(b.graph.nodes)} node(s),"
                      f" topics {', '.join(sorted({e.topic for e in b.graph.endpoints}))}", flush=True)
                links = ros2.start_links(hosted, ros2.adapter_endpoint(mode, connect, listen, locators(session)),
                                         world, ros_opts.distro)
            elif any(v.ros2_link is not None for v in hosted.vehicles):
                print("uwsimnet: the scene's <ros2Link>s are not started (they run under --ros2)", flush=True)
            if connect:
                print(f"uwsimnet: connected to {', '.join(connect)}", flush=True)
            else:
                print(f"uwsimnet: listening on {', '.join(locators(session) or listen)}", flush=True)
            chans = ",".join(str(c) for c in sorted(net.channels))
            print(f"uwsimnet: world {world!r}, channel(s) {chans}, {len(net.modems)} modem(s):"
                  f" {', '.join(net.modems) or '-'}", flush=True)
            print(f"uwsimnet: keys {broker.keys.base}/modem/<id>/{{tx,rx,status,info}}, pose/<vehicle>,"
                  " clock, control/<op>", flush=True)
            clock.start()
            until = f"for {duration:g} s" if duration is not None else "until Ctrl-C"
            pace = "realtime clock" if clock.speed == 1.0 else f"realtime clock x{clock.speed:g}"
            print(f"uwsimnet: running {until} ({pace}); trace {trace or '(none: summary only)'}", flush=True)
            while not stop.stopped and not clock.done.is_set() and not failed.is_set():
                stop.wait(0.2)
            if stop.stopped:
                print(f"uwsimnet: stopping ({signal.Signals(stop.signum).name}) at t={clock.now():.3f} s",
                      flush=True)
        finally:
            t_stop = clock.now()                # the run ends now, whenever its last event was
            faulthandler.dump_traceback_later(30, exit=True)     # a shutdown that hangs dies loudly
            clock.stop()
            if not clock.join(5.0):
                log.error("the engine thread did not stop within 5 s")
            if clock.first_error is not None or clock.fatal is not None:
                e = clock.fatal or clock.first_error
                reason, extra = "error", {"error": f"{type(e).__name__}: {e}"}
            elif stop.stopped:
                reason, extra = "signal", {"signal": signal.Signals(stop.signum).name}
            else:
                reason, extra = "duration", {}
            if not clock.running:               # the engine has ended: this thread may touch the network
                try:
                    net.stop("stopped")         # statuses to the apps go out through the outboxes
                except Exception:  # noqa: BLE001 - a network left broken by an error: said, the run ends
                    log.exception("frames in flight could not be given their outcome")
            summary = {"t": net.sched.now, **clock.stats()}
            summary["ros2_link"] = ros2.close_links(links)
            if ros is not None:
                summary["ros2"] = dict(ros.bridge.problems.counts)
                ros.close()
            if broker is not None:
                summary["bus"] = dict(broker.counters)
                broker.close()
                summary["edge"] = broker.edge_summary()
                summary["ingress_warn"] = broker.ingress_warn_s
                lost = {dev: {"rx": e["lost"].get("rx", 0), "frames": [list(x) for x in e.get("lost_rx", [])]}
                        for dev, e in sorted(summary["edge"].items()) if (e.get("lost") or {}).get("rx")}
                if lost:                        # the trace says which frames it records received never left
                    extra["lost_at_edge"] = lost
                stalled = {dev: [[*x, round(w, 3)] for x, w in e["stalled_rx"]]
                           for dev, e in sorted(summary["edge"].items()) if e.get("stalled_rx")}
                if stalled:                     # and which waited on a consumer that did not read
                    extra["stalled_at_edge"] = stalled
                # what Zenoh holds for a slow app is dropped when the session closes: give it time (bounded)
                if unsent := flush.wait():
                    extra["unsent_at_close"] = summary["unsent_at_close"] = unsent
                    log.warning("at close, %s: an app did not read what was put for it before the stop (it may"
                                " be lost)", ", ".join(f"{n} bytes unsent to {p}" for p, n in sorted(unsent.items())))
            connections.close()
            if gone := connections.summary():   # who was disconnected (until now): `back` = cut off by Zenoh
                extra["disconnected"] = gone
                summary["cut_off"] = connections.cut_off()
            if reason == "duration" and duration is not None:
                t_stop = min(t_stop, duration)
            if summary["ros2_link"]:            # the links' counters in the trace too (docs/ros2-link.md)
                extra["ros2_link"] = summary["ros2_link"]
            out.finish(net.end_record(reason, t=t_stop, **extra))     # the last batch, the end record last
            out.__exit__(None, None, None)
            try:
                session.close()
            except Exception as e:  # noqa: BLE001 - a consumer that does not read holds Zenoh's close up
                log.warning("the Zenoh session did not close in time (%s): a consumer does not read",
                            " ".join(str(e).split())[:200])
            faulthandler.cancel_dump_traceback_later()
    _summary(out.result(), summary, net)
    if trace is not None:
        print(f"trace: {trace}")
    e = clock.fatal or clock.first_error
    if e is not None:
        raise UserError(f"{scene.source}: the run stopped at t={net.sched.now:.6g} s: {type(e).__name__}: {e}"
                        " (traceback above; the trace ends there)")
    bad = plugin_failure(plugin)
    if bad:
        raise UserError(f"{scene.source}:{scene.tracing.line}: {bad}")
    return 0


def _summary(analysis: Any, s: dict[str, Any], net: Any) -> None:
    from rich.console import Console

    from .virtual import show_metrics

    console = Console()
    show_metrics(analysis.flows)
    bad = {k: v for k, v in (s.get("bus") or {}).items()     # (edge_*: the `lost at the edge` lines below)
           if k not in ("tx_messages", "poses") and not k.startswith("edge_")}
    if s.get("ros2"):
        bad["ros2"] = s["ros2"]
    end = net.end or {}
    how = f", stopped by {end['signal']}" if end.get("signal") else (", stopped by an error"
                                                                     if end.get("reason") == "error" else "")
    console.print(f"{net.scene.name}: {s['t']:.3f} s realtime{how}, {s['events']} events (late mean"
                  f" {s['late_mean'] * 1e6:.0f} us, max {s['late_max'] * 1e3:.2f} ms), {s['items']} messages"
                  f" ({s.get('items_here', 0)} run on arrival),"
                  f" {s['errors']} errors" + (f"; refused/ignored: {bad}" if bad else ""), soft_wrap=True)
    for line in ros2.link_lines(s.get("ros2_link") or {}):    # <ros2Link>: per topic (docs/ros2-link.md)
        console.print(line, markup=False, soft_wrap=True)
    # the edge (docs/runtime.md): ingress delay per modem, messages lost because a consumer did not keep up
    edge = s.get("edge") or {}
    rows = [(dev, e) for dev, e in edge.items() if not dev.startswith("*") and e.get("ingress_n")]
    if rows:
        worst = max(rows, key=lambda r: r[1]["ingress_max"])
        n = sum(e["ingress_n"] for _, e in rows)
        mean = sum(e["ingress_mean"] * e["ingress_n"] for _, e in rows) / n
        warn = s.get("ingress_warn", 0.05)
        flag = f" (over {warn * 1e3:.0f} ms: the engine did not keep up)" if worst[1]["ingress_max"] > warn else ""
        console.print(f"ingress delay (tx put to engine): {n} messages, mean {mean * 1e3:.2f} ms, max"
                      f" {worst[1]['ingress_max'] * 1e3:.2f} ms at {worst[0]}{flag}", markup=False, soft_wrap=True)
    lost = {dev: e for dev, e in edge.items() if e.get("lost") or e.get("refused")}
    for dev, e in sorted(lost.items()):
        parts = [f"{n} {kind}" for kind, n in sorted((e.get("lost") or {}).items())]
        if e.get("refused"):
            parts.append(f"{e['refused']} tx refused (ingress lane full, status dropped fifo)")
        console.print(f"lost at the edge: {dev}: {', '.join(parts)} (a consumer did not keep up)", markup=False,
                      soft_wrap=True)
    for c in s.get("cut_off") or ():
        console.print(f"cut off: {c['whatami']} {c['zid']} for {c['s']:.1f} s (t={c['t']:.3f}..{c['back']:.3f} s):"
                      " Zenoh closed its connection (it did not read, or its lease ran out); what was put for it"
                      " in that time is lost", markup=False, soft_wrap=True)
    for peer, n in sorted((s.get("unsent_at_close") or {}).items()):
        console.print(f"unsent at close: {n} bytes to {peer} (an app that did not read what was put for it before"
                      " the stop: it may be lost)", markup=False, soft_wrap=True)
    for dev, e in sorted((d, e) for d, e in edge.items() if e.get("stalled")):
        parts = ", ".join(f"{n} {kind}" for kind, n in sorted(e["stalled"].items()))
        console.print(f"stalled at the edge: {dev}: {parts} put(s) waited up to {e['stalled_max']:.1f} s (a"
                      " subscriber did not read: what it had not taken is lost; a router gives up a put after"
                      f" {WAIT_BEFORE_CLOSE_US / 1e6:g} s)", markup=False, soft_wrap=True)
