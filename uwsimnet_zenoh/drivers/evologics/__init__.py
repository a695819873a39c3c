"""EvoLogics S2C modems: the driver (`driver.EvoLogicsDriver`, AT commands over TCP, command or data mode) and
the emulator (`emulator.EvoLogicsEmulator`, an AT server backed by a simulated modem).  The AT syntax both
speak is the format room's (`formats.evologics_at`).  `DRIVER` and `EMULATOR` are their plug-ins
(drivers/registry.py): `uwsimnet driver evologics`, `uwsimnet emulate evologics`."""

from __future__ import annotations

import argparse
from typing import Any

from .._aio import listen_error
from ..registry import DriverPlugin, EmulatorPlugin


def _driver_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--host", required=True)
    p.add_argument("--port", type=int, default=9200)
    p.add_argument("--mode", choices=["auto", "im", "burst"], default="auto")
    p.add_argument("--link-mode", choices=["command", "data"], default="command",
                   help="speak the modem's command mode, or data mode (ATO, +++AT escapes)")


def _open_driver(args: argparse.Namespace, ctx: Any) -> Any:
    from .driver import EvoLogicsDriver  # noqa: PLC0415 - the device's code only when it is used

    return EvoLogicsDriver(args.host, args.port, ctx.id, mode=args.mode, link_mode=args.link_mode)


def _emulator_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--port", type=int, default=9200)
    p.add_argument("--host", default="127.0.0.1", help="address to listen on")
    p.add_argument("--interpreter", choices=["at", "net"], default="at",
                   help="at: data and command mode, AT?MODE answers AT; net: command mode only, NET (DUNE)")
    p.add_argument("--ack-timeout", type=_seconds, default=5.0, metavar="S",
                   help="FAILED(IM) for a frame with no outcome after S s of wall and of simulated time"
                        " (default 5)")


def _seconds(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        v = float("nan")
    if not 0 < v < float("inf"):
        raise argparse.ArgumentTypeError(f"expected seconds > 0, got {text!r}")
    return v


def _start_emulator(args: argparse.Namespace, backend: Any) -> tuple[Any, str]:
    from .emulator import EvoLogicsEmulator  # noqa: PLC0415

    emu = EvoLogicsEmulator(backend, args.host, args.port, interpreter=args.interpreter,
                            ack_timeout=args.ack_timeout)
    try:
        host, port = emu.start()
    except OSError as e:
        emu.close()
        raise listen_error("emulate evologics", args.host, args.port, e) from None
    return emu, f"{host}:{port}"


DRIVER = DriverPlugin("EvoLogics S2C modem, AT commands over TCP", _driver_args, _open_driver)
EMULATOR = EmulatorPlugin("EvoLogics S2C AT command server on TCP", _emulator_args, _start_emulator)
