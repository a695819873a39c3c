"""A resynchronising stream decoder for any dccomms framing (`formats.dccomms`), sans-IO: what a serial
driver or a pty emulator reads from a transparent radio link.

Like dccomms' stream reader it waits for the preamble, then reads the header and the frame; unlike it, the
stream may carry anything: bytes before a preamble are reported as `Garbage`, an impossible length as
`BadLength`, a failed CRC as `BadCrc`; in both error cases it resumes the search one byte after the false
preamble, so a frame that follows a corrupted or truncated one is still found.  It never raises on input.
"""

from __future__ import annotations

from dataclasses import dataclass

from . import dccomms as fr

BROADCAST = fr.BROADCAST


@dataclass(frozen=True)
class Frame:
    """A decoded frame: its header's addresses (framings without addresses: broadcast, 0), its payload;
    `kind` and `fields` for DcMacPacket's control packets."""

    dst: int
    src: int
    payload: bytes
    kind: str = "data"
    fields: dict[str, int] | None = None
    seq: int | None = None          # SimplePacket: its sequence number (the first two payload bytes)


@dataclass(frozen=True)
class FrameReceived:
    frame: Frame
    raw: bytes


@dataclass(frozen=True)
class Garbage:
    """Bytes that are not part of any frame (before a preamble, or left at a timeout)."""

    data: bytes


@dataclass(frozen=True)
class BadLength:
    """A preamble followed by a length field above the framing's maximum (or below what the caller allows)."""

    length: int
    raw: bytes


@dataclass(frozen=True)
class BadCrc:
    dst: int
    src: int
    length: int
    raw: bytes


@dataclass(frozen=True)
class Truncated:
    """A frame started but its remaining bytes did not arrive in time (see `FrameDecoder.expire`)."""

    expected: int
    raw: bytes


FrameEvent = FrameReceived | Garbage | BadLength | BadCrc | Truncated


class FrameDecoder:
    """Feed bytes, get frames and error reports; resynchronises on the preamble after any error.

    `framing`: any dccomms framing (`formats.dccomms`; default DataLinkFrame CRC16).  Frames of framings
    without address fields come out with dst = broadcast and src = 0 (on a transparent radio every
    receiver gets them; the application filters).  `max_payload` may be lowered (a radio with a smaller
    MTU).  `stall_timeout` (s): a frame whose bytes stop arriving is reported as `Truncated` by
    `expire(now)` after that long, and the search resumes after its preamble, so a cut-off frame cannot
    hold back the frames that follow it.
    """

    def __init__(self, max_payload: int | None = None, stall_timeout: float = 2.0,
                 framing: fr.Framing | None = None) -> None:
        self.framing = framing or fr.DEFAULT
        self.max_payload = self.framing.max_payload if max_payload is None else max_payload
        self.stall_timeout = stall_timeout
        self._buf = bytearray()
        self._since: float | None = None     # when the current partial frame started waiting
        self.counters = {"frames": 0, "garbage_bytes": 0, "bad_crc": 0, "bad_length": 0, "truncated": 0}

    @property
    def pending(self) -> int:
        """Bytes held back waiting for the rest of a frame."""
        return len(self._buf)

    def feed(self, data: bytes | bytearray | memoryview, now: float | None = None) -> list[FrameEvent]:
        self._buf += data
        out: list[FrameEvent] = []
        self._scan(out)
        self._since = now if self._buf else None     # a stall is counted from the last byte
        return out

    def expire(self, now: float) -> list[FrameEvent]:
        """Report a partial frame that has waited more than `stall_timeout` (call it periodically)."""
        if not self._buf:
            return []
        if self._since is None:
            self._since = now
            return []
        if now - self._since < self.stall_timeout:
            return []
        buf = self._buf
        pre = self.framing.preamble
        out: list[FrameEvent] = []
        if buf[:len(pre)] == pre:
            total = self._total(bytes(buf)) if len(buf) >= self.framing.header_len else None
            expected = total if total is not None else self.framing.frame_size(0)
            self.counters["truncated"] += 1
            out.append(Truncated(expected, bytes(buf)))
            del buf[:1]
        elif len(buf) < len(pre) and pre.startswith(bytes(buf)):
            self.counters["garbage_bytes"] += len(buf)
            out.append(Garbage(bytes(buf)))
            buf.clear()
        self._scan(out)
        self._since = now if self._buf else None
        return out

    def _payload_len(self, total: int) -> int:
        return total - self.framing.frame_size(0) if not isinstance(self.framing, fr.SimplePacket) \
            else self.framing.n

    def _total(self, head: bytes) -> int | None:
        """The frame's length from its header, None if its length field is impossible here."""
        total = self.framing.frame_length(head)
        if total is None or self._payload_len(total) > self.max_payload:
            return None
        return total

    def _valid_later(self, claimed: int) -> int:
        """Offset of a later preamble that starts a complete, CRC-valid frame inside the bytes held
        for an incomplete candidate of `claimed` bytes at 0; -1 if none (then the candidate waits)."""
        buf = self._buf
        pre = self.framing.preamble
        hl = self.framing.header_len
        k = buf.find(pre, 1)
        while 0 < k < claimed and k + hl <= len(buf):
            total = self._total(bytes(buf[k:k + hl]))
            if total is not None and k + total <= len(buf):
                try:
                    self.framing.parse(bytes(buf[k:k + total]))
                    return k
                except fr.FramingError:
                    pass
            k = buf.find(pre, k + 1)
        return -1

    def _scan(self, out: list[FrameEvent]) -> None:
        buf = self._buf
        f = self.framing
        pre = f.preamble
        hl = f.header_len
        while buf:
            i = buf.find(pre)
            if i < 0:
                # keep a trailing partial preamble: it may be the first part of the next one
                keep = 0
                for n in range(min(len(pre) - 1, len(buf)), 0, -1):
                    if pre.startswith(bytes(buf[-n:])):
                        keep = n
                        break
                if len(buf) > keep:
                    junk = bytes(buf[:len(buf) - keep])
                    self.counters["garbage_bytes"] += len(junk)
                    out.append(Garbage(junk))
                    del buf[:len(buf) - keep]
                return
            if i > 0:
                junk = bytes(buf[:i])
                self.counters["garbage_bytes"] += len(junk)
                out.append(Garbage(junk))
                del buf[:i]
            if len(buf) < hl:
                return
            head = bytes(buf[:hl])
            total = self._total(head)
            if total is None:
                self.counters["bad_length"] += 1
                out.append(BadLength(f.length_field(head), head))
                del buf[:1]
                continue
            if len(buf) < total:
                k = self._valid_later(total)
                if k > 0:                     # a false preamble: a whole valid frame starts later
                    junk = bytes(buf[:k])
                    self.counters["garbage_bytes"] += len(junk)
                    out.append(Garbage(junk))
                    del buf[:k]
                    continue
                return
            raw = bytes(buf[:total])
            try:
                p = f.parse(raw)
            except fr.FramingError:
                self.counters["bad_crc"] += 1
                dst, src = f.header_addresses(raw)
                out.append(BadCrc(dst, src, self._payload_len(total), raw))
                del buf[:1]
                continue
            self.counters["frames"] += 1
            dst = p.dst if p.dst is not None else BROADCAST
            src = p.src if p.src is not None else 0
            out.append(FrameReceived(Frame(dst, src, p.payload, p.kind, p.fields, p.seq), raw))
            del buf[:total]


def describe(ev: FrameEvent) -> str:
    """One line about a bad frame (the event's repr would dump up to 2 KB of raw bytes)."""
    if isinstance(ev, BadCrc):
        return f"bad CRC (frame {ev.src}->{ev.dst}, {ev.length} bytes payload)"
    if isinstance(ev, BadLength):
        return f"bad length {ev.length}"
    if isinstance(ev, Truncated):
        return f"truncated frame ({len(ev.raw)} of {ev.expected} bytes)"
    return type(ev).__name__
