"""The POSIX message-queue bridge: dccomms applications run unmodified against a simulated modem.

dccomms' `CommsDeviceService` (what an application gets from `SetCommsDeviceId("bluerov0-dev")`)
talks to the physical layer through two POSIX message queues::

    /<id>_tx_dlnk_phy   application -> PHY   (the bridge reads it)
    /<id>_rx_dlnk_phy   PHY -> application   (the bridge writes it)

Each message is one type byte then a body (dccomms_framing: FRAME 0 + a whole DataLinkFrame,
REQ_STATE 1, CMD_STATE 2 + BUSY 0 / READY 1); queues hold 10 messages of up to 7001 bytes.  The
bridge plays dccomms' PHY side (what UWSim-NET's simulator or `dccomms_s100_bridge` did): it clears
what is waiting when it starts and announces READY; every FRAME it reads goes to the modem (the
frame's dst, its payload; the source address is the modem's) and is answered READY, since the
simulated modem has its own FIFO; a REQ_STATE is answered with the state; every frame the modem
receives is written as a FRAME with a DataLinkFrame around it.  Frames that fail their CRC or cannot
be parsed are counted and skipped (and still answered READY so the application does not hang).

`GliQueueClient` is the application side, for tests and Python programs that want the dccomms wire.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections import Counter, deque
from typing import Any

from ..drivers import dccomms_framing as dl
from ..drivers._aio import LoopThread
from ..drivers.backend import BackendFrame, BackendStatus, ModemBackend, detach
from .posix_mq import MessageQueue

log = logging.getLogger("uwsimnet.bridges.mq")


class MqBridge:
    def __init__(self, backend: ModemBackend, dccomms_id: str | None = None, *, backlog: int = 1000,
                 msgsize: int = dl.GLI_MAX_FRAME + 1, maxmsg: int = dl.GLI_MAXMSG, unlink_on_close: bool = False,
                 clear_on_start: bool = True) -> None:
        self.backend = backend
        self.dccomms_id = dccomms_id or backend.id
        self.tx_name = dl.tx_queue_name(self.dccomms_id)
        self.rx_name = dl.rx_queue_name(self.dccomms_id)
        self.backlog = backlog
        self.msgsize = msgsize
        self.maxmsg = maxmsg
        self.unlink_on_close = unlink_on_close
        self.clear_on_start = clear_on_start
        self.counters: Counter[str] = Counter()
        self.state = dl.PHY_READY
        self._io = LoopThread(f"uwsimnet-mq-bridge-{self.dccomms_id}")
        self._txq: MessageQueue | None = None
        self._rxq: MessageQueue | None = None
        self._out: deque[bytes] = deque()
        self._writing = False

    # -- lifecycle ----------------------------------------------------------------------------------
    def start(self) -> None:
        self._txq = MessageQueue.open(self.tx_name, read=True, write=False, maxmsg=self.maxmsg,
                                      msgsize=self.msgsize, nonblock=True)
        self._rxq = MessageQueue.open(self.rx_name, read=False, write=True, maxmsg=self.maxmsg,
                                      msgsize=self.msgsize, nonblock=True)
        if self.clear_on_start:
            self.counters["cleared"] += self._txq.drain()
        self._io.start()
        self._io.submit(self._start)
        self.backend.on_frame.append(self._bk_frame)
        self.backend.on_status.append(self._bk_status)

    def _start(self) -> None:
        self._io.loop.add_reader(self._txq.fileno(), self._readable)
        self._queue_out(dl.gli_cmd_state(self.state))

    def close(self) -> None:
        detach(self.backend, self._bk_frame, self._bk_status)
        self._io.shutdown(self._stop)
        for q in (self._txq, self._rxq):
            if q is not None:
                q.close()
        self._txq = self._rxq = None
        if self.unlink_on_close:
            for name in (self.tx_name, self.rx_name):
                with contextlib.suppress(OSError):
                    MessageQueue.unlink(name)

    def _stop(self) -> None:
        loop = self._io.loop
        if self._txq is not None:
            loop.remove_reader(self._txq.fileno())
        if self._writing and self._rxq is not None:
            loop.remove_writer(self._rxq.fileno())
            self._writing = False

    def __enter__(self) -> MqBridge:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def info(self) -> dict[str, Any]:
        return {"id": self.dccomms_id, "tx_queue": self.tx_name, "rx_queue": self.rx_name,
                "backlog": len(self._out), "counters": dict(self.counters)}

    # -- application -> modem (loop thread) ----------------------------------------------------------
    def _readable(self) -> None:
        assert self._txq is not None
        for _ in range(64):                 # do not starve the loop if the application floods us
            try:
                msg = self._txq.receive(0)
            except OSError as e:
                self.counters["read_errors"] += 1
                log.warning("%s: %s", self.tx_name, e)
                return
            if msg is None:
                return
            self._message(msg)

    def _message(self, msg: bytes) -> None:
        try:
            m = dl.parse_gli(msg)
        except dl.FramingError as e:
            self.counters["bad_messages"] += 1
            log.info("%s: %s", self.tx_name, e)
            return
        if m.type == dl.MSG_REQ_STATE:
            self.counters["req_state"] += 1
            self._queue_out(dl.gli_cmd_state(self.state))
            return
        if m.type == dl.MSG_CMD_STATE:
            self.counters["unexpected_state"] += 1      # the application does not command the PHY
            return
        try:
            frame = dl.DataLinkFrame.decode(m.body)
        except dl.FramingError as e:
            self.counters["bad_frames"] += 1
            log.info("%s: frame refused: %s", self.tx_name, e)
        else:
            if frame.src != self.backend.address:
                self.counters["src_mismatch"] += 1
            self.counters["tx"] += 1
            self.backend.send(frame.dst, frame.payload, hint="dccomms")
        self._queue_out(dl.gli_cmd_state(dl.PHY_READY))

    # -- modem -> application -----------------------------------------------------------------------
    def _bk_frame(self, f: BackendFrame) -> None:
        if not (0 <= f.src <= 255 and 0 <= f.dst <= 255) or len(f.data) > dl.MAX_PAYLOAD:
            self.counters["rx_unrepresentable"] += 1
            return
        self._io.call(self._queue_out, dl.gli_frame(dl.encode_frame(f.dst, f.src, f.data)), True)

    def _bk_status(self, st: BackendStatus) -> None:
        self.counters[f"status_{st.event}"] += 1       # dccomms' GLI has no per-frame status to carry it

    def _queue_out(self, msg: bytes, is_frame: bool = False) -> None:
        if len(self._out) >= self.backlog:
            self.counters["rx_dropped_backlog"] += 1
            return
        if is_frame:
            self.counters["rx"] += 1
        self._out.append(msg)
        self._flush()

    def _flush(self) -> None:
        q = self._rxq
        if q is None:
            return
        while self._out:
            try:
                q.send(self._out[0])
            except BlockingIOError:
                break
            except OSError as e:
                self.counters["write_errors"] += 1
                log.warning("%s: %s (message dropped)", self.rx_name, e)
            self._out.popleft()
        loop = self._io.loop
        if self._out and not self._writing:
            loop.add_writer(q.fileno(), self._flush)
            self._writing = True
        elif not self._out and self._writing:
            loop.remove_writer(q.fileno())
            self._writing = False


class GliQueueClient:
    """The application side of the dccomms GLI queues (what `CommsDeviceService` does), blocking.

        with GliQueueClient("bluerov0-dev", address=1) as c:
            c.send(2, b"hello")
            frame = c.receive(timeout=5.0)        # a DataLinkFrame, or None
    """

    def __init__(self, dccomms_id: str, address: int = 0, *, msgsize: int = dl.GLI_MAX_FRAME + 1,
                 maxmsg: int = dl.GLI_MAXMSG) -> None:
        self.dccomms_id = dccomms_id
        self.address = address
        self.tx = MessageQueue.open(dl.tx_queue_name(dccomms_id), read=False, write=True, maxmsg=maxmsg,
                                    msgsize=msgsize)
        self.rx = MessageQueue.open(dl.rx_queue_name(dccomms_id), read=True, write=False, maxmsg=maxmsg,
                                    msgsize=msgsize)
        self.rx.drain()
        self.phy_state: int | None = None
        self.counters: Counter[str] = Counter()
        self.tx.send(dl.gli_req_state())

    def send(self, dst: int, payload: bytes) -> None:
        self.send_raw(dl.encode_frame(dst, self.address, payload))

    def send_raw(self, frame: bytes) -> None:
        """Put any bytes in a FRAME message (tests: a corrupted frame)."""
        self.phy_state = dl.PHY_BUSY
        self.tx.send(dl.gli_frame(frame))

    def receive(self, timeout: float = 5.0) -> dl.DataLinkFrame | None:
        """The next frame (state messages are absorbed on the way), or None after `timeout` s."""
        deadline = time.monotonic() + timeout
        while True:
            left = deadline - time.monotonic()
            msg = self.rx.receive(max(0.0, left))
            if msg is None:
                return None
            m = dl.parse_gli(msg)
            if m.type == dl.MSG_CMD_STATE:
                self.phy_state = m.state
                self.counters["states"] += 1
                continue
            if m.type == dl.MSG_FRAME:
                try:
                    return dl.DataLinkFrame.decode(m.body)
                except dl.FramingError:
                    self.counters["bad_frames"] += 1
                    continue

    def wait_ready(self, timeout: float = 5.0) -> bool:
        """Wait for CMD_STATE READY.  Frames that arrive meanwhile are discarded: call it before any
        traffic is expected (at start, as dccomms' Start() does)."""
        deadline = time.monotonic() + timeout
        while self.phy_state != dl.PHY_READY:
            left = deadline - time.monotonic()
            msg = self.rx.receive(max(0.0, left))
            if msg is None:
                return False
            m = dl.parse_gli(msg)
            if m.type == dl.MSG_CMD_STATE:
                self.phy_state = m.state
        return True

    def close(self) -> None:
        self.tx.close()
        self.rx.close()

    def __enter__(self) -> GliQueueClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
