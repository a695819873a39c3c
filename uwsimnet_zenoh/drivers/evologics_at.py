"""The EvoLogics S2C AT command protocol, sans-IO, for both ends of the wire.

`DriverCodec` is the host side (what a driver speaks): it builds commands and turns the modem's
output into events.  `DeviceCodec` is the modem side (what the emulator speaks): it turns a host's
bytes into commands and builds the modem's replies and notifications.  Neither does I/O nor reads a
clock; times are handed in (`now`) where a timeout matters.  Bad input never raises: it becomes a
`ProtocolError` event and the parser resynchronises on the next line.

Wire format (command mode), from the public drivers of the device (EvoLogics `evins` role_at.erl and
`dmac` parser.h, LSTS DUNE Transports/Evologics, DESERT uwinterpreters2c / evologics-drivers):

* host -> modem: `AT<command>` ended by `\\n` on Ethernet (`\\r` on serial); `AT*SEND...` carry binary
  data after the last comma, exactly `<length>` bytes, then the end of line.
* modem -> host: lines ended by `\\r\\n`.  A command gets one synchronous answer (`OK`, a value, a
  multi-line block ended by an empty line for `&V ?S ?P ?ZSL`, or `ERROR <reason>` / `BUSY <reason>`);
  asynchronous notifications may come at any time, between or before answers:

    RECV,<len>,<src>,<dst>,<bitrate>,<rssi>,<integrity>,<ptime us>,<velocity>,<data>
    RECVIM,<len>,<src>,<dst>,ack|noack|force,<duration us>,<rssi>,<integrity>,<velocity>,<data>
    RECVIMS,<len>,<src>,<dst>,<timestamp us>,<duration us>,<rssi>,<integrity>,<velocity>,<data>
    RECVPBM,<len>,<src>,<dst>,<duration us>,<rssi>,<integrity>,<velocity>,<data>
    DELIVERED,<count>,<dst>  FAILED,<count>,<dst>  DELIVEREDIM,<dst>  FAILEDIM,<dst>
    CANCELEDIM,<dst> CANCELEDIMS,<dst> CANCELEDPBM,<dst>  EXPIREDIMS,<dst>
    SENDSTART,<addr>,<type>,<duration>,<delay>  SENDEND,<addr>,<type>,<timestamp>,<duration>
    RECVSTART  RECVEND,<timestamp>,<duration>,<rssi>,<integrity>  RECVFAILED,<velocity>,<rssi>,<integrity>
    BITRATE,<local|remote>,<value>  SRCLEVEL,<n>  RADDR,<addr>  PHYON  PHYOFF  USBLLONG,...  USBLANGLES,...
    ERROR EFAULT / ERROR OVERLOAD (asynchronous errors)

  `RECV*` payloads are binary and may contain `\\r\\n`: the length field says how many bytes follow
  the header, then `\\r\\n` must follow.  The extended form `RECV*,p<pid>,<len>,...` and
  `AT*SEND*,p<pid>,<len>,...` (network protocol id) is accepted on both sides.
"""

from __future__ import annotations

import re
from collections import deque
from dataclasses import dataclass, field

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
_ASYNC = ("RECVSTART", "RECVEND,", "RECVFAILED,", "RECVSRV,", "SENDSTART,", "SENDEND,", "BITRATE,", "RADDR,",
          "SRCLEVEL,", "PHYON", "PHYOFF", "USBL", "STATUS,", "DROPCNT,", "ECLK,", "RTO,", "DELIVERED",
          "FAILED", "CANCELED", "EXPIRED")
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
    | ProtocolError


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


# =================================================================================================
# Host side
# =================================================================================================
@dataclass
class _Pending:
    request: str
    since: float | None
    lines: list[str] = field(default_factory=list)


class DriverCodec:
    """The host end of an S2C link.

    Build commands with `im()`, `burst()`, `pbm()`, `command()`; each registers a pending request so
    that its answer comes back as `Ok`/`Reply`/`Busy`/`Error` with that request's name.  Hand every
    byte the modem sends to `feed()`; call `expire(now)` now and then so that a missing answer or a
    binary payload that stopped arriving becomes a `ProtocolError('timeout')` instead of a hang.

    `eol`: `\\n` for TCP, `\\r` for a serial line.  `reply_timeout`: seconds an answer may take.
    `payload_timeout`: seconds the rest of a RECV payload may take once its header arrived.
    """

    def __init__(self, eol: str = "\n", reply_timeout: float = 5.0, payload_timeout: float = 2.0) -> None:
        self.eol = eol.encode()
        self.reply_timeout = reply_timeout
        self.payload_timeout = payload_timeout
        self._buf = bytearray()
        self._pending: deque[_Pending] = deque()
        self._partial_since: float | None = None
        self._head_end = 0           # where the data of a RECV waiting for its bytes starts
        self.counters: dict[str, int] = {"commands": 0, "lines": 0, "received": 0, "errors": 0}

    # -- building commands ----------------------------------------------------------------------
    @property
    def waiting(self) -> tuple[str, ...]:
        """Requests sent and not answered yet, oldest first."""
        return tuple(p.request for p in self._pending)

    def command(self, cmd: str, now: float | None = None) -> bytes:
        """Any AT command, e.g. `?AL`, `!L3`, `@ZX1`, `&V`, `Z1` (with or without the leading `AT`)."""
        c = cmd.strip()
        if c[:2].upper() != "AT":
            c = "AT" + c
        self._push(request_name(c), now)
        return c.encode("ascii") + self.eol

    def im(self, dst: int, data: bytes, flag: str = "ack", now: float | None = None,
           pid: int | None = None) -> bytes:
        """`AT*SENDIM,<len>,<dst>,<flag>,<data>` (flag ack | noack | force)."""
        if flag not in IM_FLAGS:
            raise ValueError(f"flag must be one of {IM_FLAGS}, got {flag!r}")
        return self._send("*SENDIM", f"{dst},{flag},", data, IM_MAX, now, pid)

    def burst(self, dst: int, data: bytes, now: float | None = None, pid: int | None = None) -> bytes:
        """`AT*SEND,<len>,<dst>,<data>`: burst data (acoustic connection, DELIVERED/FAILED reports)."""
        return self._send("*SEND", f"{dst},", data, BURST_MAX, now, pid)

    def pbm(self, dst: int, data: bytes, now: float | None = None, pid: int | None = None) -> bytes:
        """`AT*SENDPBM,<len>,<dst>,<data>`: piggy-back message."""
        return self._send("*SENDPBM", f"{dst},", data, IM_MAX, now, pid)

    def _send(self, req: str, mid: str, data: bytes, limit: int, now: float | None, pid: int | None) -> bytes:
        data = bytes(data)
        if len(data) > limit:
            raise ValueError(f"AT{req} carries at most {limit} bytes, got {len(data)}")
        self._push(req, now)
        p = f"p{pid}," if pid is not None else ""
        return f"AT{req},{p}{len(data)},{mid}".encode("ascii") + data + self.eol

    def expect(self, request: str, now: float | None = None) -> None:
        """Register a request written by other means (e.g. a transcript), so its answer pairs with it."""
        self._push(request, now)

    def _push(self, req: str, now: float | None) -> None:
        self.counters["commands"] += 1
        self._pending.append(_Pending(req, now))

    def forget(self) -> list[str]:
        """Drop every pending request and buffered byte (after a reconnect); returns the requests."""
        lost = [p.request for p in self._pending]
        self._pending.clear()
        self._buf.clear()
        self._partial_since = None
        self._head_end = 0
        return lost

    # -- parsing the modem's output ---------------------------------------------------------------
    def feed(self, data: bytes | bytearray | memoryview, now: float | None = None) -> list[DriverEvent]:
        self._buf += data
        out: list[DriverEvent] = []
        self._parse(out)
        self._partial_since = now if self._buf else None     # a stall is counted from the last byte
        return out

    def expire(self, now: float) -> list[DriverEvent]:
        out: list[DriverEvent] = []
        if self._pending:
            p = self._pending[0]
            if p.since is None:
                p.since = now
            elif now - p.since > self.reply_timeout:
                self._pending.popleft()
                self._err(out, "timeout", f"no answer to AT{p.request} in {self.reply_timeout:g} s",
                          request=p.request)
                if self._pending:
                    self._pending[0].since = now
        if self._buf:
            if self._partial_since is None:
                self._partial_since = now
            elif now - self._partial_since > self.payload_timeout:
                raw = self._skip_line(self._head_end)
                self._head_end = 0
                self._err(out, "timeout", f"incomplete output dropped after {self.payload_timeout:g} s: "
                          f"{_show(raw)}", raw)
                self._parse(out)
                self._partial_since = now if self._buf else None
        return out

    def _err(self, out: list[DriverEvent], kind: str, detail: str, raw: bytes = b"",
             request: str | None = None) -> None:
        self.counters["errors"] += 1
        out.append(ProtocolError(kind, detail, raw, request))

    def _skip_line(self, start: int = 0) -> bytes:
        """Drop the buffer up to and including the first CRLF at or after `start` (all if none)."""
        buf = self._buf
        j = buf.find(b"\r\n", start)
        end = len(buf) if j < 0 else j + 2
        raw = bytes(buf[:end])
        del buf[:end]
        return raw

    def _parse(self, out: list[DriverEvent]) -> None:
        buf = self._buf
        while buf:
            m = _RECV_HEAD.match(buf)
            if m is not None:
                if not self._recv(m, out):
                    return
                continue
            i = buf.find(b"\r\n")
            if i < 0:
                if len(buf) > MAX_LINE:
                    raw = bytes(buf)
                    buf.clear()
                    self._err(out, "overflow", f"{len(raw)} bytes without an end of line", raw)
                return
            raw = bytes(buf[:i])
            del buf[:i + 2]
            self.counters["lines"] += 1
            self._line(raw, out)

    def _recv(self, m: re.Match, out: list[DriverEvent]) -> bool:
        """A RECV* header at the start of the buffer; False means wait for more bytes."""
        buf = self._buf
        kind_kw = "RECV" + m.group(1).decode()
        nfields = _RECV_FIELDS[kind_kw]
        pos = m.end()
        commas = []
        j = pos
        while len(commas) < nfields:
            k = buf.find(b",", j)
            e = buf.find(b"\r\n", j)
            if k < 0 or (0 <= e < k):
                if e >= 0 or len(buf) - pos > 256:
                    raw = self._skip_line()
                    self._err(out, "format", f"{kind_kw} header with too few fields: {_show(raw)}", raw)
                    return True
                return False
            commas.append(k)
            j = k + 1
        fields = [bytes(buf[a:b]) for a, b in zip([pos] + [c + 1 for c in commas[:-1]], commas, strict=True)]
        head_end = commas[-1] + 1
        try:
            rec = self._recv_fields(kind_kw, fields, m.group(2))
        except (ValueError, UnicodeDecodeError) as e:
            raw = self._skip_line()
            self._err(out, "format", f"{kind_kw}: {e}: {_show(raw)}", raw)
            return True
        n = rec.pop("length")
        if not 0 <= n <= RECV_MAX:
            raw = self._skip_line()
            self._err(out, "length", f"{kind_kw} length field {n} out of range: {_show(raw)}", raw)
            return True
        if len(buf) < head_end + n + 2:
            self._head_end = head_end
            return False
        self._head_end = 0
        if buf[head_end + n:head_end + n + 2] != b"\r\n":
            raw = self._skip_line(head_end)
            self._err(out, "length", f"{kind_kw}: {n} bytes of data are not followed by CRLF "
                      f"(wrong length field): {_show(raw)}", raw)
            return True
        data = bytes(buf[head_end:head_end + n])
        del buf[:head_end + n + 2]
        self.counters["received"] += 1
        out.append(Received(data=data, **rec))
        return True

    @staticmethod
    def _recv_fields(kw: str, f: list[bytes], pid: bytes | None) -> dict:
        rec: dict = {"length": _int(f[0]), "src": _int(f[1]), "dst": _int(f[2])}
        if pid:
            rec["pid"] = int(pid[1:-1])
        if kw == "RECV":
            rec.update(kind="burst", bitrate=_int(f[3]), rssi=_intish(f[4]), integrity=_int(f[5]),
                       prop_time_us=_int(f[6]), velocity=_float(f[7]))
        elif kw == "RECVIM":
            flag = f[3].decode("ascii")
            if flag not in IM_FLAGS:
                raise ValueError(f"unknown flag {flag!r}")
            rec.update(kind="im", flag=flag, duration_us=_int(f[4]), rssi=_intish(f[5]), integrity=_int(f[6]),
                       velocity=_float(f[7]))
        elif kw == "RECVIMS":
            rec.update(kind="ims", timestamp_us=_int(f[3]), duration_us=_int(f[4]), rssi=_intish(f[5]),
                       integrity=_int(f[6]), velocity=_float(f[7]))
        else:
            rec.update(kind="pbm", duration_us=_int(f[3]), rssi=_intish(f[4]), integrity=_int(f[5]),
                       velocity=_float(f[6]))
        return rec

    def _line(self, raw: bytes, out: list[DriverEvent]) -> None:
        try:
            text = raw.decode("ascii")
        except UnicodeDecodeError:
            self._err(out, "garbage", f"non-ASCII line {_show(raw)}", raw)
            return
        if text == "":
            p = self._pending[0] if self._pending else None
            if p is not None and p.request in MULTILINE and p.lines:
                self._pending.popleft()
                out.append(Reply(p.request, "\n".join(p.lines)))
            return
        if not text.isprintable():
            self._err(out, "garbage", f"unprintable line {_show(raw)}", raw)
            return
        if text.startswith(_ASYNC):
            self._async(text, raw, out)
            return
        for word, cls in (("ERROR ", Error), ("BUSY ", Busy)):
            if text.startswith(word):
                reason = text[len(word):]
                if cls is Error and reason in _ASYNC_ERRORS:
                    out.append(Error(None, reason))
                    return
                req = self._pending.popleft().request if self._pending else None
                out.append(cls(req, reason))
                return
        if not self._pending:
            self._err(out, "unexpected", f"answer with no request waiting: {text!r}", raw)
            return
        p = self._pending[0]
        if p.request in MULTILINE:
            p.lines.append(text)
            return
        if _expects_ok(p.request):
            if text == "OK":
                self._pending.popleft()
                out.append(Ok(p.request))
            else:
                self._err(out, "unexpected", f"AT{p.request} expects OK, got {text!r}", raw)
            return
        self._pending.popleft()
        out.append(Ok(p.request) if text == "OK" else Reply(p.request, text))

    def _async(self, text: str, raw: bytes, out: list[DriverEvent]) -> None:
        try:
            for kw, cls in (("DELIVERED", Delivered), ("FAILED", Failed)):
                if text.startswith(kw):
                    rest = text[len(kw):].split(",")
                    if rest[0] == "" and len(rest) == 3:
                        out.append(cls("burst", _int(rest[2]), _int(rest[1])))
                    elif rest[0] == "IM" and len(rest) == 2:
                        out.append(cls("im", _int(rest[1])))
                    else:
                        raise ValueError("expected ,<count>,<dst> or IM,<dst>")
                    return
            for kw, cls in (("CANCELED", Canceled), ("EXPIRED", Expired)):
                if text.startswith(kw):
                    rest = text[len(kw):].split(",")
                    if len(rest) != 2 or rest[0] not in ("IM", "IMS", "PBM"):
                        raise ValueError("expected IM|IMS|PBM,<dst>")
                    out.append(cls(rest[0].lower(), _int(rest[1])))
                    return
        except ValueError as e:
            self._err(out, "format", f"{text!r}: {e}", raw)
            return
        name, _, rest = text.partition(",")
        out.append(Notification(name, tuple(rest.split(",")) if rest else ()))


# =================================================================================================
# Modem side
# =================================================================================================
@dataclass(frozen=True)
class Command:
    """A plain AT command: `AT<prefix><name><arg>`, e.g. `AT?AL` -> ('?AL', ''), `AT!L3` -> ('!L', '3'),
    `ATZ1` -> ('Z', '1'), `AT@ZX1` -> ('@ZX', '1')."""

    name: str
    arg: str
    raw: bytes


@dataclass(frozen=True)
class SendCommand:
    """`AT*SEND`, `AT*SENDIM`, `AT*SENDIMS` or `AT*SENDPBM` with its binary payload."""

    name: str                # *SEND | *SENDIM | *SENDIMS | *SENDPBM
    dst: int
    data: bytes
    flag: str | None = None  # *SENDIM: ack | noack | force
    timestamp_us: int | None = None
    pid: int | None = None


@dataclass(frozen=True)
class BadCommand:
    """Input the modem cannot take; `reply` is the line a device answers with."""

    kind: str            # garbage | format | length | overflow | timeout
    detail: str
    raw: bytes
    reply: str = "ERROR WRONG FORMAT"


DeviceEvent = Command | SendCommand | BadCommand
_EOL = (b"\r", b"\n")


class DeviceCodec:
    """The modem end: parse host commands (binary payloads included), build answers and notifications.

    A command ends at `\\r`, `\\n` or `\\r\\n`.  For `AT*SEND*` the length field decides how many bytes
    of data follow (they may contain end-of-line bytes); the end of line must follow them, otherwise
    the command is refused (`BadCommand('length')`) and the parser resumes after the first end of
    line that follows the data's start.  `expire(now)` refuses a command whose data stopped coming.
    """

    def __init__(self, payload_timeout: float = 2.0, max_data: int = BURST_MAX) -> None:
        self.payload_timeout = payload_timeout
        self.max_data = max_data
        self._buf = bytearray()
        self._partial_since: float | None = None
        self._skip_lf = False
        self._head_end = 0           # where the data of a *SEND waiting for its bytes starts

    def feed(self, data: bytes | bytearray | memoryview, now: float | None = None) -> list[DeviceEvent]:
        self._buf += data
        out: list[DeviceEvent] = []
        self._parse(out)
        self._partial_since = now if self._buf else None     # a stall is counted from the last byte
        return out

    def expire(self, now: float) -> list[DeviceEvent]:
        if not self._buf:
            return []
        if self._partial_since is None:
            self._partial_since = now
            return []
        if now - self._partial_since <= self.payload_timeout:
            return []
        raw = self._drop_line(self._head_end)
        self._head_end = 0
        out: list[DeviceEvent] = [BadCommand("timeout", f"incomplete command dropped after "
                                             f"{self.payload_timeout:g} s: {_show(raw)}", raw)]
        self._parse(out)
        self._partial_since = now if self._buf else None
        return out

    def _eol_at(self, start: int) -> int:
        buf = self._buf
        a, b = buf.find(b"\r", start), buf.find(b"\n", start)
        if a < 0:
            return b
        if b < 0:
            return a
        return min(a, b)

    def _consume_eol(self, i: int) -> None:
        """Delete up to and including the end of line at i (a following LF after CR goes too)."""
        buf = self._buf
        n = 1
        if buf[i:i + 1] == b"\r":
            if i + 1 < len(buf):
                n = 2 if buf[i + 1:i + 2] == b"\n" else 1
            else:
                self._skip_lf = True
        del buf[:i + n]

    def _parse(self, out: list[DeviceEvent]) -> None:
        buf = self._buf
        while buf:
            if self._skip_lf:
                self._skip_lf = False
                if buf[:1] == b"\n":
                    del buf[:1]
                    continue
            m = _SEND_HEAD.match(buf)
            if m is not None:
                if not self._send(m, out):
                    return
                continue
            i = self._eol_at(0)
            if i < 0:
                if len(buf) > MAX_LINE:
                    raw = bytes(buf)
                    buf.clear()
                    out.append(BadCommand("overflow", f"{len(raw)} bytes without an end of line", raw))
                return
            raw = bytes(buf[:i])
            self._consume_eol(i)
            if raw.strip() == b"":
                continue
            self._command(raw, out)

    def _command(self, raw: bytes, out: list[DeviceEvent]) -> None:
        try:
            text = raw.decode("ascii").strip()
        except UnicodeDecodeError:
            out.append(BadCommand("garbage", f"non-ASCII command {_show(raw)}", raw))
            return
        m = _CMD.fullmatch(text.upper()) if text[:2].upper() == "AT" else None
        if m is None:
            out.append(BadCommand("garbage", f"not an AT command: {text!r}", raw))
            return
        prefix, letters, arg = m.groups()
        if not prefix and len(letters) > 1 and letters[0] in "ZIHCOASN":
            letters, arg = letters[0], letters[1:] + arg   # ATZ1, ATI7, ATH0, ATC, ATO ...
        out.append(Command(prefix + letters, text[2 + len(prefix) + len(letters):], raw))

    def _send(self, m: re.Match, out: list[DeviceEvent]) -> bool:
        buf = self._buf
        name = "*SEND" + m.group(1).decode().upper()
        nfields = _SEND_FIELDS[name]
        pos = m.end()
        commas: list[int] = []
        j = pos
        while len(commas) < nfields:
            k = buf.find(b",", j)
            e = self._eol_at(j)
            if k < 0 or (0 <= e < k):
                if e >= 0 or len(buf) - pos > 64:
                    raw = self._drop_line(0)
                    out.append(BadCommand("format", f"AT{name} with too few fields: {_show(raw)}", raw))
                    return True
                return False
            commas.append(k)
            j = k + 1
        starts = [pos] + [c + 1 for c in commas[:-1]]
        f = [bytes(buf[a:b]) for a, b in zip(starts, commas, strict=True)]
        head_end = commas[-1] + 1
        try:
            n = _int(f[0])
            dst = _int(f[1])
            flag = ts = None
            if name == "*SENDIM":
                flag = f[2].decode("ascii").lower()
                if flag not in IM_FLAGS:
                    raise ValueError(f"unknown flag {flag!r}")
            elif name == "*SENDIMS":
                ts = _int(f[2]) if f[2] else None
        except (ValueError, UnicodeDecodeError) as e:
            raw = self._drop_line(0)
            out.append(BadCommand("format", f"AT{name}: {e}: {_show(raw)}", raw))
            return True
        limit = self.max_data if name == "*SEND" else min(self.max_data, IM_MAX)
        if not 0 <= n <= limit:
            raw = self._drop_line(head_end)
            out.append(BadCommand("length", f"AT{name} length {n} out of range (0..{limit})", raw,
                                  "ERROR OUT OF RANGE"))
            return True
        if len(buf) < head_end + n + 1:
            self._head_end = head_end
            return False
        self._head_end = 0
        end = head_end + n
        if buf[end:end + 1] not in _EOL:
            raw = self._drop_line(head_end)
            out.append(BadCommand("length", f"AT{name}: {n} bytes of data are not followed by an end of line "
                                  f"(wrong length field): {_show(raw)}", raw))
            return True
        data = bytes(buf[head_end:end])
        pid = int(m.group(2)[1:-1]) if m.group(2) else None
        self._consume_eol(end)
        out.append(SendCommand(name, dst, data, flag, ts, pid))
        return True

    def _drop_line(self, start: int) -> bytes:
        i = self._eol_at(start)
        if i < 0:
            raw = bytes(self._buf)
            self._buf.clear()
            return raw
        raw = bytes(self._buf[:i])
        self._consume_eol(i)
        return raw


# -- what the modem writes ------------------------------------------------------------------------
CRLF = b"\r\n"


def line(text: str) -> bytes:
    return text.encode("ascii") + CRLF


def ok() -> bytes:
    return b"OK\r\n"


def busy(reason: str) -> bytes:
    return line(f"BUSY {reason}")


def error(reason: str) -> bytes:
    return line(f"ERROR {reason}")


def block(lines: list[str]) -> bytes:
    """A multi-line answer (`AT&V`): the lines, then an empty line."""
    return b"".join(line(x) for x in lines) + CRLF


def recv(src: int, dst: int, data: bytes, bitrate: int, rssi: int, integrity: int, prop_time_us: int,
         velocity: float) -> bytes:
    head = f"RECV,{len(data)},{src},{dst},{bitrate},{rssi},{integrity},{prop_time_us},{velocity:.2f},"
    return head.encode("ascii") + bytes(data) + CRLF


def recvim(src: int, dst: int, data: bytes, flag: str, duration_us: int, rssi: int, integrity: int,
           velocity: float) -> bytes:
    head = f"RECVIM,{len(data)},{src},{dst},{flag},{duration_us},{rssi},{integrity},{velocity:.2f},"
    return head.encode("ascii") + bytes(data) + CRLF


def recvpbm(src: int, dst: int, data: bytes, duration_us: int, rssi: int, integrity: int,
            velocity: float) -> bytes:
    head = f"RECVPBM,{len(data)},{src},{dst},{duration_us},{rssi},{integrity},{velocity:.2f},"
    return head.encode("ascii") + bytes(data) + CRLF


def delivered(dst: int, count: int | None = None) -> bytes:
    """`DELIVEREDIM,<dst>` (count None) or burst `DELIVERED,<count>,<dst>`."""
    return line(f"DELIVEREDIM,{dst}" if count is None else f"DELIVERED,{count},{dst}")


def failed(dst: int, count: int | None = None) -> bytes:
    return line(f"FAILEDIM,{dst}" if count is None else f"FAILED,{count},{dst}")


def canceled(dst: int, kind: str = "IM") -> bytes:
    return line(f"CANCELED{kind},{dst}")


def notification(name: str, *fields: object) -> bytes:
    return line(",".join([name, *(str(f) for f in fields)]))
