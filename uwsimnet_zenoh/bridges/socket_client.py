"""A blocking Python client of the socket bridge (tests and scripts; any language can write its own from
socket_wire.py's format)."""

from __future__ import annotations

import logging
import socket
import time

from .socket_wire import Error, Hello, Message, Rx, Status, StreamDecoder, WireError, encode_tx

log = logging.getLogger("uwsimnet.bridges.socket")



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
