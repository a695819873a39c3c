"""The live source of `uwsimnet view`: its own Zenoh client session on the one wire (uwsimnet_gli.wire).

It subscribes to `pose/**`, `trace/*` and `clock`, follows the driver liveliness tokens (sim / real), asks
control `state` and `modem/*/info` now and then for the world's modems, and calls control `pause` /
`resume` for the page.  Callbacks only decode and hand records to the sans-IO `LiveState` (a lock and a
deque append): the broker publishes to a client like any other and never waits for a browser.
"""

from __future__ import annotations

import contextlib
import math
import threading
from collections.abc import Callable
from typing import Any

import zenoh
from uwsimnet_gli import wire
from uwsimnet_gli.wire import Keys

from ..bus.session import BusError, make_config, open_raw
from .state import LiveState

REFRESH_S = 2.0
"""How often the world's modems and vehicles are asked again (devices come and go at runtime)."""
CONNECT_TIMEOUT_MS = 3000
LINKS_S = 0.25
"""How often the links of geometry models with a Zenoh-posed end are asked again (when a pose came)."""


def client_session(connect: list[str] | None, config_file: str | None) -> zenoh.Session:
    """A client session (BusError with one line if no router accepts it); the caller closes it."""
    conf = make_config("client", connect=connect or ([] if config_file else [wire.DEFAULT_ENDPOINT]),
                       config_file=config_file, connect_timeout_ms=CONNECT_TIMEOUT_MS)
    return open_raw(conf)


def seen_worlds(session: zenoh.Session, timeout: float = 2.0) -> set[str]:
    """Worlds that answer control/state (an operator) or have a modem's driver token (anyone may see those)."""
    found = set()
    for key, get in ((f"{wire.PREFIX}/*/control/state", session.get),
                     (f"{wire.PREFIX}/*/modem/*/driver/*", session.liveliness().get)):
        with contextlib.suppress(Exception):                 # not allowed to ask: the other way tells
            for r in get(key, timeout=timeout):
                if r.ok is not None:
                    k = wire.parse(str(r.ok.key_expr))
                    if k is not None:
                        found.add(k.world)
    return found


def check_world(session: zenoh.Session, world: str, restricted: bool) -> None:
    """BusError (one line, naming the worlds seen) if no broker serves `world`.  A `restricted` identity
    (a --zenoh-config: a visitor reads traces only) that sees no world at all is let through: it cannot tell."""
    found = seen_worlds(session)
    if world not in found and (found or not restricted):
        raise BusError(f"no world {world!r} here (worlds seen: {', '.join(sorted(found)) or 'none'})")


def discover_world(session: zenoh.Session, timeout: float = 2.0) -> str:
    found = seen_worlds(session, timeout)
    if len(found) != 1:
        raise BusError("no world answers: name it with --world" if not found
                       else f"several worlds answer ({', '.join(sorted(found))}): name one with --world")
    return found.pop()


def _record(raw: bytes) -> dict[str, Any] | None:
    """A trace record from a trace sample, or None if it is not a usable one."""
    try:
        m = wire.unpack(raw, wire.MAX_TX_MESSAGE)
    except wire.CodecError:
        return None
    if not isinstance(m, dict) or m.get("ev") not in ("enq", "tx", "rx", "drop"):
        return None
    t = m.get("t")
    if not (isinstance(t, int | float) and math.isfinite(t) and isinstance(m.get("dev"), str)):
        return None
    if not all(isinstance(m.get(k), int) for k in ("src", "seq", "size")) or not isinstance(m.get("ch"), int | str):
        return None
    return m


class LiveSource:
    """    with LiveSource(session, "lab", state) as src: ...   (the session stays the caller's)"""

    def __init__(self, session: zenoh.Session, world: str, state: LiveState) -> None:
        self.session = session
        self.keys = Keys(world)
        self.state = state
        self._stop = threading.Event()
        self._drivers: dict[str, set[str]] = {}
        self._drivers_lock = threading.Lock()
        k = self.keys
        self._subs = [
            session.declare_subscriber(k.pose_all, self._on_pose),
            session.declare_subscriber(k.trace_all, self._on_trace),
            session.declare_subscriber(k.clock, self._on_clock),
            session.liveliness().declare_subscriber(k.drivers(), self._on_driver, history=True),
        ]
        self._thread = threading.Thread(target=self._refresher, name="view-refresh", daemon=True)
        self._thread.start()
        self._linker = None
        if state.links is not None:             # geometry models asked off the Zenoh threads (a query may take ms)
            self._linker = threading.Thread(target=self._links, name="view-links", daemon=True)
            self._linker.start()

    def __enter__(self) -> LiveSource:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._stop.set()
        for s in self._subs:
            with contextlib.suppress(Exception):
                s.undeclare()
        self._thread.join(timeout=5)
        if self._linker is not None:
            self._linker.join(timeout=5)

    # -- callbacks (Zenoh threads) ----------------------------------------------------------------
    def _on_pose(self, sample: zenoh.Sample) -> None:
        k = wire.parse(str(sample.key_expr))
        if k is None or k.kind != "pose":
            return
        try:
            p = wire.decode_pose(sample.payload.to_bytes())
        except wire.CodecError:
            return
        self.state.pose(k.name, p.p, p.t)

    def _on_trace(self, sample: zenoh.Sample) -> None:
        rec = _record(sample.payload.to_bytes())
        if rec is not None:
            self.state.trace(rec)

    def _on_clock(self, sample: zenoh.Sample) -> None:
        with contextlib.suppress(wire.CodecError):
            m = wire.unpack(sample.payload.to_bytes(), wire.MAX_SMALL_MESSAGE)
            if isinstance(m, dict):
                self.state.set_clock(m)

    def _on_driver(self, sample: zenoh.Sample) -> None:
        k = wire.parse(str(sample.key_expr))
        if k is None or k.leaf != "driver" or k.name is None:
            return
        with self._drivers_lock:
            kinds = self._drivers.setdefault(k.name, set())
            if sample.kind == zenoh.SampleKind.PUT:
                kinds.add(str(k.driver))
            else:
                kinds.discard(str(k.driver))
            kind = "real" if "real" in kinds else "sim" if "sim" in kinds else None
        self.state.set_kind(k.name, kind)

    # -- queries -----------------------------------------------------------------------------------
    def _get(self, key: str, timeout: float = 2.0, payload: bytes | None = None,
             on_reply: Callable[[dict[str, Any]], None] | None = None) -> list[dict[str, Any]]:
        """The decoded replies to a query; `on_reply` sees each as it comes (the query may wait its timeout
        for routers that never answer, and what the page shows must not wait with it)."""
        out = []
        try:
            for r in self.session.get(key, payload=payload, timeout=timeout,
                                      consolidation=zenoh.ConsolidationMode.NONE):
                if r.ok is not None:
                    with contextlib.suppress(wire.CodecError):
                        m = wire.unpack(r.ok.payload.to_bytes(), wire.MAX_REPLY_MESSAGE)
                        if isinstance(m, dict):
                            out.append(m)
                            if on_reply is not None:
                                on_reply(m)
        except Exception:  # noqa: BLE001 - a router gone for a moment: try again at the next refresh
            return []
        return out

    def _on_state(self, s: dict[str, Any]) -> None:
        if s.get("ok"):
            self.state.set_control(True)        # control answers: the page may pause at once
            self.state.merge_state(s)

    def refresh(self) -> None:
        """Modems and vehicles from control `state` (whether control answers says if it is allowed) and
        `modem/*/info` (FIFO capacity, range)."""
        states = [s for s in self._get(self.keys.control("state"), on_reply=self._on_state) if s.get("ok")]
        self.state.set_control(bool(states))
        modems = {}
        for m in self._get(self.keys.info_all):
            if isinstance(m.get("id"), str):
                cfg = m.get("config") if isinstance(m.get("config"), dict) else {}
                modems[m["id"]] = {"vehicle": m.get("vehicle"), "address": m.get("address"),
                                   "tx_channel": m.get("tx_channel"), "rx_channel": m.get("rx_channel"),
                                   "fifo_capacity": m.get("fifo_capacity"),
                                   "max_distance": cfg.get("max_distance"), "kind": m.get("kind"),
                                   "mac": m.get("mac"), "bitrate": m.get("bitrate")}
        if modems:
            self.state.merge_state({"modems": modems})

    def _links(self) -> None:
        while not self._stop.wait(LINKS_S):
            self.state.update_links()

    def _refresher(self) -> None:
        """Refresh every REFRESH_S; until control answers, sooner (0.1 s doubling): a fresh client session
        learns the broker's queryables a moment after it connects, and the page enables Pause at once."""
        wait = 0.1
        self.refresh()
        while not self._stop.wait(REFRESH_S if self.state.control else wait):
            wait = min(REFRESH_S, wait * 2)
            self.refresh()

    def control(self, op: str) -> dict[str, Any]:
        """pause | resume: the first successful reply, else {"ok": False, "error": ...}."""
        if op not in ("pause", "resume"):
            return {"ok": False, "error": f"unknown operation {op!r}"}
        replies = self._get(self.keys.control(op), payload=wire.pack({}))
        for r in replies:
            if r.get("ok"):
                return r            # the broker publishes a clock sample at every pause/resume: the one truth
        if not replies:
            return {"ok": False, "error": f"control/{op}: no reply (not allowed, or no simulator)"}
        return {"ok": False, "error": str(replies[0].get("error") or "refused")}
