"""A `ModemBackend` (drivers/backend.py) on a running broker: one simulated modem reached over Zenoh.

    with open_session(make_config("client", connect=["tcp/127.0.0.1:7447"])) as s:
        be = ZenohBackend(s, "acoustic-apps", "alpha-modem")     # asks the modem's `info` first
        emu = EvoLogicsEmulator(be, port=9200).start()

A thin adapter over the client library's `uwsimnet_gli.Modem` (what any application uses): `send` is its
`send` (with an integer tag of its own, mapped back to the caller's tag); its rx frames and statuses come
back as `BackendFrame` / `BackendStatus`; `now()` is its world's simulation time (`World.sim_time`, from the
broker's `clock` samples).  The addressee's outcome of a unicast frame (`delivered` / `lost`) is the output
port's `rx` or `drop` at the addressee, which reaches another process as the `trace/<channel>` record of
that event (`Outcomes`, keyed by the `seq` that status events carry), with the propagation time over its
distance (`prop_time`, the tx channel's law from `info`).

Callbacks run on Zenoh's threads: emulators only hand them to their own loop.
"""

from __future__ import annotations

import contextlib
import itertools
import logging
import random
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from typing import Any

import zenoh
from uwsimnet_gli import Frame, Modem, Status, World, wire
from uwsimnet_gli.wire import Keys

from ..errors import UwsimnetError
from ..kernel.frame import BROADCAST
from ..phy.framing import builder
from .backend import BackendFrame, BackendStatus, FrameCallback, Message, StatusCallback

log = logging.getLogger("uwsimnet.drivers.zenoh")

FALLBACK_SOUND_SPEED = 1500.0
"""m/s: the propagation law assumed when a broker's `info` has no `prop` (brokers before it was added)."""


class BackendError(UwsimnetError, RuntimeError):
    """The modem does not answer (no broker, wrong world or id, handed to a real driver)."""


def query_info(session: zenoh.Session, keys: Keys, dev: str, timeout: float = 3.0) -> dict[str, Any] | None:
    for r in session.get(keys.info(dev), timeout=timeout):
        if r.ok is not None:
            with contextlib.suppress(Exception):
                return wire.unpack(r.ok.payload.to_bytes(), wire.MAX_SMALL_MESSAGE)
    return None


def discover_world(session: zenoh.Session, timeout: float = 2.0) -> str:
    """The one world whose broker answers `uwsimnet/*/control/state`."""
    found = set()
    for r in session.get("uwsimnet/*/control/state", timeout=timeout):
        if r.ok is not None:
            parts = str(r.ok.key_expr).split("/")
            if len(parts) >= 2:
                found.add(parts[1])
    if len(found) != 1:
        raise BackendError("no simulated world answers; give --world" if not found else
                           f"several worlds answer ({', '.join(sorted(found))}); give --world")
    return found.pop()


def prop_law(info: dict[str, Any], key: str = "prop") -> tuple[float, float, bool]:
    """(min s, s per m, known) of a channel from an `info` reply: delay = min + per_m * distance.

    The broker sends `prop` (tx channel) and `rx_prop` (rx channel) as {min, per_m}: phy.channel.Channel's
    own parameters, so a custom channel's minPropTime/propTimeIncPerMeter and an acoustic channel's
    1/sound speed.  A reply without it (older broker, or a real driver) falls back to d / 1500 m/s, and
    `known` is False."""
    p = info.get(key)
    if isinstance(p, dict):
        try:
            lo, per_m = float(p["min"]), float(p["per_m"])
        except (KeyError, TypeError, ValueError):
            pass
        else:
            if lo >= 0.0 and per_m >= 0.0:
                return lo, per_m, True
    return 0.0, 1.0 / FALLBACK_SOUND_SPEED, False


class Outcomes:
    """The addressee's outcome of unicast frames, from the trace records of the output port's events
    (docs/trace-format.md): `watch(src, seq, sender_dev, fn)`, then every record to `on_trace`; `fn(event,
    reason, t, dist)` is called once, `delivered` for the first `rx` of the frame at another device (kind
    data, not implicit), `lost` for a `drop` there.  Drops at the sender are its own statuses.  The record
    may come before `watch` (the trace and the status that tells the frame's seq are different keys, in no
    order between them: a loaded machine delivered a 1-byte frame's rx first, and its sender reported
    FAILED): the last `limit` unwatched outcome records are kept for a `watch` that follows.  At most
    `limit` frames are watched (the oldest forgotten)."""

    def __init__(self, limit: int = 10000) -> None:
        self.limit = limit
        self._watch: OrderedDict[tuple[int, int], tuple[str, Callable[..., None]]] = OrderedDict()
        self._early: OrderedDict[tuple[int, int], list[dict[str, Any]]] = OrderedDict()
        self._lock = threading.Lock()           # records and statuses come on different Zenoh threads

    def watch(self, src: int, seq: int, sender_dev: str, fn: Callable[[str, str | None, float, float | None],
                                                                      None]) -> None:
        with self._lock:
            early = [r for r in self._early.pop((src, seq), ()) if r.get("dev") != sender_dev]
            if not early:
                self._watch[(src, seq)] = (sender_dev, fn)
                while len(self._watch) > self.limit:
                    self._watch.popitem(last=False)
        if early:
            self._report(early[0], fn)

    def forget(self, src: int, seq: int) -> None:
        with self._lock:
            self._watch.pop((src, seq), None)

    def on_trace(self, rec: dict[str, Any]) -> None:
        ev = rec.get("ev")
        if ev not in ("rx", "drop") or rec.get("kind", "data") != "data" or rec.get("implicit"):
            return
        key = (rec.get("src"), rec.get("seq"))
        with self._lock:
            hit = self._watch.get(key)  # type: ignore[arg-type]
            if hit is None:
                self._early.setdefault(key, []).append(rec)  # type: ignore[arg-type]
                while len(self._early) > self.limit:
                    self._early.popitem(last=False)
                return
            if rec.get("dev") == hit[0]:
                return
            del self._watch[key]  # type: ignore[arg-type]
        self._report(rec, hit[1])

    @staticmethod
    def _report(rec: dict[str, Any], fn: Callable[..., None]) -> None:
        fn("delivered" if rec.get("ev") == "rx" else "lost", rec.get("reason"), float(rec.get("t", 0.0)),
           rec.get("dist"))


class ZenohBackend:
    def __init__(self, session: zenoh.Session, world: str, dev: str, *, timeout: float = 5.0,
                 track_delivery: bool = True) -> None:
        self.session = session
        self.keys = Keys(world)
        self.id = dev
        deadline = time.monotonic() + timeout
        info = None
        while info is None and time.monotonic() < deadline:
            info = query_info(session, self.keys, dev, timeout=min(1.0, timeout))
            if info is None:
                time.sleep(0.1)
        if info is None:
            raise BackendError(f"modem {dev!r} of world {world!r} does not answer on {self.keys.info(dev)}")
        self._info = info
        self.address = int(info["address"])
        self.bitrate = float(info.get("bitrate") or 0.0) or None
        self._tx_law = prop_law(info)
        self.prop_known = self._tx_law[2]
        # received frames crossed the rx channel (another law when rxChannelId differs)
        self._rx_law = prop_law(info, "rx_prop") if "rx_prop" in info else self._tx_law
        self.on_frame: list[FrameCallback] = []
        self.on_status: list[StatusCallback] = []
        self.counters = {"sent": 0, "received": 0, "statuses": 0}
        self.tracker = Outcomes()
        self._lock = threading.Lock()
        self._tags: OrderedDict[int, tuple[Any, int]] = OrderedDict()     # our tag -> (caller's tag, dst)
        self._next = itertools.count(random.getrandbits(40) + 1)     # apart from other writers' tags
        self.world = World(world, session=session)
        self.world.clock(timeout=0)                 # its clock samples from now on (`now`)
        self.modem = Modem(self.world, dev, buffer=0, on_receive=self._on_rx, on_status=self._on_status,
                           watch_kind=False)        # (wire.USES["backend"]: it needs no kind, may not watch)
        self._subs: list[Any] = []
        if track_delivery:
            self._subs.append(session.declare_subscriber(self.keys.trace(info.get("tx_channel", 0)),
                                                         self._on_trace))

    # -- ModemBackend -----------------------------------------------------------------------------
    def now(self) -> float:
        t = self.world.sim_time(timeout=0)
        return float(self._info.get("t", 0.0)) if t is None else t

    def send(self, dst: int, data: bytes, tag: Any = None, msg: Message | None = None) -> None:
        ours = next(self._next)
        with self._lock:
            self._tags[ours] = (tag, int(dst))
            while len(self._tags) > 10000:
                self._tags.popitem(last=False)
        self.counters["sent"] += 1
        self.modem.send(int(dst), bytes(data), tag=ours, msg=None if msg is None else msg.to_wire())

    def info(self) -> dict[str, Any]:
        return dict(self._info, counters=dict(self.counters))

    def close(self) -> None:
        self.world.close()                          # its modem and clock subscriber (the session stays open)
        for e in self._subs:
            with contextlib.suppress(Exception):
                e.undeclare()
        self._subs = []

    def _framed(self, n: int) -> int:
        """Bytes of a frame of `n` payload bytes in the modem's framing (its scene's txPacketBuilder)."""
        name = self._info.get("tx_framing")
        if isinstance(name, str) and name:
            try:
                return builder(name).frame_size(n)
            except ValueError:
                pass
        return n

    # -- Zenoh callbacks --------------------------------------------------------------------------
    def _on_trace(self, sample: zenoh.Sample) -> None:
        with contextlib.suppress(Exception):
            rec = wire.unpack(sample.payload.to_bytes(), wire.MAX_SMALL_MESSAGE)
            if isinstance(rec, dict) and rec.get("src") == self.address:     # only our frames' outcomes
                self.tracker.on_trace(rec)

    def _on_rx(self, f: Frame) -> None:
        self.counters["received"] += 1
        size = self._framed(len(f.data)) + int(self._info.get("header_bytes") or 0)
        # the broker's distance (older brokers: none, and link_metrics falls back to t_rx - t_tx)
        bf = BackendFrame(f.src, f.dst, f.data, f.seq, f.t_tx, f.t_rx, size, self.bitrate,
                          f.dist, None if f.dist is None else self.prop_time(f.dist, rx=True),
                          msg=Message.from_wire(f.msg), aseq=(f.msg or {}).get("aseq"))
        for cb in list(self.on_frame):
            try:
                cb(bf)
            except Exception:  # noqa: BLE001 - a listener must not break the others
                log.exception("%s: frame listener raised", self.id)

    def _on_status(self, st: Status) -> None:
        if st.tag is None:
            return
        with self._lock:
            hit = self._tags.get(st.tag)
        if hit is None:
            return                                  # someone else's frame on this modem
        tag, dst = hit
        self.counters["statuses"] += 1
        if st.event == "dropped" and st.seq is not None:
            self.tracker.forget(self.address, st.seq)
        self._emit(BackendStatus(tag, st.event, st.reason, st.t, st.seq if st.seq is not None else -1))
        if st.event == "queued" and dst != BROADCAST and st.seq is not None:     # after queued: an outcome
            self.tracker.watch(self.address, st.seq, self.id,                  # already seen follows it
                               lambda ev, reason, t, dist, tag=tag, seq=st.seq: self._emit(
                                   BackendStatus(tag, ev, reason, t, seq, self._prop(dist))))

    def prop_time(self, dist: float, *, rx: bool = False) -> float:
        """One-way propagation time (s) over `dist` m on this modem's tx channel (rx: its rx channel), as
        the broker's PHY has it."""
        lo, per_m, _ = self._rx_law if rx else self._tx_law
        return lo + per_m * float(dist)

    def _prop(self, dist: Any) -> float | None:
        return None if dist is None else self.prop_time(dist)

    def _emit(self, st: BackendStatus) -> None:
        for cb in list(self.on_status):
            try:
                cb(st)
            except Exception:  # noqa: BLE001
                log.exception("%s: status listener raised", self.id)
