"""The socket bridge: a modem for applications that can open a TCP or UDP socket and nothing else.

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

import asyncio
import itertools
import logging
import math
import socket
import struct
import time
from collections import Counter
from dataclasses import dataclass
from typing import Any

from ..drivers._aio import LoopThread, ServerClient, TcpServer
from ..drivers.backend import BackendFrame, BackendStatus, ModemBackend, detach

log = logging.getLogger("uwsimnet.bridges.socket")

HELLO, TX, RX, STATUS, ERROR, SUBSCRIBE = 1, 2, 3, 4, 5, 6
EVENTS = ("queued", "sent", "dropped", "acked", "failed", "delivered", "lost")
MAX_DATA = 2048
MAX_BODY = 64 + MAX_DATA
NO_SEQ = 0xFFFFFFFF

_HELLO = struct.Struct(">BHH")
_TX = struct.Struct(">BHI")
_RX = struct.Struct(">BHHIdd")
_STATUS = struct.Struct(">BIBd")
_LEN = struct.Struct(">I")


class WireError(ValueError):
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


# -- the bridge ---------------------------------------------------------------------------------------
class SocketBridge:
    """Serve one modem on a TCP port and/or a UDP port (0 picks a free one; None disables)."""

    def __init__(self, backend: ModemBackend, host: str = "127.0.0.1", tcp_port: int | None = 0,
                 udp_port: int | None = None, *, max_udp_peers: int = 64) -> None:
        self.backend = backend
        self.host = host
        self.tcp_port = tcp_port
        self.udp_port = udp_port
        self.max_udp_peers = max_udp_peers
        self.counters: Counter[str] = Counter()
        self._io = LoopThread(f"uwsimnet-socket-bridge-{backend.id}")
        self._server: TcpServer | None = None
        self._udp: asyncio.DatagramTransport | None = None
        self._tcp_clients: list[_TcpClient] = []
        self._udp_peers: dict[tuple, None] = {}
        self._tokens = itertools.count(1)
        self._routes: dict[int, tuple[Any, int]] = {}      # backend tag -> (client or UDP addr, app tag)
        self.closing = False

    @property
    def max_payload(self) -> int:
        return int(self.backend.info().get("max_frame_bytes", MAX_DATA) or MAX_DATA)

    def start(self) -> SocketBridge:
        self._io.start()
        self._io.run(self._start())
        self.backend.on_frame.append(self._bk_frame)
        self.backend.on_status.append(self._bk_status)
        return self

    async def _start(self) -> None:
        loop = self._io.loop
        if self.tcp_port is not None:
            self._server = TcpServer(loop, lambda: _TcpClient(self), self.host, self.tcp_port)
            self.tcp_port = self._server.port
        if self.udp_port is not None:
            self._udp, _ = await loop.create_datagram_endpoint(lambda: _Udp(self),
                                                               local_addr=(self.host, self.udp_port))
            self.udp_port = self._udp.get_extra_info("sockname")[1]

    def close(self) -> None:
        detach(self.backend, self._bk_frame, self._bk_status)
        self._io.shutdown(self._close)

    async def _close(self) -> None:
        self.closing = True
        if self._server is not None:
            self._server.close()
        for c in list(self._tcp_clients):
            c.close()
        if self._udp is not None:
            self._udp.close()
        await asyncio.sleep(0.05)          # connections accepted just now close themselves (_TcpClient)

    def __enter__(self) -> SocketBridge:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def info(self) -> dict[str, Any]:
        return {"id": self.backend.id, "tcp_port": self.tcp_port, "udp_port": self.udp_port,
                "tcp_clients": len(self._tcp_clients), "udp_peers": len(self._udp_peers),
                "counters": dict(self.counters)}

    def hello(self) -> bytes:
        return encode_hello(self.backend.address, self.max_payload, self.backend.id)

    # -- from applications (loop thread) ------------------------------------------------------------
    def _tx(self, origin: Any, m: Tx) -> None:
        token = next(self._tokens)
        self._routes[token] = (origin, m.tag)
        while len(self._routes) > 100000:
            del self._routes[next(iter(self._routes))]
        self.counters["tx"] += 1
        self.backend.send(m.dst, m.data, tag=token)

    def _udp_message(self, dgram: bytes, addr: tuple) -> None:
        try:
            m = decode_datagram(dgram)
        except WireError as e:
            self.counters["bad_messages"] += 1
            self._sendto(encode_error(str(e)), addr)
            return
        if isinstance(m, Tx | Subscribe) and addr not in self._udp_peers:
            if len(self._udp_peers) >= self.max_udp_peers:
                self._sendto(encode_error("too many UDP peers"), addr)
                return
            self._udp_peers[addr] = None
            self._sendto(self.hello(), addr)
        if isinstance(m, Tx):
            self._tx(addr, m)
        elif not isinstance(m, Subscribe):
            self.counters["bad_messages"] += 1
            self._sendto(encode_error(f"unexpected {type(m).__name__} from an application"), addr)

    def _sendto(self, data: bytes, addr: tuple) -> None:
        if self._udp is not None:
            self._udp.sendto(data, addr)

    # -- from the modem (backend thread -> loop thread) -----------------------------------------------
    def _bk_frame(self, f: BackendFrame) -> None:
        self._io.call(self._rx, f)

    def _bk_status(self, st: BackendStatus) -> None:
        if isinstance(st.tag, int):
            self._io.call(self._status, st)

    def _rx(self, f: BackendFrame) -> None:
        self.counters["rx"] += 1
        msg = encode_rx(f.src, f.dst, f.data, f.seq if f.seq >= 0 else NO_SEQ, f.t_tx, f.t_rx)
        for c in list(self._tcp_clients):
            c.write(msg)
        for addr in self._udp_peers:
            self._sendto(msg, addr)

    def _status(self, st: BackendStatus) -> None:
        route = self._routes.get(st.tag)
        if route is None:
            return
        origin, tag = route
        t = st.t if (st.t is not None and math.isfinite(st.t)) else float("nan")
        msg = encode_status(tag, st.event, t, st.reason)
        self.counters[f"status_{st.event}"] += 1
        if isinstance(origin, _TcpClient):
            origin.write(msg)
        else:
            self._sendto(msg, origin)


class _TcpClient(ServerClient):
    def __init__(self, bridge: SocketBridge) -> None:
        super().__init__(bridge._tcp_clients)
        self.bridge = bridge
        self.decoder = StreamDecoder()

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        if self.accept(transport, self.bridge.closing):
            self.bridge.counters["tcp_connections"] += 1
            self.write(self.bridge.hello())

    def data_received(self, data: bytes) -> None:
        msgs, errs = self.decoder.feed(data)
        for m in msgs:
            if isinstance(m, Tx):
                self.bridge._tx(self, m)
            elif not isinstance(m, Subscribe):
                errs.append(f"unexpected {type(m).__name__} from an application")
        for e in errs:
            self.bridge.counters["bad_messages"] += 1
            self.write(encode_error(e))
        if self.decoder.broken:
            self.close()



class _Udp(asyncio.DatagramProtocol):
    def __init__(self, bridge: SocketBridge) -> None:
        self.bridge = bridge

    def datagram_received(self, data: bytes, addr: tuple) -> None:
        self.bridge._udp_message(data, addr)


# -- a blocking Python client ----------------------------------------------------------------------------
class SocketBridgeClient:
    """The application side over TCP (tests, scripts).

        c = SocketBridgeClient("127.0.0.1", port)      # reads HELLO: c.address, c.id
        c.send(2, b"hi", tag=7)
        c.receive(timeout=5)                            # Rx, or None; statuses collect in c.statuses
    """

    def __init__(self, host: str, port: int, timeout: float = 5.0) -> None:
        self.sock = socket.create_connection((host, port), timeout)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.decoder = StreamDecoder()
        self.pending: list[Message] = []
        self.statuses: list[Status] = []
        self.errors: list[str] = []
        first = self._next(timeout, Hello)
        if not isinstance(first, Hello):
            raise WireError("no HELLO from the bridge")
        self.address, self.max_payload, self.id = first.address, first.max_payload, first.id

    def send(self, dst: int, data: bytes, tag: int = 0) -> None:
        self.sock.sendall(encode_tx(dst, data, tag))

    def send_raw(self, data: bytes) -> None:
        self.sock.sendall(data)

    def receive(self, timeout: float = 5.0) -> Rx | None:
        m = self._next(timeout, Rx)
        return m if isinstance(m, Rx) else None

    def wait_status(self, tag: int, event: str, timeout: float = 5.0) -> Status | None:
        deadline = time.monotonic() + timeout
        while True:
            for s in self.statuses:
                if s.tag == tag and s.event == event:
                    return s
            left = deadline - time.monotonic()
            if left <= 0 or self._read(left) is False:
                return None

    def _next(self, timeout: float, want: type) -> Message | None:
        deadline = time.monotonic() + timeout
        while True:
            for i, m in enumerate(self.pending):
                if isinstance(m, want):
                    return self.pending.pop(i)
            left = deadline - time.monotonic()
            if left <= 0 or self._read(left) is False:
                return None

    def _read(self, timeout: float) -> bool:
        self.sock.settimeout(timeout)
        try:
            data = self.sock.recv(65536)
        except TimeoutError:
            return True
        if not data:
            return False
        msgs, errs = self.decoder.feed(data)
        self.errors.extend(errs)
        for m in msgs:
            if isinstance(m, Status):
                self.statuses.append(m)
            elif isinstance(m, Error):
                self.errors.append(m.text)
            else:
                self.pending.append(m)
        return True

    def close(self) -> None:
        self.sock.close()

    def __enter__(self) -> SocketBridgeClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
