"""Zenoh sessions that always close, and the configurations this project uses.

Topology (docs/runtime.md): one router per machine, everything else a client of its local router;
routers connect to each other.  Since Zenoh 1.9 two peers exchange nothing unless directly connected,
so nothing here opens a peer.  Multicast scouting is off: a router or client connects only where it is
told to (several test routers on one machine must not find each other).

A session with callback subscribers that is never closed hangs the process at exit, so every session is
opened through `open_session()` (a context manager) or closed in a `finally`.
"""

from __future__ import annotations

import contextlib
import json
import sys
from collections.abc import Iterator, Sequence
from typing import Any

import zenoh

from ..errors import UwsimnetError

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
"""Where `uwsimnet run` listens by default, and where clients connect by default."""
SWITCH_INTERVAL = 0.0005
"""sys.setswitchinterval for processes with a realtime engine thread (5 ms -> 0.5 ms thread switches)."""


class BusError(UwsimnetError, RuntimeError):
    """A Zenoh session could not be opened (bad endpoint, port in use, no router to connect to)."""


def _json(v: Any) -> str:
    return json.dumps(v)


def make_config(mode: str, *, listen: Sequence[str] = (), connect: Sequence[str] = (),
                config_file: str | None = None, connect_timeout_ms: int | None = None,
                extra: dict[str, Any] | None = None) -> zenoh.Config:
    """A Zenoh configuration: `mode` router | client; endpoints like `tcp/127.0.0.1:7447`."""
    if mode not in ("router", "client"):
        raise ValueError(f"mode must be router or client, got {mode!r}")
    try:
        conf = zenoh.Config.from_file(config_file) if config_file else zenoh.Config()
    except zenoh.ZError as e:
        raise BusError(f"{config_file}: {e}") from None
    settings: dict[str, Any] = {"mode": mode, "scouting/multicast/enabled": False}
    if mode == "router":
        settings["adminspace/enabled"] = True          # lets us read back the locators we listen on
    if listen:
        settings["listen/endpoints"] = list(listen)
    if connect:
        settings["connect/endpoints"] = list(connect)
    if connect_timeout_ms is not None and mode == "client":
        settings["connect/timeout_ms"] = connect_timeout_ms
    settings.update(extra or {})
    for k, v in settings.items():
        try:
            conf.insert_json5(k, _json(v))
        except zenoh.ZError as e:
            raise BusError(f"zenoh config {k}={v!r}: {e}") from None
    return conf


def open_raw(conf: zenoh.Config) -> zenoh.Session:
    """`zenoh.open` with a readable error; the caller must close the session (prefer open_session)."""
    try:
        return zenoh.open(conf)
    except zenoh.ZError as e:
        raise BusError(" ".join(str(e).split()).split(" at /")[0]) from None   # no Rust source paths


@contextlib.contextmanager
def open_session(conf: zenoh.Config) -> Iterator[zenoh.Session]:
    """`with open_session(conf) as s:` - the session is closed however the block ends."""
    s = open_raw(conf)
    try:
        yield s
    finally:
        with contextlib.suppress(Exception):
            s.close()


def locators(session: zenoh.Session, timeout: float = 2.0) -> list[str]:
    """The endpoints a router session listens on (read from its admin space; [] if unavailable)."""
    zid = str(session.zid())
    try:
        for r in session.get(f"@/{zid}/router", timeout=timeout):
            if r.ok is not None:
                return list(json.loads(r.ok.payload.to_bytes()).get("locators") or [])
    except Exception:  # noqa: BLE001 - informative only
        pass
    return []


def tune_threads() -> None:
    """Shorter GIL switch interval: Zenoh callback threads and the engine thread take turns faster."""
    sys.setswitchinterval(SWITCH_INTERVAL)
