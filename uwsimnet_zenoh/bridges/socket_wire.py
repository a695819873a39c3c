"""The socket bridge's wire, sans-IO: encoders, decoders and a stream decoder for the messages below.

Wire format (docs/bridges.md), all integers big-endian, identical on TCP and UDP::

    message = u32 length N | body (N bytes, N <= MAX_BODY)
    body    = u8 type | fields

    0x01 HELLO     bridge -> app   u16 address | u16 max_payload | id (UTF-8, rest)
    0x02 TX        app -> bridge   u16 dst | u32 tag | data (rest)
    0x03 RX        bridge -> app   u16 src | u16 dst | u32 seq | f64 t_tx | f64 t_rx | data (rest)
    0x04 STATUS    bridge -> app   u32 tag | u8 event | f64 t | reason (UTF-8, rest)
    0x05 ERROR     bridge -> app   text (UTF-8)
    0x06 SUBSCRIBE app -> bridge   (empty)

On TCP the bridge sends HELLO when the connection opens, RX for every frame the modem receives, and
STATUS for the frames this connection sent (tag 0 = the application gave none).  On UDP one datagram
is one message; a peer gets HELLO and starts receiving RX once it sent SUBSCRIBE or any TX.  Events:
0 queued, 1 sent, 2 dropped, 3 acked, 4 failed, 5 delivered, 6 lost.  Times are simulation seconds
(NaN if unknown); seq is 0xFFFFFFFF if unknown.  A malformed message is answered with ERROR; on TCP a
length above MAX_BODY cannot be resynchronised, so the bridge answers ERROR and closes.
"""


from __future__ import annotations

import struct
from dataclasses import dataclass

from ..errors import UwsimnetError

HELLO, TX, RX, STATUS, ERROR, SUBSCRIBE = 1, 2, 3, 4, 5, 6
EVENTS = ("queued", "sent", "dropped", "acked", "failed", "delivered", "lost", "transmitted")
MAX_DATA = 2048
MAX_BODY = 64 + MAX_DATA
NO_SEQ = 0xFFFFFFFF

_HELLO = struct.Struct(">BHH")
_TX = struct.Struct(">BHI")
_RX = struct.Struct(">BHHIdd")
_STATUS = struct.Struct(">BIBd")
_LEN = struct.Struct(">I")


class WireError(UwsimnetError, ValueError):
    pass


# -- sans-IO codec --------------------------------------------------------------------------------------
def _msg(body: bytes) -> bytes:
    return _LEN.pack(len(body)) + body


def encode_hello(address: int, max_payload: int, dev_id: str) -> bytes:
    return _msg(_HELLO.pack(HELLO, address, max_payload) + dev_id.encode())


def encode_tx(dst: int, data: bytes, tag: int = 0) -> bytes:
    return _msg(_TX.pack(TX, dst, tag) + bytes(data))


def encode_rx(src: int, dst: int, data: bytes, seq: int = NO_SEQ, t_tx: float | None = None,
              t_rx: float | None = None) -> bytes:
    nan = float("nan")
    return _msg(_RX.pack(RX, src, dst, seq & 0xFFFFFFFF, nan if t_tx is None else t_tx,
                         nan if t_rx is None else t_rx) + bytes(data))


def encode_status(tag: int, event: str, t: float, reason: str | None = None) -> bytes:
    return _msg(_STATUS.pack(STATUS, tag, EVENTS.index(event), t) + (reason or "").encode())


def encode_error(text: str) -> bytes:
    return _msg(bytes((ERROR,)) + text.encode())


def encode_subscribe() -> bytes:
    return _msg(bytes((SUBSCRIBE,)))


@dataclass(frozen=True)
class Hello:
    address: int
    max_payload: int
    id: str


@dataclass(frozen=True)
class Tx:
    dst: int
    tag: int
    data: bytes


@dataclass(frozen=True)
class Rx:
    src: int
    dst: int
    seq: int
    t_tx: float
    t_rx: float
    data: bytes


@dataclass(frozen=True)
class Status:
    tag: int
    event: str
    t: float
    reason: str


@dataclass(frozen=True)
class Error:
    text: str


@dataclass(frozen=True)
class Subscribe:
    pass


Message = Hello | Tx | Rx | Status | Error | Subscribe


def decode_body(body: bytes) -> Message:
    """One message body (after the length); WireError if it is not a valid message."""
    if not body:
        raise WireError("empty message")
    t = body[0]
    try:
        if t == HELLO:
            _, a, mp = _HELLO.unpack_from(body)
            return Hello(a, mp, body[_HELLO.size:].decode())
        if t == TX:
            _, dst, tag = _TX.unpack_from(body)
            data = body[_TX.size:]
            if len(data) > MAX_DATA:
                raise WireError(f"TX of {len(data)} bytes (max {MAX_DATA})")
            return Tx(dst, tag, data)
        if t == RX:
            _, s, d, seq, a, b = _RX.unpack_from(body)
            return Rx(s, d, seq, a, b, body[_RX.size:])
        if t == STATUS:
            _, tag, ev, tt = _STATUS.unpack_from(body)
            if ev >= len(EVENTS):
                raise WireError(f"unknown status event {ev}")
            return Status(tag, EVENTS[ev], tt, body[_STATUS.size:].decode())
        if t == ERROR:
            return Error(body[1:].decode(errors="replace"))
        if t == SUBSCRIBE:
            if len(body) != 1:
                raise WireError("SUBSCRIBE carries no fields")
            return Subscribe()
    except struct.error:
        raise WireError(f"message of type {t} too short ({len(body)} bytes)") from None
    except UnicodeDecodeError:
        raise WireError(f"message of type {t}: text is not UTF-8") from None
    raise WireError(f"unknown message type {t}")


class StreamDecoder:
    """Length-prefixed messages out of a byte stream.  `feed` returns (messages, errors); a fatal
    error (length above MAX_BODY: no way to find the next message) sets `broken`."""

    def __init__(self, max_body: int = MAX_BODY) -> None:
        self.max_body = max_body
        self._buf = bytearray()
        self.broken: str | None = None

    def feed(self, data: bytes) -> tuple[list[Message], list[str]]:
        msgs: list[Message] = []
        errs: list[str] = []
        if self.broken:
            return msgs, errs
        buf = self._buf
        buf += data
        while len(buf) >= 4:
            (n,) = _LEN.unpack_from(buf)
            if n > self.max_body or n == 0:
                self.broken = f"message length {n} out of range (1..{self.max_body})"
                errs.append(self.broken)
                buf.clear()
                break
            if len(buf) < 4 + n:
                break
            body = bytes(buf[4:4 + n])
            del buf[:4 + n]
            try:
                msgs.append(decode_body(body))
            except WireError as e:
                errs.append(str(e))
        return msgs, errs


def decode_datagram(dgram: bytes) -> Message:
    if len(dgram) < 4:
        raise WireError(f"datagram of {len(dgram)} bytes is shorter than the length prefix")
    (n,) = _LEN.unpack_from(dgram)
    if n != len(dgram) - 4:
        raise WireError(f"length prefix {n} but the datagram carries {len(dgram) - 4} bytes")
    if n > MAX_BODY:
        raise WireError(f"message of {n} bytes (max {MAX_BODY})")
    return decode_body(dgram[4:])
