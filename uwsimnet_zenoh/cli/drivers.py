"""`uwsimnet driver ...`, `uwsimnet emulate ...` and `uwsimnet bridge ...`: hardware and foreign apps on
a running broker (docs/drivers.md, docs/bridges.md).

    uwsimnet driver evologics --host H --port P --id X [--world W] [--connect E]   # real S2C modem serves X
    uwsimnet driver serial --device /dev/ttyUSB0 --id X [--address A]             # dccomms serial radio serves X
    uwsimnet emulate evologics --port P --id X [--world W] [--connect E]         # AT server for simulated X
    uwsimnet emulate serial --id X [--link PATH] [--world W] [--connect E]       # dccomms-framed pty for X
    uwsimnet bridge socket --port P --id X ...  /  uwsimnet bridge mq --id X ...
    uwsimnet bridge unet --id X [--id Y ...] | --all [--port P]                  # UnetStack nodes (fjåge JSON)

Each prints one `uwsimnet: ... ready` line on stdout once it serves, and runs until SIGINT/SIGTERM.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import signal
import sys
import threading
from collections.abc import Iterator
from typing import Any

from ..errors import UserError
from .zenoh_flags import add_zenoh_flags, check_access, client_session, configured_world

WORLD_HELP = "world name (default: the only one that answers)"


def common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--id", required=True, help="the modem's dccommsId")
    add_zenoh_flags(p, world=WORLD_HELP)


def _plugin_args(kind: str, args: argparse.Namespace) -> tuple[Any, argparse.Namespace]:
    """The plug-in named on the command line and its flags parsed by a parser it filled."""
    from ..drivers.registry import resolve

    name = args.driver if kind == "driver" else args.emulator
    plugin = resolve(kind, name)
    p = argparse.ArgumentParser(prog=f"uwsimnet {'driver' if kind == 'driver' else 'emulate'} {name}",
                                description=plugin.help)
    plugin.arguments(p)
    common(p)
    ns = p.parse_args(args.rest)
    for k, v in vars(args).items():
        if k != "rest" and not hasattr(ns, k):
            setattr(ns, k, v)
    if plugin.check is not None:
        plugin.check(ns)
    return plugin, ns


class _Context:
    """What a driver plug-in may ask (drivers/registry.DriverContext)."""

    def __init__(self, session: Any, world: str, modem: str) -> None:
        self.session, self.world, self.id = session, world, modem

    def info(self) -> dict[str, Any] | None:
        from uwsimnet_gli.wire import Keys

        from ..drivers.zenoh_backend import query_info

        return query_info(self.session, Keys(self.world), self.id)


def add_commands(sub: Any) -> None:
    """Register the subcommands on `uwsimnet`'s subparsers."""

    from ..drivers.registry import BUILTIN_DRIVERS, BUILTIN_EMULATORS, DRIVER_GROUP, EMULATOR_GROUP

    # the device's own flags come from its plug-in (drivers/registry.py), parsed once the name is known
    d = sub.add_parser("driver", help="serve a modem id with a real modem (HIL swap)",
                       epilog=f"built-in: {', '.join(BUILTIN_DRIVERS)}; plug-ins: entry points {DRIVER_GROUP}."
                              " `uwsimnet driver NAME --help` lists NAME's flags.")
    d.add_argument("driver", metavar="NAME", help="the driver")
    d.add_argument("rest", nargs=argparse.REMAINDER, help="its flags, --id and the Zenoh flags")
    d.set_defaults(fn=cmd_driver)
    e = sub.add_parser("emulate", help="make a simulated modem look like a real device",
                       epilog=f"built-in: {', '.join(BUILTIN_EMULATORS)}; plug-ins: entry points {EMULATOR_GROUP}."
                              " `uwsimnet emulate NAME --help` lists NAME's flags.")
    e.add_argument("emulator", metavar="NAME", help="the emulator")
    e.add_argument("rest", nargs=argparse.REMAINDER, help="its flags, --id and the Zenoh flags")
    e.set_defaults(fn=cmd_emulate)

    b = sub.add_parser("bridge", help="a modem for applications that cannot speak Zenoh")
    bsub = b.add_subparsers(dest="bridge", required=True)
    bs = bsub.add_parser("socket", help="TCP (and UDP) socket bridge, docs/bridges.md")
    bs.add_argument("--port", type=int, default=0, help="TCP port (0: a free one, printed)")
    bs.add_argument("--udp-port", type=int, help="also serve UDP on this port (0: a free one)")
    bs.add_argument("--host", default="127.0.0.1", help="address to listen on")
    common(bs)
    bs.set_defaults(fn=cmd_bridge)
    bm = bsub.add_parser("mq", help="dccomms POSIX message queues /<id>_tx_dlnk_phy, /<id>_rx_dlnk_phy")
    bm.add_argument("--dccomms-id", help="queue name prefix (default: --id)")
    bm.add_argument("--framing", metavar="BUILDER",
                    help="the applications' packet builder, e.g. VariableLength2BPacketBuilder (default: the"
                         " scene's txPacketBuilder of the modem, else DataLinkFrameBuilderCRC16)")
    bm.add_argument("--rx-framing", metavar="BUILDER",
                    help="the builder of the frames written to the application (default: the scene's"
                         " rxPacketBuilder, else --framing)")
    common(bm)
    bm.set_defaults(fn=cmd_bridge)
    bu = bsub.add_parser("unet", help="a UnetStack node (fjåge JSON over TCP) per modem, docs/unetstack.md")
    who = bu.add_mutually_exclusive_group(required=True)
    who.add_argument("--id", action="append", help="a modem's dccommsId (repeat: one node each)")
    who.add_argument("--all", action="store_true", help="every modem of the world, in the scene's order")
    bu.add_argument("--port", type=int, default=0, help="TCP port of the first node, the next ones follow"
                    " (0: free ones, printed)")
    bu.add_argument("--host", default="127.0.0.1", help="address to listen on")
    add_zenoh_flags(bu, world=WORLD_HELP)
    bu.set_defaults(fn=cmd_bridge_unet)

    k = sub.add_parser("vehicles", help="kinematic vehicles: poses on pose/<name>, commands on vehicle/<name>/cmd")
    k.add_argument("--vehicle", action="append", required=True, metavar="NAME=X,Y,Z",
                   help="a vehicle and its start position (repeat)")
    k.add_argument("--max-speed", type=float, default=1.0, help="m/s")
    k.add_argument("--max-accel", type=float, help="m/s^2 (default: none)")
    k.add_argument("--rate", type=float, default=10.0, help="pose samples per second")
    add_zenoh_flags(k, world=WORLD_HELP)
    k.set_defaults(fn=cmd_vehicles)


def _log() -> None:
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")


@contextlib.contextmanager
def _session(args: argparse.Namespace) -> Iterator[Any]:
    """--connect, else the endpoints of --zenoh-config / $ZENOH_CONFIG, else tcp/127.0.0.1:7447."""
    with client_session(args) as s:
        yield s


def _world(s: Any, args: argparse.Namespace) -> str:
    from ..drivers.zenoh_backend import BackendError, discover_world

    world = configured_world(args)
    if world:
        return world
    try:
        return discover_world(s)
    except BackendError as e:
        raise UserError(str(e)) from None


def _precheck(args: argparse.Namespace, program: str, modems: tuple[str, ...] = (),
              vehicles: tuple[str, ...] = ()) -> None:
    """The access check before any session is opened, when the world is known without asking."""
    world = configured_world(args)
    if world:
        check_access(args, program, world, modems, vehicles)


def _wait_for_signal() -> None:
    stop = threading.Event()
    old = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        while not stop.wait(0.5):
            pass
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)


def cmd_driver(args: argparse.Namespace) -> int:
    from ..drivers.zenoh_host import DriverHost

    plugin, args = _plugin_args("driver", args)
    _log()
    _precheck(args, "driver", (args.id,))
    with _session(args) as s:
        world = _world(s, args)
        check_access(args, "driver", world, (args.id,))
        drv = plugin.open(args, _Context(s, world, args.id))
        if not drv.open(wait=10.0):
            drv.close()
            raise UserError(f"{args.id}: the device did not open ({getattr(drv, 'last_error', '')})")
        host = DriverHost(s, world, args.id, drv)
        try:
            host.start()
            print(f"uwsimnet: driver {args.driver} ready for {world}/{args.id}", flush=True)
            _wait_for_signal()
        finally:
            host.close()
            drv.close()
    return 0


def _serve(args: argparse.Namespace, what: str, start: Any) -> int:
    """Run `start(backend) -> (service, where)` on the simulated modem args.id until a signal."""
    from ..drivers.zenoh_backend import BackendError, ZenohBackend

    _log()
    _precheck(args, "backend", (args.id,))
    with _session(args) as s:
        world = _world(s, args)
        check_access(args, "backend", world, (args.id,))
        try:
            be = ZenohBackend(s, world, args.id)
        except BackendError as e:
            raise UserError(str(e)) from None
        try:
            service, where = start(be)
            try:
                print(f"uwsimnet: {what} ready for {world}/{args.id} on {where}", flush=True)
                _wait_for_signal()
            finally:
                service.close()
        finally:
            be.close()
    return 0


def cmd_emulate(args: argparse.Namespace) -> int:
    plugin, args = _plugin_args("emulator", args)
    return _serve(args, f"emulator {args.emulator}", lambda be: plugin.start(args, be))


def cmd_bridge(args: argparse.Namespace) -> int:
    from ..drivers._aio import listen_error
    from ..drivers.dccomms import framing_arg

    def start(be: Any) -> tuple[Any, str]:
        if args.bridge == "socket":
            from ..bridges.socket_bridge import SocketBridge

            br: Any = SocketBridge(be, args.host, args.port, args.udp_port)
            try:
                br.start()
            except OSError as e:
                udp = getattr(br, "_server", None) is not None        # TCP was bound: the UDP port failed
                br.close()
                raise listen_error("bridge socket", args.host, args.udp_port if udp else args.port, e) from None
            return br, f"tcp {args.host}:{br.tcp_port}" + (f" udp {br.udp_port}" if br.udp_port else "")
        from ..bridges import posix_mq
        from ..bridges.mq_bridge import MqBridge

        if not posix_mq.available():
            raise UserError("POSIX message queues are not available on this system")
        framing_arg(args.framing)
        framing_arg(args.rx_framing, "--rx-framing")
        br = MqBridge(be, args.dccomms_id or args.id, framing=args.framing, rx_framing=args.rx_framing)
        try:
            br.start()
        except posix_mq.MqError as e:
            raise UserError(f"bridge mq: {e}") from None
        return br, f"queues {br.tx_name} {br.rx_name} framing {br.framing.name}" + (
            f" (rx {br.rx_framing.name})" if br.rx_framing.name != br.framing.name else "")

    return _serve(args, f"bridge {args.bridge}", start)


def cmd_bridge_unet(args: argparse.Namespace) -> int:
    from uwsimnet_gli import World

    from ..bridges.unet_gateway import UnetGateway
    from ..drivers._aio import listen_error

    _log()
    ids = tuple(dict.fromkeys(args.id or ()))          # --all: () = every modem, for the access check
    uses = ("modem", "info", "control")          # + pose/<vehicle> when allowed (else the state's positions)
    for program in uses:
        _precheck(args, program, ids)
    with _session(args) as s:
        world = _world(s, args)
        for program in uses:
            check_access(args, program, world, ids)
        with World(world, session=s) as w, contextlib.ExitStack() as stack:
            if args.all:
                ids = tuple(dict.fromkeys(dev for r in w.control_all("state") for dev in r.get("modems") or {}))
                if not ids:
                    raise UserError(f"bridge unet --all: no broker of world {world!r} answers with its modems")
            for i, dev in enumerate(ids):
                port = args.port + i if args.port else 0
                gw = UnetGateway(w, dev, args.host, port)
                stack.callback(gw.close)
                try:
                    gw.start()
                except OSError as e:
                    raise listen_error("bridge unet", args.host, port, e) from None
                except RuntimeError as e:
                    raise UserError(str(e)) from None
                print(f"uwsimnet: bridge unet ready for {world}/{dev} on tcp {args.host}:{gw.port}"
                      f" address {gw.address}", flush=True)
            _wait_for_signal()
    return 0


def cmd_vehicles(args: argparse.Namespace) -> int:
    from ..bus.kinematic import KinematicRunner
    from ..mobility.kinematic import KinematicVehicle

    _log()
    vehicles = []
    for spec in args.vehicle:
        name, _, where = spec.partition("=")
        try:
            p = [float(x) for x in where.split(",")] if where else [0.0, 0.0, 0.0]
            if len(p) != 3:
                raise ValueError
        except ValueError:
            raise UserError(f"--vehicle {spec!r}: expected NAME=X,Y,Z") from None
        vehicles.append(KinematicVehicle(name, p, max_speed=args.max_speed, max_accel=args.max_accel))
    _precheck(args, "vehicles", vehicles=tuple(v.name for v in vehicles))
    with _session(args) as s:
        world = _world(s, args)
        check_access(args, "vehicles", world, vehicles=tuple(v.name for v in vehicles))
        runner = KinematicRunner(s, world, vehicles, rate_hz=args.rate).start()
        try:
            print(f"uwsimnet: vehicles ready in {world}: {', '.join(v.name for v in vehicles)}", flush=True)
            _wait_for_signal()
        finally:
            runner.close()
    return 0


if __name__ == "__main__":       # pragma: no cover
    sys.exit("use `uwsimnet driver|emulate|bridge ...`")
