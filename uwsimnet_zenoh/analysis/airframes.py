"""Frames on air: every `tx` record of a trace paired with what each receiver made of that transmission.

    tracker = AirTracker()
    for rec in events:
        frame = tracker.add(rec)        # the AirFrame this record created or completed, else None

One `AirFrame` per `tx` record (a retransmission is another AirFrame of the same (`ch`, `src`, `seq`,
`kind`), with `attempt` 2, 3, ...).  A receiver-side `rx` or `drop` record of the same (`ch`, `src`, `seq`,
`kind`) is the outcome, at that receiver, of the latest transmission before it (docs/trace-format.md:
at most one outcome per receiver and transmission).  A drop whose `dev` is the frame's transmitter is a
transmitter-side drop: not an outcome on air.

Incremental and sans-IO: `uwsimnet pcap` feeds a whole trace, `uwsimnet view` feeds live trace samples.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

Key = tuple[Any, int, int, str]


@dataclass(slots=True)
class Outcome:
    dev: str
    outcome: str
    """`rx`, or the drop reason (prop, col, mult, range, nopose, ...)."""
    t: float
    dist: float | None = None


@dataclass(slots=True)
class AirFrame:
    id: int
    """0, 1, 2, ... in the order of the tx records."""
    t: float
    ch: Any
    dev: str
    src: int
    dst: int
    seq: int
    size: int
    flow: str | None
    kind: str
    attempt: int
    outcomes: dict[str, Outcome] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {"id": self.id, "t": self.t, "ch": self.ch, "dev": self.dev, "src": self.src, "dst": self.dst,
                "seq": self.seq, "size": self.size, "flow": self.flow, "kind": self.kind, "attempt": self.attempt,
                "outcomes": {d: {"outcome": o.outcome, "t": o.t, "dist": o.dist} for d, o in self.outcomes.items()}}


class AirTracker:
    """Pairs tx records with receiver outcomes; keeps only the latest transmission of each key."""

    def __init__(self, keep: bool = True) -> None:
        self.frames: list[AirFrame] = []
        """Every frame seen, in tx order (empty when `keep` is False: the caller keeps what it needs)."""
        self._keep = keep
        self._latest: dict[Key, AirFrame] = {}
        self._attempts: dict[Key, int] = {}
        self._tx_dev: dict[tuple[Any, int], str] = {}
        self._n = 0

    @staticmethod
    def key(rec: dict[str, Any]) -> Key:
        return (rec["ch"], rec["src"], rec["seq"], rec.get("kind") or "data")

    def transmitter(self, ch: Any, src: int) -> str | None:
        return self._tx_dev.get((ch, src))

    def add(self, rec: dict[str, Any]) -> AirFrame | None:
        ev = rec.get("ev")
        if ev == "enq":
            self._tx_dev.setdefault((rec["ch"], rec["src"]), rec["dev"])
            return None
        if ev == "tx":
            self._tx_dev[(rec["ch"], rec["src"])] = rec["dev"]
            k = self.key(rec)
            n = self._attempts.get(k, 0) + 1
            self._attempts[k] = n
            f = AirFrame(self._n, float(rec["t"]), rec["ch"], rec["dev"], rec["src"], rec.get("dst", 0),
                         rec["seq"], rec["size"], rec.get("flow"), rec.get("kind") or "data", n)
            self._n += 1
            self._latest[k] = f
            if self._keep:
                self.frames.append(f)
            return f
        if ev not in ("rx", "drop"):
            return None
        f = self._latest.get(self.key(rec))
        if f is None or rec["dev"] == f.dev or rec["t"] < f.t:
            return None                     # a transmitter-side drop, or no transmission to pair with
        if rec["dev"] in f.outcomes:
            return None                     # not traced by this simulator (one outcome per transmission)
        f.outcomes[rec["dev"]] = Outcome(rec["dev"], "rx" if ev == "rx" else str(rec.get("reason")),
                                         float(rec["t"]), rec.get("dist"))
        return f


def air_frames(events: Iterable[dict[str, Any]]) -> list[AirFrame]:
    """Every transmission of a trace (its records, meta excluded or not), with its receivers' outcomes."""
    tr = AirTracker()
    for rec in events:
        tr.add(rec)
    return tr.frames
