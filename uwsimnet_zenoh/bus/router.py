"""`uwsimnet router`: a standalone Zenoh router (a Python session in router mode) for one machine.

There is no zenohd on PyPI; a Python session in router mode routes for clients, peers and other routers
(plugins such as REST do not load in it).  Run one per machine; everything on the machine connects to
it in client mode; routers of different machines connect to each other with `--connect`.
"""

from __future__ import annotations

import json
import signal
import threading
from typing import Any

from ..errors import UserError
from .session import BusError, locators, make_config, open_raw

DEFAULT_ROUTER_LISTEN = "tcp/[::]:7447"
"""All interfaces, as zenohd does: other machines reach this router."""


class StopOnSignal:
    """SIGINT/SIGTERM set `event` (the first time); a second signal raises KeyboardInterrupt."""

    def __init__(self) -> None:
        self.event = threading.Event()
        self.signum: int | None = None
        self._old: dict[int, Any] = {}

    def _handler(self, signum: int, frame: Any) -> None:
        if self.event.is_set():
            raise KeyboardInterrupt
        self.signum = signum
        self.event.set()

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
            while not stop.event.wait(0.5):
                pass
        finally:
            s.close()
    print("router stopped", flush=True)
    return 0
