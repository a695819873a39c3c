"""Who is connected to the broker's session, and who Zenoh cut off and let back in.

A router closes the transport of an app that does not read: a BLOCK put that cannot enter the app's link
within `wait_before_close` closes it (zenoh-transport `universal/tx.rs`, `handle_push_result`), and so does
a lease that runs out.  What is put for the app until it connects again goes nowhere, and no put of ours
waits or fails, so the edge (bus/outbox.py) cannot count it.  Zenoh says it only in its own log.  Its
transport events say it too: a transport closed (kind DELETE), then opened again with the same ZenohId
(PUT).  This watcher keeps those events, warns when an app comes back ("was cut off for X s") and gives
the list to the trace's end record (`disconnected`), so a reading app's missing frames are explained
(docs/runtime.md).
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import zenoh

log = logging.getLogger("uwsimnet.bus.connections")

KEEP = 1000
"""Disconnections kept for the end record (the first ones; later ones are counted)."""


class Connections:
    """Transport events of one session: opened, closed, opened again.  Callbacks run on Zenoh's threads."""

    def __init__(self, now: Callable[[], float]) -> None:
        self._now = now
        """Simulation time now (the realtime clock's), to place an event on the trace's time axis."""
        self._lock = threading.Lock()
        self._open: dict[str, str] = {}
        """ZenohId -> what it is (client, peer, router), for the transports open now."""
        self._gone: dict[str, tuple[float, float, int]] = {}
        """ZenohId -> (simulation time, monotonic time, index in `events`) of its last close."""
        self.events: list[dict[str, Any]] = []
        """One per close: zid, whatami, t (closed), and back (opened again), s (wall seconds away)."""
        self.dropped = 0
        """Closes past KEEP (not listed)."""
        self._listener: Any = None

    def start(self, session: zenoh.Session) -> None:
        self._listener = session.info.declare_transport_events_listener(self.on_event, history=True)

    def close(self) -> None:
        if self._listener is not None:
            with contextlib.suppress(Exception):      # closing anyway
                self._listener.undeclare()
            self._listener = None

    def on_event(self, ev: Any) -> None:
        zid, what = str(ev.transport.zid), str(ev.transport.whatami).rsplit(".", 1)[-1].lower()
        closed = ev.kind == zenoh.SampleKind.DELETE
        self.note(zid, what, closed, self._now(), time.monotonic())

    def note(self, zid: str, what: str, closed: bool, t: float, wall: float) -> None:
        """One transport event: `closed` (DELETE) or opened (PUT) at simulation time `t`, monotonic `wall`."""
        with self._lock:
            if closed:
                self._open.pop(zid, None)
                if len(self.events) < KEEP:
                    self.events.append({"zid": zid, "whatami": what, "t": round(t, 6)})
                    self._gone[zid] = (t, wall, len(self.events) - 1)
                else:
                    self.dropped += 1
                log.info("%s %s disconnected at t=%.3f s", what, zid, t)
                return
            self._open[zid] = what
            gone = self._gone.pop(zid, None)
        if gone is not None:
            t0, wall0, i = gone
            away = wall - wall0
            with self._lock:
                self.events[i].update(back=round(t, 6), s=round(away, 3))
            log.warning("%s %s was cut off for %.1f s (t=%.3f..%.3f s) and is back: Zenoh closed its connection"
                        " (it did not read for the router's wait_before_close, or its lease ran out); what was"
                        " put for it in that time is lost", what, zid, away, t0, t)

    def summary(self) -> list[dict[str, Any]]:
        """The closes, in order (the trace's end record `disconnected`)."""
        with self._lock:
            return [dict(e) for e in self.events]

    def cut_off(self) -> list[dict[str, Any]]:
        """The closes after which the same ZenohId came back: an app Zenoh cut off, not one that left."""
        return [e for e in self.summary() if "back" in e]
