"""POSIX message queues through ctypes (librt's mq_open / mq_send / mq_receive): no extra dependency.

Linux only (a message queue descriptor is a file descriptor there, so it can sit in a selector or an
asyncio loop: readable when a message waits, writable when there is room).

    q = MessageQueue.open("/demo", create=True, maxmsg=10, msgsize=7001)
    q.send(b"\\x00hello")
    q.receive(timeout=1.0)        # b'\\x00hello'
    q.close(); MessageQueue.unlink("/demo")
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno
import os
import select
import sys

from ..errors import UwsimnetError


class MqError(UwsimnetError, OSError):
    pass


class _Attr(ctypes.Structure):
    _fields_ = [("mq_flags", ctypes.c_long), ("mq_maxmsg", ctypes.c_long), ("mq_msgsize", ctypes.c_long),
                ("mq_curmsgs", ctypes.c_long), ("_pad", ctypes.c_long * 4)]


_lib: ctypes.CDLL | None = None


def _rt() -> ctypes.CDLL:
    global _lib
    if _lib is not None:
        return _lib
    if not sys.platform.startswith("linux"):
        raise MqError(errno.ENOSYS, "POSIX message queues through ctypes are supported on Linux only")
    name = ctypes.util.find_library("rt") or "librt.so.1"
    lib = ctypes.CDLL(name, use_errno=True)
    lib.mq_open.restype = ctypes.c_int
    lib.mq_open.argtypes = [ctypes.c_char_p, ctypes.c_int, ctypes.c_uint, ctypes.POINTER(_Attr)]
    lib.mq_close.argtypes = [ctypes.c_int]
    lib.mq_unlink.argtypes = [ctypes.c_char_p]
    lib.mq_send.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_size_t, ctypes.c_uint]
    lib.mq_receive.restype = ctypes.c_ssize_t
    lib.mq_receive.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_size_t, ctypes.POINTER(ctypes.c_uint)]
    lib.mq_getattr.argtypes = [ctypes.c_int, ctypes.POINTER(_Attr)]
    lib.mq_setattr.argtypes = [ctypes.c_int, ctypes.POINTER(_Attr), ctypes.POINTER(_Attr)]
    _lib = lib
    return lib


def available() -> bool:
    try:
        _rt()
    except OSError:
        return False
    return True


def _fail(what: str, name: str) -> MqError:
    e = ctypes.get_errno()
    return MqError(e, f"{what} {name}: {os.strerror(e)}")


class MessageQueue:
    """One open descriptor of a POSIX message queue (blocking unless `nonblock`)."""

    def __init__(self, fd: int, name: str) -> None:
        self.fd = fd
        self.name = name
        self.msgsize = self.getattr()["msgsize"]
        self._buf = ctypes.create_string_buffer(self.msgsize)

    @classmethod
    def open(cls, name: str, *, read: bool = True, write: bool = True, create: bool = True,
             maxmsg: int = 10, msgsize: int = 8192, mode: int = 0o666, nonblock: bool = False) -> MessageQueue:
        lib = _rt()
        flags = os.O_RDWR if (read and write) else (os.O_RDONLY if read else os.O_WRONLY)
        if create:
            flags |= os.O_CREAT
        if nonblock:
            flags |= os.O_NONBLOCK
        attr = _Attr(0, maxmsg, msgsize, 0)
        old = os.umask(0)
        try:
            fd = lib.mq_open(name.encode(), flags, mode, ctypes.byref(attr) if create else None)
        finally:
            os.umask(old)
        if fd < 0:
            raise _fail("mq_open", name)
        return cls(fd, name)

    @staticmethod
    def unlink(name: str) -> bool:
        """Remove a queue name; False if it did not exist."""
        if _rt().mq_unlink(name.encode()) < 0:
            if ctypes.get_errno() == errno.ENOENT:
                return False
            raise _fail("mq_unlink", name)
        return True

    def fileno(self) -> int:
        return self.fd

    def getattr(self) -> dict[str, int]:
        a = _Attr()
        if _rt().mq_getattr(self.fd, ctypes.byref(a)) < 0:
            raise _fail("mq_getattr", self.name)
        return {"flags": a.mq_flags, "maxmsg": a.mq_maxmsg, "msgsize": a.mq_msgsize, "curmsgs": a.mq_curmsgs}

    def set_nonblocking(self, on: bool) -> None:
        a = _Attr(os.O_NONBLOCK if on else 0, 0, 0, 0)
        if _rt().mq_setattr(self.fd, ctypes.byref(a), None) < 0:
            raise _fail("mq_setattr", self.name)

    def send(self, msg: bytes, priority: int = 0) -> None:
        """Send one message (BlockingIOError if the queue is full and the descriptor non-blocking)."""
        if len(msg) > self.msgsize:
            raise MqError(errno.EMSGSIZE, f"{self.name}: message of {len(msg)} bytes > msgsize {self.msgsize}")
        if _rt().mq_send(self.fd, msg, len(msg), priority) < 0:
            e = ctypes.get_errno()
            if e == errno.EAGAIN:
                raise BlockingIOError(e, f"{self.name}: queue full")
            raise _fail("mq_send", self.name)

    def receive(self, timeout: float | None = None) -> bytes | None:
        """One message; None if none came within `timeout` seconds (0: do not wait; None: wait forever)."""
        if timeout is not None:
            r, _, _ = select.select([self.fd], [], [], max(0.0, timeout))
            if not r:
                return None
        n = _rt().mq_receive(self.fd, self._buf, self.msgsize, None)
        if n < 0:
            e = ctypes.get_errno()
            if e in (errno.EAGAIN, errno.EINTR):
                return None
            raise _fail("mq_receive", self.name)
        return self._buf.raw[:n]

    def drain(self) -> int:
        """Throw away every message waiting (dccomms' ClearInputQueue); returns how many."""
        n = 0
        while self.receive(0) is not None:
            n += 1
        return n

    def close(self) -> None:
        if self.fd >= 0:
            _rt().mq_close(self.fd)
            self.fd = -1

    def __enter__(self) -> MessageQueue:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
