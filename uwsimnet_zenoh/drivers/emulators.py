"""Emulators: a simulated modem that looks like the real device, so software written for the hardware
runs against the simulator unchanged.

* `EvoLogicsEmulator`: a TCP server speaking the S2C AT command set (command mode), like the modem's
  port 9200.  Point DUNE, DESERT, evins or your own code at `127.0.0.1:<port>`.
* `SerialRadioEmulator`: a pty that behaves like a transparent serial radio carrying dccomms
  DataLinkFrames (Seatooth S100 style).  Open `emulator.path` as you would `/dev/ttyUSB0`.

Both sit on a `ModemBackend` (drivers/backend.py): `SimBackend` for an in-process simulation, the
Zenoh backend (part B) for a running broker.  docs/drivers.md lists what is reproduced and how.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
import os
import time
from collections import Counter
from dataclasses import dataclass
from typing import Any

from ..phy import framing as fr
from . import dccomms_framing as dl
from . import evologics_at as at
from ._aio import FdStream, LoopThread, ServerClient, TcpServer
from .backend import BackendFrame, BackendStatus, ModemBackend, detach, link_metrics
from .serial_radio import set_raw

log = logging.getLogger("uwsimnet.drivers.emulators")

BUSY_IM = "BUSY DELIVERING"
"""Answer to AT*SENDIM while the previous instant message is still being delivered (reason text unverified)."""
ERR_FORMAT = "ERROR WRONG FORMAT"
ERR_RANGE = "ERROR OUT OF RANGE"
ERR_FULL = "ERROR BUFFER FULL"
ERR_NOT_ACCEPTED = "ERROR NOT ACCEPTED"
ERR_UNSUPPORTED = "ERROR NOT SUPPORTED"

DEFAULT_SETTINGS = {
    # name: value (AT?<name> reads it, AT!<name><value> writes it)
    "L": "0",        # source level 0 (max) .. 3
    "G": "0",        # gain: 0 normal, 1 low
    "LC": "0",       # source level control
    "CA": "1500",    # sound speed, m/s
    "RC": "3",       # connection retry count
    "RT": "2000",    # connection retry timeout, ms
    "RI": "0",       # instant message retry count
    "ZI": "0",       # idle timeout, s
    "AM": "254",     # highest address
    "AR": "1",       # remote address (burst data mode)
    "ZL": "16384",   # burst pool size, bytes
    "RP": "0",       # promiscuous mode
    "KO": "0",       # keep-online
    "C": "1",        # carrier waveform id
    "ZX": "0",       # extended notifications (AT@ZX1): SENDSTART/SENDEND/RECVSTART/RECVEND
    "ZU": "0",       # USBL position output (AT@ZU1)
    "ZF": "0",
    "CTRL": "0",
}


@dataclass
class _Tx:
    """A frame the emulated modem accepted, until its report."""

    token: int
    kind: str            # im | burst | pbm | ims
    dst: int
    length: int
    flag: str | None
    t_sent: float | None = None
    done: bool = False
    report: bool = True  # send DELIVERED/FAILED(IM) for it


class EvoLogicsEmulator:
    """An EvoLogics S2C modem on TCP, backed by a simulated modem.

    `port=0` picks a free port (see `.port` after `start()`).  `bitrate` is used for time-on-air figures
    when the backend does not say.  `ack_time` (s) is added to the propagation time before a delivery
    report, for the acknowledgement's own time on air; `ack_timeout` (s) after transmission an
    instant message without an outcome is reported FAILEDIM (addressee absent or out of range)."""

    def __init__(self, backend: ModemBackend, host: str = "127.0.0.1", port: int = 0, *,
                 bitrate: float | None = None, ack_time: float = 0.05, ack_timeout: float = 5.0,
                 payload_timeout: float = 2.0, max_clients: int = 8) -> None:
        self.backend = backend
        self.host = host
        self.port = port
        self.bitrate = bitrate
        self.ack_time = ack_time
        self.ack_timeout = ack_timeout
        self.payload_timeout = payload_timeout
        self.max_clients = max_clients
        self.settings = dict(DEFAULT_SETTINGS, AL=str(backend.address))
        self.last = {"T": "0", "E": "0", "I": "0", "V": "0.00"}
        self.counters: Counter[str] = Counter()
        self.clients: list[_AtClient] = []
        self._io = LoopThread(f"uwsimnet-emu-evologics-{backend.id}")
        self._server: TcpServer | None = None
        self._tokens = itertools.count(1)
        self._txs: dict[int, _Tx] = {}
        self._im: _Tx | None = None
        self._pool = 0
        self._ticker: asyncio.Task | None = None
        self.closing = False

    # -- lifecycle ----------------------------------------------------------------------------------
    def start(self) -> tuple[str, int]:
        self._io.start()
        self._io.run(self._start())
        self.backend.on_frame.append(self._bk_frame)
        self.backend.on_status.append(self._bk_status)
        return self.host, self.port

    async def _start(self) -> None:
        self._server = TcpServer(self._io.loop, lambda: _AtClient(self), self.host, self.port)
        self.port = self._server.port
        self._ticker = self._io.loop.create_task(self._tick())

    def close(self) -> None:
        detach(self.backend, self._bk_frame, self._bk_status)
        self._io.shutdown(self._close)

    async def _close(self) -> None:
        self.closing = True
        if self._ticker is not None:
            self._ticker.cancel()
        if self._server is not None:
            self._server.close()
        for c in list(self.clients):
            c.close()
        # a connection accepted just now gets its connection_made a moment later: it closes itself
        # then (see _AtClient), and its connection_lost must run before the loop stops
        await asyncio.sleep(0.05)

    def __enter__(self) -> EvoLogicsEmulator:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    async def _tick(self) -> None:
        while True:
            await asyncio.sleep(0.1)
            now = time.monotonic()
            for c in list(self.clients):
                for ev in c.codec.expire(now):
                    self._command(c, ev)
            for tx in list(self._txs.values()):
                if not tx.done and tx.t_sent is not None and now - tx.t_sent > self.ack_timeout:
                    self._finish(tx, False)

    # -- output -------------------------------------------------------------------------------------
    def _all(self, data: bytes) -> None:
        for c in list(self.clients):
            c.write(data)

    @property
    def _zx(self) -> bool:
        return self.settings.get("ZX") == "1"

    # -- commands (loop thread) ---------------------------------------------------------------------
    def _command(self, c: _AtClient, ev: at.DeviceEvent) -> None:
        self.counters["commands"] += 1
        if isinstance(ev, at.BadCommand):
            self.counters[f"bad_{ev.kind}"] += 1
            log.info("%s: %s", self.backend.id, ev.detail)
            c.write(at.line(ev.reply))
        elif isinstance(ev, at.SendCommand):
            c.write(self._send(ev))
        else:
            c.write(self._plain(ev))

    def _send(self, ev: at.SendCommand) -> bytes:
        if not 0 <= ev.dst <= 255:
            return at.line(ERR_RANGE)
        if ev.name in ("*SENDIM", "*SENDIMS", "*SENDPBM"):
            if self._im is not None:
                self.counters["busy"] += 1
                return at.line(BUSY_IM)
            kind = {"*SENDIM": "im", "*SENDIMS": "ims", "*SENDPBM": "pbm"}[ev.name]
            flag = ev.flag if kind == "im" else None
            report = kind == "im" and flag == "ack" and ev.dst != at.BROADCAST
            tx = _Tx(next(self._tokens), kind, ev.dst, len(ev.data), flag, report=report)
            self._im = tx
            if kind == "im":
                hint = f"im:{flag}"
            elif kind == "ims":
                hint = f"ims:{ev.timestamp_us if ev.timestamp_us is not None else ''}"
            else:
                hint = "pbm"
        else:
            pool = int(self.settings.get("ZL", "16384"))
            if self._pool + len(ev.data) > pool:
                self.counters["buffer_full"] += 1
                return at.line(ERR_FULL)
            tx = _Tx(next(self._tokens), "burst", ev.dst, len(ev.data), None, report=ev.dst != at.BROADCAST)
            self._pool += len(ev.data)
            hint = "burst"
        self._txs[tx.token] = tx
        self.counters[f"tx_{tx.kind}"] += 1
        self.backend.send(ev.dst, ev.data, tag=tx.token, hint=hint)
        return at.ok()

    def _plain(self, ev: at.Command) -> bytes:
        name, arg = ev.name, ev.arg.strip()
        s = self.settings
        if name.startswith("?"):
            key = name[1:]
            if key in self.last:
                return at.line(self.last[key])
            if key in s:
                return at.line(s[key])
            if key in ("BL", "BR"):
                return at.line(str(int(self.bitrate or self.backend.info().get("bitrate") or 0)))
            if key == "DI":
                return at.line("EMPTY" if self._im is None else "DELIVERING")
            if key == "MODE":
                return at.line("AT")
            if key == "CLOCK":
                return at.line(str(int(self.backend.now())))
            if key == "UT":
                return at.line(f"{self.backend.now():.3f}")
            return at.line(ERR_FORMAT)
        if name.startswith("!") or name.startswith("@"):
            key = name[1:]
            if key not in s:
                return at.line(ERR_FORMAT)
            if key == "AL" and arg != s["AL"]:
                return at.line(ERR_NOT_ACCEPTED)      # the simulated modem's address is the scene's
            if key == "CTRL":
                return at.ok()
            if not arg:
                return at.line(ERR_FORMAT)
            s[key] = arg
            return at.ok()
        if name == "&V":
            return at.block([f"{k}: {v}" for k, v in sorted(s.items())])
        if name in ("&W", "&F", "H", "C"):
            if name == "&F":
                self.settings = dict(DEFAULT_SETTINGS, AL=str(self.backend.address))
            return at.ok()
        if name == "Z":
            self._drop_pending()
            return at.ok()
        if name == "A":
            return at.line("INITIATION LISTEN")
        if name == "N":
            return at.line("INITIATION NOISE")
        if name == "S":
            return at.line("INITIATION DEAF")
        if name == "I":
            return at.line({"0": "1.9", "1": "phy 1.9, data 1.9", "7": "EvoLogics GmbH"}.get(arg or "0", "1.9"))
        if name == "O":
            return at.line(ERR_UNSUPPORTED)           # data mode is not emulated (see docs/drivers.md)
        return at.line(ERR_FORMAT)

    def _drop_pending(self) -> None:
        """ATZ: forget the frames waiting for a report (no DELIVERED/FAILED will come for them)."""
        for tx in self._txs.values():
            tx.done = True
        self._txs.clear()
        self._im = None
        self._pool = 0

    # -- backend events (engine thread -> loop thread) ------------------------------------------------
    def _bk_status(self, st: BackendStatus) -> None:
        if isinstance(st.tag, int) and st.tag in self._txs:
            self._io.call(self._status, st)

    def _bk_frame(self, f: BackendFrame) -> None:
        self._io.call(self._rx, f)

    def _status(self, st: BackendStatus) -> None:
        tx = self._txs.get(st.tag)
        if tx is None or tx.done:
            return
        ev = st.event
        if ev == "sent":
            tx.t_sent = time.monotonic()
            if self._zx:
                dur = int(tx.length * 8e6 / (self.bitrate or self.backend.info().get("bitrate") or 1000))
                self._all(at.notification("SENDSTART", tx.dst, tx.kind, dur, 0))
                self._all(at.notification("SENDEND", tx.dst, tx.kind, int(st.t * 1e6), dur))
            if not tx.report:
                self._finish(tx, True)
        elif ev in ("acked", "failed", "dropped"):
            self._finish(tx, ev == "acked")
        elif ev in ("delivered", "lost"):
            if not tx.report:
                return
            delay = (st.prop_time or 0.0) + self.ack_time
            self._io.loop.call_later(delay, self._finish, tx, ev == "delivered")

    def _finish(self, tx: _Tx, ok: bool) -> None:
        if tx.done:
            return
        tx.done = True
        self._txs.pop(tx.token, None)
        if tx is self._im:
            self._im = None
        if tx.kind == "burst":
            self._pool = max(0, self._pool - tx.length)
        if not tx.report:
            return
        self.counters["delivered" if ok else "failed"] += 1
        if tx.kind == "im":
            self._all(at.delivered(tx.dst) if ok else at.failed(tx.dst))
        else:
            self._all(at.delivered(tx.dst, tx.length) if ok else at.failed(tx.dst, tx.length))

    def _rx(self, f: BackendFrame) -> None:
        self.counters["rx"] += 1
        m = link_metrics(f, self.bitrate, float(self.settings.get("CA", "1500") or 1500))
        self.last.update(T=str(int(round(m.prop_time * 1e6))), E=str(m.rssi), I=str(m.integrity), V=f"{m.velocity:.2f}")
        dur_us = int(m.duration * 1e6)
        if self._zx:
            self._all(b"RECVSTART\r\n")
            self._all(at.notification("RECVEND", int((f.t_rx or 0.0) * 1e6), dur_us, m.rssi, m.integrity))
        hint = f.hint or ("im:noack" if len(f.data) <= at.IM_MAX else "burst")
        if hint.startswith("im:"):
            flag = hint[3:] if hint[3:] in at.IM_FLAGS else "noack"
            self._all(at.recvim(f.src, f.dst, f.data, flag, dur_us, m.rssi, m.integrity, m.velocity))
        elif hint.startswith("ims:"):
            ts = hint[4:] or str(int((f.t_tx or 0.0) * 1e6))
            head = f"RECVIMS,{len(f.data)},{f.src},{f.dst},{ts},{dur_us},{m.rssi},{m.integrity},{m.velocity:.2f},"
            self._all(head.encode("ascii") + f.data + at.CRLF)
        elif hint == "pbm":
            self._all(at.recvpbm(f.src, f.dst, f.data, dur_us, m.rssi, m.integrity, m.velocity))
        else:
            self._all(at.recv(f.src, f.dst, f.data, m.bitrate, m.rssi, m.integrity, int(round(m.prop_time * 1e6)),
                              m.velocity))


class _AtClient(ServerClient):
    def __init__(self, emu: EvoLogicsEmulator) -> None:
        super().__init__(emu.clients)
        self.emu = emu
        self.codec = at.DeviceCodec(payload_timeout=emu.payload_timeout)

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        if self.accept(transport, self.emu.closing or len(self.emu.clients) >= self.emu.max_clients):
            self.emu.counters["connections"] += 1

    def data_received(self, data: bytes) -> None:
        try:
            for ev in self.codec.feed(data, time.monotonic()):
                self.emu._command(self, ev)
        except Exception:  # noqa: BLE001 - one client's bad input must not stop the emulator
            log.exception("%s: error handling a command", self.emu.backend.id)



def _frame_error(ev: dl.FrameEvent) -> str:
    """One line about a bad frame (the event's repr would dump up to 2 KB of raw bytes)."""
    if isinstance(ev, dl.BadCrc):
        return f"bad CRC (frame {ev.src}->{ev.dst}, {ev.length} bytes payload)"
    if isinstance(ev, dl.BadLength):
        return f"bad length {ev.length}"
    if isinstance(ev, dl.Truncated):
        return f"truncated frame ({len(ev.raw)} of {ev.expected} bytes)"
    return type(ev).__name__


class SerialRadioEmulator:
    """A pty that behaves like a transparent serial radio carrying dccomms DataLinkFrames.

    Valid frames written to the pty go on air through the backend (to the frame's dst; the source
    address is the simulated modem's); frames the modem receives come out of the pty as DataLinkFrames.
    Garbage, bad CRCs and bad lengths written to it are counted and skipped, as a dccomms receiver
    would.  `link`: also make a symlink with that name to the pty (like a udev name)."""

    def __init__(self, backend: ModemBackend, *, link: str | None = None, max_payload: int | None = None,
                 stall_timeout: float = 2.0, framing: fr.Framing | str | None = None) -> None:
        self.backend = backend
        self.link = link
        if framing is None:       # the scene's txPacketBuilder of the modem (the broker's info), else CRC16
            info = backend.info() if hasattr(backend, "info") else {}
            framing = info.get("tx_framing") if isinstance(info, dict) else None
        self.framing = fr.builder(framing) if isinstance(framing, str) and framing else \
            (framing if isinstance(framing, fr.Framing) else fr.DEFAULT)
        self.max_payload = self.framing.max_payload if max_payload is None else max_payload
        self.decoder = dl.FrameDecoder(max_payload=self.max_payload, stall_timeout=stall_timeout,
                                       framing=self.framing)
        self.counters: Counter[str] = Counter()
        self.path = ""
        self._io = LoopThread(f"uwsimnet-emu-serial-{backend.id}")
        self._master = -1
        self._slave = -1
        self._stream: FdStream | None = None
        self._ticker: asyncio.Task | None = None

    def start(self) -> str:
        self._master, self._slave = os.openpty()
        set_raw(self._slave)
        set_raw(self._master)
        self.path = os.ttyname(self._slave)
        if self.link:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(self.link)
            os.symlink(self.path, self.link)
        self._io.start()
        self._io.submit(self._start)
        self.backend.on_frame.append(self._bk_frame)
        return self.link or self.path

    def _start(self) -> None:
        self._stream = FdStream(self._io.loop, self._master, self._on_data, self._lost)
        self._ticker = self._io.loop.create_task(self._tick())

    async def _tick(self) -> None:
        while True:
            await asyncio.sleep(0.1)
            self._events(self.decoder.expire(time.monotonic()))

    def close(self) -> None:
        detach(self.backend, self._bk_frame)
        self._io.shutdown(self._close)
        if self._slave >= 0:
            with contextlib.suppress(OSError):
                os.close(self._slave)
            self._slave = -1
        if self.link:
            with contextlib.suppress(OSError):
                os.unlink(self.link)

    def _close(self) -> None:
        if self._ticker is not None:
            self._ticker.cancel()
        if self._stream is not None:
            self._stream.close()

    def __enter__(self) -> SerialRadioEmulator:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _lost(self, exc: BaseException | None) -> None:
        log.warning("%s: pty closed (%s)", self.backend.id, exc)

    def _on_data(self, data: bytes) -> None:
        self.counters["bytes_in"] += len(data)
        self._events(self.decoder.feed(data, time.monotonic()))

    def _events(self, events: list[dl.FrameEvent]) -> None:
        for ev in events:
            if isinstance(ev, dl.FrameReceived):
                f = ev.frame
                if self.framing.addressed and f.src != self.backend.address:
                    self.counters["src_mismatch"] += 1
                self.counters["tx"] += 1
                self.backend.send(f.dst, f.payload, hint="dccomms")
            else:
                self.counters[type(ev).__name__] += 1
                if isinstance(ev, dl.Garbage):       # line noise, notifications: routine on a serial line
                    log.info("%s: %d bytes of garbage on the pty skipped", self.backend.id, len(ev.data))
                else:                                # a frame the application meant to send was lost
                    log.warning("%s: %s on the pty, frame skipped", self.backend.id, _frame_error(ev))

    def _bk_frame(self, f: BackendFrame) -> None:
        if (self.framing.addressed and not (0 <= f.src <= 255 and 0 <= f.dst <= 255)) \
                or len(f.data) > self.max_payload or self.framing.check_payload(len(f.data)) is not None:
            self.counters["rx_unrepresentable"] += 1
            return
        self.counters["rx"] += 1
        self._io.call(self._write, self.framing.encode(f.data, dst=f.dst, src=f.src))

    def _write(self, data: bytes) -> None:
        if self._stream is not None:
            self._stream.write(data)

    def info(self) -> dict[str, Any]:
        return {"path": self.path, "link": self.link, "counters": dict(self.counters),
                "decoder": dict(self.decoder.counters)}
