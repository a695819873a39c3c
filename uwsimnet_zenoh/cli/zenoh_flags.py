"""The Zenoh options of every `uwsimnet` command that opens a session, defined once (as zenoh-python's
examples/common/common.py does for its examples).  `gli` (gli_clients/python/uwsimnet_gli/cli.py) has
the same options with the same meaning.

    --connect ENDPOINT    a router to connect to (repeat); replaces the file's connect endpoints
    --listen ENDPOINT     an endpoint to listen on (commands that can be a router: run, router)
    --world NAME          the world (default: the only one that answers; with an access control that
                          names a world, always give it: discovery asks `uwsimnet/*/control/state`)
    --zenoh-config FILE   a Zenoh JSON5 configuration (TLS, user/password), default $ZENOH_CONFIG;
                          without --connect/--listen its endpoints are the ones used

When a session cannot be opened the command says so in one line, with the endpoints it tried and the
file they came from, and exits 2.
"""

from __future__ import annotations

import argparse
import contextlib
import os
from collections.abc import Iterator
from typing import Any

from ..errors import UserError

DEFAULT_CONNECT = "tcp/127.0.0.1:7447"
"""uwsimnet_gli.wire.DEFAULT_ENDPOINT (tests/test_cli.py holds them equal), not imported here: the uwsimnet_gli
package brings zenoh, asyncio and msgpack, which a virtual run does not need (start-up time)."""

ENV = "ZENOH_CONFIG"


def add_zenoh_flags(p: argparse.ArgumentParser, *, listen: bool = False, world: str | None = None,
                    connect_help: str | None = None, listen_help: str | None = None,
                    config_help: str | None = None, config_aliases: tuple[str, ...] = ()) -> None:
    """--connect, --zenoh-config (+ aliases), and --listen / --world when asked (`world`: its help)."""
    p.add_argument("--connect", action="append", metavar="ENDPOINT",
                   help=connect_help or f"Zenoh router to connect to (repeat; default: the --zenoh-config"
                                        f" file's, else {DEFAULT_CONNECT})")
    if listen:
        p.add_argument("--listen", action="append", metavar="ENDPOINT",
                       help=listen_help or "Zenoh endpoint to listen on (repeat)")
    p.add_argument("--zenoh-config", *config_aliases, dest="zenoh_config", metavar="FILE",
                   help=config_help or f"Zenoh JSON5 client configuration (TLS, user/password; default ${ENV});"
                                       " its endpoints unless --connect is given")
    if world is not None:
        p.add_argument("--world", help=world)


def config_file(args: argparse.Namespace, *, env: bool = True) -> str | None:
    """--zenoh-config, else $ZENOH_CONFIG (when `env`), else None."""
    return getattr(args, "zenoh_config", None) or (os.environ.get(ENV) or None if env else None)


@contextlib.contextmanager
def client_session(args: argparse.Namespace, *, timeout_ms: int = 3000) -> Iterator[Any]:
    """`with client_session(args) as s:` - a client of --connect / the file's endpoints; one-line
    UserError (`zenoh: cannot connect to tls/10.77.0.1:7447 (from FILE): ...`) when it cannot."""
    from ..bus.session import BusError, open_client  # noqa: PLC0415 - zenoh only when needed

    try:
        s = open_client(args.connect or (), config_file(args), connect_timeout_ms=timeout_ms)
    except BusError as e:
        raise UserError(f"zenoh: {e}") from None
    try:
        yield s
    finally:
        with contextlib.suppress(Exception):
            s.close()


def access(args: argparse.Namespace) -> dict[str, Any] | None:
    """What the deployment allows this identity (the `metadata.uwsimnet` of a rendered configuration)."""
    from ..bus.session import BusError, file_access  # noqa: PLC0415

    try:
        return file_access(config_file(args))
    except BusError as e:
        raise UserError(f"zenoh: {e}") from None


def configured_world(args: argparse.Namespace) -> str | None:
    """--world, else the one world the configuration's access control names, else None (discover)."""
    if getattr(args, "world", None):
        return args.world
    from uwsimnet_gli import wire  # noqa: PLC0415 - zenoh only when needed

    w = (access(args) or {}).get("world")
    return w if isinstance(w, str) and wire.is_chunk(w) else None


def check_access(args: argparse.Namespace, program: str, world: str, modems: tuple[str, ...] = (),
                 vehicles: tuple[str, ...] = ()) -> None:
    """UserError (one line) if the configuration's access control would drop what `program` (a key of
    `uwsimnet_gli.wire.USES`) declares: refused at once instead of a silent hang."""
    from uwsimnet_gli import wire  # noqa: PLC0415 - zenoh only when needed

    a = access(args)
    refused = wire.access_refusals(a, program, world, modems, vehicles)
    if refused:
        raise UserError(wire.refusal_message(a, refused))
