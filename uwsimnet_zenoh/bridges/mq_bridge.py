"""The POSIX message-queue bridge: dccomms applications run unmodified against a simulated modem.

dccomms' `CommsDeviceService` (what an application gets from `SetCommsDeviceId("bluerov0-dev")`)
talks to the physical layer through two POSIX message queues::

    /<id>_tx_dlnk_phy   application -> PHY   (the bridge reads it)
    /<id>_rx_dlnk_phy   PHY -> application   (the bridge writes it)

As dccomms 0710d53 defines it (docs/bridges.md has the file:line of each fact): queues of 10 messages of up
to 8192 bytes, mode 0777, created by whichever side opens first; a message is one type byte then a body:
FRAME 0 + the whole packet buffer (the frame, padding to the packet builder's largest frame, then the
12-byte virtual area seq/src/dst, u32 little-endian), REQ_STATE 1, CMD_STATE 2 + BUSY 0 / READY 1.

The bridge plays dccomms' PHY side (what UWSim-NET's simulator, dccomms_ros' ROSCommsDevice, did).  It
reads and writes frames in the modem's framing (the scene's txPacketBuilder/rxPacketBuilder, which the
broker publishes in the modem's info; DataLinkFrame CRC16 when there is none, the original's default):

* app -> modem: a FRAME is parsed as dccomms does (`formats.dccomms`), checked like IsOk(), and handed to the
  modem for its destination (DataLinkFrame: the header's dst; other framings: the virtual area's).  It
  is answered READY, since the simulated modem has its own FIFO.  A message the bridge refuses (unknown
  type, a frame that fails its CRC or cannot be parsed, a payload the modem cannot carry) is logged as a
  WARNING with the reason and counted (`info()["refused"]`); it is still answered READY so that the
  application, which marked the PHY busy when it wrote, does not wait forever.
* modem -> app: every frame is written as a FRAME message in the receiving framing, with the virtual
  area filled as the original simulator did: seq = the sending application's (its virtual area's, carried as
  the wire's `aseq`; the modem's seq when the sender set none), src = the sender's address, dst.

`GliQueueClient` is the application side (what `CommsDeviceService` does), for tests and Python programs.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import time
from collections import Counter, deque
from dataclasses import dataclass
from typing import Any

from ..drivers._aio import LoopThread
from ..drivers.app_seq import AppSeq, app_seq
from ..drivers.backend import BackendFrame, BackendStatus, ModemBackend, detach
from ..formats import dccomms as fr
from .posix_mq import MessageQueue, MqError

log = logging.getLogger("uwsimnet.bridges.mq")

QUEUE_MODE = 0o777
"""dccomms creates its queues with permission 0777 under umask 0 (CommsDeviceService.cpp:64,111)."""
WARN_FIRST = 10
"""Refusals of one reason logged one by one; past that, every 100th (with the running count)."""


def _msgqueue_limit() -> str:
    try:
        import resource  # noqa: PLC0415 - only for the message

        return str(resource.getrlimit(resource.RLIMIT_MSGQUEUE)[0])
    except (ImportError, AttributeError, OSError, ValueError):
        return "?"


tx_queue_name, rx_queue_name = fr.tx_queue_name, fr.rx_queue_name


def _framing(value: fr.Framing | str | None, info: dict[str, Any], key: str) -> fr.Framing:
    if isinstance(value, fr.Framing):
        return value
    name = value or info.get(key) or info.get("tx_framing")
    return fr.builder(name) if isinstance(name, str) and name else fr.DEFAULT


class MqBridge:
    def __init__(self, backend: ModemBackend, dccomms_id: str | None = None, *,
                 framing: fr.Framing | str | None = None, rx_framing: fr.Framing | str | None = None,
                 backlog: int = 1000, msgsize: int = fr.GLI_MSGSIZE, maxmsg: int = fr.GLI_MAXMSG,
                 mode: int = QUEUE_MODE, unlink_on_close: bool = False, clear_on_start: bool = True) -> None:
        self.backend = backend
        self.dccomms_id = dccomms_id or backend.id
        self.tx_name = tx_queue_name(self.dccomms_id)
        self.rx_name = rx_queue_name(self.dccomms_id)
        info = backend.info() if hasattr(backend, "info") else {}
        info = info if isinstance(info, dict) else {}
        self.framing = _framing(framing, info, "tx_framing")
        """What the application writes (the device's txPacketBuilder)."""
        self.rx_framing = _framing(rx_framing if rx_framing is not None else framing, info, "rx_framing")
        """What the application reads (the device's rxPacketBuilder, else its txPacketBuilder)."""
        self.backlog = backlog
        self.msgsize = msgsize
        self.maxmsg = maxmsg
        self.mode = mode
        self.unlink_on_close = unlink_on_close
        self.clear_on_start = clear_on_start
        self.counters: Counter[str] = Counter()
        self.refused: Counter[str] = Counter()
        self.last_refusal: str | None = None
        self.state = fr.PHY_READY
        self._seq = 0
        self._io = LoopThread(f"uwsimnet-mq-bridge-{self.dccomms_id}")
        self._txq: MessageQueue | None = None
        self._rxq: MessageQueue | None = None
        self._out: deque[bytes] = deque()
        self._writing = False

    # -- lifecycle ----------------------------------------------------------------------------------
    def start(self) -> None:
        try:
            self._txq = MessageQueue.open(self.tx_name, read=True, write=False, maxmsg=self.maxmsg,
                                          msgsize=self.msgsize, mode=self.mode, nonblock=True)
            self._rxq = MessageQueue.open(self.rx_name, read=False, write=True, maxmsg=self.maxmsg,
                                          msgsize=self.msgsize, mode=self.mode, nonblock=True)
        except MqError as e:
            if self._txq is not None:
                self._txq.close()
                self._txq = None
            if e.errno == errno.EMFILE:   # Linux: also the per-user RLIMIT_MSGQUEUE byte budget
                raise MqError(e.errno, f"{e.strerror}: the user's message-queue budget (ulimit -q,"
                                       f" {_msgqueue_limit()} bytes) is used up or too many files are open;"
                                       f" each dccomms queue of {self.maxmsg} x {self.msgsize} bytes takes about"
                                       f" {self.maxmsg * (self.msgsize + 64)} bytes: raise ulimit -q or remove"
                                       " stale queues") from None
            raise
        for q, need in ((self._txq, self.framing.message_size), (self._rxq, self.rx_framing.message_size)):
            if q.msgsize < need:       # someone created the queue smaller: frames will not fit
                log.warning("%s: queue messages hold %d bytes, a FRAME message of %s is %d", q.name, q.msgsize,
                            self.framing.name if q is self._txq else self.rx_framing.name, need)
        if self.clear_on_start:
            self.counters["cleared"] += self._txq.drain()
        self._io.start()
        self._io.submit(self._start)
        self.backend.on_frame.append(self._bk_frame)
        self.backend.on_status.append(self._bk_status)

    def _start(self) -> None:
        self._io.loop.add_reader(self._txq.fileno(), self._readable)
        self._queue_out(fr.state_message(self.state))

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
                "framing": self.framing.name, "rx_framing": self.rx_framing.name,
                "message_size": self.framing.message_size, "backlog": len(self._out),
                "counters": dict(self.counters), "refused": dict(self.refused), "last_refusal": self.last_refusal}

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

    def _refuse(self, kind: str, reason: str) -> None:
        self.counters["refused"] += 1
        self.refused[kind] += 1
        n = self.refused[kind]
        self.last_refusal = reason
        if n <= WARN_FIRST or n % 100 == 0:
            more = f" ({n} so far)" if n > WARN_FIRST else ""
            log.warning("%s: message refused: %s%s", self.tx_name, reason, more)

    def _message(self, msg: bytes) -> None:
        if not msg:
            self._refuse("empty", "empty message")
            return
        kind = msg[0]
        if kind == fr.MSG_REQ_STATE:
            self.counters["req_state"] += 1
            self._queue_out(fr.state_message(self.state))
            return
        if kind == fr.MSG_CMD_STATE:
            self.counters["unexpected_state"] += 1      # the application does not command the PHY
            return
        if kind != fr.MSG_FRAME:
            self._refuse("type", f"unknown message type {kind} ({len(msg)} bytes)")
            return
        try:
            self._frame(msg)
        finally:
            self._queue_out(fr.state_message(fr.PHY_READY))

    def _frame(self, msg: bytes) -> None:
        f = self.framing
        try:
            m = fr.parse_frame_message(f, msg)
        except fr.FramingError as e:
            self._refuse("frame", f"{f.name}: {e} (message of {len(msg)} bytes)")
            return
        if m.packet.kind != "data":                     # DcMac rts/cts/sync: made by the MAC, not carried
            self._refuse("control", f"{f.name}: a {m.packet.kind} packet is DcMac's own control frame; run DcMac"
                                    " in the scene (its MAC) instead of in the application")
            return
        if m.va is None:
            self.counters["no_virtual_area"] += 1       # frame-only message: not dccomms' layout
        dst = m.dst
        if not 0 <= dst <= fr.MAX_ADDRESS:
            self._refuse("dst", f"destination {dst} is not an address (virtual area dst, {f.name})")
            return
        if m.packet.src is not None and m.packet.src != self.backend.address:
            self.counters["src_mismatch"] += 1
        self.counters["tx"] += 1
        # the application's own seq (its virtual area's; a frame-only SimplePacket: its frame's) goes along
        seq = m.va.seq if m.va is not None else m.packet.seq
        self.backend.send(dst, m.packet.payload, msg=None if seq is None else AppSeq(seq))  # type: ignore[arg-type]

    # -- modem -> application -----------------------------------------------------------------------
    def _bk_frame(self, f: BackendFrame) -> None:
        rf = self.rx_framing
        top = rf.max_address
        if (rf.addressed and not (0 <= f.src <= top and (0 <= f.dst <= top or f.dst == fr.BROADCAST))) \
                or rf.check_payload(len(f.data)) is not None:
            self.counters["rx_unrepresentable"] += 1
            return
        seq = app_seq(f)
        if seq is None:                 # an application that set none (on Zenoh): the modem's seq, else ours
            seq = f.seq if f.seq is not None and f.seq >= 0 else self._seq
        self._seq += 1
        msg = fr.frame_message(rf, rf.encode(f.data, dst=f.dst, src=f.src), fr.VirtualArea(seq, f.src, f.dst))
        self._io.call(self._queue_out, msg, True)

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


@dataclass(frozen=True)
class Received:
    """A frame an application read: payload, addresses (DataLinkFrame: its header; others: the virtual
    area), the virtual area's seq."""

    payload: bytes
    src: int
    dst: int
    seq: int
    packet: fr.Packet


class GliQueueClient:
    """The application side of the dccomms GLI queues (what `CommsDeviceService` does), blocking.

        with GliQueueClient("bluerov0-dev", address=1, framing="VariableLength2BPacketBuilder") as c:
            c.send(2, b"hello")
            frame = c.receive(timeout=5.0)        # a Received, or None

    As dccomms: queues created with 10 messages of 8192 bytes, mode 0777; REQ_STATE at start; every FRAME
    message is the whole packet buffer with the virtual area (seq, src = `address`, dst).  dccomms'
    ClearInputQueue reads with a 4000-byte buffer, which fails at once on 8192-byte queues, so, like it,
    the client does not clear what is waiting."""

    def __init__(self, dccomms_id: str, address: int = 0, *, framing: fr.Framing | str | None = None,
                 msgsize: int = fr.GLI_MSGSIZE, maxmsg: int = fr.GLI_MAXMSG) -> None:
        self.dccomms_id = dccomms_id
        self.address = address
        self.framing = _framing(framing, {}, "tx_framing")
        self.tx = MessageQueue.open(tx_queue_name(dccomms_id), read=False, write=True, maxmsg=maxmsg,
                                    msgsize=msgsize, mode=QUEUE_MODE)
        self.rx = MessageQueue.open(rx_queue_name(dccomms_id), read=True, write=False, maxmsg=maxmsg,
                                    msgsize=msgsize, mode=QUEUE_MODE)
        self.phy_state: int | None = fr.PHY_BUSY
        self.counters: Counter[str] = Counter()
        self._seq = 0
        self.tx.send(bytes((fr.MSG_REQ_STATE,)))

    def message(self, dst: int, payload: bytes, seq: int | None = None) -> bytes:
        """The FRAME message dccomms writes for `payload` to `dst`."""
        if seq is None:
            seq, self._seq = self._seq, self._seq + 1
        frame = self.framing.encode(payload, dst=dst if self.framing.addressed else fr.BROADCAST,
                                    src=self.address if self.framing.addressed else 0)
        return fr.frame_message(self.framing, frame, fr.VirtualArea(seq, self.address, dst))

    def send(self, dst: int, payload: bytes, seq: int | None = None) -> None:
        self.send_raw(self.message(dst, payload, seq))

    def send_raw(self, msg: bytes) -> None:
        """Put any bytes on the queue (tests: a corrupted frame); the PHY is marked BUSY, as dccomms does."""
        self.phy_state = fr.PHY_BUSY
        self.tx.send(msg)

    def receive(self, timeout: float = 5.0) -> Received | None:
        """The next valid frame (state messages are absorbed on the way), or None after `timeout` s."""
        deadline = time.monotonic() + timeout
        while True:
            left = deadline - time.monotonic()
            msg = self.rx.receive(max(0.0, left))
            if msg is None:
                return None
            if not msg:
                continue
            if msg[0] == fr.MSG_CMD_STATE and len(msg) == 2:
                self.phy_state = msg[1]
                self.counters["states"] += 1
                continue
            if msg[0] == fr.MSG_FRAME:
                try:
                    m = fr.parse_frame_message(self.framing, msg)
                except fr.FramingError:
                    self.counters["bad_frames"] += 1
                    continue
                va = m.va or fr.VirtualArea()
                p = m.packet
                return Received(p.payload, p.src if p.src is not None else va.src,
                                p.dst if p.dst is not None else va.dst, va.seq, p)

    def wait_ready(self, timeout: float = 5.0) -> bool:
        """Wait for CMD_STATE READY.  Frames that arrive meanwhile are discarded: call it before any
        traffic is expected (at start, as dccomms' Start() does)."""
        deadline = time.monotonic() + timeout
        while self.phy_state != fr.PHY_READY:
            left = deadline - time.monotonic()
            msg = self.rx.receive(max(0.0, left))
            if msg is None:
                return False
            if len(msg) == 2 and msg[0] == fr.MSG_CMD_STATE:
                self.phy_state = msg[1]
        return True

    def close(self) -> None:
        self.tx.close()
        self.rx.close()

    def __enter__(self) -> GliQueueClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
