"""The EvoLogics S2C emulator: a simulated modem that looks like the real device, so software written for
the hardware runs against the simulator unchanged.  `EvoLogicsEmulator` is a TCP server speaking the S2C
AT command set (`formats.evologics_at`), command and data mode, like the modem's port 9200, or the `net`
interpreter.  Point evins, dmac, DESERT, DUNE (`interpreter="net"`) or your own code at
`127.0.0.1:<port>`.  It sits on a `ModemBackend` (drivers/backend.py): `SimBackend` for an in-process
simulation, `ZenohBackend` for a running broker.  docs/drivers.md lists what is reproduced and how.
"""

from __future__ import annotations

import asyncio
import itertools
import logging
import time
from collections import Counter, deque
from dataclasses import dataclass, field
from typing import Any

from ...formats import evologics_at as at
from .._aio import LoopThread, ServerClient, TcpServer
from ..backend import BackendFrame, BackendStatus, Message, ModemBackend, detach, link_metrics

log = logging.getLogger("uwsimnet.drivers.emulators")

# -- the modem's own words (vendor AT manual 1.7, section 5.1.3: the complete lists) -------------------
ERR_FORMAT = "ERROR WRONG FORMAT"
ERR_RANGE = "ERROR OUT OF RANGE"
ERR_FULL = "ERROR BUFFER FULL"
ERR_NOT_ACCEPTED = "ERROR NOT ACCEPTED"
ERR_DESTINATION = "ERROR WRONG DESTINATION ADDRESS"
ERRORS = ("ERROR EFAULT", "ERROR OVERLOAD", "ERROR PHY OFF", "ERROR CONFIGURATION NOT STORED", ERR_NOT_ACCEPTED,
          ERR_DESTINATION, "ERROR UNKNOWN COMMAND", ERR_FORMAT, "ERROR BUFFER IS NOT EMPTY",
          "ERROR BUFFERS ARE NOT EMPTY", ERR_FULL, ERR_RANGE, "ERROR PROTOCOL ID", "ERROR PROTOCOL ID DUPLICATION",
          "ERROR INTERNAL")
BUSY_FORMATS = ("BUSY DELIVERING DATA TO {}", "BUSY RECEIVING DATA FROM {}", "BUSY CLOSING CONNECTION WITH {}",
                "BUSY DELIVERING INSTANT MESSAGE TO {}", "BUSY RECEIVING INSTANT MESSAGE FROM {}",
                "BUSY BACKOFF STATE")


def busy_im(dst: int) -> str:
    """Answer to a message while the previous one is still on air."""
    return f"BUSY DELIVERING INSTANT MESSAGE TO {dst}"


FIRMWARE = "1.9"
ATI1 = "phy: 0x40803016, mac:       v1.9"
"""ATI1 in the form of the manual's example (`phy: 0x40803016, mac:       v1.7.1`, section 5.3.9), which
DUNE reads with sscanf("phy:%*[^0]%[^,], mac:%*[^v]v%s"); the version numbers are ours."""

# -- air times (µs) -------------------------------------------------------------------------------------
S2C_UNIT_US = 2048
"""Every instant-message duration in the manual's examples is a multiple of 2048 µs."""


def im_duration_us(n: int) -> int:
    """Time on air of an instant message (IM, IMS, PBM) of `n` bytes: a fit to the manual's examples,
    1 byte 155648 µs and 4 bytes 182272 µs (76 and 89 units of 2048 µs: preamble plus 13 units per 3 bytes),
    the modem's IM rate, not the burst bit rate.  Unverified beyond those two points."""
    return S2C_UNIT_US * (76 + (13 * (max(1, n) - 1) + 2) // 3)


IMACK_US = S2C_UNIT_US * 72
"""Time on air of an IM acknowledgement without a PBM: the same fit at 0 bytes (unverified)."""

_TYPE = {"im": "im", "ims": "ims", "pbm": "service|pbm", "burst": "burst"}
"""SENDSTART/SENDEND <type> (section 5.6 lists no lone pbm: here a PBM goes with a service message)."""

CLOCK_WRAP = 1 << 32
"""AT?CLOCK is a 32-bit microsecond counter (manual section 5.9.16)."""

DEFAULT_SETTINGS = {
    # name: value (AT?<name> reads it, AT!<name><value> writes it)
    "L": "0",        # source level 0 (max) .. 3
    "G": "0",        # gain: 0 normal, 1 low
    "LC": "0",       # source level control
    "CA": "1500",    # sound speed, m/s
    "RC": "3",       # connection retry count
    "RT": "2000",    # connection retry timeout, ms
    "RI": "0",       # instant message retry count
    "ZI": "0",       # idle timeout, s
    "AM": "254",     # highest address
    "AR": "1",       # remote address (burst data in data mode goes there)
    "ZL": "16384",   # burst pool size, bytes
    "RP": "0",       # promiscuous mode
    "KO": "0",       # keep-online
    "C": "1",        # carrier waveform id
    "ZC": "10",      # cluster size
    "ZP": "750",     # packet time, ms
    "DA": "0",       # wake up active time, s
    "DT": "0",       # wake up period, s
    "ZH": "0",       # hold timeout, s
    "DW": "0",       # awake remote mode
    "DR": "0",       # remote active time
}
CHANNEL_SETTINGS = ("ZX", "ZU", "ZF", "ZA", "ZS")
"""`AT@` settings belong to the data channel, i.e. to one TCP connection here: ZX extended notifications,
ZU positioning output, ZF extended networking (RECV*,p<pid>, forms), ZA, ZS."""
SETTING_NAMES = (("Source Level", "L"), ("Source Level Control", "LC"), ("Gain", "G"), ("Carrier Waveform ID", "C"),
                 ("Local Address", "AL"), ("Highest Address", "AM"), ("Cluster Size", "ZC"), ("Packet Time", "ZP"),
                 ("Retry Count", "RC"), ("Retry Timeout", "RT"), ("Wake Up Active Time", "DA"),
                 ("Wake Up Period", "DT"), ("Promiscuous Mode", "RP"), ("Sound Speed", "CA"),
                 ("IM Retry Count", "RI"), ("Pool Size", "ZL"), ("Hold Timeout", "ZH"), ("Idle Timeout", "ZI"))
"""AT&V lines: the names and order of a real modem's answer (firmware 1.8 bytes in the Rock driver's tests,
`IM Retry Count` as firmware 1.9 spells it), the order DESERT reads them in."""


@dataclass
class _Tx:
    """A frame the emulated modem accepted, until its report."""

    token: int
    kind: str            # im | burst | pbm | ims
    dst: int
    length: int
    flag: str | None
    pid: int = 0
    dur_us: int = 0
    report: bool = True  # send DELIVERED/FAILED(IM) for it
    phase: str = "air"   # wait (IMS before its time) | air | ack (ack IM waiting for its acknowledgement)
    t_sent: float | None = None     # wall (monotonic) s when it left the air, and the simulation's time then
    sim_sent: float = 0.0
    done: bool = False
    timers: list[asyncio.TimerHandle] = field(default_factory=list)


class EvoLogicsEmulator:
    """An EvoLogics S2C modem on TCP, backed by a simulated modem.

    `port=0` picks a free port (see `.port` after `start()`).  `bitrate` is used for burst time-on-air
    figures when the backend does not say.  `ack_time` (s): the acknowledgement's time on air before a
    delivery report (None: the modelled IMACK_US); `ack_timeout` (s) after transmission an instant
    message without an outcome is reported FAILEDIM (addressee absent or out of range): once that much wall
    time and that much simulated time have passed, so a broker or machine running late (its outcome late
    too) does not turn a delivered frame into a FAILED one.  `interpreter`:
    `at` (the default: data and command mode, `AT?MODE` answers AT) or `net` (command mode only, AT?MODE
    answers NET: what DUNE requires).  docs/drivers.md lists what is reproduced."""

    def __init__(self, backend: ModemBackend, host: str = "127.0.0.1", port: int = 0, *,
                 bitrate: float | None = None, ack_time: float | None = None, ack_timeout: float = 5.0,
                 payload_timeout: float = 2.0, max_clients: int = 8, interpreter: str = "at") -> None:
        if interpreter not in ("at", "net"):
            raise ValueError(f"interpreter must be at or net, got {interpreter!r}")
        self.backend = backend
        self.host = host
        self.port = port
        self.bitrate = bitrate
        self.ack_time = ack_time
        self.ack_timeout = ack_timeout
        self.payload_timeout = payload_timeout
        self.max_clients = max_clients
        self.interpreter = interpreter
        self.settings = dict(DEFAULT_SETTINGS, AL=str(backend.address))
        self.last = {"T": "0", "E": "0", "I": "0", "V": "0.00"}
        self.counters: Counter[str] = Counter()
        self.clients: list[_AtClient] = []
        self._io = LoopThread(f"uwsimnet-emu-evologics-{backend.id}")
        self._server: TcpServer | None = None
        self._tokens = itertools.count(1)
        self._txs: dict[int, _Tx] = {}
        self._msg: _Tx | None = None       # the instant message (IM, IMS, PBM) being delivered
        self._di = "EMPTY"                # AT?DI once no message is being delivered
        self._pool = 0
        self._delivered_bytes = 0
        self._stream: deque[tuple[int, bytes, int]] = deque()   # data-mode packets not yet handed over
        self._streaming: _Tx | None = None
        self._ticker: asyncio.Task | None = None
        self.closing = False

    # -- lifecycle ----------------------------------------------------------------------------------
    def start(self) -> tuple[str, int]:
        self._io.start()
        self._io.run(self._start())
        self.backend.on_frame.append(self._bk_frame)
        self.backend.on_status.append(self._bk_status)
        return self.host, self.port

    async def _start(self) -> None:
        self._server = TcpServer(self._io.loop, lambda: _AtClient(self), self.host, self.port)
        self.port = self._server.port
        self._ticker = self._io.loop.create_task(self._tick())

    def close(self) -> None:
        detach(self.backend, self._bk_frame, self._bk_status)
        self._io.shutdown(self._close)

    async def _close(self) -> None:
        self.closing = True
        if self._ticker is not None:
            self._ticker.cancel()
        for tx in self._txs.values():
            for h in tx.timers:
                h.cancel()
        if self._server is not None:
            self._server.close()
        for c in list(self.clients):
            c.close()
        # a connection accepted just now gets its connection_made a moment later: it closes itself
        # then (see _AtClient), and its connection_lost must run before the loop stops
        await asyncio.sleep(0.05)

    def __enter__(self) -> EvoLogicsEmulator:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    async def _tick(self) -> None:
        while True:
            await asyncio.sleep(0.1)
            now = time.monotonic()
            for c in list(self.clients):
                for ev in c.codec.expire(now):
                    self._command(c, ev)
                c.flush_data()
            for tx in list(self._txs.values()):
                if (not tx.done and tx.t_sent is not None and now - tx.t_sent > self.ack_timeout
                        and self.backend.now() - tx.sim_sent > self.ack_timeout):
                    self._finish(tx, False)

    # -- time -----------------------------------------------------------------------------------------
    def clock_us(self) -> int:
        """AT?CLOCK: the simulation time in µs on a 32-bit counter."""
        return int(self.backend.now() * 1e6) % CLOCK_WRAP

    def _later(self, tx: _Tx | None, delay_us: float, fn: Any, *args: Any) -> None:
        h = self._io.loop.call_later(max(0.0, delay_us) / 1e6, fn, *args)
        if tx is not None:
            tx.timers.append(h)

    def _burst_us(self, n: int) -> int:
        return int(n * 8e6 / (self.bitrate or self.backend.info().get("bitrate") or 1000))

    # -- output -------------------------------------------------------------------------------------
    def _note(self, text: bytes, extended: bool = False) -> None:
        """A notification (one line, without CRLF) to every client: `+++AT:<len>:` framed in data mode;
        extended ones (AT@ZX1) only to the clients that asked for them."""
        for c in list(self.clients):
            if extended and c.channel["ZX"] != "1":
                continue
            c.write(at.bes("", text) if c.codec.mode == "data" else text + at.CRLF)

    @staticmethod
    def _answer(c: _AtClient, name: str, ties: bool, text: str | list[str]) -> None:
        if isinstance(text, list):
            body = b"".join(at.line(x) for x in text)
            c.write(at.bes(name, body) if ties else body + at.CRLF)
        else:
            c.write(at.bes(name, text.encode("ascii")) if ties else at.line(text))

    # -- commands (loop thread) ---------------------------------------------------------------------
    def _command(self, c: _AtClient, ev: at.DeviceEvent) -> None:
        self.counters["commands"] += 1
        if isinstance(ev, at.RawData):
            c.add_data(ev.data)
            return
        if isinstance(ev, at.BadCommand):
            self.counters[f"bad_{ev.kind}"] += 1
            log.info("%s: %s", self.backend.id, ev.detail)
            self._answer(c, at.request_name(ev.raw.decode("latin-1").lstrip("+")), ev.ties, ev.reply)
        elif isinstance(ev, at.SendCommand):
            answer = self._send(c, ev)
            if answer is not None:
                self._answer(c, ev.name, ev.ties, answer)
        else:
            answer = self._plain(c, ev)
            if answer is not None:
                self._answer(c, ev.name, ev.ties and ev.name != "C", answer)

    def _send(self, c: _AtClient, ev: at.SendCommand) -> str:
        pid = c.pid if ev.pid is None else ev.pid
        if not 1 <= ev.dst <= 255 or not 0 <= pid <= 7:
            return ERR_RANGE
        if ev.dst == self.backend.address:
            return ERR_DESTINATION
        if ev.name == "*SEND":
            return self._burst(ev.dst, ev.data, pid, report=True)
        kind = {"*SENDIM": "im", "*SENDIMS": "ims", "*SENDPBM": "pbm"}[ev.name]
        flag = ev.flag if kind == "im" else None
        if flag == "ack" and ev.dst == at.BROADCAST:
            return ERR_FORMAT              # "if flag is ack in broadcast mode, a syntax error" (section 5.5.1)
        cur = self._msg
        if cur is not None and cur.phase in ("air", "wait"):
            self.counters["busy"] += 1
            return busy_im(cur.dst)
        if cur is not None:                # messages are not queued: a new one cancels (section 5.5.4)
            self._cancel(cur)
        tx = _Tx(next(self._tokens), kind, ev.dst, len(ev.data), flag, pid, im_duration_us(len(ev.data)),
                 report=kind == "im" and flag == "ack")
        self._txs[tx.token] = tx
        self._msg = tx
        self.counters[f"tx_{kind}"] += 1
        delay = 0
        if kind == "ims" and ev.timestamp_us is not None:
            delay = (ev.timestamp_us - self.clock_us()) % CLOCK_WRAP
            if delay > CLOCK_WRAP // 2:    # in the past: the IMS expires
                self._expire(tx)
                return "OK"
            tx.phase = "wait"
        self._later(tx, 0, self._tx_start, tx, ev.data, Message(kind, flag, ev.timestamp_us, pid), delay)
        return "OK"

    def _tx_start(self, tx: _Tx, data: bytes, msg: Message, delay: int) -> None:
        """Just after the OK: SENDSTART (an IMS's with the delay until its time), then on air."""
        if tx.done:
            return
        if self._ext_any():
            self._note(f"SENDSTART,{tx.dst},{_TYPE[tx.kind]},{tx.dur_us},{delay}".encode(), extended=True)
        if delay:
            self._later(tx, delay, self._on_air, tx, data, msg)
        else:
            self._on_air(tx, data, msg)

    def _on_air(self, tx: _Tx, data: bytes, msg: Message) -> None:
        if tx.done:
            return
        tx.phase = "air"
        t0 = self.clock_us()
        self.backend.send(tx.dst, data, tag=tx.token, msg=msg)
        self._later(tx, tx.dur_us, self._air_end, tx, t0)

    def _air_end(self, tx: _Tx, t0: int) -> None:
        if tx.kind == "ims" or self._ext_any():
            self._note(f"SENDEND,{tx.dst},{_TYPE[tx.kind]},{t0},{tx.dur_us}".encode(), extended=tx.kind != "ims")
        if tx.done:
            return
        self._sent(tx)
        if tx.report:
            tx.phase = "ack"
        else:
            self._finish(tx, True)

    def _burst(self, dst: int, data: bytes, pid: int, report: bool, stream: bool = False) -> str:
        pool = int(self.settings.get("ZL", "16384") or 16384)
        if self._pool + len(data) > pool:
            self.counters["buffer_full"] += 1
            return ERR_FULL
        tx = _Tx(next(self._tokens), "burst", dst, len(data), None, pid, self._burst_us(len(data)),
                 report=report and dst != at.BROADCAST)
        self._txs[tx.token] = tx
        self._pool += len(data)
        self.counters["tx_burst"] += 1
        if stream:
            self._streaming = tx
        t0 = self.clock_us()
        if self._ext_any():                              # after the OK
            self._later(tx, 0, self._note, f"SENDSTART,{dst},burst,{tx.dur_us},0".encode(), True)
            self._later(tx, tx.dur_us, self._note, f"SENDEND,{dst},burst,{t0},{tx.dur_us}".encode(), True)
        self.backend.send(dst, data, tag=tx.token, msg=Message("burst", pid=pid))
        return "OK"

    def data_mode_burst(self, c: _AtClient, data: bytes) -> None:
        """Data mode: bytes from the host are burst data to the Remote Address (section 5.4.1)."""
        dst = int(self.settings.get("AR", "0") or 0)
        if dst == 0 or dst == self.backend.address:
            self._note(f"DROPCNT,{len(data)}".encode())
            return
        pool = int(self.settings.get("ZL", "16384") or 16384)
        queued = sum(len(d) for _, d, _ in self._stream)
        if self._pool + queued + len(data) > pool:
            self.counters["buffer_full"] += 1
            self._note(f"DROPCNT,{len(data)}".encode())
            return
        n = self._packet_bytes()
        for i in range(0, len(data), n):
            self._stream.append((dst, data[i:i + n], c.pid))
        self._pump_stream()

    def _packet_bytes(self) -> int:
        """Data-mode burst data goes out in packets of Packet Time (AT?ZP, ms) at the bit rate, no larger than
        the simulated modem takes (its max_frame_bytes and FIFO, less its header)."""
        info = self.backend.info()
        hdr = int(info.get("header_bytes") or 0)
        limits = [at.BURST_MAX]
        for key in ("max_frame_bytes", "fifo_capacity"):
            if info.get(key):
                limits.append(int(info[key]) - hdr)
        bitrate = self.bitrate or info.get("bitrate")
        zp = int(self.settings.get("ZP") or 0)
        if zp and bitrate:
            limits.append(int(zp / 1000 * float(bitrate) / 8))
        return max(16, min(limits))

    def _pump_stream(self) -> None:
        """One data-mode packet at a time to the simulated modem: the next once the previous one is out."""
        while self._stream and (self._streaming is None or self._streaming.done):
            dst, data, pid = self._stream.popleft()
            self._burst(dst, data, pid, report=True, stream=True)

    def _ext_any(self) -> bool:
        return any(c.channel["ZX"] == "1" for c in self.clients)

    def _di_text(self) -> str:
        m = self._msg
        if m is not None:
            return f"DELIVERING,{m.kind},{m.pid}"
        return self._di

    def _link_status(self) -> str | list[str]:
        """`AT?S`: one line from the `at` interpreter; a block ended by an empty line from `net`, which is
        what evins waits for there (role_at.erl 3b5c6c0, from_term_helper: `{"?S", net} -> multiline`, a
        multiline answer ends at "\\n\\r\\n")."""
        text = f"INITIATION LISTEN {max(0, int(self.settings.get('ZL') or 16384) - self._pool)}"
        return [text] if self.interpreter == "net" else text

    def _plain(self, c: _AtClient, ev: at.Command) -> str | list[str] | None:
        name, arg = ev.name, ev.arg.strip()
        s = self.settings
        if name.startswith("?"):
            key = name[1:]
            if key in self.last:
                return self.last[key]
            if key in CHANNEL_SETTINGS:
                return c.channel[key]
            if key in s:
                return s[key]
            answers = {"BL": lambda: str(int(self.bitrate or self.backend.info().get("bitrate") or 0)),
                       "DI": self._di_text, "PID": lambda: str(c.pid),
                       "MODE": lambda: self.interpreter.upper(), "CLOCK": lambda: str(self.clock_us()),
                       "UT": lambda: f"{self.backend.now():.3f}", "PHY": lambda: "ON",
                       "ZE": lambda: str(self._delivered_bytes), "ZD": lambda: "0", "ZO": lambda: "0",
                       "S": self._link_status}
            answers["BR"] = answers["BL"]
            fn = answers.get(key)
            return fn() if fn is not None else ERR_FORMAT
        if name.startswith("@"):
            key = name[1:]
            if key == "CTRL":
                return "OK"
            if key in CHANNEL_SETTINGS:
                if arg not in ("0", "1"):
                    return ERR_RANGE if arg else ERR_FORMAT
                c.channel[key] = arg
                return "OK"
            if key == "ZL":
                name = "!ZL"
            else:
                return ERR_FORMAT
        if name.startswith("!"):
            key = name[1:]
            if key not in s:
                return ERR_FORMAT
            if key == "AL" and arg != s["AL"]:
                return ERR_NOT_ACCEPTED      # the simulated modem's address is the scene's
            if not arg.lstrip("-").isdigit():
                return ERR_FORMAT
            if key in ("L", "LC", "G") and not 0 <= int(arg) <= (3 if key == "L" else 1):
                return ERR_RANGE
            s[key] = arg
            return "OK"
        if name == "&V":
            return [f"{label}: {s.get(key, '0')}" for label, key in SETTING_NAMES]
        if name in ("&W", "H"):
            return "OK"
        if name == "&F":
            self.settings = dict(DEFAULT_SETTINGS, AL=str(self.backend.address))
            return "OK"
        if name == "Z":
            if arg == "0":               # reset: no answer (section 5.3.8)
                self._drop_pending()
                return None
            if arg not in ("", "1", "2", "3", "4"):
                return ERR_RANGE if arg.isdigit() else ERR_FORMAT
            self._drop_pending(bursts=arg in ("", "1", "4"), messages=arg in ("", "3", "4"))
            return "OK"
        if name == "A":
            return "INITIATION LISTEN"
        if name == "N":
            return "INITIATION NOISE"
        if name == "S":
            return "INITIATION DEAF"
        if name == "D":
            return "INITIATION ESTABLISH"
        if name == "I":
            n = arg or "0"
            if n == "0":
                return FIRMWARE
            if n == "1":
                return ATI1
            if n == "7":
                return "EvoLogics GmbH"
            return ERR_RANGE if n.isdigit() else ERR_FORMAT
        if name == "O":
            return None if self.interpreter == "at" else ERR_FORMAT   # ATO: no answer (section 5.3.2)
        if name == "C":
            return "OK" if self.interpreter == "at" else ERR_FORMAT
        return ERR_FORMAT

    def _drop_pending(self, bursts: bool = True, messages: bool = True) -> None:
        """ATZn: forget the frames waiting for a report (no DELIVERED/FAILED will come for them)."""
        for tx in list(self._txs.values()):
            if (tx.kind == "burst" and bursts) or (tx.kind != "burst" and messages):
                self._retire(tx)
        if messages:
            self._di = "EMPTY"
        if bursts:
            self._stream.clear()
            self._streaming = None

    def _retire(self, tx: _Tx) -> None:
        tx.done = True
        for h in tx.timers:
            h.cancel()
        self._txs.pop(tx.token, None)
        if tx is self._msg:
            self._msg = None
        if tx.kind == "burst":
            self._pool = max(0, self._pool - tx.length)

    def _cancel(self, tx: _Tx) -> None:
        self._retire(tx)
        self.counters["canceled"] += 1
        # after the answer to the message that cancels it
        self._io.loop.call_soon(self._note, f"CANCELED{tx.kind.upper()},{tx.dst}".encode())

    def _expire(self, tx: _Tx) -> None:
        self._retire(tx)
        self._di = f"EXPIRED,ims,{tx.pid}"
        self.counters["expired"] += 1
        self._io.loop.call_soon(self._note, f"EXPIREDIMS,{tx.dst}".encode())

    # -- backend events (engine thread -> loop thread) ------------------------------------------------
    def _bk_status(self, st: BackendStatus) -> None:
        if isinstance(st.tag, int) and st.tag in self._txs:
            self._io.call(self._status, st)

    def _bk_frame(self, f: BackendFrame) -> None:
        self._io.call(self._rx, f)

    def _status(self, st: BackendStatus) -> None:
        tx = self._txs.get(st.tag)
        if tx is None or tx.done:
            return
        ev = st.event
        if tx.kind == "burst":
            if tx is self._streaming and ev in ("sent", "transmitted", "dropped", "failed"):
                self._streaming = None
                self._io.loop.call_soon(self._pump_stream)
            if ev in ("sent", "transmitted"):    # transmitted: the simulated MAC awaits an ACK
                self._sent(tx)
                if not tx.report:
                    self._finish(tx, True)
            elif ev in ("acked", "failed", "dropped"):
                self._finish(tx, ev == "acked")
            elif ev in ("delivered", "lost") and tx.report:
                self._later(tx, (st.prop_time or 0.0) * 1e6, self._finish, tx, ev == "delivered")
            return
        if ev in ("failed", "dropped"):
            self._finish(tx, False)
        elif ev in ("delivered", "lost") and tx.report:
            # the addressee reports the message dur_us after it arrived (RECVEND), acknowledges at once,
            # and the acknowledgement needs one propagation time plus its own time on air
            back = (st.prop_time or 0.0) * 1e6
            ack = IMACK_US if self.ack_time is None else self.ack_time * 1e6
            if ev == "delivered":
                # what the acknowledgement is received with: the link at the addressee's distance
                d = (st.prop_time or 0.0) * float(self.settings.get("CA", "1500") or 1500)
                lm = link_metrics(BackendFrame(tx.dst, self.backend.address, b"", distance=d, prop_time=st.prop_time))
                self._later(tx, tx.dur_us + back, self._ack_start, tx)
                self._later(tx, tx.dur_us + back + ack, self._ack_end, tx, int(ack), lm)
            else:
                self._later(tx, tx.dur_us + back + ack, self._finish, tx, False)

    def _sent(self, tx: _Tx) -> None:
        """The frame has left: its ack timeout starts, on both clocks (see the class docstring)."""
        tx.t_sent = time.monotonic()
        tx.sim_sent = self.backend.now()

    def _ack_start(self, tx: _Tx) -> None:
        if not tx.done:
            self._note(b"RECVSTART", extended=True)

    def _ack_end(self, tx: _Tx, ack_us: int, lm: Any) -> None:
        if tx.done:
            return
        t = self.clock_us()
        # AT?T is measured on the acknowledgement of an instant message too (manual section 5.12.5)
        self.last.update(T=str(int(round(lm.prop_time * 1e6))), E=str(lm.rssi), I=str(lm.integrity))
        self._note(f"RECVEND,{(t - ack_us) % CLOCK_WRAP},{ack_us},{lm.rssi},{lm.integrity}".encode(), extended=True)
        self._finish(tx, True)

    def _finish(self, tx: _Tx, ok: bool) -> None:
        if tx.done:
            return
        self._retire(tx)
        if tx.kind == "burst" and ok:
            self._delivered_bytes += tx.length
        if tx.kind != "burst" and not ok:
            self._di = f"FAILED,im,{tx.pid}" if tx.kind == "im" else "EMPTY"
        elif tx.kind != "burst":
            self._di = "EMPTY"
        if not tx.report:
            return
        self.counters["delivered" if ok else "failed"] += 1
        if tx.kind == "im":
            self._note(at.delivered(tx.dst)[:-2] if ok else at.failed(tx.dst)[:-2])
        else:
            self._note(at.delivered(tx.dst, tx.length)[:-2] if ok else at.failed(tx.dst, tx.length)[:-2])

    def _rx(self, f: BackendFrame) -> None:
        self.counters["rx"] += 1
        m = link_metrics(f, self.bitrate, float(self.settings.get("CA", "1500") or 1500))
        self.last.update(T=str(int(round(m.prop_time * 1e6))), E=str(m.rssi), I=str(m.integrity),
                         V=f"{m.velocity:.2f}")
        msg = f.msg
        if msg is None or msg.kind not in ("burst", "im", "ims", "pbm"):
            msg = Message("im", "noack") if len(f.data) <= at.IM_MAX else Message("burst")
        self._note(b"RECVSTART", extended=True)
        if msg.kind == "burst":
            # the simulator spent the burst's time on air (its bit rate) before handing it over
            dur = self._burst_us(len(f.data))
            self._rx_end(f, msg, m, dur, (self.clock_us() - dur) % CLOCK_WRAP)
        else:
            # an instant message is on air at the modem's IM rate, not the simulator's bit rate: the frame's
            # arrival is taken as the start of reception and the modem reports it once demodulated
            dur = im_duration_us(len(f.data))
            self._later(None, dur, self._rx_end, f, msg, m, dur, self.clock_us())

    def _rx_end(self, f: BackendFrame, msg: Message, m: Any, dur: int, t_start: int) -> None:
        self._note(f"RECVEND,{t_start},{dur},{m.rssi},{m.integrity}".encode(), extended=True)
        pid = msg.pid or 0
        vel = f"{m.velocity:.4f}"
        kind, data = msg.kind, f.data
        if kind == "burst":
            head = f",{f.src},{f.dst},{m.bitrate},{m.rssi},{m.integrity},{int(round(m.prop_time * 1e6))},{vel},"
            word = "RECV"
        elif kind == "im":
            head = f",{f.src},{f.dst},{msg.flag or 'noack'},{dur},{m.rssi},{m.integrity},{vel},"
            word = "RECVIM"
        elif kind == "ims":
            head = f",{f.src},{f.dst},{t_start},{dur},{m.rssi},{m.integrity},{vel},"
            word = "RECVIMS"
        else:
            head = f",{f.src},{f.dst},{dur},{m.rssi},{m.integrity},{vel},"
            word = "RECVPBM"
        plain = f"{word},{len(data)}{head}".encode() + data
        ext = f"{word},p{pid},{len(data)}{head}".encode() + data
        for c in list(self.clients):
            if kind == "burst" and c.codec.mode == "data":
                c.write(data)               # data mode: received burst data goes out as it is
                continue
            body = ext if c.channel["ZF"] == "1" else plain
            c.write(at.bes("", body) if c.codec.mode == "data" else body + at.CRLF)
        if kind == "im" and msg.flag == "ack" and f.dst == self.backend.address and self._ext_any():
            ack = IMACK_US if self.ack_time is None else int(self.ack_time * 1e6)
            t0 = self.clock_us()
            self._note(f"SENDSTART,{f.src},imack,{ack},0".encode(), extended=True)
            self._later(None, ack, self._note, f"SENDEND,{f.src},imack,{t0},{ack}".encode(), True)


class _AtClient(ServerClient):
    def __init__(self, emu: EvoLogicsEmulator) -> None:
        super().__init__(emu.clients)
        self.emu = emu
        self.codec = at.DeviceCodec(payload_timeout=emu.payload_timeout, data_mode=emu.interpreter == "at")
        self.channel = dict.fromkeys(CHANNEL_SETTINGS, "0")
        self.pid = 0
        self._data = bytearray()

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        if self.accept(transport, self.emu.closing or len(self.emu.clients) >= self.emu.max_clients):
            self.emu.counters["connections"] += 1

    def data_received(self, data: bytes) -> None:
        try:
            for ev in self.codec.feed(data, time.monotonic()):
                if not isinstance(ev, at.RawData):
                    self.flush_data()        # burst data written before a command goes first
                self.emu._command(self, ev)
            self.flush_data()
        except Exception:  # noqa: BLE001 - one client's bad input must not stop the emulator
            log.exception("%s: error handling a command", self.emu.backend.id)

    def add_data(self, data: bytes) -> None:
        self._data += data

    def flush_data(self) -> None:
        if self._data:
            data, self._data = bytes(self._data), bytearray()
            self.emu.data_mode_burst(self, data)
