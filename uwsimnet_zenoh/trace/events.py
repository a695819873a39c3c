"""Trace events and their sinks.

Every frame's life is told as `enq`, `tx`, `rx` and `drop` records (docs/trace-format.md).  The core
emits through one `Tracer`; records are built only when a sink listens, so an untraced benchmark run
pays for a counter increment and nothing else.  Sinks are handed open files or callables: the core
never opens anything itself.
"""

from __future__ import annotations

import importlib
import json
import logging
from collections import Counter
from collections.abc import Callable
from typing import IO, Any

from ..kernel.frame import Frame

Record = dict[str, Any]
_EVENTS = ("enq", "tx", "rx", "drop")
log = logging.getLogger("uwsimnet.trace")


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
            rec["dist"] = round(float(dist), 3)
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
        self._dumps = json.JSONEncoder(separators=(",", ":"), ensure_ascii=False).encode

    def __call__(self, rec: Record) -> None:
        self._write(self._dumps(rec) + "\n")

    def header(self, meta: Record) -> None:
        self._write(self._dumps(meta) + "\n")


class CallbackSink:
    """Calls `on_enq/on_tx/on_rx/on_drop(record)` on a user object (the `netTracingScript` class).

    A handler that raises (anything, `SystemExit` included) is reported once in the log with its
    traceback and the plug-in is disabled for the rest of the run: the run itself, and the frame whose
    record it was handed, go on.  `failed` then holds the exception and `failed_at` the record's time;
    the run functions end such a run with exit code 2 (docs/runtime.md)."""

    def __init__(self, obj: Any, name: str | None = None) -> None:
        self._handlers = {ev: getattr(obj, f"on_{ev}", None) for ev in _EVENTS}
        self.name = name or type(obj).__name__
        self.failed: BaseException | None = None
        self.failed_at: float | None = None

    def __call__(self, rec: Record) -> None:
        h = self._handlers.get(rec["ev"])
        if h is not None:
            try:
                h(rec)
            except (KeyboardInterrupt, GeneratorExit):
                raise
            except BaseException as e:  # noqa: BLE001 - user code: reported once, then switched off
                self._handlers = {}
                self.failed = e
                self.failed_at = rec.get("t")
                log.error("tracing class %s raised %s in on_%s at t=%s; it is disabled for the rest of the"
                          " run", self.name, type(e).__name__, rec["ev"], rec.get("t"), exc_info=e)


def load_tracing_class(spec: str) -> Any:
    """Instantiate a user tracing class named `module:Class` (importing user code is the point here)."""
    mod_name, sep, cls_name = spec.partition(":")
    if not sep or not mod_name or not cls_name:
        raise ValueError(f"tracing class must be 'module:Class', got {spec!r}")
    try:
        cls = getattr(importlib.import_module(mod_name), cls_name)
    except (Exception, SystemExit) as e:  # noqa: BLE001 - importing user code: any failure is one line
        raise ValueError(f"cannot load tracing class {spec!r}: {type(e).__name__}: {e}") from None
    if not isinstance(cls, type):
        raise ValueError(f"tracing class {spec!r} is not a class")
    handlers = [f"on_{ev}" for ev in _EVENTS if callable(getattr(cls, f"on_{ev}", None))]
    if not handlers:
        raise ValueError(f"tracing class {spec!r} implements none of on_enq, on_tx, on_rx, on_drop")
    try:
        return cls()
    except (Exception, SystemExit) as e:  # noqa: BLE001
        raise ValueError(f"tracing class {spec!r} could not be created: {type(e).__name__}: {e}") from None
