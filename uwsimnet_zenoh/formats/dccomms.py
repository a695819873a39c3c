"""Every dccomms framing, sans-IO: DataLinkFrame (CRC16, CRC32, no FCS), VariableLength2BPacket,
VariableLengthPacket, SimplePacket(n, CRC16 | none), DcMacPacket (the original's own MAC frame), and the GLI
messages that carry them.  Written once here: the PHY (framed sizes on air), the scene (builder names), the
POSIX-queue bridge, the serial driver and its emulator all read this module.

Facts (dccomms 0710d53, dccomms_packets 0deed72; docs/bridges.md has the file:line of each):

=========================  =========================================================  ===========
framing                    frame (header fields big-endian)                             max frame
=========================  =========================================================  ===========
DataLinkFrame crc16        ``55 55 | dst | src | len u16 | payload <= 2048 | crc16``   2056
DataLinkFrame crc32        ``55 55 | dst | src | len u16 | payload <= 2048 | crc32``   2058
DataLinkFrame nofcs        ``55 55 | dst | src | len u16 | payload <= 2048``           2054
VariableLength2BPacket     ``55 | len u16 | payload <= 2048 | crc16(payload)``        2053
VariableLengthPacket       ``55 | len u8 | payload <= 255 | crc16(payload)``          259
SimplePacket(n, crc16)     ``55 | payload (exactly n) | crc16(payload)``              n + 3
SimplePacket(n, none)      ``55 | payload (exactly n)``                               n + 1
DcMacPacket data           ``55 | src:4 dst:4 | flags | len lo | payload <= 2047 | crc16``  2056
DcMacPacket rts / cts      ``55 | src:4 dst:4 | flags | ack:5 half:3 | half lo | crc16`` (7 bytes)
DcMacPacket sync           ``55 | src:4 dst:4 | flags | master ack mask | crc16`` (6 bytes)
=========================  =========================================================  ===========

DataLinkFrame's FCS covers dst..payload; the frame is valid when the CRC over dst..FCS is 0.  CRC16 is
CRC-16/XMODEM; dccomms' CRC32 is polynomial 0x04C11DB7, MSB first, initial value 0 and **no final xor**
(check value 0x89A1897F, not zlib's).  A FRAME message on the queues is the type byte 0, then the packet
buffer at its largest: the frame, padding up to the maximum frame, then the 12-byte virtual area
``seq u32 | src u32 | dst u32`` little-endian (x86 host order).  Framings without address fields carry
addresses only there; SimplePacket's sequence number is its first two payload bytes (big-endian).

Decoding checks exactly what dccomms checks, and only that: the preamble is *not* checked (dccomms does
not on this path), a DataLinkFrame length above 2048 is refused (dccomms throws), a VariableLength2BPacket
length above 2048 reads as 0 (then the CRC decides), and the FCS is checked as IsOk() does.
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass

from ..errors import UwsimnetError

BROADCAST = 255
VIRTUAL_AREA = 12
MSG_FRAME, MSG_REQ_STATE, MSG_CMD_STATE = 0, 1, 2
PHY_BUSY, PHY_READY = 0, 1
GLI_MAXFRAMESIZE = 8191
"""dccomms' default `maxframesize`: queues are created with mq_msgsize 8191 + 1 = 8192."""
GLI_MSGSIZE = GLI_MAXFRAMESIZE + 1
GLI_MAXMSG = 10
GLI_MODE = 0o777


# -- CRCs -------------------------------------------------------------------------------------------
def _crc16_table() -> tuple[int, ...]:
    out = []
    for i in range(256):
        c = i << 8
        for _ in range(8):
            c = ((c << 1) ^ 0x1021) if c & 0x8000 else (c << 1)
        out.append(c & 0xFFFF)
    return tuple(out)


def _crc32_table() -> tuple[int, ...]:
    out = []
    for i in range(256):
        c = i << 24
        for _ in range(8):
            c = ((c << 1) ^ 0x04C11DB7) if c & 0x80000000 else (c << 1)
        out.append(c & 0xFFFFFFFF)
    return tuple(out)


_T16: tuple[int, ...] = ()
_T32: tuple[int, ...] = ()
"""The tables, made on the first CRC (every run imports this module, few compute a CRC: start-up time)."""


def _tables() -> tuple[tuple[int, ...], tuple[int, ...]]:
    global _T16, _T32
    _T16, _T32 = _crc16_table(), _crc32_table()
    return _T16, _T32


def crc16(data: bytes | bytearray | memoryview, crc: int = 0) -> int:
    """CRC-16/XMODEM as dccomms' Checksum::crc16 (check: crc16(b"123456789") == 0x31C3)."""
    t = _T16 or _tables()[0]
    for b in data:
        crc = ((crc << 8) & 0xFF00) ^ t[(crc >> 8) ^ b]
    return crc


def crc32(data: bytes | bytearray | memoryview, crc: int = 0) -> int:
    """dccomms' Checksum::crc32: poly 0x04C11DB7, MSB first, init 0, no final xor (check 0x89A1897F)."""
    t = _T32 or _tables()[1]
    for b in data:
        crc = ((crc << 8) & 0xFFFFFFFF) ^ t[(crc >> 24) ^ b]
    return crc


# -- packets -----------------------------------------------------------------------------------------
class FramingError(UwsimnetError, ValueError):
    """A buffer dccomms would not accept as a packet of this framing; str(e) is the reason."""


@dataclass(frozen=True)
class Packet:
    """A decoded packet.  `dst`/`src`: DataLinkFrame's header bytes (None for the other framings, whose
    addresses travel in the virtual area only).  `seq`: SimplePacket's first two payload bytes."""

    payload: bytes
    size: int                       # frame bytes (what goes on air)
    dst: int | None = None
    src: int | None = None
    seq: int | None = None
    kind: str = "data"              # DcMacPacket: data | rts | cts | sync (the others carry data only)
    fields: dict[str, int] | None = None
    """DcMacPacket rts/cts: {"rts_size", "slave_ack_mask"}; sync: {"master_ack_mask"}."""


class Framing:
    """One dccomms packet builder.  Subclasses set the layout; all methods are pure."""

    name: str                       # the builder class name a scene gives in <className>
    max_payload: int
    max_frame: int                  # the packet buffer's frame area (frame + padding)
    addressed = False               # dst/src in the frame itself (DataLinkFrame, DcMacPacket)
    max_address = 255               # the largest address the frame's own fields hold (addressed framings)
    preamble: bytes = b"\x55"
    header_len: int                 # bytes needed to know the frame's length

    @property
    def buffer_size(self) -> int:
        """dccomms' Packet::GetBufferSize(): frame area + virtual area."""
        return self.max_frame + VIRTUAL_AREA

    @property
    def message_size(self) -> int:
        """Bytes of a FRAME message on the queues (type byte + buffer)."""
        return 1 + self.buffer_size

    def frame_size(self, payload_len: int) -> int:
        raise NotImplementedError

    def check_payload(self, n: int) -> str | None:
        """Why a payload of n bytes cannot be framed (None if it can)."""
        if n > self.max_payload:
            return f"payload of {n} bytes exceeds {self.max_payload} ({self.name})"
        return None

    def encode(self, payload: bytes, dst: int = BROADCAST, src: int = 0) -> bytes:
        raise NotImplementedError

    def frame_length(self, head: bytes) -> int | None:
        """Total frame length from its first `header_len` bytes; None if the length field is impossible
        (the frame cannot be delimited)."""
        raise NotImplementedError

    def parse(self, buf: bytes | bytearray | memoryview) -> Packet:
        """The packet at the start of `buf` (more bytes may follow): dccomms' CreateFromBuffer then
        IsOk().  FramingError with the reason where dccomms would reject it."""
        raise NotImplementedError

    def __repr__(self) -> str:
        return self.name

    def length_field(self, head: bytes) -> int:
        """The payload length the header claims (for error reports)."""
        return self.frame_length(head) or 0

    def header_addresses(self, raw: bytes) -> tuple[int, int]:
        """(dst, src) as the frame's header says (framings without addresses: broadcast, 0)."""
        return BROADCAST, 0

    def _need(self, b: bytes, n: int) -> None:
        if len(b) < n:
            raise FramingError(f"{len(b)} bytes, the {self.name} needs {n}")


class DataLinkFrame(Framing):
    FCS_SIZES = {"crc16": 2, "crc32": 4, "nofcs": 0}
    NAMES = {"crc16": "DataLinkFrameBuilderCRC16", "crc32": "DataLinkFrameBuilderCRC32",
             "nofcs": "DataLinkFrameBuilderNoFCS"}
    addressed = True
    preamble = b"\x55\x55"
    header_len = 6
    max_payload = 2048

    def __init__(self, fcs: str = "crc16") -> None:
        if fcs not in self.FCS_SIZES:
            raise ValueError(f"DataLinkFrame fcs must be one of {sorted(self.FCS_SIZES)}, got {fcs!r}")
        self.fcs = fcs
        self.fcs_size = self.FCS_SIZES[fcs]
        self.name = self.NAMES[fcs]
        self.max_frame = 6 + self.max_payload + self.fcs_size

    def frame_size(self, payload_len: int) -> int:
        return 6 + payload_len + self.fcs_size

    def _fcs(self, covered: bytes) -> bytes:
        if self.fcs == "crc16":
            return crc16(covered).to_bytes(2, "big")
        if self.fcs == "crc32":
            return crc32(covered).to_bytes(4, "big")
        return b""

    def encode(self, payload: bytes, dst: int = BROADCAST, src: int = 0) -> bytes:
        if not (0 <= dst <= 255 and 0 <= src <= 255):
            raise ValueError(f"DataLinkFrame addresses are one byte: dst={dst} src={src}")
        if (why := self.check_payload(len(payload))) is not None:
            raise ValueError(why)
        body = bytes((dst, src)) + len(payload).to_bytes(2, "big") + bytes(payload)
        return b"\x55\x55" + body + self._fcs(body)

    def frame_length(self, head: bytes) -> int | None:
        n = int.from_bytes(head[4:6], "big")
        return None if n > self.max_payload else self.frame_size(n)

    def length_field(self, head: bytes) -> int:
        return int.from_bytes(head[4:6], "big")

    def header_addresses(self, raw: bytes) -> tuple[int, int]:
        return raw[2], raw[3]

    def parse(self, buf: bytes | bytearray | memoryview) -> Packet:
        b = bytes(buf)
        self._need(b, 6)
        n = int.from_bytes(b[4:6], "big")
        if n > self.max_payload:
            raise FramingError(f"length {n} exceeds {self.max_payload}")
        end = self.frame_size(n)
        self._need(b, end)
        covered = b[2:end]
        if self.fcs == "crc16" and crc16(covered) != 0:
            raise FramingError("bad FCS (CRC16)")
        if self.fcs == "crc32" and crc32(covered) != 0:
            raise FramingError("bad FCS (CRC32)")
        return Packet(b[6:6 + n], end, dst=b[2], src=b[3])


class VariableLength2BPacket(Framing):
    name = "VariableLength2BPacketBuilder"
    max_payload = 2048
    max_frame = 1 + 2 + 2048 + 2
    header_len = 3

    def frame_size(self, payload_len: int) -> int:
        return payload_len + 5

    def encode(self, payload: bytes, dst: int = BROADCAST, src: int = 0) -> bytes:
        if (why := self.check_payload(len(payload))) is not None:
            raise ValueError(why)
        p = bytes(payload)
        return b"\x55" + len(p).to_bytes(2, "big") + p + crc16(p).to_bytes(2, "big")

    def frame_length(self, head: bytes) -> int | None:
        n = int.from_bytes(head[1:3], "big")
        return self.frame_size(n if n <= self.max_payload else 0)

    def length_field(self, head: bytes) -> int:
        return int.from_bytes(head[1:3], "big")

    def parse(self, buf: bytes | bytearray | memoryview) -> Packet:
        b = bytes(buf)
        self._need(b, 3)
        n = int.from_bytes(b[1:3], "big")
        if n > self.max_payload:        # dccomms reads an impossible length as 0 (then the CRC decides)
            n = 0
        end = self.frame_size(n)
        self._need(b, end)
        if crc16(b[3:end]) != 0:
            raise FramingError("bad CRC16")
        return Packet(b[3:3 + n], end)


class VariableLengthPacket(Framing):
    name = "VariableLengthPacketBuilder"
    max_payload = 255
    max_frame = 1 + 1 + 255 + 2
    header_len = 2

    def frame_size(self, payload_len: int) -> int:
        return payload_len + 4

    def encode(self, payload: bytes, dst: int = BROADCAST, src: int = 0) -> bytes:
        if (why := self.check_payload(len(payload))) is not None:
            raise ValueError(why)
        p = bytes(payload)
        return b"\x55" + bytes((len(p),)) + p + crc16(p).to_bytes(2, "big")

    def frame_length(self, head: bytes) -> int | None:
        return self.frame_size(head[1])

    def length_field(self, head: bytes) -> int:
        return head[1]

    def parse(self, buf: bytes | bytearray | memoryview) -> Packet:
        b = bytes(buf)
        self._need(b, 2)
        n = b[1]
        end = self.frame_size(n)
        self._need(b, end)
        if crc16(b[2:end]) != 0:
            raise FramingError("bad CRC16")
        return Packet(b[2:2 + n], end)


class SimplePacket(Framing):
    """Exactly `n` payload bytes (a shorter payload is padded with zeros; dccomms leaves whatever was in
    its buffer there)."""

    header_len = 1

    def __init__(self, n: int, fcs: str = "crc16") -> None:
        if n < 2:
            raise ValueError(f"SimplePacket payload size must be >= 2 (its sequence number), got {n}")
        if fcs not in ("crc16", "nofcs"):
            raise ValueError(f"SimplePacket fcs must be crc16 or nofcs, got {fcs!r}")
        self.n = n
        self.fcs = fcs
        self.fcs_size = 2 if fcs == "crc16" else 0
        self.max_payload = n
        self.max_frame = 1 + n + self.fcs_size
        self.name = f"SimplePacketBuilder{n}{fcs}"

    def frame_size(self, payload_len: int) -> int:
        return self.max_frame

    def encode(self, payload: bytes, dst: int = BROADCAST, src: int = 0) -> bytes:
        if (why := self.check_payload(len(payload))) is not None:
            raise ValueError(why)
        p = bytes(payload).ljust(self.n, b"\0")
        return b"\x55" + p + (crc16(p).to_bytes(2, "big") if self.fcs_size else b"")

    def frame_length(self, head: bytes) -> int | None:
        return self.max_frame

    def length_field(self, head: bytes) -> int:
        return self.n

    def parse(self, buf: bytes | bytearray | memoryview) -> Packet:
        b = bytes(buf)
        self._need(b, self.max_frame)
        if self.fcs_size and crc16(b[1:self.max_frame]) != 0:
            raise FramingError("bad CRC16")
        p = b[1:1 + self.n]
        return Packet(p, self.max_frame, seq=int.from_bytes(p[:2], "big"))


class DcMacPacket(Framing):
    """The DcMac MAC's frame (`DcMacPacketBuilder`), as the original's TWINBOT runs built it: dccomms_examples
    `src/include/dccomms_examples/DcMac.h` and `src/DcMac.cpp` at 3cfb74d (2019-05-19), the version
    `testing/mac_twinbot.sh` (9f101b2, 2019-08-03) loads from `libdccomms_examples_<rev>_packets.so`
    (the format moved unchanged to the umci module in 0b989d5; the `time` field it had before was removed
    in a3049e4, 2019-04-08).  Facts, DcMac.cpp lines:

    * 17-31: ``55 | add | flags | variable area``; 195-226: `add` = src << 4 | dst, four bits each;
    * 202-217: `flags` bits 0-2 the type, sync 0, rts 1, cts 2, data 3 (4-7: unknown, never IsOk);
    * 129-132, 85-90: data: payload length bits 8-10 in `flags` bits 4-6, bits 0-7 in the byte after
      `flags` (so 2047 at most, although MAX_PAYLOAD_SIZE is 2048), then the payload;
    * 237-247: rts/cts: two bytes, the announced data size halved and rounded up (11 bits: byte 0 bits 0-2,
      byte 1), read back doubled; 52-64: the same byte 0's bits 3-7 are the slave ack mask;
    * 39-50, 66-70: sync: one byte, the master's ack mask;
    * 150-191: CRC16 (XMODEM) over add .. end of the variable area, stored big-endian; IsOk when the CRC
      over add .. FCS is 0.  6-13: the packet buffer holds 1 + 2 + 2 + 2 + 1 + 2048 = 2056 bytes.

    A data packet carries a payload like any framing (`encode`, `frame_size` = payload + 6); rts, cts and
    sync packets parse with `kind` and `fields` and carry no payload."""

    name = "DcMacPacketBuilder"
    addressed = True
    max_address = 15
    max_payload = 0x7FF
    max_frame = 1 + 1 + 1 + 2 + 2 + 1 + 2048
    header_len = 4
    TYPES = ("sync", "rts", "cts", "data")
    _BODY = {"sync": 1, "rts": 2, "cts": 2}

    def frame_size(self, payload_len: int) -> int:
        return payload_len + 6

    @staticmethod
    def _add(dst: int, src: int) -> int:
        if not (0 <= dst <= 15 and 0 <= src <= 15):
            raise ValueError(f"DcMacPacket addresses are four bits: dst={dst} src={src}")
        return src << 4 | dst

    def _framed(self, body: bytes) -> bytes:
        return b"\x55" + body + crc16(body).to_bytes(2, "big")

    def encode(self, payload: bytes, dst: int = 15, src: int = 0) -> bytes:
        """A data packet (DcMac has no broadcast address: 255 becomes 15, the largest four-bit one)."""
        if (why := self.check_payload(len(payload))) is not None:
            raise ValueError(why)
        n = len(payload)
        body = bytes((self._add(15 if dst == BROADCAST else dst, src), 3 | (n >> 4) & 0x70, n & 0xFF))
        return self._framed(body + bytes(payload))

    def control(self, kind: str, dst: int = 0, src: int = 0, *, rts_size: int = 0, slave_ack_mask: int = 0,
                master_ack_mask: int = 0) -> bytes:
        """An rts, cts or sync packet (what DcMac's SetRtsDataSize / SetSlaveAckMask / SetMasterAckMask write)."""
        if kind == "sync":
            body = bytes((master_ack_mask & 0xFF,))
        elif kind in ("rts", "cts"):
            half = -(-rts_size // 2)
            body = bytes((((slave_ack_mask << 3) & 0xF8) | (half & 0x700) >> 8, half & 0xFF))
        else:
            raise ValueError(f"DcMacPacket control kinds are sync, rts, cts; got {kind!r}")
        return self._framed(bytes((self._add(dst, src), self.TYPES.index(kind))) + body)

    def frame_length(self, head: bytes) -> int | None:
        t = head[2] & 7
        if t > 3:
            return None                                      # unknown type: dccomms cannot delimit it
        if t == 3:
            return self.frame_size((head[2] & 0x70) << 4 | head[3])
        return 5 + self._BODY[self.TYPES[t]]

    def length_field(self, head: bytes) -> int:
        return (head[2] & 0x70) << 4 | head[3]

    def header_addresses(self, raw: bytes) -> tuple[int, int]:
        return raw[1] & 0xF, raw[1] >> 4

    def parse(self, buf: bytes | bytearray | memoryview) -> Packet:
        b = bytes(buf)
        self._need(b, 3)
        t = b[2] & 7
        if t > 3:
            raise FramingError(f"unknown DcMac packet type {t}")
        kind = self.TYPES[t]
        self._need(b, 4)
        end = self.frame_length(b[:4])
        assert end is not None
        self._need(b, end)
        if crc16(b[1:end]) != 0:
            raise FramingError("bad CRC16")
        dst, src = self.header_addresses(b)
        if kind == "data":
            return Packet(b[4:end - 2], end, dst=dst, src=src)
        if kind == "sync":
            fields = {"master_ack_mask": b[3]}
        else:
            fields = {"rts_size": ((b[3] & 7) << 8 | b[4]) * 2, "slave_ack_mask": b[3] >> 3}
        return Packet(b"", end, dst=dst, src=src, kind=kind, fields=fields)


# -- builder names ---------------------------------------------------------------------------------
ORIGINAL_BUILDERS = ("DataLinkFrameBuilderCRC16", "VariableLength2BPacketBuilder", "VariableLengthPacketBuilder",
                     "SimplePacketBuilder20crc16", "SimplePacketBuilder9crc16", "SimplePacketBuilder109crc16",
                     "DcMacPacketBuilder")
"""The packet-builder classes dccomms, dccomms_packets and dccomms_examples (DcMac) register with
class_loader (what an original scene can name)."""
_SIMPLE = re.compile(r"SimplePacketBuilder([0-9]+)(crc16|nofcs)")


def builder(name: str) -> Framing:
    """The framing of a packet-builder class name (ValueError listing the known ones otherwise).
    Beyond the original's registered names: DataLinkFrameBuilderCRC32, DataLinkFrameBuilderNoFCS and
    SimplePacketBuilder<n>crc16 / SimplePacketBuilder<n>nofcs for any n >= 2."""
    key = name.strip()
    for fcs, n in DataLinkFrame.NAMES.items():
        if key == n:
            return DataLinkFrame(fcs)
    if key == VariableLength2BPacket.name:
        return VariableLength2BPacket()
    if key == VariableLengthPacket.name:
        return VariableLengthPacket()
    if key == DcMacPacket.name:
        return DcMacPacket()
    if (m := _SIMPLE.fullmatch(key)) is not None and int(m.group(1)) >= 2:
        return SimplePacket(int(m.group(1)), m.group(2))
    raise ValueError(f"unknown packet builder {key!r} (known: {', '.join(known_builders())},"
                     " SimplePacketBuilder<n>crc16|nofcs)")


def known_builders() -> list[str]:
    return [*DataLinkFrame.NAMES.values(), VariableLength2BPacket.name, VariableLengthPacket.name,
            "SimplePacketBuilder20crc16", "SimplePacketBuilder9crc16", "SimplePacketBuilder109crc16",
            DcMacPacket.name]


DEFAULT = DataLinkFrame("crc16")
"""UWSim-NET's default packet builder (uwsim NetSim::GetSim, DataLinkFramePacketBuilder(crc16))."""


# -- GLI messages ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class VirtualArea:
    seq: int = 0
    src: int = 0
    dst: int = 0

    def pack(self) -> bytes:
        return struct.pack("<III", self.seq & 0xFFFFFFFF, self.src & 0xFFFFFFFF, self.dst & 0xFFFFFFFF)

    @classmethod
    def unpack(cls, b: bytes) -> VirtualArea:
        return cls(*struct.unpack("<III", b))


def frame_message(framing: Framing, frame: bytes, va: VirtualArea) -> bytes:
    """A FRAME message as dccomms writes it: 00 | frame | zero padding to the maximum frame | virtual area."""
    if len(frame) > framing.max_frame:
        raise ValueError(f"frame of {len(frame)} bytes exceeds {framing.name}'s {framing.max_frame}")
    return bytes((MSG_FRAME,)) + frame + bytes(framing.max_frame - len(frame)) + va.pack()


@dataclass(frozen=True)
class FrameMessage:
    packet: Packet
    va: VirtualArea | None          # None: the message is too short to hold one (not dccomms' layout)

    @property
    def dst(self) -> int:
        """Where the frame goes: DataLinkFrame's header, else the virtual area (broadcast if absent)."""
        if self.packet.dst is not None:
            return self.packet.dst
        return self.va.dst if self.va is not None else BROADCAST


def parse_frame_message(framing: Framing, msg: bytes | bytearray | memoryview) -> FrameMessage:
    """A FRAME message's packet and virtual area (FramingError with the reason otherwise)."""
    b = bytes(msg)
    if not b:
        raise FramingError("empty message")
    if b[0] != MSG_FRAME:
        raise FramingError(f"not a FRAME message (type {b[0]})")
    body = b[1:]
    pkt = framing.parse(body)
    va = VirtualArea.unpack(body[framing.max_frame:framing.buffer_size]) \
        if len(body) >= framing.buffer_size else None
    return FrameMessage(pkt, va)


MAX_ADDRESS = 0xFFFF
"""The largest modem address a frame can be sent to in this simulator (uwsimnet_gli.wire.MAX_ADDRESS)."""


def state_message(state: int) -> bytes:
    """CMD_STATE: the PHY tells the application it is BUSY (0) or READY (1)."""
    return bytes((MSG_CMD_STATE, state))


def req_state_message() -> bytes:
    """REQ_STATE: the application asks the PHY for its state (no body)."""
    return bytes((MSG_REQ_STATE,))


def tx_queue_name(dccomms_id: str) -> str:
    """The queue the application writes frames to (the PHY side reads it)."""
    return f"/{dccomms_id}_tx_dlnk_phy"


def rx_queue_name(dccomms_id: str) -> str:
    """The queue the application reads frames from (the PHY side writes it)."""
    return f"/{dccomms_id}_rx_dlnk_phy"


@dataclass(frozen=True)
class GliMessage:
    type: int
    body: bytes

    @property
    def state(self) -> int | None:
        return self.body[0] if self.type == MSG_CMD_STATE and self.body else None


def parse_gli(msg: bytes | bytearray | memoryview) -> GliMessage:
    """Split a queue message into its type byte and body (FramingError if empty or of unknown type)."""
    b = bytes(msg)
    if not b:
        raise FramingError("empty GLI message")
    if b[0] not in (MSG_FRAME, MSG_REQ_STATE, MSG_CMD_STATE):
        raise FramingError(f"unknown GLI message type {b[0]}")
    if b[0] == MSG_CMD_STATE and len(b) != 2:
        raise FramingError(f"CMD_STATE message of {len(b)} bytes (expected 2)")
    return GliMessage(b[0], b[1:])
