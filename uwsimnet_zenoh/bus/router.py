"""`uwsimnet router`: a standalone Zenoh router (a Python session in router mode) for one machine.

There is no zenohd on PyPI; a Python session in router mode routes for clients, peers and other routers
(plugins such as REST do not load in it).  Run one per machine; everything on the machine connects to
it in client mode; routers of different machines connect to each other with `--connect`.
"""

from __future__ import annotations

import json
import signal
import threading
import time
from typing import Any

from ..errors import UserError
from .session import BusError, locators, make_config, open_raw

DEFAULT_ROUTER_LISTEN = "tcp/[::]:7447"
"""All interfaces, as zenohd does: other machines reach this router."""


class StopOnSignal:
    """SIGINT/SIGTERM set `signum` (the first time); a second signal raises KeyboardInterrupt.

    The handler takes no lock.  It runs on the main thread between two bytecodes, maybe while that thread
    holds a lock itself: it used to set a threading.Event, and a signal that came while the main thread was
    inside that Event's `wait` deadlocked the process on the Event's own lock (a realtime run that never
    ended after SIGTERM, once in ~1300 tests under load).  The main thread polls `wait()` instead."""

    SLICE = 0.05
    """s: how soon `wait` sees a signal (the sleep resumes after the handler, PEP 475)."""

    def __init__(self) -> None:
        self.signum: int | None = None
        self._old: dict[int, Any] = {}

    def _handler(self, signum: int, frame: Any) -> None:
        if self.signum is not None:
            raise KeyboardInterrupt
        self.signum = signum

    @property
    def stopped(self) -> bool:
        return self.signum is not None

    def wait(self, timeout: float) -> bool:
        """Sleep up to `timeout` s, less if a signal comes; True if one has come."""
        end = time.monotonic() + timeout
        while self.signum is None and (left := end - time.monotonic()) > 0:
            time.sleep(min(left, self.SLICE))
        return self.signum is not None

    def __enter__(self) -> StopOnSignal:
        if threading.current_thread() is threading.main_thread():
            for s in (signal.SIGINT, signal.SIGTERM):
                self._old[s] = signal.signal(s, self._handler)
        return self

    def __exit__(self, *exc: Any) -> None:
        for s, h in self._old.items():
            signal.signal(s, h)


def _endpoints(raw: str, mode: str) -> list[str]:
    """Endpoints from a `get_json` answer: a list, or Zenoh's per-mode default `{"router": [...], ...}`."""
    v = json.loads(raw)
    if isinstance(v, dict):
        v = v.get(mode) or []
    return [str(e) for e in v] if isinstance(v, list) else []


def run_router(args: Any) -> int:

    # --listen wins; else the file's listen endpoints (TLS-only configurations); else tcp/[::]:7447
    config = getattr(args, "zenoh_config", None) or getattr(args, "config", None)
    listen = args.listen or ([] if config else [DEFAULT_ROUTER_LISTEN])
    try:
        conf = make_config("router", listen=listen, connect=args.connect or (), config_file=config)
        if not listen:
            listen = _endpoints(conf.get_json("listen/endpoints"), "router") or [DEFAULT_ROUTER_LISTEN]
    except (BusError, ValueError) as e:
        raise UserError(f"router: {e}") from None
    with StopOnSignal() as stop:
        try:
            s = open_raw(conf)
        except BusError as e:
            raise UserError(f"router: cannot start on {', '.join(listen)}: {e}") from None
        try:
            where = locators(s) or listen
            print(f"zenoh router {s.zid()} listening on {', '.join(where)}", flush=True)
            if args.connect:
                print(f"connecting to {', '.join(args.connect)}", flush=True)
            print("Ctrl-C to stop", flush=True)
            while not stop.wait(0.5):
                pass
        finally:
            s.close()
    print("router stopped", flush=True)
    return 0
