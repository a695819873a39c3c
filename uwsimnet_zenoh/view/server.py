"""The web server of `uwsimnet view` (aiohttp): the page, its static files, the document and live updates.

    GET  /                 the page (static/index.html; static/view.js, static/view.css: no build step)
    GET  /api/doc          the document (view.state): a replay's whole trace, or a live snapshot
    GET  /ws               live: a WebSocket that sends {"type": "snapshot", "doc"} then
                           {"type": "updates", "updates": [...]} batches
    POST /api/control/OP   live: pause | resume through the world's control API (403 when not allowed)

Each WebSocket is served by its own task that reads the bounded update log of `LiveState`; a browser that
reads slowly only delays its own task (and gets a snapshot when it falls out of the log), a closed one
ends it.  Nothing here ever makes a Zenoh callback wait.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import signal
from collections.abc import Callable
from pathlib import Path
from typing import Any

from aiohttp import WSMsgType, web

from .state import LiveState

STATIC = Path(__file__).with_name("static")
BATCH_S = 0.05
"""A WebSocket task collects updates for this long before sending them as one message."""
IDLE_TIMEOUT_S = 15.0
"""An HTTP connection that sends no complete request for this long (silent, half-open, or one header a
minute) is closed (#41: they used to stay open forever)."""
SEND_TIMEOUT_S = 10.0
"""A browser that takes longer than this to take one message is dropped."""

_dumps = json.JSONEncoder(separators=(",", ":"), allow_nan=False, default=str).encode


def _finite(obj: Any) -> Any:
    """The same data with every NaN or infinity as None (JSON has neither)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_finite(v) for v in obj]
    return obj


def _json_bytes(obj: Any) -> bytes:
    try:
        return _dumps(obj).encode()
    except ValueError:                      # NaN/inf somewhere (e.g. a live record): as null
        return _dumps(_finite(obj)).encode()


class ViewServer:
    """One page for either source: `doc` (a replay's document) or `live` (+ `control`, a callable op -> reply)."""

    def __init__(self, *, doc: dict[str, Any] | None = None, live: LiveState | None = None,
                 control: Callable[[str], dict[str, Any]] | None = None) -> None:
        if (doc is None) == (live is None):
            raise ValueError("a ViewServer shows one source: doc or live")
        self._doc = None if doc is None else _json_bytes(doc)
        self.live = live
        self._control = control
        self._wakes: set[asyncio.Event] = set()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._pending = False
        self.clients = 0
        self._sockets: set[web.WebSocketResponse] = set()
        self.hosts: set[str] = set()
        """Host headers this page answers (set by start(): its own address, localhost): anything else is a
        DNS-rebinding name or a foreign page, refused (#41)."""
        self.refused = 0
        self.idle_timeout = IDLE_TIMEOUT_S
        self.app = web.Application(middlewares=[self._same_origin])
        self.app.on_shutdown.append(self._close_sockets)
        self.app.router.add_get("/", self._index)
        self.app.router.add_get("/api/doc", self._api_doc)
        self.app.router.add_get("/ws", self._ws)
        self.app.router.add_post("/api/control/{op}", self._api_control)
        self.app.router.add_static("/static/", STATIC)

    # -- wake-ups from Zenoh threads: coalesced, one call_soon_threadsafe at a time -------------------
    def _on_change(self) -> None:
        if self._pending or self._loop is None:
            return
        self._pending = True
        with contextlib.suppress(RuntimeError):            # loop closed at shutdown
            self._loop.call_soon_threadsafe(self._fire)

    def _fire(self) -> None:
        self._pending = False
        for w in self._wakes:
            w.set()

    async def start(self, host: str, port: int) -> tuple[web.AppRunner, int]:
        """Serve on host:port (0 = any free port); (runner, the port).  OSError if the port is taken."""
        self._loop = asyncio.get_running_loop()
        if self.live is not None:
            self.live.listeners.append(self._on_change)
        runner = web.AppRunner(self.app, access_log=None, shutdown_timeout=2.0, keepalive_timeout=self.idle_timeout)
        await runner.setup()
        site = web.TCPSite(runner, host, port, reuse_address=False)
        try:
            await site.start()
        except OSError:
            await runner.cleanup()
            raise
        server = site._server                                 # noqa: SLF001 - the only way to the bound port
        sock = server.sockets[0] if server is not None and server.sockets else None
        bound = sock.getsockname()[1] if sock is not None else port
        names = {host, f"[{host}]" if ":" in host else host, "localhost", "127.0.0.1", "[::1]"}
        self.hosts = {f"{n.lower()}:{bound}" for n in names}
        return runner, bound

    async def _close_sockets(self, _app: web.Application) -> None:
        for ws in list(self._sockets):
            with contextlib.suppress(Exception):
                await asyncio.wait_for(ws.close(code=1001, message=b"server shutdown"), 2.0)

    @web.middleware
    async def _same_origin(self, req: web.Request, handler: Callable[[web.Request], Any]) -> web.StreamResponse:
        """403 for a foreign Host (DNS rebinding) and for a foreign Origin (another site's page or socket)."""
        origin = req.headers.get("Origin")
        if req.host.lower() not in self.hosts or (origin is not None and origin.lower() not in
                                                   {f"http://{h}" for h in self.hosts}):
            self.refused += 1
            return web.Response(status=403, text="foreign Host or Origin\n")
        return await handler(req)

    # -- handlers ----------------------------------------------------------------------------------
    async def _index(self, _req: web.Request) -> web.StreamResponse:
        return web.FileResponse(STATIC / "index.html", headers={"Cache-Control": "no-store"})

    async def _api_doc(self, _req: web.Request) -> web.Response:
        if self._doc is not None:
            body = self._doc
        else:
            assert self.live is not None
            body = _json_bytes(self.live.snapshot()[1])
        return web.Response(body=body, content_type="application/json", headers={"Cache-Control": "no-store"})

    async def _api_control(self, req: web.Request) -> web.Response:
        op = req.match_info["op"]
        if self.live is None or self._control is None or not self.live.control:
            return web.json_response({"ok": False, "error": "control is not available here"}, status=403)
        if op not in ("pause", "resume"):
            return web.json_response({"ok": False, "error": f"unknown operation {op!r}"}, status=404)
        reply = await asyncio.get_running_loop().run_in_executor(None, self._control, op)
        return web.json_response(json.loads(_json_bytes(reply)), status=200 if reply.get("ok") else 502)

    async def _ws(self, req: web.Request) -> web.StreamResponse:
        ws = web.WebSocketResponse(heartbeat=20.0)
        await ws.prepare(req)
        if self.live is None:
            await ws.close()
            return ws
        self.clients += 1
        self._sockets.add(ws)
        wake = asyncio.Event()
        self._wakes.add(wake)
        reader = asyncio.ensure_future(self._drain(ws))
        try:
            seq, doc = self.live.snapshot()
            await asyncio.wait_for(ws.send_bytes(_json_bytes({"type": "snapshot", "doc": doc})), SEND_TIMEOUT_S)
            while not ws.closed and not reader.done():
                with contextlib.suppress(asyncio.TimeoutError):
                    await asyncio.wait_for(wake.wait(), 1.0)
                wake.clear()
                await asyncio.sleep(BATCH_S)
                got = self.live.since(seq)
                if got is None:                        # fell behind the log: start again from a snapshot
                    seq, doc = self.live.snapshot()
                    msg = {"type": "snapshot", "doc": doc}
                else:
                    seq, ups = got
                    if not ups:
                        continue
                    msg = {"type": "updates", "updates": ups}
                await asyncio.wait_for(ws.send_bytes(_json_bytes(msg)), SEND_TIMEOUT_S)
        except (TimeoutError, ConnectionError, RuntimeError):
            pass
        finally:
            self.clients -= 1
            self._sockets.discard(ws)
            self._wakes.discard(wake)
            reader.cancel()
            with contextlib.suppress(Exception):
                await ws.close()
        return ws

    @staticmethod
    async def _drain(ws: web.WebSocketResponse) -> None:
        async for msg in ws:                                   # the page sends nothing; notice closes
            if msg.type in (WSMsgType.CLOSE, WSMsgType.ERROR):
                break


async def serve_forever(server: ViewServer, host: str, port: int, on_ready: Callable[[str], None],
                        stop: asyncio.Event | None = None) -> None:
    """Serve until SIGINT/SIGTERM (or `stop`); `on_ready(url)` once listening.  OSError if the port is taken."""
    runner, bound = await server.start(host, port)
    stop = stop or asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError, ValueError):
            loop.add_signal_handler(sig, stop.set)
    try:
        on_ready(f"http://{host if ':' not in host else f'[{host}]'}:{bound}/")
        await stop.wait()
    finally:
        await runner.shutdown()
        await runner.cleanup()
