"""A modem's output on its Zenoh keys, written once for simulated and real modems (and a trace record's put).

`ModemEndpoint` holds the `modem/<id>/rx` and `modem/<id>/status` publishers and the modem's outbox
(bus/outbox.py): `rx(...)` and `status(...)` queue the message's fields, never waiting; the outbox's thread
encodes them with the one wire (uwsimnet_gli.wire) and puts, so the engine (the output port's listener)
spends no time on encoding.  The broker serves its simulated modems through it (bus/broker.py) and the driver
host its real ones (drivers/zenoh_host.py), so both publish with the same congestion control, the same
message shapes and the same accounting of what a slow consumer lost (`stats()`, on `info` as `edge`).
"""

from __future__ import annotations

import contextlib
from typing import Any

import zenoh
from uwsimnet_gli import wire
from uwsimnet_gli.wire import Keys

from ..trace.events import row_record
from .outbox import OUTBOX_CAPACITY, Outbox

BLOCK = zenoh.CongestionControl.BLOCK
"""rx frames and status events wait for room rather than being dropped by Zenoh: both come at modem rates,
and with *drop* Zenoh gives up after `wait_before_drop` (1 ms) without a free batch, which a loaded machine
hits (the app then missed frames the trace says it received).  *Block* waits at most `wait_before_close`
(2 s on our routers, bus/session.py), on the outbox's thread, never on the engine's or a driver's: what a
stuck consumer costs is that modem's outbox, its long puts counted (`stalled`) and its overflow (`dropped`)."""


class ModemEndpoint:
    __slots__ = ("id", "rx_pub", "status_pub", "out")

    def __init__(self, session: zenoh.Session, keys: Keys, dev: str, out: Outbox | None = None,
                 capacity: int = OUTBOX_CAPACITY) -> None:
        self.id = dev
        self.rx_pub = session.declare_publisher(keys.rx(dev), congestion_control=BLOCK, express=True)
        self.status_pub = session.declare_publisher(keys.status(dev), congestion_control=BLOCK, express=True)
        self.out = out if out is not None else Outbox(dev, capacity)

    def rx(self, src: int, dst: int, data: bytes, seq: int, t_tx: float, t_rx: float,
           dist: float | None = None, msg: dict[str, Any] | None = None) -> bool:
        """Queue an rx message; False if it was lost at the edge (counted in `out.dropped["rx"]`).  The fields
        are taken now (a frame's `t_tx` changes if it is sent again), encoded on the outbox's thread."""
        return self.out.put(self._put_rx, (src, dst, data, seq, t_tx, t_rx, dist, msg), "rx", ident=(src, seq))

    def status(self, tag: Any, event: str, reason: str | None, t: float, seq: int | None = None) -> bool:
        """Queue a status message (a non-int tag goes as nil); False if lost at the edge."""
        if not isinstance(tag, int) or isinstance(tag, bool):
            tag = None
        # not urgent (one per frame queued, one per frame sent): only an rx frame, whose delivery time is
        # modelled, is worth a thread wake-up and switch in the middle of the engine's work; a status goes
        # out when the engine is done with what is due (Outbox.put)
        return self.out.put(self._put_status, (tag, event, reason, t, seq), "status", urgent=False)

    def _put_rx(self, fields: tuple[Any, ...]) -> None:
        """(the outbox's thread)"""
        self.rx_pub.put(wire.encode_rx(*fields))

    def _put_status(self, fields: tuple[Any, ...]) -> None:
        """(the outbox's thread)"""
        self.status_pub.put(wire.encode_status(*fields))

    def stats(self) -> dict[str, Any]:
        return self.out.stats()

    def info(self, fields: dict[str, Any], *, kind: str, world: str, t: float,
             ingress: dict[str, Any]) -> dict[str, Any]:
        """The modem's `info` reply (docs/gli-protocol.md), the same for simulated and real modems:
        `fields` (what the modem itself says) plus who answers, the outbox (`edge`) and how its tx
        messages came in (`ingress`)."""
        out = dict(fields)
        out.update({"id": self.id, "kind": kind, "world": world, "t": t, "edge": self.out.stats(),
                    "ingress": ingress})
        return out

    def undeclare_after_queued(self) -> None:
        """Undeclare the publishers once what is queued for them has gone (the outbox stays usable)."""
        for p in (self.rx_pub, self.status_pub):
            self.out.put(_undeclare, p, "undeclare")

    def close(self, timeout: float = 1.0) -> None:
        """Let what is queued go out (up to `timeout` s), then undeclare."""
        self.out.close(timeout)
        for p in (self.rx_pub, self.status_pub):
            _undeclare(p)


def put_record(item: tuple[Any, float, Any]) -> None:
    """(a trace outbox's thread) `(publisher, t9, row)`: the trace record of a row of the output port's batch
    (trace.events.row_record, its time `t9`), made and encoded here, off the engine, and put."""
    pub, t9, row = item
    pub.put(wire.pack(row_record(t9, row)))


def _undeclare(e: Any) -> None:
    with contextlib.suppress(Exception):          # closing anyway
        e.undeclare()
