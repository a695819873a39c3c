"""The dccomms serial radio emulator: a pty that behaves like a transparent serial radio (Seatooth S100
style) carrying dccomms frames in the modem's framing (`formats.dccomms`).  Open `emulator.path` as you would
`/dev/ttyUSB0`.  It sits on a `ModemBackend` (drivers/backend.py)."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import time
from collections import Counter
from typing import Any

from ...formats import dccomms as fr
from ...formats import dccomms_stream as ds
from .._aio import FdStream, LoopThread
from ..app_seq import AppSeq
from ..backend import BackendFrame, ModemBackend, detach
from .driver import set_raw

log = logging.getLogger("uwsimnet.drivers.emulators")


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
        self.decoder = ds.FrameDecoder(max_payload=self.max_payload, stall_timeout=stall_timeout,
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

    def _events(self, events: list[ds.FrameEvent]) -> None:
        for ev in events:
            if isinstance(ev, ds.FrameReceived):
                f = ev.frame
                if f.kind != "data":                 # DcMac rts/cts/sync: the MAC's, not a frame to carry
                    self.counters[f"control_{f.kind}"] += 1
                    continue
                if self.framing.addressed and f.src != self.backend.address:
                    self.counters["src_mismatch"] += 1
                self.counters["tx"] += 1
                self.backend.send(f.dst, f.payload,       # a SimplePacket's seq is the sending app's
                                  msg=None if f.seq is None else AppSeq(f.seq))  # type: ignore[arg-type]
            else:
                self.counters[type(ev).__name__] += 1
                if isinstance(ev, ds.Garbage):       # line noise, notifications: routine on a serial line
                    log.info("%s: %d bytes of garbage on the pty skipped", self.backend.id, len(ev.data))
                else:                                # a frame the application meant to send was lost
                    log.warning("%s: %s on the pty, frame skipped", self.backend.id, ds.describe(ev))

    def _bk_frame(self, f: BackendFrame) -> None:
        top = self.framing.max_address
        if (self.framing.addressed and not (0 <= f.src <= top and (0 <= f.dst <= top or f.dst == fr.BROADCAST))) \
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
