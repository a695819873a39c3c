"""The EvoLogics AT protocol's vocabulary: limits, the events a host sees, and small parsers shared by
both ends (host.py, device.py)."""

from __future__ import annotations

import re
from dataclasses import dataclass

IM_MAX = 64
"""Largest instant message (AT*SENDIM / AT*SENDPBM payload), bytes."""
BURST_MAX = 1024
"""Largest AT*SEND payload accepted per command by the emulator and the driver (unverified on hardware)."""
RECV_MAX = 4096
"""Largest RECV* length field the driver accepts before calling it garbage."""
BROADCAST = 255
MAX_LINE = 8192
"""A line longer than this without an end is garbage (the buffer is dropped)."""
MULTILINE = frozenset({"&V", "?S", "?P", "?ZSL"})
"""Commands whose answer is a block of lines ended by an empty line."""
IM_FLAGS = ("ack", "noack", "force")

# number of comma-separated fields between the keyword and the payload (length included)
_RECV_FIELDS = {"RECV": 8, "RECVIM": 8, "RECVIMS": 8, "RECVPBM": 7}
_RECV_HEAD = re.compile(rb"RECV(|IM|IMS|PBM),(p\d+,)?")
_SEND_HEAD = re.compile(rb"AT\*SEND(|IM|IMS|PBM),(p\d+,)?", re.IGNORECASE)
_SEND_FIELDS = {"*SEND": 2, "*SENDIM": 3, "*SENDIMS": 3, "*SENDPBM": 2}   # incl. length, before data
_ASYNC = ("RECVSTART", "RECVEND,", "RECVFAILED,", "RECVSRV,", "RECVPROBE,", "SENDSTART,", "SENDEND,",
          "BITRATE,", "RADDR,", "SRCLEVEL,", "PHYON", "PHYOFF", "USBL", "STATUS,", "DROPCNT,", "ECLK,", "RTO,",
          "DELIVERED", "FAILED", "CANCELED", "EXPIRED", "%")
"""Line prefixes that are asynchronous notifications, never the answer to a request (evins role_at.erl
answer_split: RECVPROBE, %<key>,<params> and the rest)."""
DEFERRED = "[*]"
"""Prefix of an answer whose setting applies once the acoustic link is idle (manual 1.7 section 5.1.3)."""
BES_HEAD = re.compile(rb"\+\+\+AT([^:\r\n]{0,32}):(\d{1,5}):")
"""A back escape sequence in data mode: +++AT<request>:<length>:<body>CRLF (manual 1.7 section 4.2.3)."""
_ASYNC_ERRORS = ("EFAULT", "OVERLOAD")
_CMD = re.compile(r"AT([?!@&*]?)([A-Z]+)(.*)", re.DOTALL)


# =================================================================================================
# Events (modem -> host)
# =================================================================================================
@dataclass(frozen=True)
class Ok:
    """`OK`: the pending request was accepted."""

    request: str | None


@dataclass(frozen=True)
class Reply:
    """Any other synchronous answer: a setting's value, a version string, a multi-line block."""

    request: str | None
    text: str


@dataclass(frozen=True)
class Busy:
    request: str | None
    reason: str


@dataclass(frozen=True)
class Error:
    """`ERROR <reason>` in answer to `request` (None: an asynchronous error such as EFAULT)."""

    request: str | None
    reason: str


@dataclass(frozen=True)
class Received:
    """A RECV, RECVIM, RECVIMS or RECVPBM notification.

    `kind`: burst | im | ims | pbm.  Units as on the wire: durations, timestamps and propagation times
    in microseconds, rssi in dB, velocity in m/s.  Fields a kind does not carry are None."""

    kind: str
    src: int
    dst: int
    data: bytes
    rssi: int | None = None
    integrity: int | None = None
    velocity: float | None = None
    bitrate: int | None = None
    duration_us: int | None = None
    prop_time_us: int | None = None
    timestamp_us: int | None = None
    flag: str | None = None
    pid: int | None = None


@dataclass(frozen=True)
class Delivered:
    """`DELIVERED,<count>,<dst>` (kind burst) or `DELIVEREDIM,<dst>` (kind im)."""

    kind: str
    dst: int
    count: int | None = None


@dataclass(frozen=True)
class Failed:
    kind: str
    dst: int
    count: int | None = None


@dataclass(frozen=True)
class Canceled:
    kind: str            # im | ims | pbm
    dst: int


@dataclass(frozen=True)
class Expired:
    kind: str            # ims
    dst: int


@dataclass(frozen=True)
class Notification:
    """Any other asynchronous line: `name` (SENDSTART, RECVEND, BITRATE, PHYOFF, USBLLONG, ...) and its
    comma-separated `fields` as text."""

    name: str
    fields: tuple[str, ...] = ()


@dataclass(frozen=True)
class Data:
    """Burst data the modem passed through in data mode: the bytes outside any `+++AT` framing."""

    data: bytes


@dataclass(frozen=True)
class ProtocolError:
    """Output that breaks the protocol; the parser has skipped it.

    `kind`: garbage (a line nothing expects), format (a known line with bad fields), length (binary data
    not followed by the end of line where the length field says), overflow (no end of line in
    MAX_LINE bytes), unexpected (an answer when no request waits, or the wrong kind of answer),
    timeout (no answer in time, or binary data that stopped arriving)."""

    kind: str
    detail: str
    raw: bytes = b""
    request: str | None = None
    """For a timeout: the request that got no answer (it is no longer pending)."""


DriverEvent = Ok | Reply | Busy | Error | Received | Delivered | Failed | Canceled | Expired | Notification \
    | Data | ProtocolError


def _int(s: bytes | str) -> int:
    s = s.decode("ascii") if isinstance(s, bytes | bytearray) else s
    s = s.strip()
    if not re.fullmatch(r"[+-]?\d+", s):
        raise ValueError(f"not an integer: {s!r}")
    return int(s)


def _intish(s: bytes | str) -> int:
    """An integer field some firmwares print with decimals (rssi): rounded."""
    return int(round(_float(s)))


def _float(s: bytes | str) -> float:
    s = s.decode("ascii") if isinstance(s, bytes | bytearray) else s
    v = float(s)
    if v != v or v in (float("inf"), float("-inf")):
        raise ValueError(f"not a finite number: {s!r}")
    return v


def _show(b: bytes, n: int = 60) -> str:
    r = repr(bytes(b[:n]))
    return r + ("..." if len(b) > n else "")


def request_name(command: str) -> str:
    """The request an `AT...` command line waits on: `AT?AL` -> `?AL`, `AT!L3` -> `!L`, `ATZ1` -> `Z`,
    `AT*SENDIM,...` -> `*SENDIM`."""
    c = command.strip()
    if c[:2].upper() == "AT":
        c = c[2:]
    if c.startswith("*"):
        return c.split(",", 1)[0].upper()
    m = re.match(r"([?!@&]?)([A-Za-z]+)", c)
    return (m.group(1) + m.group(2).upper()) if m else c.upper()


def _expects_ok(request: str) -> bool:
    """Setters, sends, resets: answered OK (or ERROR/BUSY).  Queries (`?X`, `I`) answer a value."""
    return not (request.startswith("?") or request in ("&V", "I"))
