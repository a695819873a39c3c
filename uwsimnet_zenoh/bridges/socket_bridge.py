"""The socket bridge: a modem for applications that can open a TCP or UDP socket and nothing else
(the messages are in socket_wire.py, a blocking client in socket_client.py; docs/bridges.md)."""

from __future__ import annotations

import asyncio
import itertools
import logging
import math
from collections import Counter
from typing import Any

from ..drivers._aio import LoopThread, ServerClient, TcpServer
from ..drivers.app_seq import app_seq
from ..drivers.backend import BackendFrame, BackendStatus, ModemBackend, detach
from .socket_wire import (
    MAX_DATA,
    NO_SEQ,
    StreamDecoder,
    Subscribe,
    Tx,
    WireError,
    decode_datagram,
    encode_error,
    encode_hello,
    encode_rx,
    encode_status,
)

log = logging.getLogger("uwsimnet.bridges.socket")



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
        seq = app_seq(f)                # the sending application's seq (an mq-bridge app's), else the modem's
        msg = encode_rx(f.src, f.dst, f.data, seq if seq is not None else f.seq if f.seq >= 0 else NO_SEQ,
                        f.t_tx, f.t_rx)
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
