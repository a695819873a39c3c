"""The frame: what a modem puts on air, plus the bookkeeping that follows it through the simulator."""

from __future__ import annotations

from typing import Any, Final

BROADCAST: Final = 255
"""Destination address that every modem on the channel accepts (as in dccomms)."""


class Frame:
    """A frame on its way from one modem to others.

    `size` is what goes on air (payload + device header + MAC overhead): it sets the transmission time,
    the loss probability and the FIFO occupancy.  `payload` is what the application handed over.
    `info` carries MAC header fields (announced durations, ack numbers) that the simulator does not model
    as bytes one by one.  `msg` is what the sender's device said about the message (the wire's tx `kind`,
    `flag`, `ts`, `pid`): opaque to the simulator, handed to the receivers as it came.
    """

    __slots__ = ("src", "dst", "seq", "size", "payload", "data", "flow", "kind", "t_enq", "tag", "dev",
                 "info", "t_tx", "tries", "msg", "final")

    def __init__(self, src: int, dst: int, seq: int, size: int, payload: int, *, data: bytes | None = None,
                 flow: str | None = None, kind: str = "data", t_enq: float = 0.0, tag: Any = None,
                 dev: str = "", info: dict | None = None, msg: dict | None = None) -> None:
        self.src = src
        self.dst = dst
        self.seq = seq
        self.size = size
        self.payload = payload
        self.data = data
        self.flow = flow
        self.kind = kind
        self.t_enq = t_enq
        self.tag = tag
        self.dev = dev
        self.info = info
        self.msg = msg
        self.t_tx = -1.0
        self.tries = 0
        self.final: str | None = None
        """The reason of its drop at the transmitter, once dropped there (nothing more can happen to it)."""

    @property
    def broadcast(self) -> bool:
        return self.dst == BROADCAST

    def __repr__(self) -> str:
        return (f"Frame({self.kind} {self.dev} {self.src}->{self.dst} seq={self.seq} size={self.size}"
                f" flow={self.flow})")
