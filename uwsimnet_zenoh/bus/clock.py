"""Simulation time of a running world, as seen from another process: the broker's `clock` samples
({t, epoch, speed, paused}, docs/gli-protocol.md) give it without a query per reading.  Processes that
model something in time (vehicles, emulators) step on this clock, not on the wall, so that a paused
world freezes them and `uwsimnet run --speed` speeds them up with it."""

from __future__ import annotations

import contextlib
from typing import Any

import zenoh
from uwsimnet_gli import wire
from uwsimnet_gli.wire import Keys
from uwsimnet_gli.world import is_clock, sim_time

__all__ = ["WorldClock", "sim_time"]


class WorldClock:
    """    clock = WorldClock(session, Keys(world)); t = clock.now()      # None until the first sample"""

    def __init__(self, session: zenoh.Session, keys: Keys) -> None:
        self._last: dict[str, Any] | None = None
        self._sub = session.declare_subscriber(keys.clock, self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        with contextlib.suppress(Exception):
            m = wire.unpack(sample.payload.to_bytes(), wire.MAX_SMALL_MESSAGE)
            if is_clock(m):
                self._last = m

    def now(self) -> float | None:
        """Simulation time now; None before the first clock sample."""
        m = self._last
        return None if m is None else sim_time(m)

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self._sub.undeclare()
