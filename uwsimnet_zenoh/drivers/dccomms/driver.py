"""A transparent serial radio (WFS Seatooth S100 style) with dccomms framing (DataLinkFrame by default).

The radio itself has no addressing: whatever bytes go into its serial port come out of the other
radios' ports.  dccomms puts a DataLinkFrame (`55 55 | dst | src | len BE | payload | CRC16 BE`) around
each packet, and so does this driver: `send(dst, data)` writes one frame with our `address` as source,
and every valid frame read from the port becomes a received frame.  Garbage between frames, bad CRCs
and impossible lengths are reported (`on_event`, kind protocol-error) and skipped; the decoder
resynchronises on the next preamble.

The port is a serial device or a pty path (an emulator's, see `dccomms.emulator.SerialRadioEmulator`), put in
raw mode with termios (no echo, no line discipline, 8N1, `baud`).  Frames for other addresses are
dropped unless `promiscuous=True` (as the original: without a MAC, dccomms applications filter).

The radio gives no delivery report: a frame is `sent` once written to the port.
"""

from __future__ import annotations

import os
import termios
import time
import tty
from typing import Any

from ...formats import dccomms as fr
from ...formats import dccomms_stream as ds
from .._aio import FdStream
from ..base import Driver, RxFrame

BAUDS = {n: getattr(termios, f"B{n}") for n in (1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200, 230400)
         if hasattr(termios, f"B{n}")}


def open_raw_tty(path: str, baud: int | None = 9600) -> int:
    """Open a serial device or pty in raw mode (8N1, no echo, no flow control); returns the fd."""
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        set_raw(fd, baud)
    except Exception:
        os.close(fd)
        raise
    return fd


def set_raw(fd: int, baud: int | None = None) -> None:
    tty.setraw(fd, termios.TCSANOW)
    attrs = termios.tcgetattr(fd)
    attrs[2] &= ~(termios.PARENB | termios.CSTOPB | termios.CSIZE | getattr(termios, "CRTSCTS", 0))
    attrs[2] |= termios.CS8 | termios.CREAD | termios.CLOCAL
    attrs[0] &= ~(termios.IXON | termios.IXOFF | termios.IXANY)
    if baud is not None:
        if baud not in BAUDS:
            raise ValueError(f"unsupported baud rate {baud} (one of {sorted(BAUDS)})")
        attrs[4] = attrs[5] = BAUDS[baud]
    termios.tcsetattr(fd, termios.TCSANOW, attrs)


class SerialRadioDriver(Driver):
    driver_name = "serial-radio"

    def __init__(self, path: str, address: int, modem_id: str | None = None, *, baud: int | None = 9600,
                 promiscuous: bool = False, stall_timeout: float = 2.0, framing: fr.Framing | str | None = None,
                 **kw: Any) -> None:
        self.framing = fr.builder(framing) if isinstance(framing, str) else (framing or fr.DEFAULT)
        top = min(254, self.framing.max_address) if self.framing.addressed else 254
        if not 0 <= address <= top:
            raise ValueError(f"a {self.framing.name} address is 0..{top}, got {address}")
        """The dccomms framing on the serial line (default DataLinkFrame CRC16; dccomms_s100_bridge used a
        SimplePacket by default): frames of framings without addresses are heard by every radio."""
        kw.setdefault("max_payload", self.framing.max_payload)
        super().__init__(modem_id or f"serial-{os.path.basename(path)}", address=address, **kw)
        self.path = path
        self.baud = baud
        self.promiscuous = promiscuous
        self.decoder = ds.FrameDecoder(max_payload=self.max_payload, stall_timeout=stall_timeout,
                                       framing=self.framing)
        self._stream: FdStream | None = None

    async def _open_link(self) -> FdStream:
        fd = open_raw_tty(self.path, self.baud)
        self._stream = FdStream(self.loop, fd, self._on_data, self.link_lost)
        return self._stream

    def _on_data(self, data: bytes) -> None:
        self.counters["bytes_in"] += len(data)
        self._on_bytes(data)

    def _check(self, dst: int, data: bytes) -> str | None:
        if not 0 <= dst <= 255 or (self.framing.addressed and dst != fr.BROADCAST and dst > self.framing.max_address):
            return "invalid"
        if len(data) > self.max_payload or self.framing.check_payload(len(data)) is not None:
            return "size"
        return None

    def _pump(self) -> None:
        while self.queue and self._link is not None:
            req = self.queue.popleft()
            self.write(self.framing.encode(req.data, dst=req.dst, src=self.address or 0))
            self.counters["tx"] += 1
            self.emit_status(req, "sent")

    def _on_bytes(self, data: bytes) -> None:
        self._events(self.decoder.feed(data, time.monotonic()))

    def _on_tick(self, now: float) -> None:
        self._events(self.decoder.expire(now))

    def _on_link_lost(self) -> None:
        self._stream = None
        self.decoder = ds.FrameDecoder(max_payload=self.max_payload, stall_timeout=self.decoder.stall_timeout,
                                       framing=self.framing)

    def _events(self, events: list[ds.FrameEvent]) -> None:
        for ev in events:
            if isinstance(ev, ds.FrameReceived):
                f = ev.frame
                if f.kind != "data":                     # DcMac rts/cts/sync: the MAC's, no payload to hand up
                    self.counters[f"control_{f.kind}"] += 1
                    continue
                if not self.promiscuous and f.dst not in (self.address, ds.BROADCAST):
                    self.counters["rx_not_for_us"] += 1
                    continue
                meta: dict[str, Any] = {"size": len(ev.raw)}
                if f.seq is not None:                    # a SimplePacket's own seq: the sender app's
                    meta["aseq"] = f.seq
                self.emit_frame(RxFrame(f.src, f.dst, f.payload, time.time(), meta=meta))
            elif isinstance(ev, ds.Garbage):
                self.emit_event("protocol-error", f"garbage: {len(ev.data)} bytes outside any frame", ev.data)
            else:
                self.emit_event("protocol-error", ds.describe(ev) + (f" (max {self.max_payload})"
                                if isinstance(ev, ds.BadLength) else ""), ev.raw)

    def _info(self) -> dict[str, Any]:
        return {"path": self.path, "baud": self.baud, "promiscuous": self.promiscuous, "framing": self.framing.name,
                "decoder": dict(self.decoder.counters)}
