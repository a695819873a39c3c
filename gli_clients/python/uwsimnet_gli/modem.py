"""`Modem`: one modem of a world, simulated or real, as an application sees it.

    modem = Modem(world, "bravo-modem")
    modem.wait_kind(timeout=5)                  # 'sim' or 'real' once a driver serves it
    tag = modem.send(1, b"ping")                # -> the tag its status events carry
    st = modem.wait_status(tag, timeout=5)      # its final status: 'sent' (nothing acknowledges it),
                                                # 'acked' / 'failed' (a MAC or modem with ACKs), 'dropped'
    for frame in modem.frames(timeout=10):      # blocking iterator
        print(frame.src, frame.data)
    frame = await modem.areceive(timeout=5)     # asyncio
    modem.on_receive(lambda f: ...)             # callback (runs on a Zenoh thread: keep it short)

Frames are kept in one bounded buffer consumed by `receive`/`frames`/`areceive`/`aframes` (the oldest
are dropped when it is full; `dropped` counts them); callbacks see every frame independently.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import random
import threading
import time
from collections import OrderedDict, deque
from collections.abc import AsyncIterator, Callable, Iterable, Iterator
from typing import Any, Protocol

import zenoh

from .records import Frame, Status, read_map, read_rx, read_status
from .wire import FINAL_EVENTS, Keys, check_chunk, encode_tx

__all__ = ["FINAL_EVENTS", "Modem"]
_tags = itertools.count(random.SystemRandom().getrandbits(31) + 1)
"""Auto tags: per process, from a random start (two apps on one modem rarely share a tag)."""


class WorldLike(Protocol):
    """What a modem needs of its world (uwsimnet_gli.World is one; declared here so that only the world
    imports the modem): its session, keys and name, and the list of its modems it closes with it."""

    name: str
    keys: Keys
    session: zenoh.Session
    _modems: list[Any]


class Modem:
    def __init__(self, world: WorldLike, dev: str, *, buffer: int = 4096,
                 on_receive: Callable[[Frame], Any] | None = None,
                 on_status: Callable[[Status], Any] | None = None, watch_kind: bool = True) -> None:
        self.world = world
        self.id = check_chunk(dev, "modem id")
        k = world.keys
        s = world.session
        self._frames: deque[Frame] = deque()
        self._buffer = max(0, buffer)
        self.dropped = 0
        self._cond = threading.Condition()
        self._async_waiters: list[tuple[asyncio.AbstractEventLoop, asyncio.Future]] = []
        self._rx_cbs: list[Callable[[Frame], Any]] = [on_receive] if on_receive else []
        self._st_cbs: list[Callable[[Status], Any]] = [on_status] if on_status else []
        self._kind_cbs: list[Callable[[str | None], Any]] = []
        self._status: OrderedDict[int, list[Status]] = OrderedDict()
        self._drivers: set[str] = set()
        self._closed = False
        self._tx = s.declare_publisher(k.modem(self.id, "tx"), express=True,
                                       congestion_control=zenoh.CongestionControl.BLOCK)
        self._subs = [
            s.declare_subscriber(k.modem(self.id, "rx"), self._on_rx),
            s.declare_subscriber(k.modem(self.id, "status"), self._on_status),
        ]
        if watch_kind:          # who serves it (`kind`); False: a program whose role may not watch
            self._subs.append(s.liveliness().declare_subscriber(k.modem(self.id, "driver/*"), self._on_driver,
                                                                history=True))
        world._modems.append(self)

    def __repr__(self) -> str:
        return f"Modem({self.world.name!r}, {self.id!r}, kind={self.kind!r})"

    def __enter__(self) -> Modem:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        for e in (self._tx, *self._subs):
            with contextlib.suppress(Exception):
                e.undeclare()
        with contextlib.suppress(ValueError):
            self.world._modems.remove(self)
        with self._cond:
            self._cond.notify_all()

    # -- sending ---------------------------------------------------------------------------------
    def send(self, dst: int, data: bytes | bytearray | str, *, tag: int | None = None,
             flow: str | None = None, msg: dict | None = None) -> int:
        """Hand `data` to the modem for address `dst` (255 = broadcast); returns the frame's tag
        (yours, or a fresh one) which its status events carry.  `flow` names the scene flow the frame
        belongs to (trace attribution), if any.  `msg`: the kind of message, e.g. `{"kind": "im", "flag":
        "ack"}` (docs/gli-protocol.md: kind, flag, ts, pid), passed to the receivers' `Frame.msg`."""
        if isinstance(data, str):
            data = data.encode()
        if tag is None:
            tag = next(_tags)
        self._tx.put(encode_tx(dst, data, tag, flow, msg))
        return tag

    # -- receiving -------------------------------------------------------------------------------
    def on_receive(self, cb: Callable[[Frame], Any]) -> Callable[[Frame], Any]:
        """Call `cb(frame)` for every frame (on a Zenoh thread); usable as a decorator."""
        self._rx_cbs.append(cb)
        return cb

    def receive(self, timeout: float | None = None) -> Frame | None:
        """The next buffered frame, waiting up to `timeout` s (None: forever); None on timeout."""
        with self._cond:
            if not self._cond.wait_for(lambda: self._frames or self._closed, timeout):
                return None
            return self._frames.popleft() if self._frames else None

    def frames(self, timeout: float | None = None) -> Iterator[Frame]:
        """Frames as they come; ends when none arrives for `timeout` s (None: never) or on close."""
        while True:
            f = self.receive(timeout)
            if f is None:
                return
            yield f

    async def areceive(self, timeout: float | None = None) -> Frame | None:
        """asyncio: the next frame, or None after `timeout` s."""
        loop = asyncio.get_running_loop()
        deadline = None if timeout is None else loop.time() + timeout
        while True:
            with self._cond:
                if self._frames:
                    return self._frames.popleft()
                if self._closed:
                    return None
                fut = loop.create_future()
                self._async_waiters.append((loop, fut))
            try:
                left = None if deadline is None else max(0.0, deadline - loop.time())
                await asyncio.wait_for(fut, left)
            except asyncio.TimeoutError:
                with self._cond:
                    if self._frames:
                        return self._frames.popleft()
                return None
            finally:
                with self._cond, contextlib.suppress(ValueError):
                    self._async_waiters.remove((loop, fut))

    async def aframes(self, timeout: float | None = None) -> AsyncIterator[Frame]:
        """asyncio: `async for frame in modem.aframes(): ...` (ends like `frames`)."""
        while True:
            f = await self.areceive(timeout)
            if f is None:
                return
            yield f

    def _on_rx(self, sample: zenoh.Sample) -> None:
        f = read_rx(sample.payload.to_bytes(), self.id, time.time())
        if f is None:
            return
        for cb in self._rx_cbs:
            with contextlib.suppress(Exception):     # a user callback must not kill the subscriber
                cb(f)
        if not self._buffer:
            return
        with self._cond:
            if len(self._frames) >= self._buffer:
                self._frames.popleft()
                self.dropped += 1
            self._frames.append(f)
            self._cond.notify()
            for loop, fut in self._async_waiters:
                with contextlib.suppress(RuntimeError):        # loop closed
                    loop.call_soon_threadsafe(_wake, fut)
            self._async_waiters.clear()

    # -- status ----------------------------------------------------------------------------------
    def on_status(self, cb: Callable[[Status], Any]) -> Callable[[Status], Any]:
        """Call `cb(status)` for every status event of this modem (on a Zenoh thread)."""
        self._st_cbs.append(cb)
        return cb

    def statuses(self, tag: int) -> list[Status]:
        """Status events seen so far for `tag` (the last 4096 tags are remembered)."""
        with self._cond:
            return list(self._status.get(tag, ()))

    def wait_status(self, tag: int, events: Iterable[str] = FINAL_EVENTS,
                    timeout: float | None = 5.0) -> Status | None:
        """The first status of `tag` whose event is in `events`, or None after `timeout` s.  The default
        is the frame's one final status (`FINAL_EVENTS`: sent, acked, failed, dropped): with a MAC or a
        modem that acknowledges, `transmitted` comes first and the wait goes on to `acked`/`failed`."""
        want = set(events)

        def found() -> Status | None:
            for st in self._status.get(tag, ()):
                if st.event in want:
                    return st
            return None
        with self._cond:
            self._cond.wait_for(lambda: found() is not None or self._closed, timeout)
            return found()

    def _on_status(self, sample: zenoh.Sample) -> None:
        st = read_status(sample.payload.to_bytes(), self.id)
        if st is None:
            return
        for cb in self._st_cbs:
            with contextlib.suppress(Exception):
                cb(st)
        if st.tag is None:
            return
        with self._cond:
            lst = self._status.get(st.tag)
            if lst is None:
                lst = self._status[st.tag] = []
                if len(self._status) > 4096:
                    self._status.popitem(last=False)
            lst.append(st)
            self._cond.notify_all()

    # -- who serves it ---------------------------------------------------------------------------
    @property
    def kind(self) -> str | None:
        """'real' while a real driver serves the modem, 'sim' while the simulator does, else None."""
        d = self._drivers
        return "real" if "real" in d else "sim" if "sim" in d else None

    def on_kind(self, cb: Callable[[str | None], Any]) -> Callable[[str | None], Any]:
        """Call `cb(kind)` whenever `kind` changes (sim <-> real, or None when nobody serves it)."""
        self._kind_cbs.append(cb)
        return cb

    def wait_kind(self, kinds: Iterable[str] = ("sim", "real"), timeout: float | None = 5.0) -> str | None:
        """Wait until the modem is served by one of `kinds`; the kind, or None on timeout."""
        want = set(kinds)
        with self._cond:
            self._cond.wait_for(lambda: self.kind in want or self._closed, timeout)
            return self.kind if self.kind in want else None

    def _on_driver(self, sample: zenoh.Sample) -> None:
        kind = str(sample.key_expr).rsplit("/", 1)[-1]
        with self._cond:
            before = self.kind
            if sample.kind == zenoh.SampleKind.PUT:
                self._drivers.add(kind)
            else:
                self._drivers.discard(kind)
            after = self.kind
            self._cond.notify_all()
        if after != before:
            for cb in self._kind_cbs:
                with contextlib.suppress(Exception):
                    cb(after)

    # -- info ------------------------------------------------------------------------------------
    def info(self, timeout: float = 2.0) -> dict[str, Any] | None:
        """Configuration and live state from whoever serves the modem (kind, fifo bytes, counters...)."""
        for r in self.world.session.get(self.world.keys.modem(self.id, "info"), timeout=timeout):
            if r.ok is not None:
                try:
                    m = read_map(r.ok.payload.to_bytes())
                except Exception:  # noqa: BLE001
                    continue
                if isinstance(m, dict):
                    return m
        return None


def _wake(fut: asyncio.Future) -> None:
    if not fut.done():
        fut.set_result(None)
