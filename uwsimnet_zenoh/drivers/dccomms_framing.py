"""dccomms framing, sans-IO: the DataLinkFrame, its CRC, a resynchronising stream decoder, GLI messages.

The layout, as in dccomms (`include/dccomms/DataLinkFrame.h`, `src/DataLinkFrame.cpp`, CRC16 variant)::

    55 55 | dst u8 | src u8 | len u16 BE | payload (len <= 2048) | FCS u16 BE
    '----'  '-----------------------------------------------'    '------'
   preamble          covered by the CRC                          CRC16 XMODEM

CRC16 is XMODEM (polynomial 0x1021, initial value 0, no reflection, no final xor), computed over
dst..payload and stored big-endian; a frame is valid when the CRC over dst..FCS is 0.  dccomms'
stream reader waits for the preamble, then reads the fields, and refuses a length above 2048.

`FrameDecoder` does the same over a byte stream that may carry anything: bytes before a preamble are
reported as `Garbage`, an impossible length as `BadLength`, a failed CRC as `BadCrc`; in both error
cases it resumes the search one byte after the false preamble, so a frame that follows a corrupted or
truncated one is still found.  It never raises on input.

The GLI messages are what dccomms' `CommsDeviceService` exchanges over its POSIX message queues
(`/<id>_tx_dlnk_phy`, `/<id>_rx_dlnk_phy`): one type byte (FRAME 0, REQ_STATE 1, CMD_STATE 2) followed by
the whole packet buffer (frame, padding to the builder's maximum, 12-byte virtual area: see
`phy.framing.frame_message`) or by one state byte (BUSY 0, READY 1).  Every other dccomms framing, and the
CRC32 variant, is in `phy.framing`.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import UwsimnetError
from ..phy import framing as fr

PREAMBLE = b"\x55\x55"
HEADER_SIZE = 6                    # preamble + dst + src + len
FCS_SIZE = 2
OVERHEAD = HEADER_SIZE + FCS_SIZE
MAX_PAYLOAD = 2048
MAX_FRAME = OVERHEAD + MAX_PAYLOAD
BROADCAST = 255


def _table() -> tuple[int, ...]:
    out = []
    for i in range(256):
        c = i << 8
        for _ in range(8):
            c = ((c << 1) ^ 0x1021) if c & 0x8000 else (c << 1)
        out.append(c & 0xFFFF)
    return tuple(out)


_CRC_TABLE = _table()


def crc16_xmodem(data: bytes | bytearray | memoryview, crc: int = 0) -> int:
    """CRC-16/XMODEM of `data`, continuing from `crc` (check value: crc16_xmodem(b"123456789") == 0x31C3)."""
    t = _CRC_TABLE
    for b in data:
        crc = ((crc << 8) & 0xFF00) ^ t[(crc >> 8) ^ b]
    return crc


class FramingError(UwsimnetError, ValueError):
    """A buffer that is not one valid DataLinkFrame (strict decoding only; the stream decoder reports)."""


@dataclass(frozen=True)
class DataLinkFrame:
    dst: int
    src: int
    payload: bytes

    def encode(self) -> bytes:
        return encode_frame(self.dst, self.src, self.payload)

    @classmethod
    def decode(cls, buf: bytes | bytearray | memoryview) -> DataLinkFrame:
        """Exactly one frame, preamble included; FramingError otherwise."""
        b = bytes(buf)
        if len(b) < OVERHEAD:
            raise FramingError(f"{len(b)} bytes is shorter than an empty frame ({OVERHEAD})")
        if b[:2] != PREAMBLE:
            raise FramingError(f"no preamble (starts with {b[:2].hex()})")
        n = int.from_bytes(b[4:6], "big")
        if n > MAX_PAYLOAD:
            raise FramingError(f"payload length {n} exceeds {MAX_PAYLOAD}")
        if len(b) != OVERHEAD + n:
            raise FramingError(f"length field says {n} payload bytes, the buffer holds {len(b) - OVERHEAD}")
        if crc16_xmodem(b[2:]) != 0:
            raise FramingError("bad CRC")
        return cls(b[2], b[3], b[6:6 + n])


def encode_frame(dst: int, src: int, payload: bytes | bytearray | memoryview) -> bytes:
    """One DataLinkFrame (CRC16).  Addresses are one byte (255 is broadcast); payload <= 2048 bytes."""
    if not (0 <= dst <= 255 and 0 <= src <= 255):
        raise ValueError(f"dccomms addresses are one byte: dst={dst} src={src}")
    n = len(payload)
    if n > MAX_PAYLOAD:
        raise ValueError(f"payload of {n} bytes exceeds {MAX_PAYLOAD}")
    body = bytes((dst, src)) + n.to_bytes(2, "big") + bytes(payload)
    return PREAMBLE + body + crc16_xmodem(body).to_bytes(2, "big")


# -- stream decoding -----------------------------------------------------------------------------
@dataclass(frozen=True)
class FrameReceived:
    frame: DataLinkFrame
    raw: bytes


@dataclass(frozen=True)
class Garbage:
    """Bytes that are not part of any frame (before a preamble, or left at a timeout)."""

    data: bytes


@dataclass(frozen=True)
class BadLength:
    """A preamble followed by a length field above MAX_PAYLOAD (or below what the caller allows)."""

    length: int
    raw: bytes


@dataclass(frozen=True)
class BadCrc:
    dst: int
    src: int
    length: int
    raw: bytes


@dataclass(frozen=True)
class Truncated:
    """A frame started but its remaining bytes did not arrive in time (see `FrameDecoder.expire`)."""

    expected: int
    raw: bytes


FrameEvent = FrameReceived | Garbage | BadLength | BadCrc | Truncated


class FrameDecoder:
    """Feed bytes, get frames and error reports; resynchronises on the preamble after any error.

    `framing`: any dccomms framing (`phy.framing`; default DataLinkFrame CRC16).  Frames of framings
    without address fields come out with dst = broadcast and src = 0 (on a transparent radio every
    receiver gets them; the application filters).  `max_payload` may be lowered (a radio with a smaller
    MTU).  `stall_timeout` (s): a frame whose bytes stop arriving is reported as `Truncated` by
    `expire(now)` after that long, and the search resumes after its preamble, so a cut-off frame cannot
    hold back the frames that follow it.
    """

    def __init__(self, max_payload: int | None = None, stall_timeout: float = 2.0,
                 framing: fr.Framing | None = None) -> None:
        self.framing = framing or fr.DEFAULT
        self.max_payload = self.framing.max_payload if max_payload is None else max_payload
        self.stall_timeout = stall_timeout
        self._buf = bytearray()
        self._since: float | None = None     # when the current partial frame started waiting
        self.counters = {"frames": 0, "garbage_bytes": 0, "bad_crc": 0, "bad_length": 0, "truncated": 0}

    @property
    def pending(self) -> int:
        """Bytes held back waiting for the rest of a frame."""
        return len(self._buf)

    def feed(self, data: bytes | bytearray | memoryview, now: float | None = None) -> list[FrameEvent]:
        self._buf += data
        out: list[FrameEvent] = []
        self._scan(out)
        self._since = now if self._buf else None     # a stall is counted from the last byte
        return out

    def expire(self, now: float) -> list[FrameEvent]:
        """Report a partial frame that has waited more than `stall_timeout` (call it periodically)."""
        if not self._buf:
            return []
        if self._since is None:
            self._since = now
            return []
        if now - self._since < self.stall_timeout:
            return []
        buf = self._buf
        pre = self.framing.preamble
        out: list[FrameEvent] = []
        if buf[:len(pre)] == pre:
            total = self._total(bytes(buf)) if len(buf) >= self.framing.header_len else None
            expected = total if total is not None else self.framing.frame_size(0)
            self.counters["truncated"] += 1
            out.append(Truncated(expected, bytes(buf)))
            del buf[:1]
        elif len(buf) < len(pre) and pre.startswith(bytes(buf)):
            self.counters["garbage_bytes"] += len(buf)
            out.append(Garbage(bytes(buf)))
            buf.clear()
        self._scan(out)
        self._since = now if self._buf else None
        return out

    def _payload_len(self, total: int) -> int:
        return total - self.framing.frame_size(0) if not isinstance(self.framing, fr.SimplePacket) \
            else self.framing.n

    def _total(self, head: bytes) -> int | None:
        """The frame's length from its header, None if its length field is impossible here."""
        total = self.framing.frame_length(head)
        if total is None or self._payload_len(total) > self.max_payload:
            return None
        return total

    def _length_field(self, head: bytes) -> int:
        f = self.framing
        if isinstance(f, fr.DataLinkFrame):
            return int.from_bytes(head[4:6], "big")
        if isinstance(f, fr.VariableLength2BPacket):
            return int.from_bytes(head[1:3], "big")
        if isinstance(f, fr.VariableLengthPacket):
            return head[1]
        return self._payload_len(f.max_frame)

    def _valid_later(self, claimed: int) -> int:
        """Offset of a later preamble that starts a complete, CRC-valid frame inside the bytes held
        for an incomplete candidate of `claimed` bytes at 0; -1 if none (then the candidate waits)."""
        buf = self._buf
        pre = self.framing.preamble
        hl = self.framing.header_len
        k = buf.find(pre, 1)
        while 0 < k < claimed and k + hl <= len(buf):
            total = self._total(bytes(buf[k:k + hl]))
            if total is not None and k + total <= len(buf):
                try:
                    self.framing.parse(bytes(buf[k:k + total]))
                    return k
                except fr.FramingError:
                    pass
            k = buf.find(pre, k + 1)
        return -1

    def _scan(self, out: list[FrameEvent]) -> None:
        buf = self._buf
        f = self.framing
        pre = f.preamble
        hl = f.header_len
        while buf:
            i = buf.find(pre)
            if i < 0:
                # keep a trailing partial preamble: it may be the first part of the next one
                keep = 0
                for n in range(min(len(pre) - 1, len(buf)), 0, -1):
                    if pre.startswith(bytes(buf[-n:])):
                        keep = n
                        break
                if len(buf) > keep:
                    junk = bytes(buf[:len(buf) - keep])
                    self.counters["garbage_bytes"] += len(junk)
                    out.append(Garbage(junk))
                    del buf[:len(buf) - keep]
                return
            if i > 0:
                junk = bytes(buf[:i])
                self.counters["garbage_bytes"] += len(junk)
                out.append(Garbage(junk))
                del buf[:i]
            if len(buf) < hl:
                return
            head = bytes(buf[:hl])
            total = self._total(head)
            if total is None:
                self.counters["bad_length"] += 1
                out.append(BadLength(self._length_field(head), head))
                del buf[:1]
                continue
            if len(buf) < total:
                k = self._valid_later(total)
                if k > 0:                     # a false preamble: a whole valid frame starts later
                    junk = bytes(buf[:k])
                    self.counters["garbage_bytes"] += len(junk)
                    out.append(Garbage(junk))
                    del buf[:k]
                    continue
                return
            raw = bytes(buf[:total])
            try:
                p = f.parse(raw)
            except fr.FramingError:
                self.counters["bad_crc"] += 1
                n = self._payload_len(total)
                out.append(BadCrc(raw[2] if f.addressed else BROADCAST, raw[3] if f.addressed else 0, n, raw))
                del buf[:1]
                continue
            self.counters["frames"] += 1
            dst = p.dst if p.dst is not None else BROADCAST
            src = p.src if p.src is not None else 0
            out.append(FrameReceived(DataLinkFrame(dst, src, p.payload), raw))
            del buf[:total]


def encoder(framing: fr.Framing | None = None):
    """`encode(dst, src, payload) -> bytes` in `framing` (default DataLinkFrame CRC16)."""
    f = framing or fr.DEFAULT
    return lambda dst, src, payload: f.encode(payload, dst=dst, src=src)


# -- GLI messages (dccomms CommsDeviceService over POSIX message queues) -------------------------
# The FRAME message carries the whole packet buffer (frame, padding, virtual area): phy.framing.frame_message
# and parse_frame_message build and read it for every framing; here only the type byte and the states.
MSG_FRAME = 0
MSG_REQ_STATE = 1
MSG_CMD_STATE = 2
PHY_BUSY = 0
PHY_READY = 1
GLI_MAX_FRAME = 8191
"""dccomms' default `maxframesize` (CommsDeviceService.h:30); a queue message is at most this + 1 type byte."""
GLI_MAXMSG = 10


def tx_queue_name(dccomms_id: str) -> str:
    """The queue the application writes frames to (the PHY side reads it)."""
    return f"/{dccomms_id}_tx_dlnk_phy"


def rx_queue_name(dccomms_id: str) -> str:
    """The queue the application reads frames from (the PHY side writes it)."""
    return f"/{dccomms_id}_rx_dlnk_phy"


def gli_req_state() -> bytes:
    return bytes((MSG_REQ_STATE,))


def gli_cmd_state(state: int) -> bytes:
    return bytes((MSG_CMD_STATE, state))


@dataclass(frozen=True)
class GliMessage:
    type: int
    body: bytes

    @property
    def state(self) -> int | None:
        return self.body[0] if self.type == MSG_CMD_STATE and self.body else None


def parse_gli(msg: bytes | bytearray | memoryview) -> GliMessage:
    """Split a queue message into its type byte and body (FramingError if empty or of unknown type)."""
    b = bytes(msg)
    if not b:
        raise FramingError("empty GLI message")
    if b[0] not in (MSG_FRAME, MSG_REQ_STATE, MSG_CMD_STATE):
        raise FramingError(f"unknown GLI message type {b[0]}")
    if b[0] == MSG_CMD_STATE and len(b) != 2:
        raise FramingError(f"CMD_STATE message of {len(b)} bytes (expected 2)")
    return GliMessage(b[0], b[1:])
