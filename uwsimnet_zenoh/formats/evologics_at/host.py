"""The host side of the EvoLogics AT protocol (what a driver speaks): commands out, events in."""

from __future__ import annotations

import re
from collections import deque
from dataclasses import dataclass, field

from .events import (
    _ASYNC,
    _ASYNC_ERRORS,
    _RECV_FIELDS,
    _RECV_HEAD,
    BES_HEAD,
    BURST_MAX,
    DEFERRED,
    IM_FLAGS,
    IM_MAX,
    MAX_LINE,
    MULTILINE,
    RECV_MAX,
    Busy,
    Canceled,
    Data,
    Delivered,
    DriverEvent,
    Error,
    Expired,
    Failed,
    Notification,
    Ok,
    ProtocolError,
    Received,
    Reply,
    _expects_ok,
    _float,
    _int,
    _intish,
    _show,
    request_name,
)


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

    Data mode (`mode="data"`, or after `command("O")`): commands go out as `+++AT<cmd>` (the time independent
    escape sequence), the modem's answers and notifications come back as `+++AT<req>:<len>:<body>` and
    `+++AT:<len>:<body>` and are parsed like command-mode lines; every other byte is burst data (`Data`).
    `command("C")` returns to command mode (answered `OK`).  A `[*]` prefix (deferred setting) is accepted
    on answers: `[*]OK` is `Ok`, `[*]3` is `Reply('3')`.
    """

    def __init__(self, eol: str = "\n", reply_timeout: float = 5.0, payload_timeout: float = 2.0,
                 mode: str = "command") -> None:
        if mode not in ("command", "data"):
            raise ValueError(f"mode must be command or data, got {mode!r}")
        self.mode = mode
        self._dbuf = bytearray()     # data mode: bytes not yet known to be burst data or a BES
        self._dsince: float | None = None
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
        wire = self._prefix() + c.encode("ascii") + self.eol
        req = request_name(c)
        if req == "O":               # ATO: no answer (manual 1.7 section 5.3.2); data mode from now on
            self.mode = "data"
            return wire
        if req == "C":               # ATC: answered OK once the modem is in command mode
            self.mode = "command"
        self._push(req, now)
        return wire

    def _prefix(self) -> bytes:
        return b"+++" if self.mode == "data" else b""

    def raw(self, data: bytes) -> bytes:
        """Data mode: burst data for the Remote Address (`AT!AR`), written as is."""
        if self.mode != "data":
            raise ValueError("raw burst data is only possible in data mode (send ATO first)")
        return bytes(data)

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
        return self._prefix() + f"AT{req},{p}{len(data)},{mid}".encode("ascii") + data + self.eol

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
        self._dbuf.clear()
        self._dsince = None
        self._partial_since = None
        self._head_end = 0
        return lost

    # -- parsing the modem's output ---------------------------------------------------------------
    def feed(self, data: bytes | bytearray | memoryview, now: float | None = None) -> list[DriverEvent]:
        out: list[DriverEvent] = []
        if self.mode == "data":
            self._dbuf += data
            self._data(out)
            self._dsince = now if self._dbuf else None
        else:
            self._buf += data
        self._parse(out)
        self._partial_since = now if self._buf else None     # a stall is counted from the last byte
        return out

    def _data(self, out: list[DriverEvent], flush: bool = False) -> None:
        """Data mode: cut BES frames out of the stream; their bodies go to the line parser, the rest is data."""
        buf = self._dbuf
        esc = b"+++AT"
        while buf:
            i = buf.find(esc)
            if i < 0:
                keep = 0 if flush else next((k for k in (4, 3, 2, 1) if buf.endswith(esc[:k])), 0)
                n = len(buf) - keep
                if n:
                    out.append(Data(bytes(buf[:n])))
                    del buf[:n]
                return
            if i > 0:
                out.append(Data(bytes(buf[:i])))
                del buf[:i]
                continue
            m = BES_HEAD.match(buf)
            if m is None:
                if not flush and len(buf) < 48 and re.fullmatch(rb"\+\+\+AT[^:\r\n]{0,32}(:\d{0,5})?", buf):
                    return                                   # the head is still arriving
                out.append(Data(bytes(buf[:1])))             # '+' of burst data, not an escape
                del buf[:1]
                continue
            end = m.end() + int(m.group(2))
            if len(buf) < end + 2:
                if flush:
                    raw = bytes(buf)
                    buf.clear()
                    self._err(out, "timeout", f"incomplete +++AT frame dropped: {_show(raw)}", raw)
                return
            if buf[end:end + 2] != b"\r\n":
                raw = bytes(buf[:m.end()])
                del buf[:m.end()]
                self._err(out, "length", f"+++AT frame of {m.group(2).decode()} bytes not followed by CRLF: "
                          f"{_show(raw)}", raw)
                continue
            self._buf += buf[m.end():end + 2]                # body + CRLF: a command-mode line
            del buf[:end + 2]
            self._parse(out)                                 # now, to keep its order with the data

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
        if self._dbuf:
            if self._dsince is None:
                self._dsince = now
            elif now - self._dsince > self.payload_timeout:
                self._data(out, flush=True)
                self._parse(out)
                self._dsince = None
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
            b = BES_HEAD.match(buf) if buf[:1] == b"+" else None
            if b is not None:                # a data-mode frame written just before ATC took effect
                end = b.end() + int(b.group(2))
                if len(buf) < end + 2:
                    return
                if buf[end:end + 2] == b"\r\n":
                    del buf[:b.end()]
                    continue
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
        if text.startswith(DEFERRED):
            text = text[len(DEFERRED):]
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
