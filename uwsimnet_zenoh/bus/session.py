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
WAIT_BEFORE_CLOSE_US = 2_000_000
"""How long a router lets a BLOCK put wait on a link that does not drain before it closes that link (Zenoh's
`transport/link/tx/queue/congestion_control/block/wait_before_close`, default 5 s).  With Zenoh's 5 s, a
consumer stopped while a busy modem's rx fills its buffers froze *every* put of the router for ~1.5-1.9 s,
from the 5 s wait running out (~8.5 s after the stop) to the 10 s lease closing that consumer (bench_realtime
`--stall`, 4 of 4 runs; tests/test_edge_e2e.py); with 1-2 s, 0 of 4.  A consumer that cannot take a message for
2 s once its buffers are full is cut off, as it would be at 5 s, and the other links never wait."""
ZENOH_WAIT_BEFORE_CLOSE_US = 5_000_000
"""Zenoh's default of the above (a configuration file that sets another value keeps it)."""
SHARED_MEMORY = False
"""Whether this project's sessions pass payloads to apps on the same machine through Zenoh's shared memory
(Zenoh's `transport/shared_memory/enabled`, default true).  Off: with it, a payload over its threshold is a
buffer of the putting session, and when that session closes an app that has not yet taken it loses it.  A
slow app's backlog at the broker's stop went with the broker (the reading-app test: 186 of 316 frames in a
loaded run; a router putting 300 x 64 kB to an app taking 30 ms each, then closing: 265 of 300 arrive with
it on, 300 with it off; docs/runtime.md).  A frame has to reach its app whenever the broker stops; frames
are rarely over the 3 kB threshold, so the copy it saves is small."""
SWITCH_INTERVAL = 0.0005
"""sys.setswitchinterval for processes with a realtime engine thread (5 ms -> 0.5 ms thread switches)."""


class BusError(UwsimnetError, RuntimeError):
    """A Zenoh session could not be opened (bad endpoint, port in use, no router to connect to)."""


_WAIT_BEFORE_CLOSE = "transport/link/tx/queue/congestion_control/block/wait_before_close"
_SHARED_MEMORY = "transport/shared_memory/enabled"


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
    settings: dict[str, Any] = {"mode": mode, "scouting/multicast/enabled": False,
                                _SHARED_MEMORY: SHARED_MEMORY}
    if mode == "router":
        settings["adminspace/enabled"] = True          # lets us read back the locators we listen on
        if json.loads(conf.get_json(_WAIT_BEFORE_CLOSE)) == ZENOH_WAIT_BEFORE_CLOSE_US:
            settings[_WAIT_BEFORE_CLOSE] = WAIT_BEFORE_CLOSE_US
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


def file_endpoints(path: str) -> tuple[str, list[str], list[str]]:
    """(mode, connect, listen) endpoints of a Zenoh configuration file (Zenoh's per-mode defaults
    `{"router": [...], ...}` resolved for the file's mode); BusError if it does not load."""
    try:
        conf = zenoh.Config.from_file(path)
        mode = json.loads(conf.get_json("mode")) or "client"
        eps = {k: json.loads(conf.get_json(f"{k}/endpoints")) for k in ("connect", "listen")}
    except (zenoh.ZError, ValueError) as e:
        raise BusError(f"{path}: {' '.join(str(e).split())}") from None
    out = {k: [str(e) for e in (v.get(mode) or [] if isinstance(v, dict) else v or [])] for k, v in eps.items()}
    return str(mode), out["connect"], out["listen"]


def access_of(conf: zenoh.Config) -> dict[str, Any] | None:
    """The `metadata.uwsimnet` access section of a configuration rendered by `uwsimnet deploy render`."""
    try:
        v = json.loads(conf.get_json("metadata"))
    except (zenoh.ZError, ValueError):
        return None
    a = v.get("uwsimnet") if isinstance(v, dict) else None
    return a if isinstance(a, dict) else None


def file_access(path: str | None) -> dict[str, Any] | None:
    """`access_of` a configuration file (None without a file, or if it has no access section)."""
    if not path:
        return None
    try:
        return access_of(zenoh.Config.from_file(path))
    except zenoh.ZError as e:
        raise BusError(f"{path}: {' '.join(str(e).split())}") from None


def client_config(connect: Sequence[str] = (), config_file: str | None = None, *,
                  connect_timeout_ms: int | None = 3000) -> tuple[zenoh.Config, list[str]]:
    """A client configuration and the endpoints it connects to: `connect` when given (replacing the
    file's), else the file's `connect/endpoints`, else DEFAULT_ENDPOINT."""
    endpoints = list(connect)
    if not endpoints and config_file:
        endpoints = file_endpoints(config_file)[1]
    endpoints = endpoints or [DEFAULT_ENDPOINT]
    return make_config("client", connect=endpoints, config_file=config_file,
                       connect_timeout_ms=connect_timeout_ms), endpoints


def open_client(connect: Sequence[str] = (), config_file: str | None = None, *,
                connect_timeout_ms: int | None = 3000) -> zenoh.Session:
    """A client session (the caller closes it); BusError `cannot connect to ENDPOINTS (why)` in one line,
    naming the endpoints it tried (and the file they came from)."""
    conf, endpoints = client_config(connect, config_file, connect_timeout_ms=connect_timeout_ms)
    try:
        return open_raw(conf)
    except BusError as e:
        src = f" (from {config_file})" if config_file and not connect else ""
        raise BusError(f"cannot connect to {', '.join(endpoints)}{src}: {e}") from None


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
