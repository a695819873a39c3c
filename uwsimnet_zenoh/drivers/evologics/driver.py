"""EvoLogics S2C modem driver over TCP (AT command set, command mode).

    drv = EvoLogicsDriver("192.168.0.147", 9200, modem_id="bluerov0-dev",
                          on_frame=print, on_status=print)
    drv.open()
    drv.send(2, b"hello", tag=1)       # queued -> sent (OK) -> acked (DELIVEREDIM,2) | failed (FAILEDIM,2)
    drv.query("?T")                    # '1875' (last propagation time, us)
    drv.close()

How frames map onto the device (`mode`):
* `im`: every frame is an instant message `AT*SENDIM,<len>,<dst>,ack,<data>` (at most 64 bytes; the
  `ack` flag unless `im_ack=False` or broadcast).  `OK` -> status `sent`; `DELIVEREDIM` -> `acked`;
  `FAILEDIM` / `CANCELEDIM` -> `failed`.
* `burst`: `AT*SEND,<len>,<dst>,<data>` (up to 1024 bytes); `DELIVERED,<n>,<dst>` -> `acked`,
  `FAILED` -> `failed`.
* `auto` (default): instant messages up to 64 bytes, burst above.

The modem answers one command at a time, refuses a new instant message (`BUSY ...`) while the previous
one is on air, and cancels an acknowledged one whose acknowledgement has not come yet when another
message is sent (CANCELEDIM), so the driver keeps its own FIFO: it sends the next command only when the
previous one is answered, and the next instant message only when the previous acknowledged one's
delivery report came (or `ack_timeout` passed).  A frame the modem refuses as busy is not dropped: the
driver asks `AT?DI` every `busy_poll` seconds until the modem says EMPTY (or FAILED / EXPIRED), as DESERT
does, and sends it again; after `busy_retries` polls without the modem getting free it reports it
`failed` (reason `busy`).  Queries (`query()`) go ahead of queued frames.  An `ERROR` answer to a send
ends that frame `dropped` (reason `error`, the device's text in the status detail).  Answers may carry
the `[*]` prefix of a deferred setting.  Received RECV / RECVIM / RECVIMS / RECVPBM become frames with
rssi, integrity and the rest in `meta`; RECVPROBE, `%...` and the other notifications are asynchronous
events, never the answer to a query.  Anything malformed the device says is reported through `on_event`
(kind protocol-error) and counted; the parser resynchronises on the next line.

`link_mode="data"`: after connecting the driver sends `ATO` and speaks data mode (commands as `+++AT...`,
answers and notifications framed `+++AT<cmd>:<len>:`); burst data the modem passes through outside any
framing becomes frames with `src` 0 (data mode does not say who sent it) and `meta["kind"] == "data"`.
"""

from __future__ import annotations

import asyncio
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

from ...formats import evologics_at as at
from ..base import Driver, RxFrame, StreamLink, TxRequest


@dataclass
class _Query:
    command: str
    future: Any = None                 # concurrent.futures.Future for query(); None for init commands
    result: list[str] = field(default_factory=list)
    poll: bool = False                 # AT?DI while a frame waits after BUSY


class EvoLogicsDriver(Driver):
    driver_name = "evologics"

    def __init__(self, host: str, port: int = 9200, modem_id: str | None = None, *, mode: str = "auto",
                 im_ack: bool = True, init: tuple[str, ...] = ("?AL",), eol: str = "\n",
                 reply_timeout: float = 5.0, ack_timeout: float = 30.0, connect_timeout: float = 5.0,
                 max_bursts: int = 4, busy_poll: float = 0.2, busy_retries: int = 10, link_mode: str = "command",
                 **kw: Any) -> None:
        if mode not in ("auto", "im", "burst"):
            raise ValueError(f"mode must be auto, im or burst, got {mode!r}")
        if link_mode not in ("command", "data"):
            raise ValueError(f"link_mode must be command or data, got {link_mode!r}")
        kw.setdefault("max_payload", at.BURST_MAX if mode != "im" else at.IM_MAX)
        super().__init__(modem_id or f"evologics-{host}:{port}", **kw)
        self.host = host
        self.port = port
        self.mode = mode
        self.im_ack = im_ack
        self.init = tuple(init)
        self.ack_timeout = ack_timeout
        self.connect_timeout = connect_timeout
        self.max_bursts = max_bursts
        self.busy_poll = busy_poll
        self.busy_retries = busy_retries
        self.link_mode = link_mode
        self.codec = at.DriverCodec(eol=eol, reply_timeout=reply_timeout)
        self.settings: dict[str, str] = {}
        """Last answer to each query (e.g. '?AL' -> '1')."""
        self._queries: deque[_Query] = deque()
        self._cmd: TxRequest | _Query | None = None      # what the modem owes a synchronous answer for
        self._im: TxRequest | None = None                # instant message awaiting its delivery report
        self._bursts: deque[TxRequest] = deque()         # burst data awaiting DELIVERED / FAILED
        self._busy: TxRequest | None = None              # refused as busy: resent once AT?DI says EMPTY
        self._busy_next = 0.0

    # -- public ---------------------------------------------------------------------------------------
    def query(self, command: str, timeout: float = 10.0) -> str:
        """Send an AT command (e.g. `?AL`, `!L3`, `&V`) and return its answer (`OK` for setters).

        Raises RuntimeError on BUSY / ERROR / timeout / disconnection."""
        import concurrent.futures

        fut: concurrent.futures.Future = concurrent.futures.Future()
        self._io.call(self._add_query, _Query(command, fut))
        try:
            return fut.result(timeout)
        except concurrent.futures.TimeoutError:
            raise RuntimeError(f"{self.modem_id}: no answer to {command!r} in {timeout} s") from None

    # -- Driver hooks ---------------------------------------------------------------------------------
    async def _open_link(self) -> StreamLink:
        _, proto = await asyncio.wait_for(
            self.loop.create_connection(lambda: StreamLink(self), self.host, self.port),
            self.connect_timeout)
        return proto

    def _on_open(self) -> None:
        self.codec.mode = "command"
        if self.link_mode == "data":
            self.write(self.codec.command("O"))          # no answer; the codec parses data mode from now on
        for cmd in reversed(self.init):
            self._queries.appendleft(_Query(cmd))

    def _check(self, dst: int, data: bytes) -> str | None:
        if not 0 <= dst <= 255:
            return "invalid"
        limit = at.IM_MAX if self.mode == "im" else at.BURST_MAX
        if len(data) > limit:
            return "size"
        return None

    def _kind(self, req: TxRequest) -> str:
        if self.mode == "auto":
            return "im" if len(req.data) <= at.IM_MAX else "burst"
        return self.mode

    def _pump(self) -> None:
        if self._cmd is not None or self._link is None:
            return
        now = time.monotonic()
        if self._queries:
            q = self._queries.popleft()
            self._cmd = q
            self.write(self.codec.command(q.command, now))
            return
        if self._busy is not None:
            if now >= self._busy_next:
                self._cmd = _Query("?DI", poll=True)
                self.write(self.codec.command("?DI", now))
            return
        if not self.queue:
            return
        req = self.queue[0]
        kind = self._kind(req)
        if kind == "im" and self._im is not None:
            return                      # the modem is still delivering the previous instant message
        if kind == "burst" and len(self._bursts) >= self.max_bursts:
            return
        self.queue.popleft()
        req.extra["kind"] = kind
        if kind == "im":
            flag = "ack" if (self.im_ack and req.dst != at.BROADCAST) else "noack"
            req.extra["flag"] = flag
            wire = self.codec.im(req.dst, req.data, flag, now)
        else:
            wire = self.codec.burst(req.dst, req.data, now)
        self._cmd = req
        req.stage = "command"
        self.counters[f"tx_{kind}"] += 1
        self.write(wire)

    def _on_bytes(self, data: bytes) -> None:
        for ev in self.codec.feed(data, time.monotonic()):
            self._handle(ev)
        self._pump()

    def _on_tick(self, now: float) -> None:
        for ev in self.codec.expire(now):
            self._handle(ev)
        if self._busy is not None and self._cmd is None and now >= self._busy_next:
            self._pump()
        if self._im is not None and now - self._im.extra.get("t_ok", now) > self.ack_timeout:
            req, self._im = self._im, None
            self.emit_status(req, "failed", "timeout", f"no delivery report in {self.ack_timeout:g} s")
        while self._bursts and now - self._bursts[0].extra.get("t_ok", now) > self.ack_timeout:
            self.emit_status(self._bursts.popleft(), "failed", "timeout",
                             f"no delivery report in {self.ack_timeout:g} s")
        if self._link is not None:
            self._pump()

    def _on_link_lost(self) -> None:
        self.codec.forget()
        cmd, self._cmd = self._cmd, None
        if isinstance(cmd, TxRequest):
            self.emit_status(cmd, "failed", "disconnected", "link lost before the modem answered")
        elif isinstance(cmd, _Query):
            self._fail_query(cmd, "link lost")
        if self._im is not None:
            req, self._im = self._im, None
            self.emit_status(req, "failed", "disconnected", "link lost before the delivery report")
        if self._busy is not None:                       # sent again once the link is back
            self.queue.appendleft(self._busy)
            self._busy = None
        while self._bursts:
            self.emit_status(self._bursts.popleft(), "failed", "disconnected", "link lost")
        for q in [q for q in self._queries if q.future is None]:
            self._queries.remove(q)        # init commands are queued again on the next open

    def _info(self) -> dict[str, Any]:
        return {"host": self.host, "port": self.port, "mode": self.mode, "settings": dict(self.settings),
                "link_mode": self.link_mode,
                "awaiting": {"answer": self._describe(self._cmd),
                             "im_report": self._im.dst if self._im else None,
                             "busy_retry": self._busy.dst if self._busy else None,
                             "burst_reports": [r.dst for r in self._bursts]}}

    # -- protocol events ----------------------------------------------------------------------------
    @staticmethod
    def _describe(c: TxRequest | _Query | None) -> str | None:
        if c is None:
            return None
        return c.command if isinstance(c, _Query) else f"send to {c.dst} ({len(c.data)} bytes)"

    def _add_query(self, q: _Query) -> None:
        if self._closing:
            self._fail_query(q, "driver closed")
            return
        self._queries.append(q)
        if self._link is not None:
            self._pump()

    def _fail_query(self, q: _Query, why: str) -> None:
        if q.future is not None and not q.future.done():
            q.future.set_exception(RuntimeError(f"{self.modem_id}: {q.command}: {why}"))

    def _polled(self, text: str | None) -> None:
        """The answer to AT?DI while a frame waits after BUSY (None: the poll failed)."""
        req = self._busy
        if req is None:
            return
        polls = req.extra.get("polls", 0) + 1
        req.extra["polls"] = polls
        if text is not None and text.startswith("DELIVERING"):
            if polls >= self.busy_retries:
                self._busy = None
                self.emit_status(req, "failed", "busy", f"the modem stayed busy ({text}) through {polls} "
                                 f"AT?DI polls {self.busy_poll:g} s apart")
            else:
                self._busy_next = time.monotonic() + self.busy_poll
            return
        self._busy = None                                # EMPTY, FAILED, EXPIRED: free again
        self.counters["busy_resent"] += 1
        self.queue.appendleft(req)

    def _answer(self, q: _Query, text: str) -> None:
        if q.poll:
            self._polled(text)
            return
        self.settings[at.request_name(q.command)] = text
        if at.request_name(q.command) == "?AL":
            try:
                self.address = int(text)
            except ValueError:
                self.emit_event("protocol-error", f"AT?AL answered {text!r}")
        if q.future is not None and not q.future.done():
            q.future.set_result(text)

    def _handle(self, ev: at.DriverEvent) -> None:
        cmd = self._cmd
        if isinstance(ev, at.Received):
            meta = {k: v for k, v in (("kind", ev.kind), ("bitrate", ev.bitrate), ("duration_us", ev.duration_us),
                                      ("prop_time_us", ev.prop_time_us), ("velocity", ev.velocity),
                                      ("flag", ev.flag), ("timestamp_us", ev.timestamp_us), ("pid", ev.pid))
                    if v is not None}
            self.emit_frame(self._rx(ev, meta))
        elif isinstance(ev, at.Ok | at.Reply):
            text = "OK" if isinstance(ev, at.Ok) else ev.text
            if cmd is None:
                self.emit_event("protocol-error", f"answer {text!r} with no command pending")
                return
            self._cmd = None
            if isinstance(cmd, _Query):
                self._answer(cmd, text)
            elif text == "OK":
                cmd.extra["t_ok"] = time.monotonic()
                report = cmd.dst != at.BROADCAST and (cmd.extra["kind"] == "burst" or (
                    cmd.extra["kind"] == "im" and cmd.extra.get("flag") == "ack"))
                self.emit_status(cmd, "transmitted" if report else "sent")     # report: acked/failed follows
                if report and cmd.extra["kind"] == "burst":
                    self._bursts.append(cmd)
                elif report:
                    self._im = cmd
            else:
                self.emit_status(cmd, "dropped", "error", f"unexpected answer {text!r}")
        elif isinstance(ev, at.Busy | at.Error):
            word = "BUSY" if isinstance(ev, at.Busy) else "ERROR"
            if ev.request is None and isinstance(ev, at.Error):
                self.emit_event("warning", f"asynchronous error from the modem: ERROR {ev.reason}")
                return
            if cmd is None:
                self.emit_event("protocol-error", f"{word} {ev.reason} with no command pending")
                return
            self._cmd = None
            if isinstance(cmd, _Query):
                if cmd.poll:
                    self._polled(None)
                self._fail_query(cmd, f"{word} {ev.reason}")
            elif word == "BUSY":
                self.counters["busy"] += 1
                self._busy = cmd
                self._busy_next = time.monotonic() + self.busy_poll
                self.emit_event("busy", f"BUSY {ev.reason}: AT?DI every {self.busy_poll:g} s, then again")
            else:
                self.emit_status(cmd, "dropped", word.lower(), f"{word} {ev.reason}")
        elif isinstance(ev, at.Delivered | at.Failed | at.Canceled):
            self._report(ev)
        elif isinstance(ev, at.Expired | at.Notification):
            name = ev.name if isinstance(ev, at.Notification) else f"EXPIRED{ev.kind.upper()}"
            fields = ",".join(ev.fields) if isinstance(ev, at.Notification) else str(ev.dst)
            self.emit_event("notification", f"{name},{fields}" if fields else name)
        elif isinstance(ev, at.Data):
            self.emit_frame(RxFrame(0, self.address if self.address is not None else at.BROADCAST, ev.data,
                                    time.time(), None, None, {"kind": "data"}))
        elif isinstance(ev, at.ProtocolError):
            self.emit_event("protocol-error", f"{ev.kind}: {ev.detail}", ev.raw)
            if ev.kind == "timeout" and ev.request is not None and cmd is not None:
                self._cmd = None
                if isinstance(cmd, _Query):
                    if cmd.poll:
                        self._polled(None)
                    self._fail_query(cmd, "no answer")
                else:
                    self.emit_status(cmd, "failed", "timeout", "the modem did not answer the command")

    @staticmethod
    def _rx(ev: at.Received, meta: dict[str, Any]) -> RxFrame:
        return RxFrame(ev.src, ev.dst, ev.data, time.time(), ev.rssi, ev.integrity, meta)

    def _report(self, ev: at.Delivered | at.Failed | at.Canceled) -> None:
        ok = isinstance(ev, at.Delivered)
        if ev.kind == "im":
            req = self._im
            if req is None or req.dst != ev.dst:
                self.emit_event("protocol-error", f"unexpected {type(ev).__name__.upper()}IM,{ev.dst}")
                return
            self._im = None
        elif ev.kind == "burst":
            req = next((r for r in self._bursts if r.dst == ev.dst), None)
            if req is None:
                self.emit_event("protocol-error", f"unexpected burst report for {ev.dst}")
                return
            self._bursts.remove(req)
        else:
            self.emit_event("notification", f"{type(ev).__name__.upper()}{ev.kind.upper()},{ev.dst}")
            return
        if ok:
            self.emit_status(req, "acked")
        else:
            reason = "canceled" if isinstance(ev, at.Canceled) else "noack"
            self.emit_status(req, "failed", reason, f"the modem reported {reason}")
