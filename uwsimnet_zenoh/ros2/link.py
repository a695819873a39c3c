"""The ROS 2 link's on-air core, sans-IO (docs/ros2-link.md): which topics cross, the compact header,
fragmentation to the modem's MTU, reassembly, per-topic queues with priorities, and the counters.

No zenoh, no clock of its own: the glue hands it CDR samples, frames and `now` (seconds) and sends what it
returns, so the same core runs over a simulated modem or a real one after a HIL swap.

On air, every frame is `header + chunk` (all integers little-endian):

    byte 0     bit 7 F (fragmented), bit 6 Z (payload is raw DEFLATE of the CDR), bits 5..0 topic index
    byte 1     message sequence number (per sender and topic, mod 256)
    if F:      byte 2 fragment index, byte 3 index of the last fragment (count - 1)
    first frame of a message only (unfragmented, or fragment index 0):
               4 bytes: sender's source timestamp in microseconds, mod 2**32 (rmw_zenoh attachment stamp)
    rest       the chunk of the (possibly compressed) CDR sample as the sender's graph published it

The receiver takes the full timestamp as the one congruent to the 32-bit value that is nearest its own
clock (the window is +-35 minutes, far beyond any acoustic latency).
"""

from __future__ import annotations

import math
import struct
import zlib
from collections import deque
from dataclasses import dataclass, field

# the settings are the scene's model (one for <ros2Link> and --topic); re-exported for the link's users
from ..scene.ros2_link import BROADCAST, MAX_TOPICS, LinkError, TopicRule, check_rules, parse_rule  # noqa: F401
from . import wire as rw

MAX_FRAGMENTS = 256
_STAMP = struct.Struct("<I")
_WRAP = 1 << 32


# == header ===========================================================================================

@dataclass(frozen=True)
class Header:
    topic: int
    seq: int
    index: int = 0
    count: int = 1
    compressed: bool = False
    stamp_us: int | None = None     # 32-bit wrapped; present on the first frame of a message

    @property
    def size(self) -> int:
        return 2 + (2 if self.count > 1 else 0) + (4 if self.index == 0 else 0)


def header_size(count: int, first: bool) -> int:
    return 2 + (2 if count > 1 else 0) + (4 if first else 0)


def encode_header(h: Header) -> bytes:
    if not 0 <= h.topic < MAX_TOPICS or not 1 <= h.count <= MAX_FRAGMENTS or not 0 <= h.index < h.count:
        raise LinkError(f"header out of range: {h}")
    out = bytearray([(0x80 if h.count > 1 else 0) | (0x40 if h.compressed else 0) | h.topic, h.seq & 0xFF])
    if h.count > 1:
        out += bytes([h.index, h.count - 1])
    if h.index == 0:
        out += _STAMP.pack((h.stamp_us or 0) % _WRAP)
    return bytes(out)


def decode_frame(frame: bytes) -> tuple[Header, bytes]:
    """(header, chunk); LinkError('short') when the frame cannot hold its header."""
    if len(frame) < 2:
        raise LinkError("short")
    b0, seq = frame[0], frame[1]
    pos, index, count = 2, 0, 1
    if b0 & 0x80:
        if len(frame) < 4:
            raise LinkError("short")
        index, count, pos = frame[2], frame[3] + 1, 4
        if count == 1:
            raise LinkError("fragment count 1 with F set")
    stamp = None
    if index == 0:
        if len(frame) < pos + 4:
            raise LinkError("short")
        stamp = _STAMP.unpack_from(frame, pos)[0]
        pos += 4
    return Header(b0 & 0x3F, seq, index, count, bool(b0 & 0x40), stamp), bytes(frame[pos:])


def unwrap_stamp(stamp_us: int, now_ns: int) -> int:
    """The full source timestamp (ns) nearest `now_ns` whose microseconds are congruent to `stamp_us`."""
    now_us = now_ns // 1000
    base = now_us - (now_us % _WRAP) + stamp_us
    best = min((base - _WRAP, base, base + _WRAP), key=lambda c: abs(c - now_us))
    return best * 1000


# == the link's own frames: topic index 63 ===========================================================

CONTROL = MAX_TOPICS
QOS_ANNOUNCE = 1
QOS_PERIOD_S = 30.0
"""A topic's QoS is announced before its first message and again before a message every this often (a lost
announcement is made good)."""


def encode_qos(topic: int, qos: rw.QoS) -> bytes:
    """`3f 01 <topic> <rel | dur << 2 | hist << 4> <depth u16>`: the QoS of the publisher on the sender's graph."""
    return bytes([CONTROL, QOS_ANNOUNCE, topic, qos.reliability | qos.durability << 2 | qos.history << 4]) \
        + struct.pack("<H", min(qos.depth, 0xFFFF))


def is_control(frame: bytes) -> bool:
    return len(frame) >= 2 and frame[0] == CONTROL


def decode_qos(frame: bytes) -> tuple[int, rw.QoS]:
    """(topic index, QoS) of an announcement; LinkError for anything else."""
    if len(frame) != 6 or frame[0] != CONTROL or frame[1] != QOS_ANNOUNCE:
        raise LinkError("not a QoS announcement")
    b = frame[3]
    try:
        return frame[2], rw.QoS(b & 3, b >> 2 & 3, b >> 4 & 3, struct.unpack_from("<H", frame, 4)[0])
    except rw.Ros2WireError as e:
        raise LinkError(f"QoS announcement: {e.detail}") from None


# == fragmentation ====================================================================================

def fragment(topic: int, seq: int, payload: bytes, compressed: bool, stamp_ns: int, mtu: int) -> list[bytes]:
    """The frames of one message, each at most `mtu` bytes. LinkError('oversize') past 256 fragments."""
    stamp = (stamp_ns // 1000) % _WRAP
    if header_size(1, True) + len(payload) <= mtu:
        return [encode_header(Header(topic, seq, 0, 1, compressed, stamp)) + payload]
    first = mtu - header_size(2, True)
    rest = mtu - header_size(2, False)
    if first <= 0 or rest <= 0:
        raise LinkError(f"mtu {mtu} cannot hold a fragment header")
    count = 1 + math.ceil(max(0, len(payload) - first) / rest)
    if count > MAX_FRAGMENTS:
        raise LinkError("oversize")
    frames = [encode_header(Header(topic, seq, 0, count, compressed, stamp)) + payload[:first]]
    for i in range(1, count):
        lo = first + (i - 1) * rest
        frames.append(encode_header(Header(topic, seq, i, count, compressed)) + payload[lo:lo + rest])
    return frames


def pack(payload: bytes, compress: bool) -> tuple[bytes, bool]:
    """Raw DEFLATE (zlib, wbits -15) when it makes the sample smaller, else the CDR as it came."""
    if compress:
        c = zlib.compressobj(9, zlib.DEFLATED, -15)
        z = c.compress(payload) + c.flush()
        if len(z) < len(payload):
            return z, True
    return payload, False


def unpack(payload: bytes, compressed: bool) -> bytes:
    if not compressed:
        return payload
    d = zlib.decompressobj(-15)
    try:
        out = d.decompress(payload, 1 << 24)
    except zlib.error:
        raise LinkError("inflate") from None
    if not d.eof or d.unconsumed_tail:
        raise LinkError("inflate")
    return out


@dataclass
class _Partial:
    count: int
    compressed: bool
    stamp_us: int | None
    first_t: float
    chunks: dict[int, bytes] = field(default_factory=dict)


class Reassembler:
    """Whole messages from frames. A message is delivered only when all its fragments arrived; one whose
    fragment is missing is dropped whole (reason 'lost') when a later message of the same sender and topic
    starts, or after `timeout` seconds; `drops` counts per topic index."""

    def __init__(self, timeout: float = 60.0) -> None:
        self.timeout = timeout
        self._open: dict[tuple[int, int], tuple[int, _Partial]] = {}
        self.drops: dict[tuple[int, str], int] = {}

    def _drop(self, topic: int, reason: str) -> None:
        self.drops[(topic, reason)] = self.drops.get((topic, reason), 0) + 1

    def expire(self, now: float) -> None:
        for k, (_seq, p) in list(self._open.items()):
            if now - p.first_t > self.timeout:
                del self._open[k]
                self._drop(k[1], "lost")

    def push(self, src: int, frame: bytes, now: float) -> tuple[int, bytes, int | None] | None:
        """(topic index, CDR payload, 32-bit stamp) when `frame` completes a message, else None.
        Raises LinkError for a frame that cannot be read (the caller counts it as malformed)."""
        h, chunk = decode_frame(frame)
        self.expire(now)
        key = (src, h.topic)
        if h.count == 1:
            self._supersede(key, h.seq)
            return h.topic, unpack(chunk, h.compressed), h.stamp_us
        cur = self._open.get(key)
        if cur is not None and cur[0] != h.seq:
            self._supersede(key, h.seq)
            cur = None
        if cur is None:
            if h.index != 0:
                self._drop(h.topic, "lost")       # its first fragment never came: the message is gone
                return None
            cur = (h.seq, _Partial(h.count, h.compressed, h.stamp_us, now))
            self._open[key] = cur
        p = cur[1]
        if h.count != p.count:
            del self._open[key]
            raise LinkError("fragment count changed within a message")
        p.chunks[h.index] = chunk
        if len(p.chunks) < p.count:
            return None
        del self._open[key]
        return h.topic, unpack(b"".join(p.chunks[i] for i in range(p.count)), p.compressed), p.stamp_us

    def _supersede(self, key: tuple[int, int], seq: int) -> None:
        cur = self._open.get(key)
        if cur is not None and cur[0] != seq:
            del self._open[key]
            self._drop(key[1], "lost")


# == the sending side: per-topic queues ===============================================================

@dataclass
class TopicStats:
    offered: int = 0
    sent: int = 0
    frames: int = 0
    bytes: int = 0
    received: int = 0
    dropped: dict[str, int] = field(default_factory=dict)
    latency_sum: float = 0.0
    latency_max: float = 0.0

    def drop(self, reason: str) -> None:
        self.dropped[reason] = self.dropped.get(reason, 0) + 1

    def as_dict(self) -> dict:
        mean = self.latency_sum / self.received if self.received else None
        return {"offered": self.offered, "sent": self.sent, "frames": self.frames, "bytes": self.bytes,
                "received": self.received, "dropped": dict(sorted(self.dropped.items())),
                "latency_mean_s": mean, "latency_max_s": self.latency_max if self.received else None}


@dataclass
class _Message:
    frames: deque[bytes]
    started: bool = False


class Sender:
    """Per-topic queues feeding one modem one frame at a time. `next_frame` serves the lowest priority
    number first, at frame granularity: a control message waits at most for the frame already on air,
    never behind the rest of an image. keep_last drops the oldest unsent message past `depth`
    ('superseded'); fifo refuses the newest ('queue_full'). A message already started is never cut."""

    def __init__(self, rules: list[TopicRule], mtu: int) -> None:
        self.rules = check_rules(rules)
        self.mtu = mtu
        self.index = {r.name: i for i, r in enumerate(rules)}
        self.stats = [TopicStats() for _ in rules]
        self._queues: list[deque[_Message]] = [deque() for _ in rules]
        self._seq = [0] * len(rules)
        self._last_accept = [-math.inf] * len(rules)
        self._tokens = [float(r.budget) for r in rules]
        self._token_t = [0.0] * len(rules)
        self.qos: list[rw.QoS | None] = [None] * len(rules)
        self._announced = [-math.inf] * len(rules)
        self._control: deque[tuple[int, bytes]] = deque()
        self.control_frames = 0

    def set_qos(self, topic: str, qos: rw.QoS) -> bool:
        """The QoS of the topic's publisher on this robot's graph (from its token); True when it changed
        (announced again before the next message)."""
        i = self.index.get(topic)
        if i is None or self.qos[i] == qos:
            return False
        self.qos[i] = qos
        self._announced[i] = -math.inf
        return True

    def offer(self, topic: str, cdr: bytes, stamp_ns: int, now: float) -> str | None:
        """Queue one sample; None when queued, else the reason it was dropped (also counted)."""
        i = self.index.get(topic)
        if i is None or self.rules[i].direction == "in":
            return "unknown_topic"
        r, st = self.rules[i], self.stats[i]
        st.offered += 1
        if r.rate and now - self._last_accept[i] < 1.0 / r.rate - 1e-9:
            st.drop("rate")
            return "rate"
        payload, z = pack(cdr, r.compress)
        try:
            frames = fragment(i, self._seq[i], payload, z, stamp_ns, self.mtu)
        except LinkError:
            st.drop("oversize")
            return "oversize"
        size = sum(map(len, frames))
        if r.budget:
            self._tokens[i] = min(float(r.budget), self._tokens[i] + (now - self._token_t[i]) * r.budget)
            self._token_t[i] = now
            if size > self._tokens[i]:
                st.drop("budget")
                return "budget"
            self._tokens[i] -= size
        q = self._queues[i]
        waiting = sum(1 for m in q if not m.started)
        if waiting >= r.depth:
            if r.policy == "fifo":
                st.drop("queue_full")
                return "queue_full"
            oldest = next(m for m in q if not m.started)
            q.remove(oldest)
            st.drop("superseded")
        self._seq[i] = (self._seq[i] + 1) & 0xFF
        self._last_accept[i] = now
        qos = self.qos[i]
        if qos is not None and now - self._announced[i] >= QOS_PERIOD_S:
            self._control.append((r.dst, encode_qos(i, qos)))
            self._announced[i] = now
        q.append(_Message(deque(frames)))
        return None

    def pending(self) -> int:
        return len(self._control) + sum(len(m.frames) for q in self._queues for m in q)

    def next_frame(self) -> tuple[int, bytes] | None:
        """(destination address, frame) of the most urgent waiting frame, or None. QoS announcements go
        first: each precedes the message it was queued with."""
        if self._control:
            self.control_frames += 1
            return self._control.popleft()
        best = None
        for i, q in enumerate(self._queues):
            if q and (best is None or self.rules[i].priority < self.rules[best].priority):
                best = i
        if best is None:
            return None
        q, st = self._queues[best], self.stats[best]
        m = q[0]
        m.started = True
        frame = m.frames.popleft()
        if not m.frames:
            q.popleft()
            st.sent += 1
        st.frames += 1
        st.bytes += len(frame)
        return self.rules[best].dst, frame


def diagnostic_status(summary: dict, modem: str) -> list[dict]:
    """A link summary as diagnostic_msgs/DiagnosticStatus fields: one status per topic (level WARN when it
    dropped anything), one for the problems counted."""
    out = []
    for name, d in summary["topics"].items():
        values = [{"key": k, "value": str(d[k])} for k in ("offered", "sent", "frames", "bytes", "received")]
        values += [{"key": f"dropped_{k}", "value": str(n)} for k, n in d["dropped"].items()]
        values += [{"key": k, "value": f"{d[k]:.6f}"} for k in ("latency_mean_s", "latency_max_s") if d[k] is not None]
        values += [{"key": k, "value": d[k]} for k in ("qos_out", "qos_in") if k in d]
        out.append({"level": 1 if d["dropped"] else 0, "name": f"uwsimnet_link/{modem}{name}",
                    "message": "dropped messages" if d["dropped"] else "ok", "hardware_id": modem, "values": values})
    bad = summary["problems"]
    out.append({"level": 1 if bad else 0, "name": f"uwsimnet_link/{modem}", "message": "problems" if bad else "ok",
                "hardware_id": modem, "values": [{"key": k, "value": str(n)} for k, n in bad.items()]})
    return out
