"""dccomms serial radios (WFS Seatooth S100 style): a transparent serial link carrying dccomms frames
(`formats.dccomms`, any packet builder).  `driver.SerialRadioDriver` speaks to a radio's port,
`emulator.SerialRadioEmulator` makes a simulated modem a pty radio.  `DRIVER` and `EMULATOR` are their
plug-ins (drivers/registry.py): `uwsimnet driver serial`, `uwsimnet emulate serial`."""

from __future__ import annotations

import argparse
import os
from typing import Any

from ...errors import UserError
from ..registry import DriverPlugin, EmulatorPlugin

FRAMING_HELP = ("dccomms packet builder on the line (default: the modem's txPacketBuilder in the scene, else"
                " DataLinkFrameBuilderCRC16)")


def framing_arg(name: str | None, flag: str = "--framing") -> str | None:
    """A packet-builder name checked (one-line error naming the known builders)."""
    if not name:
        return None
    from ...formats.dccomms import builder  # noqa: PLC0415

    try:
        return builder(name).name
    except ValueError as e:
        raise UserError(f"{flag}: {e}") from None


def _driver_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--device", required=True, help="serial device or pty path")
    p.add_argument("--address", type=int, help="the radio's address (default: the simulated modem's)")
    p.add_argument("--baud", type=int, default=9600, help="0: leave the line speed alone (pty)")
    p.add_argument("--framing", metavar="BUILDER", help=FRAMING_HELP)


def _open_driver(args: argparse.Namespace, ctx: Any) -> Any:
    from .driver import SerialRadioDriver  # noqa: PLC0415 - the device's code only when it is used

    address, framing = args.address, framing_arg(args.framing)
    if address is None or framing is None:
        info = ctx.info()
        if info is None and address is None:
            raise UserError(f"{ctx.id}: no simulated modem answers in world {ctx.world!r}; give --address")
        if address is None:
            address = int(info["address"])
        if framing is None and info is not None:
            framing = info.get("tx_framing") or None
    try:
        return SerialRadioDriver(args.device, address, ctx.id, baud=args.baud or None, framing=framing)
    except ValueError as e:
        raise UserError(f"driver serial: {e}") from None


def _emulator_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--link", metavar="PATH", help="also make a symlink PATH to the pty (like a udev name)")
    p.add_argument("--framing", metavar="BUILDER", help=FRAMING_HELP.replace("line", "pty"))


def _check_emulator(args: argparse.Namespace) -> None:
    link = args.link
    if link and os.path.lexists(link) and not os.path.islink(link):     # the emulator replaces old links only
        raise UserError(f"--link {link}: exists and is not a symlink; not replacing it")
    framing_arg(args.framing)


def _start_emulator(args: argparse.Namespace, backend: Any) -> tuple[Any, str]:
    from .emulator import SerialRadioEmulator  # noqa: PLC0415

    link = args.link
    emu = SerialRadioEmulator(backend, link=link, framing=framing_arg(args.framing))
    try:
        emu.start()
    except OSError as e:
        emu.close()
        raise UserError(f"emulate serial: cannot create the pty{f' or --link {link}' if link else ''}: {e}") from None
    return emu, emu.path + (f" link {link}" if link else "")


DRIVER = DriverPlugin("transparent serial radio carrying dccomms frames", _driver_args, _open_driver,
                      lambda args: framing_arg(args.framing) and None)
EMULATOR = EmulatorPlugin("pty speaking dccomms frames (transparent serial radio)", _emulator_args, _start_emulator,
                          _check_emulator)
