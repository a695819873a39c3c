"""A trace as a pcapng capture for Wireshark (`uwsimnet pcap TRACE -o FILE.pcapng`, docs/view.md).

Every frame on air (every `tx` record) is one Enhanced Packet Block; each channel is one interface
(`ch0`, `ch1`, ...; link type LINKTYPE_USER0 = 147, nanosecond timestamps = simulation time).  The trace
carries no payload, so a packet is the link-layer header below and nothing else; its original length is
the header plus the frame's bytes on air.  `uwsimnet_zenoh/analysis/uwsimnet.lua` decodes it.

Header (network byte order), version 1:

    off  size  field
      0     4  magic "UWSN"
      4     1  version (1)
      5     1  kind: 0 data, 1 ctrl, 255 other
      6     2  header length in bytes (this whole header)
      8     2  channel id (65535 if the trace names the channel with a string)
     10     2  src address
     12     2  dst address (255 = broadcast)
     14     2  attempt: 1 for the first transmission of (channel, src, seq, kind), 2 for the next, ...
     16     4  seq
     20     4  size: bytes on air (payload + device header + MAC overhead)
     24     s  transmitter dccommsId (s: a string = 1 byte length + UTF-8)
      .     s  flow name (length 0 = none)
      .     1  number of receivers with an outcome, then per receiver:
                 s   receiver dccommsId
                 1   outcome code: 0 rx, 1 prop, 2 col, 3 mult, 4 range, 5 nopose, 255 other
                 s   outcome as text (rx, prop, col, ... or the trace's reason)
                 8   float64: time of the outcome minus time of the transmission, s
                 4   float32: distance at transmission start, m (NaN if the trace has none)

Pure functions over records: the only I/O is reading the trace and writing the one output file.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterable
from os import PathLike
from pathlib import Path
from typing import Any

from .airframes import AirFrame, air_frames
from .read import open_source

MAGIC = b"UWSN"
VERSION = 1
LINKTYPE_USER0 = 147
KINDS = {"data": 0, "ctrl": 1}
OUTCOMES = {"rx": 0, "prop": 1, "col": 2, "mult": 3, "range": 4, "nopose": 5}
OTHER = 255
NO_CHANNEL = 0xFFFF
DISSECTOR = Path(__file__).with_name("uwsimnet.lua")
"""The Wireshark Lua dissector shipped with the package (`tshark -X lua_script:PATH`)."""

_SHB, _IDB, _EPB = 0x0A0D0D0A, 0x00000001, 0x00000006


def _s(text: str | None) -> bytes:
    b = (text or "").encode("utf-8")[:255]
    return bytes([len(b)]) + b


def _u16(x: Any, default: int) -> int:
    return x if isinstance(x, int) and not isinstance(x, bool) and 0 <= x <= 0xFFFF else default


def link_header(f: AirFrame) -> bytes:
    """The link-layer header of one frame on air (layout in the module docstring)."""
    rx = b"".join(_s(o.dev) + bytes([OUTCOMES.get(o.outcome, OTHER)]) + _s(o.outcome)
                  + struct.pack(">df", o.t - f.t, math.nan if o.dist is None else float(o.dist))
                  for o in list(f.outcomes.values())[:255])
    tail = _s(f.dev) + _s(f.flow) + bytes([min(len(f.outcomes), 255)]) + rx
    n = 24 + len(tail)
    head = MAGIC + struct.pack(">BBHHHHHII", VERSION, KINDS.get(f.kind, OTHER), n, _u16(f.ch, NO_CHANNEL),
                               _u16(f.src, 0xFFFF), _u16(f.dst, 0xFFFF), min(f.attempt, 0xFFFF),
                               f.seq & 0xFFFFFFFF, max(0, f.size) & 0xFFFFFFFF)
    return head + tail


def _pad(b: bytes) -> bytes:
    return b + b"\0" * (-len(b) % 4)


def _opt(code: int, value: bytes) -> bytes:
    return struct.pack("<HH", code, len(value)) + _pad(value)


def _block(kind: int, body: bytes) -> bytes:
    n = 12 + len(body)
    return struct.pack("<II", kind, n) + body + struct.pack("<I", n)


def _shb(app: str) -> bytes:
    body = struct.pack("<IHHq", 0x1A2B3C4D, 1, 0, -1) + _opt(4, app.encode()) + _opt(0, b"")
    return _block(_SHB, body)


def _idb(name: str, description: str) -> bytes:
    opts = _opt(2, name.encode()) + _opt(3, description.encode()) + _opt(9, bytes([9])) + _opt(0, b"")
    return _block(_IDB, struct.pack("<HHI", LINKTYPE_USER0, 0, 0) + opts)


def _epb(iface: int, t: float, data: bytes, orig_len: int) -> bytes:
    ns = max(0, round(t * 1e9))
    body = struct.pack("<IIIII", iface, ns >> 32, ns & 0xFFFFFFFF, len(data), orig_len) + _pad(data)
    return _block(_EPB, body)


def pcapng(frames: Iterable[AirFrame], meta: dict[str, Any] | None = None) -> bytes:
    """The capture: one interface per channel (in order of first use), one packet per frame on air."""
    frames = list(frames)
    meta = meta or {}
    chans: dict[Any, int] = {}
    for f in frames:
        chans.setdefault(f.ch, len(chans))
    scene = meta.get("scene")
    out = [_shb("uwsimnet" + (f" scene {scene} seed {meta.get('seed')}" if scene else ""))]
    out += [_idb(f"ch{ch}", f"uwsimnet channel {ch}") for ch in chans]
    for f in frames:
        h = link_header(f)
        out.append(_epb(chans[f.ch], f.t, h, len(h) + max(0, f.size)))
    return b"".join(out)


def trace_to_pcapng(trace: str | PathLike[str] | Iterable[dict[str, Any]], out: str | PathLike[str]) -> int:
    """Write the pcapng of a trace (path or records) to `out`; the number of packets.  TraceError on a bad
    trace (nothing is written then)."""
    meta, events = open_source(trace)
    frames = air_frames(events)
    Path(out).write_bytes(pcapng(frames, meta))
    return len(frames)
