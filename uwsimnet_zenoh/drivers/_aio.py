"""An asyncio event loop on a thread of its own, for the drivers, emulators and bridges.

Their public methods are plain blocking/thread-safe calls; underneath, every socket, pty and message
queue is served by one loop thread per object, so protocol cores (sans-IO) are driven from callbacks
that never race each other.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import errno
import logging
import os
import socket
import struct
import threading
from collections.abc import Callable, Coroutine
from typing import Any

from ..errors import UserError

try:
    import fcntl
    import termios
    _OUTQ: int | None = getattr(termios, "TIOCOUTQ", None)     # = SIOCOUTQ on a Linux TCP socket
except ImportError:                                             # Windows: the transport's buffer only
    _OUTQ = None

log = logging.getLogger("uwsimnet.drivers")


class LoopThread:
    def __init__(self, name: str) -> None:
        self.name = name
        self.loop = asyncio.new_event_loop()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        if self._thread is not None:
            return
        ready = threading.Event()

        def main() -> None:
            asyncio.set_event_loop(self.loop)
            self.loop.call_soon(ready.set)
            try:
                self.loop.run_forever()
            finally:
                with contextlib.suppress(Exception):
                    pending = asyncio.all_tasks(self.loop)
                    for t in pending:
                        t.cancel()
                    if pending:
                        self.loop.run_until_complete(asyncio.gather(*pending, return_exceptions=True))
                    # let closing transports run their connection_lost (which closes their sockets)
                    self.loop.run_until_complete(asyncio.sleep(0.01))
                self.loop.close()

        self._thread = threading.Thread(target=main, name=self.name, daemon=True)
        self._thread.start()
        ready.wait(5.0)

    @property
    def started(self) -> bool:
        return self._thread is not None

    @property
    def in_loop(self) -> bool:
        return self._thread is not None and threading.current_thread() is self._thread

    def call(self, fn: Callable[..., Any], *args: Any) -> None:
        """Run fn(*args) on the loop thread soon (thread-safe; a no-op once the loop is closed)."""
        if self.in_loop:
            self.loop.call_soon(fn, *args)
            return
        with contextlib.suppress(RuntimeError):      # loop closed: the object is shutting down
            self.loop.call_soon_threadsafe(fn, *args)

    def run(self, coro: Coroutine[Any, Any, Any], timeout: float | None = 10.0) -> Any:
        """Run a coroutine on the loop and wait for its result (from another thread)."""
        fut = asyncio.run_coroutine_threadsafe(coro, self.loop)
        try:
            return fut.result(timeout)
        except concurrent.futures.TimeoutError:
            fut.cancel()
            raise TimeoutError(f"{self.name}: no result in {timeout} s") from None

    def submit(self, fn: Callable[..., Any], *args: Any, timeout: float | None = 10.0) -> Any:
        """Run a plain function on the loop thread and wait for its result."""
        if self.in_loop:
            return fn(*args)

        async def wrap() -> Any:
            return fn(*args)
        return self.run(wrap(), timeout)

    def shutdown(self, closing: Callable[[], Any] | None = None, timeout: float = 5.0) -> None:
        """Run `closing` (a function or a coroutine function) on the loop, ignoring its errors and
        timeout (the object is going anyway), then stop the loop.  A loop never started is left alone."""
        if self._thread is None:
            return
        if closing is not None:
            with contextlib.suppress(Exception):
                if asyncio.iscoroutinefunction(closing):
                    self.run(closing(), timeout)
                else:
                    self.submit(closing, timeout=timeout)
        self.stop()

    def stop(self, timeout: float = 5.0) -> None:
        if self._thread is None:
            return
        with contextlib.suppress(RuntimeError):
            self.loop.call_soon_threadsafe(self.loop.stop)
        if not self.in_loop:
            self._thread.join(timeout)


class FdStream:
    """A non-blocking file descriptor (pty, tty) on a loop: reads go to `on_data`, writes are buffered.

    `on_lost(exc)` is called once when the fd reports EOF or an error (a pty whose other end closed
    gives EIO).  The fd is closed by `close()` only if `owns_fd`."""

    def __init__(self, loop: asyncio.AbstractEventLoop, fd: int, on_data: Callable[[bytes], None],
                 on_lost: Callable[[BaseException | None], None], owns_fd: bool = True,
                 read_size: int = 4096) -> None:
        self.loop = loop
        self.fd = fd
        self.on_data = on_data
        self.on_lost = on_lost
        self.owns_fd = owns_fd
        self.read_size = read_size
        self._out = bytearray()
        self._writing = False
        self.closed = False
        os.set_blocking(fd, False)
        loop.add_reader(fd, self._readable)

    def _readable(self) -> None:
        try:
            data = os.read(self.fd, self.read_size)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as e:
            self._lose(e)
            return
        if not data:
            self._lose(None)
            return
        self.on_data(data)

    def write(self, data: bytes) -> None:
        if self.closed:
            return
        self._out += data
        self._flush()

    def _flush(self) -> None:
        while self._out and not self.closed:
            try:
                n = os.write(self.fd, self._out)
            except (BlockingIOError, InterruptedError):
                break
            except OSError as e:
                self._lose(e)
                return
            del self._out[:n]
        if self._out and not self._writing and not self.closed:
            self.loop.add_writer(self.fd, self._flush)
            self._writing = True
        elif not self._out and self._writing:
            self.loop.remove_writer(self.fd)
            self._writing = False

    @property
    def backlog(self) -> int:
        return len(self._out)

    def _lose(self, exc: BaseException | None) -> None:
        if self.closed:
            return
        self.close()
        self.on_lost(exc)

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        with contextlib.suppress(Exception):
            self.loop.remove_reader(self.fd)
        if self._writing:
            with contextlib.suppress(Exception):
                self.loop.remove_writer(self.fd)
        if self.owns_fd:
            with contextlib.suppress(OSError):
                os.close(self.fd)


class ServerClient(asyncio.Protocol):
    """A TCP connection of a server that keeps its live connections in a list: `accept` admits it (or
    closes it when `refuse`), it leaves the list when it goes, and `write`/`close` are safe after that."""

    def __init__(self, clients: list[Any]) -> None:
        self.clients = clients
        self.transport: asyncio.Transport | None = None

    def accept(self, transport: asyncio.BaseTransport, refuse: bool) -> bool:
        self.transport = transport  # type: ignore[assignment]
        if refuse:
            transport.close()
            return False
        self.clients.append(self)
        return True

    def connection_lost(self, exc: Exception | None) -> None:
        if self in self.clients:
            self.clients.remove(self)

    def write(self, data: bytes) -> None:
        if self.transport is not None and not self.transport.is_closing():
            self.transport.write(data)

    def close(self) -> None:
        if self.transport is not None:
            self.transport.close()

    def waiting(self) -> int:
        """Bytes written to the peer and not yet taken by it: the transport's buffer and, where the OS says
        (Linux's SIOCOUTQ), the socket's send queue.  The kernel's queue alone grows to megabytes (send-buffer
        autotuning) before the transport buffers anything, so a peer that does not read is seen only with it."""
        t = self.transport
        if t is None:
            return 0
        n = t.get_write_buffer_size()
        sock = t.get_extra_info("socket")
        if sock is not None and _OUTQ is not None:
            with contextlib.suppress(OSError, ValueError):
                n += struct.unpack("i", fcntl.ioctl(sock.fileno(), _OUTQ, b"\0\0\0\0"))[0]
        return n


class TcpServer:
    """A listening TCP socket on a loop whose accepted connections go to `factory()` protocols.

    Unlike `loop.create_server`, closing it never loses a connection that was accepted but not yet
    handed to its protocol (Python 3.11 drops such a socket without closing it, so the peer never
    learns the server went away): every accepted socket becomes a transport, and a protocol that
    sees its owner closing closes it."""

    def __init__(self, loop: asyncio.AbstractEventLoop, factory: Callable[[], asyncio.Protocol], host: str,
                 port: int, backlog: int = 16) -> None:
        self.loop = loop
        self.factory = factory
        family, kind, proto, _, addr = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
        self.sock = socket.socket(family, kind, proto)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.bind(addr)
        self.sock.listen(backlog)
        self.sock.setblocking(False)
        self.port: int = self.sock.getsockname()[1]
        self.closed = False
        loop.add_reader(self.sock.fileno(), self._accept)

    def _accept(self) -> None:
        for _ in range(16):
            try:
                conn, _ = self.sock.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError as e:
                log.warning("accept: %s", e)
                return
            conn.setblocking(False)
            self.loop.create_task(self._adopt(conn))

    async def _adopt(self, conn: socket.socket) -> None:
        try:
            await self.loop.connect_accepted_socket(self.factory, sock=conn)
        except Exception:  # noqa: BLE001 - the connection is refused, the server goes on
            conn.close()

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        with contextlib.suppress(Exception):
            self.loop.remove_reader(self.sock.fileno())
        self.sock.close()


def listen_error(what: str, host: str, port: int, e: OSError) -> UserError:
    """One line for a port that cannot be served."""
    why = e.strerror or " ".join(str(e).split())
    hint = " (another emulator, bridge or modem server holds it? give another --port, 0 for a free one)" \
        if e.errno == errno.EADDRINUSE else ""
    return UserError(f"{what}: cannot listen on {host}:{port}: {why}{hint}")
