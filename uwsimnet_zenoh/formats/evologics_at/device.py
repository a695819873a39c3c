"""The device side of the EvoLogics AT protocol (what the emulator speaks): a host's bytes to commands, and
the modem's replies and notifications."""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass

from .events import _CMD, _SEND_FIELDS, _SEND_HEAD, BURST_MAX, IM_FLAGS, IM_MAX, MAX_LINE, _int, _show


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
    ties: bool = False
    """Came as `+++AT...` in data mode: the answer goes back as `+++AT<name>:<len>:<answer>`."""


@dataclass(frozen=True)
class SendCommand:
    """`AT*SEND`, `AT*SENDIM`, `AT*SENDIMS` or `AT*SENDPBM` with its binary payload."""

    name: str                # *SEND | *SENDIM | *SENDIMS | *SENDPBM
    dst: int
    data: bytes
    flag: str | None = None  # *SENDIM: ack | noack | force
    timestamp_us: int | None = None
    pid: int | None = None
    ties: bool = False


@dataclass(frozen=True)
class BadCommand:
    """Input the modem cannot take; `reply` is the line a device answers with."""

    kind: str            # garbage | format | length | overflow | timeout
    detail: str
    raw: bytes
    reply: str = "ERROR WRONG FORMAT"
    ties: bool = False


@dataclass(frozen=True)
class RawData:
    """Data mode: host bytes that are not an escape sequence, i.e. burst data for the Remote Address."""

    data: bytes


DeviceEvent = Command | SendCommand | BadCommand | RawData
TIES_MAX = 1054
"""Longest AT command, characters (manual 1.7 section 5.1.1); a longer +++AT... is burst data."""
_EOL = (b"\r", b"\n")


class DeviceCodec:
    """The modem end: parse host commands (binary payloads included), build answers and notifications.

    A command ends at `\\r`, `\\n` or `\\r\\n`.  For `AT*SEND*` the length field decides how many bytes
    of data follow (they may contain end-of-line bytes); the end of line must follow them, otherwise
    the command is refused (`BadCommand('length')`) and the parser resumes after the first end of
    line that follows the data's start.  `expire(now)` refuses a command whose data stopped coming.

    Data mode (`mode="data"`; `ATO` switches to it when `data_mode` is allowed, `ATC` back): host bytes are
    burst data (`RawData`) except a time independent escape sequence `+++AT<command><eol>` (manual 1.7
    section 4.2.2), parsed as above; a `+++AT...` that is not a command in the right format is burst data.
    The switch happens as the `ATO`/`ATC` line is parsed, so bytes written right after it are read in the
    new mode.
    """

    def __init__(self, payload_timeout: float = 2.0, max_data: int = BURST_MAX, mode: str = "command",
                 data_mode: bool = True) -> None:
        self.mode = mode
        self.data_mode = data_mode
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
        out: list[DeviceEvent] = []
        if self.mode == "data" and not self._buf.startswith(b"+++AT*SEND"):
            self._parse_data(out, flush=True)            # a lone '+', '++' or an unterminated +++AT...
        else:
            raw = self._drop_line(self._head_end)
            self._head_end = 0
            out.append(BadCommand("timeout", f"incomplete command dropped after {self.payload_timeout:g} s: "
                                  f"{_show(raw)}", raw))
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
            if self.mode == "data":
                if not self._parse_data(out):
                    return
                continue
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

    def _parse_data(self, out: list[DeviceEvent], flush: bool = False) -> bool:
        """One step in data mode; False: wait for more bytes."""
        buf = self._buf
        if self._skip_lf:
            self._skip_lf = False
            if buf[:1] == b"\n":
                del buf[:1]
                return True
        i = buf.find(b"+++")
        if i < 0:
            keep = 0 if flush else len(buf) - len(buf.rstrip(b"+"))
            n = len(buf) - min(keep, 2)
            if n:
                out.append(RawData(bytes(buf[:n])))
                del buf[:n]
            return bool(n) and bool(buf)
        if i > 0:
            out.append(RawData(bytes(buf[:i])))
            del buf[:i]
            return True
        if len(buf) < 5 and not flush and b"+++AT".startswith(bytes(buf)):
            return False
        if buf[3:5] != b"AT":
            out.append(RawData(bytes(buf[:1])))
            del buf[:1]
            return True
        m = _SEND_HEAD.match(buf, 3)
        if m is not None:
            n = len(out)
            done = self._send(m, out)
            out[n:] = [dataclasses.replace(ev, ties=True) for ev in out[n:]]
            return done
        e = self._eol_at(3)
        if e < 0:
            if len(buf) > TIES_MAX + 3 or flush:
                out.append(RawData(bytes(buf[:3])))      # not a command after all: burst data
                del buf[:3]
                return True
            return False
        raw = bytes(buf[:e])
        self._consume_eol(e)
        n = len(out)
        self._command(raw[3:], out)
        if len(out) > n and isinstance(out[-1], BadCommand):
            out[-1] = RawData(raw + b"\n")               # a TIES in wrong format is burst data (section 4.2.2)
        elif len(out) > n:
            out[-1] = dataclasses.replace(out[-1], ties=True)
        return True

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
        if not prefix and len(letters) > 1 and letters[0] in "ZIHCOASND":
            letters, arg = letters[0], letters[1:] + arg   # ATZ1, ATI7, ATH0, ATC, ATO ...
        name = prefix + letters
        out.append(Command(name, text[2 + len(prefix) + len(letters):], raw))
        if name == "O" and self.data_mode:
            self.mode = "data"
        elif name == "C":
            self.mode = "command"

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


def bes(request: str, body: bytes) -> bytes:
    """Data mode, back escape sequence (manual 1.7 section 4.2.3): `+++AT<request>:<len>:<body>CRLF`.

    `body` is the answer (or, with request "", the notification) without its final CRLF; `len` counts it."""
    return f"+++AT{request}:{len(body)}:".encode("ascii") + bytes(body) + CRLF


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
