"""An EvoLogics S2C host written from the public grammar, not from uwsimnet's codec.

Test helper.  The rules are EvoLogics evins' `src/role_at.erl` (the modem-output splitter `to_term`:
`bes_split`, `answer_split`, the `*_extract` functions), the vendor AT manual 1.7 (data mode framing, answers)
and the formats of DUNE (`Transports/Evologics/Driver.hpp` sscanf strings), DESERT (`uwinterpreters2c.cpp`
AT&V order) and Rock (`UsblParser.cpp` AT&V keys).  Nothing is imported from uwsimnet_zenoh: the point is to
check the emulator against what real host software accepts.

`Splitter` cuts a modem's byte stream into terms, the way role_at does; `Host` is a blocking TCP client that
uses it (command mode or data mode, as evins' fsm_conf drives a modem).
"""

from __future__ import annotations

import re
import socket
import time
from dataclasses import dataclass, field

# -- field types as role_at converts them (binary_to_integer / binary_to_float) ---------------------------
_INT = re.compile(rb"[+-]?\d+\Z")
_FLOAT = re.compile(rb"[+-]?\d+\.\d+([eE][+-]?\d+)?\Z")   # Erlang binary_to_float needs the point


def _i(b: bytes) -> int:
    if not _INT.match(b):
        raise ValueError(f"not an integer: {b!r}")
    return int(b)


def _f(b: bytes) -> float:
    if not _FLOAT.match(b):
        raise ValueError(f"not a float with a decimal point: {b!r}")
    return float(b)


@dataclass(frozen=True)
class Term:
    """kind: sync (an answer: `req`, `value`), async (`name`, `fields`), recv (`name` recv|recvim|recvims|
    recvpbm, `fields` as role_at's tuple, `data`, `pid`), raw (burst data bytes in data mode), error."""

    kind: str
    name: str = ""
    value: str = ""
    fields: tuple = ()
    data: bytes = b""
    pid: int | None = None
    req: str | None = None


_RECV = re.compile(rb"^(RECV(|PBM|IM|IMS),)(p(\d+),(\d+)|(\d+))(,.*)", re.S)
_ASYNC = re.compile(rb"^(RECVPROBE,|RECVSTART|RECVEND,|RECVFAILED,|RECVSRV,|SEND[^,]*,|BITRATE,|RADDR,|SRCLEVEL,"
                    rb"|PHYON|PHYOFF|USBL[^,]*,|ECLK,|RTO,|DROPCNT,|DELIVERED|FAILED|EXPIRED|CANCELED|STATUS,|%)"
                    rb"(.*?)\r\n(.*)", re.S)
_ERR = re.compile(rb"^(ERROR|BUSY) (.*?)\r\n(.*)", re.S)
_BES = re.compile(rb"(.*?)(\+{3}AT.*?):(\d+):(.*)", re.S)
_MAYBE_BES = re.compile(rb"(.*?[^+]*)(\+{3}(AT.*?:\d*|AT[^:]{0,10}:?|AT?|A?)|\+{0,2})\Z", re.S)
MULTILINE = {"&V", "?S", "?P", "?ZSL"}


def _split4(p: bytes, n: int) -> list[bytes]:
    f = p.split(b",")
    if len(f) != n:
        raise ValueError(f"{n} fields expected, got {len(f)}")
    return f


def _async(key: bytes, p: bytes) -> Term:
    """role_at's *_extract for one asynchronous line (key and parameters without CRLF)."""
    k = key.decode()
    try:
        if k == "RECVSTART" or k in ("PHYON", "PHYOFF"):
            if p:
                raise ValueError("trailing text")
            return Term("async", k)
        if k == "RECVEND,":
            return Term("async", "RECVEND", fields=tuple(_i(x) for x in _split4(p, 4)))
        if k == "RECVFAILED,":
            v, r, i = _split4(p, 3)
            return Term("async", "RECVFAILED", fields=(_f(v), _i(r), _i(i)))
        if k == "RECVPROBE,":
            b, us, d, r, i, v = _split4(p, 6)
            return Term("async", "RECVPROBE", fields=(_i(b), _i(us), _i(d), _i(r), _i(i), _f(v)))
        if k == "RECVSRV,":
            s, d, t, dec, tr, r, i = _split4(p, 7)
            return Term("async", "RECVSRV", fields=(_i(s), _i(d), t.decode(), _i(dec), _i(tr), _i(r), _i(i)))
        if k in ("SENDSTART,", "SENDEND,"):
            a, t, x, y = _split4(p, 4)
            return Term("async", k[:-1], fields=(_i(a), t.decode(), _i(x), _i(y)))
        if k == "BITRATE,":
            d, v = _split4(p, 2)
            return Term("async", "BITRATE", fields=(d.decode(), _i(v)))
        if k in ("RADDR,", "SRCLEVEL,", "DROPCNT,", "RTO,"):
            return Term("async", k[:-1], fields=(_i(p),))
        if k == "DELIVERED" or k == "FAILED":
            f = p.split(b",")
            if f[0] == b"" and len(f) == 3:
                return Term("async", k, fields=(_i(f[1]), _i(f[2])))
            if f[0] == b"IM" and len(f) == 2:
                return Term("async", k + "IM", fields=(_i(f[1]),))
            raise ValueError("bad delivery report")
        if k == "CANCELED":
            f = p.split(b",")
            if f[0] in (b"IM", b"IMS", b"PBM") and len(f) == 2:
                return Term("async", "CANCELED" + f[0].decode(), fields=(_i(f[1]),))
            raise ValueError("bad cancel report")
        if k == "EXPIRED":
            f = p.split(b",")
            if f[0] == b"IMS" and len(f) == 2:
                return Term("async", "EXPIREDIMS", fields=(_i(f[1]),))
            raise ValueError("bad expiry report")
        if k == "STATUS,":
            f = p.split(b",", 1)
            if len(f) != 2:
                raise ValueError("STATUS needs 2 fields")
            return Term("async", "STATUS", fields=(f[0].decode(), f[1].decode()))
        if k == "%":
            f = p.split(b",", 1)
            if len(f) != 2:
                raise ValueError("%key,params expected")
            return Term("async", "%" + f[0].decode(), fields=(f[1].decode(),))
        if k.startswith("USBL"):
            n = {"USBLLONG,": 16, "USBLANGLES,": 13, "USBLPHYD,": 12, "USBLPHYP,": 22}.get(k)
            if n is None or len(p.split(b",")) != n:
                raise ValueError("bad USBL line")
            return Term("async", k[:-1], fields=tuple(x.decode() for x in p.split(b",")))
        if k == "ECLK,":
            _split4(p, 5)
            return Term("async", "ECLK", fields=tuple(x.decode() for x in p.split(b",")))
        return Term("error", "wrongAsync", value=(key + p).decode("latin-1"))
    except (ValueError, UnicodeDecodeError) as e:
        return Term("error", "parseError", value=f"{k}{p.decode('latin-1')}: {e}")


class Splitter:
    """role_at:to_term/3 in Python: feed modem bytes, get terms.  `mode` command | data."""

    def __init__(self, mode: str = "command") -> None:
        self.mode = mode
        self.more = b""
        self.wait: str = "no"          # no | singleline | multiline
        self.request: str = ""
        self.pid = 0

    def expect(self, request: str) -> None:
        """A request was written: its answer is a sync term (role_at from_term sets waitsync/request)."""
        self.request = request
        self.wait = "multiline" if request in MULTILINE else "singleline"

    def feed(self, chunk: bytes) -> list[Term]:
        buf = self.more + chunk
        self.more = b""
        if self.mode == "data":
            return self._bes(buf)
        out, self.more = self._answers(buf)
        return out

    # -- data mode: bes_split ----------------------------------------------------------------------
    def _bes(self, buf: bytes) -> list[Term]:
        out: list[Term] = []
        while buf:
            m = _BES.match(buf)
            if m is None:
                mm = _MAYBE_BES.match(buf)
                raw, tail = (mm.group(1), buf[len(mm.group(1)):]) if mm else (buf, b"")
                if raw:
                    out.append(Term("raw", data=raw))
                self.more = tail
                return out
            pre, head, n, rest = m.group(1), m.group(2), int(m.group(3)), m.group(4)
            if len(rest) < n + 2:
                self.more = buf
                return out
            if rest[n:n + 2] != b"\r\n":
                out.append(Term("raw", data=pre + head + b":" + m.group(3) + b":"))
                buf = rest
                continue
            if pre:
                out.append(Term("raw", data=pre))
            body, buf = rest[:n] + b"\r\n", rest[n + 2:]
            req = head[5:].decode("latin-1")
            if req == "" or self.wait == "no" or req == self.request:
                terms, more = self._answers(body)
                if more:
                    out.append(Term("error", "besParseError", value=body.decode("latin-1")))
                out.extend(terms[:1] if terms else [])
                out.extend(terms[1:])
            else:
                out.append(Term("error", "besUnexpectedSync", value=f"{req} while waiting {self.request}"))
        return out

    # -- answer_split ------------------------------------------------------------------------------
    def _answers(self, buf: bytes) -> tuple[list[Term], bytes]:
        out: list[Term] = []
        while buf:
            if b"\r\n" not in buf:
                return out, buf
            m = _RECV.match(buf)
            if m is not None:
                t, rest = self._recv(m, buf)
                if t is None:
                    return out, buf
                out.append(t)
                if t.kind == "error":
                    return out, b""
                buf = rest
                continue
            m = _ASYNC.match(buf)
            if m is not None:
                out.append(_async(m.group(1), m.group(2)))
                buf = m.group(3)
                continue
            m = _ERR.match(buf)
            if m is not None:
                word, reason, buf = m.group(1).decode(), m.group(2).decode("latin-1"), m.group(3)
                if word == "ERROR" and reason in ("EFAULT", "OVERLOAD"):
                    out.append(Term("async", "ERROR", value=reason))
                else:
                    out.append(Term("sync", req=self.request, value=f"{word} {reason}"))
                    self.wait, self.request = "no", ""
                continue
            if self.wait == "singleline":
                line, _, buf = buf.partition(b"\r\n")
                out.append(Term("sync", req=self.request, value=line.decode("latin-1")))
                self.wait, self.request = "no", ""
                continue
            if self.wait == "multiline":
                i = buf.find(b"\n\r\n")
                if i < 0:
                    return out, buf
                out.append(Term("sync", req=self.request, value=buf[:i + 1].decode("latin-1")))
                buf = buf[i + 3:]
                self.wait, self.request = "no", ""
                continue
            out.append(Term("error", "unexpectedSync", value=buf.decode("latin-1")))
            return out, b""
        return out, b""

    def _recv(self, m: re.Match, buf: bytes) -> tuple[Term | None, bytes]:
        kind = {b"RECV,": "recv", b"RECVIM,": "recvim", b"RECVIMS,": "recvims", b"RECVPBM,": "recvpbm"}[m.group(1)]
        pid = int(m.group(4)) if m.group(4) else None
        n = int(m.group(5) or m.group(6))
        tail = m.group(7)
        nf = 6 if kind == "recvpbm" else 7
        parts = tail[1:].split(b",", nf)
        if len(parts) <= nf:
            return Term("error", "binaryParseError", name=kind, value=tail.decode("latin-1")), b""
        head, rest = parts[:nf], parts[nf]
        if len(rest) < n + 2:
            return None, buf
        if rest[n:n + 2] != b"\r\n":
            return Term("error", "binaryParseError", name=kind, value=tail.decode("latin-1")), b""
        try:
            if kind == "recvpbm":
                s, d, dur, r, i, v = head
                fields = (n, _i(s), _i(d), _i(dur), _i(r), _i(i), _f(v))
            elif kind == "recvim":
                s, d, flag, dur, r, i, v = head
                if flag not in (b"ack", b"noack", b"force"):
                    raise ValueError(f"flag {flag!r}")
                fields = (n, _i(s), _i(d), flag.decode(), _i(dur), _i(r), _i(i), _f(v))
            else:
                s, d, x, dur, r, i, v = head
                fields = (n, _i(s), _i(d), _i(x), _i(dur), _i(r), _i(i), _f(v))
        except ValueError as e:
            return Term("error", "binaryParseError", name=kind, value=str(e)), b""
        return Term("recv", name=kind, fields=fields, data=rest[:n], pid=pid), rest[n + 2:]


# -- the other hosts' checks ---------------------------------------------------------------------------
def dune_ati1(line: str) -> tuple[str, str] | None:
    """DUNE: sscanf(str, "phy:%*[^0]%[^,], mac:%*[^v]v%s", phy, mac) == 2."""
    m = re.match(r"phy:[^0]+(0[^,]*), mac:[^v]+v(\S+)", line)
    return (m.group(1), m.group(2)) if m else None


def dune_recvim(line: bytes) -> bool:
    """DUNE (firmware >= 1.7): "RECVIM,%lu,%u,%u,%[^,],%u,%f,%u,%f,%n" == 8 and a payload left."""
    m = re.match(rb"RECVIM,(\d+),(\d+),(\d+),([^,]+),(\d+),([-+]?[\d.]+),(\d+),([-+]?[\d.]+),", line)
    return bool(m) and m.end() < len(line)


ATV_KEYS = ("Source Level", "Source Level Control", "Gain", "Carrier Waveform ID", "Local Address",
            "Highest Address", "Cluster Size", "Packet Time", "Retry Count", "Retry Timeout",
            "Wake Up Active Time", "Wake Up Period", "Promiscuous Mode", "Sound Speed", "IM Retry Count",
            "Pool Size", "Hold Timeout", "Idle Timeout")
"""AT&V lines in DESERT's positional order (uwinterpreters2c.cpp CURR_SETTINGS) = a real 1.8 capture
(Rock test_UsblParser.cpp peer1_8) with firmware 1.9's "IM Retry Count" spelling."""


def atv_ok(block: str) -> str | None:
    """None if DESERT and Rock both read this AT&V block; else why not."""
    lines = [x for x in block.replace("\r", "").split("\n") if x]
    keys = []
    for x in lines:
        x = x.strip("[*]")
        k, sep, v = x.partition(":")
        if not sep or not v.startswith(" "):
            return f"not '<key>: <value>': {x!r}"
        if k not in ATV_KEYS:
            return f"Rock rejects the key {k!r}"
        if k != "Pool Size" and not re.fullmatch(r" *-?\d+", v):
            return f"DESERT stoi fails on {x!r}"
        keys.append(k)
    if tuple(keys) != ATV_KEYS:
        return f"DESERT reads positionally, order differs: {keys}"
    return None


# -- a blocking host on TCP ------------------------------------------------------------------------------
@dataclass
class Host:
    """evins-like host on a TCP AT port.  `command()` writes `AT<cmd>` (`+++AT<cmd>` in data mode) and returns
    the answer's text; asynchronous terms and raw data collect in `events` / `raw`."""

    host: str
    port: int
    eol: bytes = b"\n"
    timeout: float = 10.0
    sock: socket.socket | None = None
    split: Splitter = field(default_factory=Splitter)
    events: list[Term] = field(default_factory=list)
    raw: bytearray = field(default_factory=bytearray)
    errors: list[Term] = field(default_factory=list)
    lines: int = 0
    seen: list[tuple[float, Term]] = field(default_factory=list)
    """Every term but raw data, with the monotonic time it was read."""

    def __enter__(self) -> Host:
        self.sock = socket.create_connection((self.host, self.port), timeout=self.timeout)
        self.sock.settimeout(0.05)
        return self

    def __exit__(self, *exc: object) -> None:
        if self.sock is not None:
            self.sock.close()

    @property
    def data_mode(self) -> bool:
        return self.split.mode == "data"

    def write(self, b: bytes) -> None:
        assert self.sock is not None
        self.sock.sendall(b)

    def pump(self, seconds: float = 0.0) -> list[Term]:
        """Read what the modem wrote for up to `seconds` (at least one poll)."""
        assert self.sock is not None
        out: list[Term] = []
        end = time.monotonic() + seconds
        while True:
            try:
                chunk = self.sock.recv(65536)
                if not chunk:
                    raise ConnectionError("modem closed the connection")
            except TimeoutError:
                chunk = b""
            if chunk:
                out.extend(self._take(self.split.feed(chunk)))
            if time.monotonic() >= end:
                return out

    def _take(self, terms: list[Term]) -> list[Term]:
        for t in terms:
            if t.kind == "raw":
                self.raw += t.data
                continue
            self.lines += 1
            self.seen.append((time.monotonic(), t))
            if t.kind == "error":
                self.errors.append(t)
            elif t.kind != "sync":
                self.events.append(t)
        return terms

    def request(self, wire: bytes, req: str) -> str:
        """Write one request and wait for its answer (sync term)."""
        self.split.expect(req)
        self.write(wire)
        end = time.monotonic() + self.timeout
        while time.monotonic() < end:
            for t in self.pump(0.05):
                if t.kind == "sync":
                    return t.value
        raise TimeoutError(f"no answer to {req}")

    def command(self, cmd: str) -> str:
        """`cmd` without AT, e.g. `?AL`, `!AR2`, `@ZX1`, `&V`."""
        m = re.match(r"[?!@&*]?[A-Z]+", cmd)      # the request name: the command without its argument
        req = m.group(0) if m else cmd
        prefix = b"+++" if self.data_mode else b""
        return self.request(prefix + b"AT" + cmd.encode() + self.eol, req)

    def send(self, kind: str, dst: int, data: bytes, flag: str = "ack", ts: int | None = None,
             pid: int | None = None) -> str:
        """AT*SEND / *SENDIM / *SENDIMS / *SENDPBM (evins' from_term forms), returns the answer."""
        p = f"p{pid}," if pid is not None else ""
        mid = {"burst": f"{dst},", "im": f"{dst},{flag},", "ims": f"{dst},{'' if ts is None else ts},",
               "pbm": f"{dst},"}[kind]
        name = {"burst": "*SEND", "im": "*SENDIM", "ims": "*SENDIMS", "pbm": "*SENDPBM"}[kind]
        prefix = b"+++" if self.data_mode else b""
        wire = prefix + f"AT{name},{p}{len(data)},{mid}".encode() + data + self.eol
        return self.request(wire, name)

    def to_data_mode(self) -> None:
        """fsm_conf: AT?MODE must say AT, then ATO (no answer) and parse in data mode."""
        mode = self.command("?MODE")
        if mode != "AT":
            raise AssertionError(f"AT?MODE answered {mode!r}")
        self.write(b"ATO" + self.eol)
        self.split.mode = "data"

    def wait_for(self, pred, seconds: float = 10.0) -> Term:
        """The first collected asynchronous term (or received message) that `pred` accepts, consumed."""
        end = time.monotonic() + seconds
        while True:
            for t in self.events:
                if pred(t):
                    self.events.remove(t)
                    return t
            if time.monotonic() >= end:
                raise TimeoutError(f"nothing matched in {seconds} s; have {self.events}")
            self.pump(0.05)
