"""`ServerClient.waiting` (drivers/_aio.py): what a server wrote to a peer and the peer has not taken, on real
loopback TCP.  The kernel's send queue (autotuned to megabytes) fills before asyncio's transport buffers a
byte, so a server that counted only the transport's buffer would not see a peer that does not read until
megabytes later, and the peer could stall first (the unet gateway's lazy-client test hung that way)."""

from __future__ import annotations

import asyncio
import fcntl
import socket
import struct
import sys
import termios

import pytest

from uwsimnet_zenoh.drivers._aio import ServerClient, TcpServer

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="SIOCOUTQ is Linux's")


class _Client(ServerClient):
    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.accept(transport, False)


def _unread(s: socket.socket) -> int:
    return struct.unpack("i", fcntl.ioctl(s.fileno(), termios.FIONREAD, b"\0\0\0\0"))[0]


def test_waiting_counts_the_kernels_queue_until_the_peer_reads() -> None:
    async def main() -> None:
        loop = asyncio.get_running_loop()
        clients: list[ServerClient] = []
        server = TcpServer(loop, lambda: _Client(clients), "127.0.0.1", 0)
        peer = socket.socket()
        peer.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)     # a peer that takes little and reads nothing
        peer.setblocking(False)
        try:
            await loop.sock_connect(peer, ("127.0.0.1", server.port))
            for _ in range(6000):
                if clients:
                    break
                await asyncio.sleep(0.01)
            c = clients[0]
            total = 3 << 20
            c.write(b"x" * total)
            for _ in range(6000):           # settled: every byte is either waiting or in the peer's socket
                if c.waiting() + _unread(peer) == total:
                    break
                await asyncio.sleep(0.01)
            assert c.waiting() + _unread(peer) == total
            assert c.waiting() > 1 << 20                     # most of it waits for the peer
            assert c.transport is not None and c.transport.get_write_buffer_size() < c.waiting()
            got = 0
            while got < total:                               # the peer reads: nothing waits any more
                got += len(await loop.sock_recv(peer, 1 << 16))
            for _ in range(6000):
                if c.waiting() == 0:
                    break
                await asyncio.sleep(0.01)
            assert c.waiting() == 0 and got == total
        finally:
            peer.close()
            for c in clients:
                c.close()
            server.close()
            await asyncio.sleep(0)

    asyncio.run(main())
