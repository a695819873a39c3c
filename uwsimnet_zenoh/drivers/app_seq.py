"""The sending application's sequence number, carried from its bridge or device to the receivers' (wire `aseq`).

dccomms applications number their packets themselves (SetVirtualSeq) and the receiving application reads that
number (GetSeq): the original simulator carried the sender's virtual area to the receivers.  A bridge hands it
to its backend as the message of the frame, and writes it back where the receiving application reads it; a
framing that carries a seq itself (SimplePacket) hands that one over from a serial line."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from .backend import BackendFrame


@dataclass(frozen=True)
class AppSeq:
    """The sending application's sequence number as a backend message (the wire's `aseq`, no `kind`): what
    the original simulator carried from the sender's virtual area to the receivers' (dccomms SetVirtualSeq)."""

    aseq: int

    def to_wire(self) -> dict[str, Any]:
        return {"aseq": self.aseq & 0xFFFFFFFF}


def app_seq(f: BackendFrame) -> int | None:
    """The sender application's sequence number of a received frame, when its backend message carries one."""
    v = getattr(f, "aseq", None)           # BackendFrame.aseq (docs/bridges.md: what the backends must pass)
    if v is None:
        m = f.msg
        v = m.get("aseq") if isinstance(m, dict) else getattr(m, "aseq", None)
    return v if isinstance(v, int) and not isinstance(v, bool) else None
