"""`gli`: send, listen, info, pose, flow and control from the command line (like Zenoh's z_pub/z_sub).

    gli send alpha-modem 2 "hello"                 # one frame from alpha-modem to address 2
    gli send alpha-modem 2 --count 10 --interval 0.5 --size 64 --wait
    gli listen bravo-modem --status                # frames (and status events) as they come
    gli listen                                     # every modem of the world
    gli info                                       # every modem: kind, address, FIFO, counters
    gli pose bravo 120 0 10 --velocity 1 0 0 --rate 10
    gli flow --src alpha-modem --dst 2 --size 32 --interval 1 --name alpha-to-bravo
    gli control pause ; gli control move vehicle='"bravo"' p='[10,0,5]'
    gli vehicle bravo waypoint='[10,0,5]'          # a kinematic vehicle (`uwsimnet vehicles`)
    gli trace --count 10                           # trace events (what a visitor may read)

Common options (as `uwsimnet`'s): -e/--connect ENDPOINT (default: the configuration file's, else
tcp/127.0.0.1:7447), -w/--world NAME (default: the only world that answers), --zenoh-config FILE (alias
--config; a Zenoh JSON5 client configuration, default $ZENOH_CONFIG; --connect replaces its endpoints).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import queue
import random
import sys
import time
from collections.abc import Sequence
from typing import Any

import zenoh

from uwsimnet_gli.world import GliError, World, config_access, load_config

from .records import Frame, Status, read_map, read_rx, read_status
from .wire import DEFAULT_ENDPOINT, access_refusals, refusal_message


def _world(args: argparse.Namespace, *checks: tuple[Any, ...]) -> World:
    """The world of the options; `checks` = (program, modems, vehicles) the command will run: refused
    at once, before any session is opened, when the configuration's access section does not allow it."""
    conf = load_config(args.config, args.connect)
    access = config_access(conf)
    name = args.world or (access or {}).get("world")
    if access is not None and isinstance(name, str) and name != "*":
        for program, modems, vehicles in checks:
            refused = access_refusals(access, program, name, modems, vehicles)
            if refused:
                raise GliError(refusal_message(access, refused))
    world = World(args.world, connect=args.connect or DEFAULT_ENDPOINT, config=conf)
    try:
        for program, modems, vehicles in checks:        # the world may have been discovered
            world.check(program, modems, vehicles)
    except BaseException:
        world.close()
        raise
    return world


def _show(data: bytes) -> str:
    head, more = data[:64], (f"... ({len(data)} B)" if len(data) > 64 else "")
    try:
        text = head.decode()
        if text.isprintable():
            return repr(text) + more
    except UnicodeDecodeError:
        pass
    return head.hex() + more


def _frame_json(f: Frame) -> str:
    d: dict[str, Any] = {"modem": f.modem, "src": f.src, "dst": f.dst, "seq": f.seq, "t_tx": f.t_tx,
                         "t_rx": f.t_rx, "size": len(f.data), "data_hex": f.data.hex()}
    with contextlib.suppress(UnicodeDecodeError):
        d["text"] = f.data.decode()
    return json.dumps(d)


# -- commands -----------------------------------------------------------------------------------
def cmd_send(args: argparse.Namespace) -> int:
    with _world(args, ("modem", [args.modem], ())) as world:
        modem = world.modem(args.modem)
        kind = modem.wait_kind(timeout=args.timeout)
        if kind is None:
            print(f"warning: nobody serves {args.modem!r} in world {world.name!r} (no driver token: no broker"
                  " or driver serves it, or this identity may not use it)", file=sys.stderr)
        key = world.keys.modem(args.modem, "tx")
        print(f"Declaring Publisher on '{key}' ({kind or 'no driver'})...")
        bad = 0
        for i in range(args.count):
            if args.hex:
                data = bytes.fromhex(args.data or "")
            elif args.data is not None:
                data = args.data.encode()
            else:
                data = f"[{i:4d}] Hello from gli".encode()
            if args.size is not None:
                data = (data * (args.size // max(1, len(data)) + 1))[:args.size] if data else bytes(args.size)
            tag = modem.send(args.dst, data, flow=args.flow)
            print(f"Sending to {args.dst} (tag {tag}, {len(data)} B): {_show(data)}")
            if args.wait:
                st = modem.wait_status(tag, timeout=args.timeout)
                if st is None:
                    print(f"  no final status within {args.timeout:g} s")
                    bad += 1
                else:
                    print(f"  {st.event}" + (f" ({st.reason})" if st.reason else "") + f" at t={st.t:.6f}")
                    bad += st.event in ("dropped", "failed")
            if i + 1 < args.count:
                time.sleep(args.interval)
        time.sleep(0.05)            # let the last put leave before the session closes
    return 1 if bad else 0


def cmd_listen(args: argparse.Namespace) -> int:
    with _world(args, ("listen", args.modem or ["*"], ())) as world:
        s = world.session
        mods = args.modem or ["*"]
        n = 0
        done = False
        q: queue.Queue = queue.Queue()

        def rx(sample: zenoh.Sample) -> None:
            dev = str(sample.key_expr).split("/")[-2]
            q.put(read_rx(sample.payload.to_bytes(), dev, time.time()))

        def st(sample: zenoh.Sample) -> None:
            dev = str(sample.key_expr).split("/")[-2]
            q.put(read_status(sample.payload.to_bytes(), dev))
        subs = []
        for m in mods:
            key = world.keys.modem(m, "rx")
            print(f"Declaring Subscriber on '{key}'...", file=sys.stderr)
            subs.append(s.declare_subscriber(key, rx))
            if args.status:
                subs.append(s.declare_subscriber(world.keys.modem(m, "status"), st))
        print("Press CTRL-C to quit...", file=sys.stderr)
        deadline = None if args.timeout is None else time.monotonic() + args.timeout
        try:
            while not done:
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0:
                    break
                try:
                    item = q.get(timeout=0.2 if left is None else min(0.2, left))
                except queue.Empty:
                    continue
                if isinstance(item, Frame):
                    n += 1
                    if args.json:
                        print(_frame_json(item), flush=True)
                    else:
                        print(f">> [rx] {item.modem} <- {item.src} (dst {item.dst}, seq {item.seq})"
                              f" t_tx={item.t_tx:.6f} t_rx={item.t_rx:.6f}: {_show(item.data)}", flush=True)
                    done = args.count is not None and n >= args.count
                elif isinstance(item, Status):
                    if args.json:
                        print(json.dumps({"modem": item.modem, "tag": item.tag, "event": item.event,
                                          "reason": item.reason, "t": item.t}), flush=True)
                    else:
                        print(f">> [status] {item.modem} tag {item.tag}: {item.event}"
                              + (f" ({item.reason})" if item.reason else "") + f" t={item.t:.6f}", flush=True)
        finally:
            for sub in subs:
                sub.undeclare()
    if args.count is not None and n < args.count:
        print(f"{n} of {args.count} frame(s) within {args.timeout:g} s", file=sys.stderr)
        return 1
    return 0


def cmd_info(args: argparse.Namespace) -> int:
    with _world(args, ("info", [args.modem or "*"], ())) as world:
        key = world.keys.modem(args.modem or "*", "info")
        out = []
        for r in world.session.get(key, timeout=args.timeout):
            if r.ok is not None:
                try:
                    out.append(read_map(r.ok.payload.to_bytes()))
                except Exception:  # noqa: BLE001
                    continue
        if not out:
            print(f"no reply on '{key}'", file=sys.stderr)
            return 1
        out.sort(key=lambda d: str(d.get("id")))
        if args.json:
            print(json.dumps(out, indent=2, default=str))
            return 0
        for d in out:
            c = d.get("counters") or {}
            pos = d.get("position")
            print(f"{d.get('id')}: {d.get('kind')}, address {d.get('address')}, vehicle {d.get('vehicle')},"
                  f" channels tx {d.get('tx_channel')} rx {d.get('rx_channel')}, {d.get('bitrate')} bps,"
                  f" fifo {d.get('fifo_bytes')}/{d.get('fifo_capacity')} B,"
                  f" pose {'-' if pos is None else ' '.join(f'{x:g}' for x in pos)},"
                  f" counters {' '.join(f'{k}={v}' for k, v in c.items())}")
    return 0


def _check_vehicle(world: World, vehicle: str) -> None:
    """GliError when the world's brokers answer and none has `vehicle`: a pose for a name no scene has is
    published to nobody, so a typo would otherwise pass in silence.  Unchecked (a note on stderr) when no
    broker answers `control/state` (not started yet, or this identity may not ask)."""
    if world.access is not None and access_refusals(world.access, "control", world.name):
        print(f"gli: this identity may not ask world {world.name!r} for its vehicles (control/state);"
              f" {vehicle!r} is not checked", file=sys.stderr)
        return                                  # the routers would drop the query: no answer to wait for
    replies = [r for r in world.control_all("state") if r.get("ok")]
    if not replies:
        print(f"gli: no broker of world {world.name!r} answers control/state; {vehicle!r} is not checked",
              file=sys.stderr)
        return
    names = sorted({n for r in replies for n in (r.get("vehicles") or {})})
    if vehicle not in names:
        raise GliError(f"pose: no vehicle {vehicle!r} in world {world.name!r}"
                       f" (vehicles: {', '.join(names) or 'none'})")


def cmd_pose(args: argparse.Namespace) -> int:
    p0 = (args.x, args.y, args.z)
    v = tuple(args.velocity) if args.velocity else None
    with _world(args, ("pose", (), [args.vehicle])) as world:
        _check_vehicle(world, args.vehicle)
        key = world.keys.pose(args.vehicle)
        print(f"Declaring Publisher on '{key}'...", file=sys.stderr)
        if not args.rate:
            world.publish_pose(args.vehicle, p0, v=v)
            print(f"Putting pose {p0}" + (f" v={v}" if v else ""))
            time.sleep(0.05)
            return 0
        period = 1.0 / args.rate
        t0 = time.monotonic()
        i = 0
        while args.count is None or i < args.count:
            t = i * period
            if args.duration is not None and t > args.duration:
                break
            p = tuple(a + (b * t if v else 0.0) for a, b in zip(p0, v or (0, 0, 0), strict=True))
            world.publish_pose(args.vehicle, p, v=v)
            if args.verbose:
                print(f"Putting pose {tuple(round(x, 3) for x in p)}", flush=True)
            i += 1
            delay = t0 + i * period - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        time.sleep(0.05)
    return 0


def run_flow(world: World, src: str, dst: int, size: int, interval: float, *, arrival: str = "periodic",
             start: float = 0.0, stop: float | None = None, name: str | None = None, seed: int = 0,
             count: int | None = None, on_send=None) -> int:
    """A scene-style flow as an app: frames of `size` bytes from `src` to `dst` at simulation times
    start, start+interval, ... (or Poisson arrivals of that mean gap) until `stop`; returns frames sent.
    Times follow the world's clock (pauses included)."""
    modem = world.modem(src)
    if world.clock(timeout=5.0) is None:
        raise GliError(f"no clock sample from world {world.name!r}")
    rng = random.Random(seed)
    gap = (lambda: rng.expovariate(1.0 / interval)) if arrival == "poisson" else (lambda: interval)
    t = start + (gap() if arrival == "poisson" else 0.0)
    now = world.sim_time() or 0.0
    k = 0
    while t < now:                                  # joined late: skip the past
        k += 1
        t = start + k * interval if arrival == "periodic" else t + gap()
    sent = 0
    while (stop is None or t < stop) and (count is None or sent < count):
        while True:
            now = world.sim_time() or 0.0
            left = t - now
            if left <= 0:
                break
            c = world.clock(0)
            speed = float((c or {}).get("speed") or 1.0)
            time.sleep(min(0.2, left / speed) if left / speed > 0.002 else 0.0005)
        data = sent.to_bytes(4, "big")[:size].ljust(size, b"\0")
        tag = modem.send(dst, data, flow=name)
        if on_send is not None:
            on_send(sent, t, tag)
        sent += 1
        k += 1
        t = start + k * interval if arrival == "periodic" else t + gap()
    time.sleep(0.05)
    return sent


def cmd_flow(args: argparse.Namespace) -> int:
    interval = args.interval if args.interval else 1.0 / args.rate
    with _world(args, ("modem", [args.src], ()), ("clock", (), ())) as world:
        until = f" to {args.stop:g}" if args.stop is not None else ""
        print(f"flow {args.name or '-'}: {args.src} -> {args.dst}, {args.size} B every {interval:g} s"
              f" ({args.arrival}) from t={args.start:g}{until}", file=sys.stderr)

        def show(i: int, t: float, tag: int) -> None:
            if args.verbose:
                print(f"[{i:5d}] t={t:.3f} tag {tag}", flush=True)
        n = run_flow(world, args.src, args.dst, args.size, interval, arrival=args.arrival, start=args.start,
                     stop=args.stop, name=args.name, seed=args.seed, count=args.count, on_send=show)
        print(f"sent {n} frames", file=sys.stderr)
    return 0


def _json_value(s: str) -> Any:
    try:
        return json.loads(s)
    except json.JSONDecodeError:
        return s


def cmd_control(args: argparse.Namespace) -> int:
    req = _kv(args.args)
    with _world(args, ("control", (), ())) as world:
        replies = world.control_all(args.op, timeout=args.timeout, **req)
    if not replies:
        print(f"control/{args.op}: no reply", file=sys.stderr)
        return 1
    for r in replies:
        print(json.dumps(r, indent=2, default=str))
    return 0 if all(r.get("ok") for r in replies) else 1


def _kv(items: Sequence[str]) -> dict[str, Any]:
    req: dict[str, Any] = {}
    for item in items:
        k, sep, v = item.partition("=")
        if not sep:
            raise GliError(f"expected KEY=VALUE, got {item!r}")
        req[k] = _json_value(v)
    return req


def cmd_vehicle(args: argparse.Namespace) -> int:
    cmd = _kv(args.args)
    with _world(args, ("command", (), [args.vehicle])) as world:
        print(f"Declaring Publisher on '{world.keys.vehicle_cmd(args.vehicle)}'...", file=sys.stderr)
        world.command_vehicle(args.vehicle, **cmd)
        print(f"Putting command {json.dumps(cmd)}")
        time.sleep(0.05)            # let the put leave before the session closes
    return 0


def cmd_trace(args: argparse.Namespace) -> int:
    with _world(args, ("trace", (), ())) as world:
        q: queue.Queue = queue.Queue()
        key = world.keys.trace_all
        print(f"Declaring Subscriber on '{key}'...", file=sys.stderr)
        sub = world.session.declare_subscriber(key, lambda s: q.put(s.payload.to_bytes()))
        n = 0
        deadline = None if args.timeout is None else time.monotonic() + args.timeout
        try:
            while args.count is None or n < args.count:
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0:
                    break
                try:
                    raw = q.get(timeout=0.2 if left is None else min(0.2, left))
                except queue.Empty:
                    continue
                rec = read_map(raw)
                if isinstance(rec, dict):
                    n += 1
                    print(json.dumps(rec, default=lambda b: b.hex() if isinstance(b, bytes) else str(b)),
                          flush=True)
        finally:
            sub.undeclare()
    if n == 0:
        print(f"no trace event on '{key}'", file=sys.stderr)
        return 1
    return 0


# -- parser -------------------------------------------------------------------------------------
def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="gli", description="uwsimnet modems over Zenoh: send, listen, info,"
                                " pose, flow, control")
    # the Zenoh options of `uwsimnet` (uwsimnet_zenoh/cli/zenoh_flags.py), with the same meaning
    p.add_argument("-e", "--connect", action="append", metavar="ENDPOINT",
                   help=f"Zenoh router to connect to (repeat; default: the --zenoh-config file's, else"
                        f" {DEFAULT_ENDPOINT})")
    p.add_argument("-w", "--world", help="world name (default: the only one that answers)")
    p.add_argument("--zenoh-config", "--config", dest="config", metavar="FILE",
                   help="Zenoh JSON5 client configuration (TLS, user/password; default $ZENOH_CONFIG);"
                        " its endpoints unless --connect is given")
    sub = p.add_subparsers(dest="cmd", required=True)

    s = sub.add_parser("send", help="send frames from a modem")
    s.add_argument("modem")
    s.add_argument("dst", type=int, help="destination address (255 = broadcast)")
    s.add_argument("data", nargs="?", help="payload text (default: a counter message)")
    s.add_argument("--hex", action="store_true", help="DATA is hex")
    s.add_argument("--size", type=int, help="payload bytes (repeats/truncates DATA)")
    s.add_argument("--count", type=int, default=1)
    s.add_argument("--interval", type=float, default=1.0, help="s between frames")
    s.add_argument("--flow", help="scene flow the frames belong to (trace attribution)")
    s.add_argument("--wait", action="store_true", help="wait for and print each frame's final status (sent;"
                   " acked/failed with a MAC or modem that acknowledges; dropped)")
    s.add_argument("--timeout", type=float, default=5.0, help="s to wait for the driver and for each status")
    s.set_defaults(fn=cmd_send)

    li = sub.add_parser("listen", help="print frames received by modems")
    li.add_argument("modem", nargs="*", help="dccommsIds (default: all)")
    li.add_argument("--status", action="store_true", help="also status events")
    li.add_argument("--count", type=int, help="stop after this many frames")
    li.add_argument("--timeout", type=float, help="stop after this many seconds")
    li.add_argument("--json", action="store_true", help="one JSON object per line")
    li.set_defaults(fn=cmd_listen)

    i = sub.add_parser("info", help="configuration and live state of modems")
    i.add_argument("modem", nargs="?")
    i.add_argument("--json", action="store_true")
    i.add_argument("--timeout", type=float, default=2.0)
    i.set_defaults(fn=cmd_info)

    po = sub.add_parser("pose", help="publish a vehicle's pose (once, or at a rate)")
    po.add_argument("vehicle")
    po.add_argument("x", type=float)
    po.add_argument("y", type=float)
    po.add_argument("z", type=float)
    po.add_argument("--velocity", type=float, nargs=3, metavar=("VX", "VY", "VZ"))
    po.add_argument("--rate", type=float, help="Hz: keep publishing (moving with --velocity)")
    po.add_argument("--count", type=int)
    po.add_argument("--duration", type=float, help="s")
    po.add_argument("-v", "--verbose", action="store_true")
    po.set_defaults(fn=cmd_pose)

    f = sub.add_parser("flow", help="run a traffic flow as an app (simulation-time schedule)")
    f.add_argument("--src", required=True, help="sending modem (dccommsId)")
    f.add_argument("--dst", required=True, type=int)
    f.add_argument("--size", required=True, type=int)
    g = f.add_mutually_exclusive_group(required=True)
    g.add_argument("--interval", type=float, help="s between frames (mean for poisson)")
    g.add_argument("--rate", type=float, help="frames per s")
    f.add_argument("--arrival", choices=["periodic", "poisson"], default="periodic")
    f.add_argument("--start", type=float, default=0.0, help="simulation time of the first frame")
    f.add_argument("--stop", type=float)
    f.add_argument("--count", type=int)
    f.add_argument("--name", help="flow name (as in the scene: the trace attributes frames to it)")
    f.add_argument("--seed", type=int, default=0)
    f.add_argument("-v", "--verbose", action="store_true")
    f.set_defaults(fn=cmd_flow)

    c = sub.add_parser("control", help="runtime control: state, pause, resume, move, add_device,"
                       " remove_device")
    c.add_argument("op")
    c.add_argument("args", nargs="*", help="KEY=VALUE (VALUE parsed as JSON when it is JSON)")
    c.add_argument("--timeout", type=float, default=2.0)
    c.set_defaults(fn=cmd_control)

    ve = sub.add_parser("vehicle", help="command a kinematic vehicle (`uwsimnet vehicles`): waypoint, v, ...")
    ve.add_argument("vehicle")
    ve.add_argument("args", nargs="+", help="KEY=VALUE (VALUE parsed as JSON), e.g. waypoint=[10,0,5]")
    ve.set_defaults(fn=cmd_vehicle)

    tr = sub.add_parser("trace", help="print trace events as the broker publishes them (JSON lines)")
    tr.add_argument("--count", type=int, help="stop after this many events")
    tr.add_argument("--timeout", type=float, help="stop after this many seconds")
    tr.set_defaults(fn=cmd_trace)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.fn(args)
    except GliError as e:
        print(f"gli: {e}", file=sys.stderr)
        return 2
    except (ValueError, zenoh.ZError) as e:
        print(f"gli: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
