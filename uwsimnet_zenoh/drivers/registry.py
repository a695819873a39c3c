"""The driver port: names to drivers (`uwsimnet driver NAME`) and emulators (`uwsimnet emulate NAME`).

A driver serves a modem id with a real device; an emulator makes a simulated modem look like a device.  Each
is a plug-in object: the built-ins are named here (their device packages, `evologics/` and `dccomms/`, are
imported only when asked for), others come from installed packages through the entry-point groups
`uwsimnet.drivers` and `uwsimnet.emulators` (docs/drivers.md), read only when a name no built-in has is
asked for or the names are listed (reading every distribution's entry points costs ~25 ms).  Built-in
names win.  Nothing here knows a device: the CLI asks the plug-in for its arguments and lets it open
itself."""

from __future__ import annotations

import argparse
import importlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

from ..errors import UserError

if TYPE_CHECKING:
    from .backend import ModemBackend
    from .base import Driver

DRIVER_GROUP = "uwsimnet.drivers"
EMULATOR_GROUP = "uwsimnet.emulators"


class DriverContext(Protocol):
    """What a driver plug-in may ask of the command that hosts it."""

    id: str
    world: str

    def info(self) -> dict[str, Any] | None:
        """The simulated modem's `info` (address, tx_framing, ...) before the swap; None if none answers."""


class Service(Protocol):
    def close(self) -> None: ...


@dataclass(frozen=True)
class DriverPlugin:
    """`uwsimnet driver NAME`: `arguments(parser)` adds the device's flags (the CLI adds --id and the Zenoh
    flags); `open(args, ctx)` returns a `drivers.base.Driver`, not opened yet (the host opens it).  Raise
    `errors.UserError` for a bad argument: it is printed as one line, exit 2."""

    help: str
    arguments: Callable[[argparse.ArgumentParser], None]
    open: Callable[[argparse.Namespace, DriverContext], Driver]
    check: Callable[[argparse.Namespace], None] | None = None
    """Checks of the arguments alone, run before any Zenoh session is opened (UserError)."""


@dataclass(frozen=True)
class EmulatorPlugin:
    """`uwsimnet emulate NAME`: `arguments(parser)` as above; `start(args, backend)` serves the simulated
    modem `backend` as the device and returns (something with close(), where it serves, for the ready line)."""

    help: str
    arguments: Callable[[argparse.ArgumentParser], None]
    start: Callable[[argparse.Namespace, ModemBackend], tuple[Service, str]]
    check: Callable[[argparse.Namespace], None] | None = None
    """Checks of the arguments alone, run before any Zenoh session is opened (UserError)."""


BUILTIN_DRIVERS = {"evologics": "uwsimnet_zenoh.drivers.evologics:DRIVER",
                   "serial": "uwsimnet_zenoh.drivers.dccomms:DRIVER"}
BUILTIN_EMULATORS = {"evologics": "uwsimnet_zenoh.drivers.evologics:EMULATOR",
                     "serial": "uwsimnet_zenoh.drivers.dccomms:EMULATOR"}
_KINDS: dict[str, tuple[str, dict[str, str], type]] = {
    "driver": (DRIVER_GROUP, BUILTIN_DRIVERS, DriverPlugin),
    "emulator": (EMULATOR_GROUP, BUILTIN_EMULATORS, EmulatorPlugin),
}


def _entry_points(group: str) -> dict[str, Any]:
    from importlib.metadata import entry_points  # noqa: PLC0415 - only for names no built-in has (start-up)

    return {ep.name: ep for ep in entry_points(group=group)}


def names(kind: str) -> list[str]:
    """Every name of `kind` (driver | emulator): built-ins, then installed plug-ins."""
    group, builtin, _ = _KINDS[kind]
    return [*builtin, *sorted(n for n in _entry_points(group) if n not in builtin)]


def _load(value: str) -> Any:
    mod, _, attr = value.partition(":")
    obj: Any = importlib.import_module(mod)
    for part in attr.split(".") if attr else ():
        obj = getattr(obj, part)
    return obj


def resolve(kind: str, name: str) -> Any:
    """The `DriverPlugin` / `EmulatorPlugin` named `name`; UserError (one line) for an unknown name or a
    plug-in that does not load or is not one."""
    group, builtin, cls = _KINDS[kind]
    if name in builtin:
        return _load(builtin[name])
    ep = _entry_points(group).get(name)
    if ep is None:
        raise UserError(f"unknown {kind} {name!r} (known: {', '.join(names(kind))}; plug-ins register under the"
                        f" entry-point group {group})")
    try:
        obj = ep.load()
    except Exception as e:  # noqa: BLE001 - whatever a broken plug-in raises becomes one line
        raise UserError(f"{kind} plug-in {name!r} ({ep.value}) does not load: {type(e).__name__}: {e}") from None
    if not isinstance(obj, cls):
        raise UserError(f"{kind} plug-in {name!r} ({ep.value}) is a {type(obj).__name__}, not a"
                        f" uwsimnet_zenoh.drivers.registry.{cls.__name__}")
    return obj
