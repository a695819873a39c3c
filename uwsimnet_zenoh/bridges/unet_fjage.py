"""fjåge's JSON protocol, the wire of UnetStack gateways (docs/unetstack.md): line-delimited JSON objects,
`action`s for the directory, `send` carrying a message `{"clazz", "data"}`.

Sans-IO: `LineReader` cuts a byte stream into objects, the builders return the line to write.  Every fact
here is from fjåge's docs/protocol.qmd and the public gateways (fjagepy 2.2.0 `Gateway.py`, `JSONMessage.py`,
`Message.py`; fjåge `param/ParameterMessageBehavior.java`), as named in docs/unetstack.md.
"""

from __future__ import annotations

import base64
import json
import struct
import uuid
from typing import Any

MAX_LINE = 1 << 20
"""Longest line a client may send (bytes): a DatagramReq of a 2 KiB frame is a few KiB."""

ALIVE = b'{"alive": true}\n'
"""What a master container sends on a new connection (fjagepy answers it, and ignores it otherwise)."""

ACTIONS = ("agents", "containsAgent", "services", "agentForService", "agentsForService", "send",
           "wantsMessagesFor", "shutdown", "auth")

_ARRAY = {"[B": "b", "[S": "h", "[I": "i", "[J": "q", "[F": "f", "[D": "d"}


class ProtocolError(ValueError):
    """A line that is not a fjåge JSON object: one log line, the line is skipped."""


class LineReader:
    """Bytes in, JSON objects out; `\\n`, `\\r` or `\\r\\n` end a line (protocol.qmd, Transport)."""

    def __init__(self, max_line: int = MAX_LINE) -> None:
        self.buf = bytearray()
        self.max_line = max_line

    def feed(self, data: bytes) -> list[dict[str, Any] | ProtocolError]:
        """The objects of the complete lines, each or the error that line gave, in order.  A line over
        `max_line` raises ProtocolError: the stream cannot be trusted any more."""
        self.buf += data
        out: list[dict[str, Any] | ProtocolError] = []
        while True:
            cut = min((i for i in (self.buf.find(b"\n"), self.buf.find(b"\r")) if i >= 0), default=-1)
            if cut < 0:
                break
            line = bytes(self.buf[:cut])
            del self.buf[:cut + 1]
            if line.strip():
                out.append(parse(line))
        if len(self.buf) > self.max_line:
            raise ProtocolError(f"a line longer than {self.max_line} bytes")
        return out


def parse(line: bytes) -> dict[str, Any] | ProtocolError:
    try:
        obj = json.loads(line)
    except (ValueError, UnicodeDecodeError) as e:
        return ProtocolError(f"not JSON ({str(e).split(':')[0]})")
    if not isinstance(obj, dict):
        return ProtocolError(f"a JSON {type(obj).__name__}, not an object")
    return obj


def line(obj: dict[str, Any]) -> bytes:
    return json.dumps(obj, separators=(",", ":")).encode() + b"\n"


def new_id() -> str:
    return str(uuid.uuid4())


def response(req: dict[str, Any], **fields: Any) -> bytes:
    """The answer to a directory action: the same `id`, `inResponseTo` the action."""
    return line({"id": req.get("id"), "inResponseTo": req.get("action"), **fields})


def send(clazz: str, data: dict[str, Any]) -> bytes:
    """A message to the client (`relay` false: it goes no further, as UnetStack's own)."""
    data.setdefault("msgID", new_id())
    return line({"action": "send", "message": {"clazz": clazz, "data": data}, "relay": False})


def reply(req: dict[str, Any], clazz: str, perf: str, sender: str, **fields: Any) -> bytes:
    """A message in reply to the message `req` (its `data`): to its sender, `inReplyTo` its msgID.  Its own
    fields first, then Message's (the order fjåge's Java classes declare them in): fjåge's C gateway reads
    the data's keys pairwise and loses its place after an array, so an array goes after what it reads."""
    return send(clazz, {**fields, "perf": perf, "recipient": req.get("sender"), "sender": sender,
                        "inReplyTo": req.get("msgID")})


def byte_array(data: bytes) -> dict[str, str]:
    """A Java byte[] as fjåge writes it: base64 of the bytes (readers get signed values, -128..127)."""
    return {"clazz": "[B", "data": base64.b64encode(data).decode()}


def read_bytes(v: Any) -> bytes:
    """A byte array as clients send it: a list of integers (-128..255) or a base64 `[B` object.
    ValueError if it is neither."""
    if v is None:
        return b""
    if isinstance(v, dict):
        clazz = v.get("clazz")
        if clazz not in _ARRAY or not isinstance(v.get("data"), str):
            raise ValueError(f"an array of class {clazz!r}, not [B")
        raw = base64.b64decode(v["data"], validate=True)
        if clazz != "[B":
            n = len(raw) // struct.calcsize(_ARRAY[clazz])
            v = list(struct.unpack(f"<{n}{_ARRAY[clazz]}", raw[:n * struct.calcsize(_ARRAY[clazz])]))
        else:
            return raw
    if not isinstance(v, list) or not all(isinstance(x, int) and not isinstance(x, bool) and -128 <= x <= 255
                                          for x in v):
        raise ValueError("data must be a list of bytes (-128..255) or a [B array")
    return bytes(x & 0xFF for x in v)
