"""The driver SDK: what every real-modem driver has in common, whatever the wire.

A driver owns one link to one device (TCP socket, serial line, pty) and turns it into the modem
abstraction the simulator's modems offer: `send(dst, data, tag)` answered by status events
(queued, sent, acked, dropped, failed) and received frames (src, dst, data, plus rssi / integrity
when the device reports them).  It is transport-agnostic: a subclass says how to open its link
(`_open_link`), what to do with the bytes that come in (`_on_bytes`) and how to put the next queued
frame on the wire (`_pump`); the base does the rest:

* lifecycle: `open()` starts the driver's I/O thread and connects; `close()` stops it.  States:
  closed -> connecting -> open -> (link lost) -> reconnecting -> open ... -> closed.
* reconnect with exponential backoff (`backoff_initial` doubling up to `backoff_max`), forever
  unless `reconnect=False`; frames queued meanwhile wait (up to `queue_limit`).
* a tick (`tick` s) that lets protocol cores expire timeouts.
* `info()`: a dict for the `modem/<id>/info` queryable (kind real, state, counters, ...).
* callbacks: `on_frame(RxFrame)`, `on_status(TxStatus)`, `on_event(DriverEvent)` (state changes and
  protocol errors: malformed device output is reported there and counted, never fatal).  They run on
  the driver's I/O thread and must not block (hand off to a queue, or `put` to Zenoh, which does not).

Part B attaches a driver to Zenoh by plugging these callbacks in (rx -> `modem/<id>/rx`, status ->
`modem/<id>/status`) and calling `send()` from the `modem/<id>/tx` subscriber.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

from ._aio import LoopThread

log = logging.getLogger("uwsimnet.drivers")

STATES = ("closed", "connecting", "open", "reconnecting")


@dataclass(frozen=True)
class RxFrame:
    """A frame the device received.  `t` is time.time() when the driver got it; `rssi` (dB) and
    `integrity` when the device reports them; `meta` holds the rest of what it said (kind, bitrate,
    propagation time, velocity, ...)."""

    src: int
    dst: int
    data: bytes
    t: float
    rssi: float | None = None
    integrity: float | None = None
    meta: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class TxStatus:
    """What became of a frame given to `send()`: `event` queued | sent | acked | dropped | failed (the
    simulator's vocabulary), `reason` a short token for dropped/failed, `detail` free text."""

    tag: Any
    event: str
    reason: str | None
    t: float
    detail: str = ""


@dataclass(frozen=True)
class DriverEvent:
    """Something the application may want to know that is not a frame: `kind` state | connect-failed |
    protocol-error | notification | warning, `detail` text, `data` the offending bytes if any."""

    kind: str
    detail: str
    data: bytes = b""
    t: float = 0.0


@dataclass
class TxRequest:
    dst: int
    data: bytes
    tag: Any
    t: float
    stage: str = "queued"
    extra: dict[str, Any] = field(default_factory=dict)


class Link(Protocol):
    """An open connection to the device (what `_open_link` returns)."""

    def write(self, data: bytes) -> None: ...
    def close(self) -> None: ...


class LinkLost(Exception):
    pass


class Driver:
    """Base class of the real-modem drivers (see the module docstring)."""

    driver_name = "driver"

    def __init__(self, modem_id: str, *, address: int | None = None,
                 on_frame: Callable[[RxFrame], None] | None = None,
                 on_status: Callable[[TxStatus], None] | None = None,
                 on_event: Callable[[DriverEvent], None] | None = None,
                 reconnect: bool = True, backoff_initial: float = 0.2, backoff_max: float = 5.0,
                 queue_limit: int = 64, tick: float = 0.1, max_payload: int = 2048) -> None:
        self.modem_id = modem_id
        self.address = address
        self.on_frame: list[Callable[[RxFrame], None]] = [on_frame] if on_frame else []
        self.on_status: list[Callable[[TxStatus], None]] = [on_status] if on_status else []
        self.on_event: list[Callable[[DriverEvent], None]] = [on_event] if on_event else []
        self.reconnect = reconnect
        self.backoff_initial = backoff_initial
        self.backoff_max = backoff_max
        self.queue_limit = queue_limit
        self.tick = tick
        self.max_payload = max_payload
        self.state = "closed"
        self.queue: deque[TxRequest] = deque()
        self.counters: Counter[str] = Counter()
        self.last_error: str | None = None
        self.connected_since: float | None = None
        self._io = LoopThread(f"uwsimnet-driver-{modem_id}")
        self._link: Link | None = None
        self._lost: asyncio.Event | None = None
        self._task: asyncio.Task | None = None
        self._closing = False
        self._open_evt = threading.Event()
        self._ever_opened = False

    # -- public API (any thread) --------------------------------------------------------------------
    def open(self, wait: float | None = 5.0) -> bool:
        """Start the I/O thread and connect (reconnecting in the background if that fails).

        Waits up to `wait` seconds for the link to be up and returns whether it is."""
        self._closing = False
        self._io.start()
        self._io.call(self._start)
        if wait:
            return self._open_evt.wait(wait)
        return self.state == "open"

    def wait_open(self, timeout: float) -> bool:
        return self._open_evt.wait(timeout)

    def close(self, timeout: float = 5.0) -> None:
        """Close the link and stop the I/O thread; frames still queued end `failed` (reason closed)."""
        if self._closing:
            return
        self._closing = True
        if not self._io.started:
            return
        with contextlib.suppress(Exception):
            self._io.submit(self._shutdown, timeout=timeout)
        self._io.stop(timeout)

    def send(self, dst: int, data: bytes, tag: Any = None) -> None:
        """Queue a frame for `dst` (thread-safe).  Its fate comes back through `on_status`."""
        self.counters["send_calls"] += 1
        self._io.call(self._enqueue, int(dst), bytes(data), tag)

    def info(self) -> dict[str, Any]:
        """Configuration and live state, for the `modem/<id>/info` queryable."""
        return {
            "id": self.modem_id, "kind": "real", "driver": self.driver_name, "address": self.address,
            "state": self.state, "queue": len(self.queue), "queue_limit": self.queue_limit,
            "connected_since": self.connected_since, "counters": dict(self.counters),
            "last_error": self.last_error, **self._info(),
        }

    # -- for subclasses -----------------------------------------------------------------------------
    async def _open_link(self) -> Link:
        raise NotImplementedError

    def _on_open(self) -> None:
        """The link is up (send initialisation commands here)."""

    def _on_bytes(self, data: bytes) -> None:
        raise NotImplementedError

    def _pump(self) -> None:
        """Put queued frames on the wire when the device can take them."""
        raise NotImplementedError

    def _on_tick(self, now: float) -> None:
        """Periodic: expire protocol timeouts."""

    def _on_link_lost(self) -> None:
        """The link went down: forget protocol state tied to it (the queue is kept)."""

    def _check(self, dst: int, data: bytes) -> str | None:
        """A reason token if this frame cannot be sent at all (validated before queuing)."""
        if not 0 <= dst <= 65535:
            return "invalid"
        if len(data) > self.max_payload:
            return "size"
        return None

    def _info(self) -> dict[str, Any]:
        return {}

    # -- helpers for subclasses (I/O thread) --------------------------------------------------------
    def write(self, data: bytes) -> None:
        if self._link is None:
            raise LinkLost("no link")
        self.counters["bytes_out"] += len(data)
        self._link.write(data)

    def emit_frame(self, frame: RxFrame) -> None:
        self.counters["rx"] += 1
        for cb in self.on_frame:
            try:
                cb(frame)
            except Exception:  # noqa: BLE001 - a callback must not break the driver
                log.exception("%s: on_frame callback raised", self.modem_id)

    def emit_status(self, req: TxRequest | None, event: str, reason: str | None = None, detail: str = "",
                    tag: Any = None) -> None:
        self.counters[f"status_{event}"] += 1
        st = TxStatus(req.tag if req is not None else tag, event, reason, time.time(), detail)
        if req is not None:
            req.stage = event
        for cb in self.on_status:
            try:
                cb(st)
            except Exception:  # noqa: BLE001
                log.exception("%s: on_status callback raised", self.modem_id)

    def emit_event(self, kind: str, detail: str, data: bytes = b"") -> None:
        self.counters[f"event_{kind}"] += 1
        if kind in ("protocol-error", "connect-failed", "warning"):
            self.last_error = detail
            log.warning("%s: %s: %s", self.modem_id, kind, detail)
        ev = DriverEvent(kind, detail, data, time.time())
        for cb in self.on_event:
            try:
                cb(ev)
            except Exception:  # noqa: BLE001
                log.exception("%s: on_event callback raised", self.modem_id)

    @property
    def loop(self) -> asyncio.AbstractEventLoop:
        return self._io.loop

    def link_lost(self, exc: BaseException | None = None) -> None:
        """Call from the link when it goes down."""
        if exc is not None:
            self.last_error = f"link lost: {exc}"
        if self._lost is not None:
            self._lost.set()

    # -- internals (I/O thread) ---------------------------------------------------------------------
    def _start(self) -> None:
        if self._task is None or self._task.done():
            self._task = self.loop.create_task(self._run())

    def _set_state(self, state: str) -> None:
        if state != self.state:
            self.state = state
            self.emit_event("state", state)

    async def _run(self) -> None:
        backoff = self.backoff_initial
        ticker = self.loop.create_task(self._ticker())
        try:
            while not self._closing:
                self._set_state("reconnecting" if self._ever_opened else "connecting")
                try:
                    link = await self._open_link()
                except (TimeoutError, OSError, ValueError) as e:
                    self.counters["connect_failures"] += 1
                    self.emit_event("connect-failed", f"{type(e).__name__}: {e}")
                    if not self.reconnect:
                        break
                    await asyncio.sleep(backoff)
                    backoff = min(backoff * 2, self.backoff_max)
                    continue
                backoff = self.backoff_initial
                self._lost = asyncio.Event()
                self._link = link
                self._ever_opened = True
                self.connected_since = time.time()
                self.counters["connects"] += 1
                self._set_state("open")
                self._open_evt.set()
                try:
                    self._on_open()
                    self._pump()
                except LinkLost:
                    pass
                await self._lost.wait()
                self._open_evt.clear()
                self._link = None
                self.connected_since = None
                with contextlib.suppress(Exception):
                    link.close()
                self._on_link_lost()
                if self._closing:
                    break
                self.counters["disconnects"] += 1
                if not self.reconnect:
                    break
                self._set_state("reconnecting")
                await asyncio.sleep(backoff)
                backoff = min(backoff * 2, self.backoff_max)
        finally:
            ticker.cancel()
            self._set_state("closed")

    async def _ticker(self) -> None:
        while True:
            await asyncio.sleep(self.tick)
            try:
                self._on_tick(time.monotonic())
            except LinkLost:
                pass
            except Exception:  # noqa: BLE001 - the ticker must survive a bug in a subclass
                log.exception("%s: tick raised", self.modem_id)

    def _enqueue(self, dst: int, data: bytes, tag: Any) -> None:
        req = TxRequest(dst, data, tag, time.monotonic())
        why = self._check(dst, data)
        if why is not None:
            self.emit_status(req, "dropped", why, f"refused before queuing: {why}")
            return
        if len(self.queue) >= self.queue_limit:
            self.emit_status(req, "dropped", "fifo", f"driver queue full ({self.queue_limit})")
            return
        self.queue.append(req)
        self.emit_status(req, "queued")
        if self._link is not None:
            with contextlib.suppress(LinkLost):
                self._pump()

    def _shutdown(self) -> None:
        self._closing = True
        if self._lost is not None:
            self._lost.set()
        if self._link is not None:
            with contextlib.suppress(Exception):
                self._link.close()
        while self.queue:
            self.emit_status(self.queue.popleft(), "failed", "closed", "driver closed")
        self._open_evt.clear()


class StreamLink(asyncio.Protocol):
    """A TCP connection as a driver link: bytes go to `driver._on_bytes`, EOF/errors to `link_lost`."""

    def __init__(self, driver: Driver) -> None:
        self.driver = driver
        self.transport: asyncio.Transport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]

    def data_received(self, data: bytes) -> None:
        self.driver.counters["bytes_in"] += len(data)
        try:
            self.driver._on_bytes(data)
        except LinkLost:
            pass
        except Exception:  # noqa: BLE001 - a parser bug must not kill the link
            log.exception("%s: error handling device output", self.driver.modem_id)

    def connection_lost(self, exc: Exception | None) -> None:
        self.transport = None
        self.driver.link_lost(exc)

    def write(self, data: bytes) -> None:
        if self.transport is None or self.transport.is_closing():
            raise LinkLost("connection closed")
        self.transport.write(data)

    def close(self) -> None:
        if self.transport is not None:
            self.transport.close()
