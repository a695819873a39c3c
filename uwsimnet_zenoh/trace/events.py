"""Trace events and their sinks.

Every frame's life is told as `enq`, `tx`, `rx` and `drop` records (docs/trace-format.md).  The core
emits through one `Tracer`; records are built only when a sink listens, so an untraced benchmark run
pays for a counter increment and nothing else.  Sinks are handed open files or callables: the core
never opens anything itself.
"""

from __future__ import annotations

import importlib
import json
import math
from collections import Counter
from collections.abc import Callable
from typing import IO, Any

from ..kernel.frame import Frame

Record = dict[str, Any]
_EVENTS = ("enq", "tx", "rx", "drop")


class Tracer:
    def __init__(self) -> None:
        self.sinks: list[Callable[[Record], None]] = []
        self.counts: Counter[tuple[str, str | None]] = Counter()

    def add(self, sink: Callable[[Record], None]) -> None:
        self.sinks.append(sink)

    def emit(self, t: float, ev: str, ch: int, dev: str, frame: Frame, reason: str | None = None,
             fifo: int | None = None, dist: float | None = None, implicit: bool = False) -> None:
        self.counts[ev, reason] += 1
        if not self.sinks:
            return
        rec: Record = {"t": round(t, 9), "ev": ev, "ch": ch, "dev": dev, "src": frame.src, "dst": frame.dst,
                       "seq": frame.seq, "size": frame.size, "flow": frame.flow, "kind": frame.kind}
        if reason is not None:
            rec["reason"] = reason
        if fifo is not None:
            rec["fifo"] = fifo
        if dist is not None:
            rec["dist"] = round(float(dist), 3) if math.isfinite(dist) else None   # JSON has no inf/NaN
        if implicit:
            rec["implicit"] = True      # rx of a frame addressed to another modem (no MAC: implicit broadcast)
        for sink in self.sinks:
            sink(rec)

    def count(self, ev: str, reason: str | None = None) -> int:
        if reason is None and ev == "drop":
            return sum(n for (e, _), n in self.counts.items() if e == "drop")
        return self.counts[ev, reason]


class JsonlSink:
    """Writes one compact JSON object per line to an open text file (deterministic key order)."""

    def __init__(self, fh: IO[str]) -> None:
        self._write = fh.write
        self._enc = json.JSONEncoder(separators=(",", ":"), ensure_ascii=False, allow_nan=False).encode

    def _dumps(self, rec: Record) -> str:
        try:
            return self._enc(rec)
        except ValueError:                  # a NaN or an infinity somewhere: written as null (valid JSON)
            return self._enc(finite(rec))

    def __call__(self, rec: Record) -> None:
        self._write(self._dumps(rec) + "\n")

    def header(self, meta: Record) -> None:
        self._write(self._dumps(meta) + "\n")


def finite(v: Any) -> Any:
    """`v` with every non-finite float replaced by None (docs/trace-format.md: null)."""
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if isinstance(v, dict):
        return {k: finite(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [finite(x) for x in v]
    return v


class CallbackSink:
    """Calls `on_enq/on_tx/on_rx/on_drop(record)` on a user object (the `netTracingScript` class)."""

    def __init__(self, obj: Any) -> None:
        self._handlers = {ev: getattr(obj, f"on_{ev}", None) for ev in _EVENTS}

    def __call__(self, rec: Record) -> None:
        h = self._handlers.get(rec["ev"])
        if h is not None:
            h(rec)


def load_tracing_class(spec: str) -> Any:
    """Instantiate a user tracing class named `module:Class` (importing user code is the point here)."""
    mod_name, sep, cls_name = spec.partition(":")
    if not sep or not mod_name or not cls_name:
        raise ValueError(f"tracing class must be 'module:Class', got {spec!r}")
    try:
        cls = getattr(importlib.import_module(mod_name), cls_name)
    except (ImportError, AttributeError) as e:
        raise ValueError(f"cannot load tracing class {spec!r}: {e}") from None
    return cls()
