"""The trace's sinks: the JSONL writer, the columnar writer and the user's tracing class, listeners of the
output port (trace/tracer.py: `Tracer`, `Listener`, `Batch`, `record`, re-exported here).  Every frame's life
is told as `enq`, `tx`, `rx` and `drop` records (docs/trace-format.md).  Sinks are handed open files or
callables: the core never opens anything itself (ArrowSink opens the path it is given).
"""

from __future__ import annotations

import importlib
import io
import json
import math
from typing import IO, Any

import msgspec

from ..kernel.frame import Frame
from ..kernel.rx import doppler as rx_doppler
from .tracer import (
    ROW_FIELDS,
    Batch,
    BatchConsumer,
    Batcher,
    Callback,
    Listener,
    Record,
    Records,
    Row,
    Tracer,
    level,
    record,
    rounded,
)
from .tracer import lines as make_lines

__all__ = ["ROW_FIELDS", "ArrowSink", "Batch", "BatchConsumer", "Batcher", "Callback", "CallbackSink", "JsonlSink",
           "Listener", "Record", "Records", "Row", "Tracer", "finite", "load_tracing_class", "record", "rounded",
           "row_record"]

_EVENTS = ("enq", "tx", "rx", "drop")




def row_record(t9: float, r: Row) -> Record:
    """`record()` of a batch row whose time is already rounded."""
    rec: Record = {"t": t9, "ev": r[1], "ch": r[2], "dev": r[3], "src": r[4], "dst": r[5], "seq": r[6],
                   "size": r[7], "flow": r[8], "kind": r[9]}
    reason, fifo, dist = r[10], r[11], r[12]
    if reason is not None:
        rec["reason"] = reason
    if fifo is not None:
        rec["fifo"] = fifo
    if dist is not None:
        rec["dist"] = round(float(dist), 3) if math.isfinite(dist) else None
        dop = rx_doppler(dist)
        if dop is not None:
            rec["doppler"] = dop
        lv = level(dist)
        if lv is not None:
            rec["level"] = lv
    if r[13]:
        rec["implicit"] = True
    return rec


_encode = json.JSONEncoder(separators=(",", ":"), ensure_ascii=False, allow_nan=False).encode


def finite(v: Any) -> Any:
    """`v` with every non-finite float replaced by None (docs/trace-format.md: null)."""
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if isinstance(v, dict):
        return {k: finite(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [finite(x) for x in v]
    return v


def _dumps(rec: Any) -> str:
    """The reference encoding of a record: compact, key order kept, floats as Python's repr; a NaN or an
    infinity anywhere is written as null (valid JSON)."""
    try:
        return _encode(rec)
    except ValueError:
        return _encode(finite(rec))


class _Line(msgspec.Struct, omit_defaults=True, gc=False):
    """One event as msgspec encodes it: the record's keys in the record's order; the optional ones
    (reason, fifo, dist, doppler, level; implicit when False) left out, as `record()` does."""

    t: float
    ev: str
    ch: int
    dev: str
    src: int
    dst: int
    seq: int
    size: int
    flow: str | None
    kind: str
    reason: str | None = None
    fifo: int | None = None
    dist: float | None = None
    doppler: float | None = None
    level: float | None = None
    implicit: bool = False


def _plain(x: float) -> bool:
    """Does msgspec write this float exactly as Python's json (float repr) does?  Both give the shortest
    round-tripping digits; they differ only in how they write exponents (`1e-05` vs `1e-5`), which
    Python uses below 1e-4 and from 1e16 on (and non-finite values, which json writes as NaN)."""
    return 1e-4 <= x < 1e15 or x == 0.0


class JsonlSink(Listener):
    """Writes one compact JSON object per line to an open file, text or binary (deterministic key order).

    As a record sink (`tracer.add(sink)`) it writes each record at once with Python's json.  As a
    listener (`tracer.listen(sink)`) it encodes events with msgspec in batches of `batch` lines
    and writes them together: byte for byte the same file, several times faster.  Call `flush()` (or
    `close()`) before the file is closed."""

    def __init__(self, fh: IO[str] | IO[bytes], batch: int = 4096) -> None:
        self._fh = fh
        self._binary = not isinstance(fh, io.TextIOBase)
        self._batch = batch
        self._buf: list[_Line] = []
        self._encode_lines = msgspec.json.Encoder().encode_lines

    def _write(self, text: str) -> None:
        self._fh.write(text.encode("utf-8") if self._binary else text)  # type: ignore[arg-type]

    def __call__(self, rec: Record) -> None:
        self.flush()
        self._write(_dumps(rec) + "\n")

    def header(self, meta: Record) -> None:
        self.flush()
        self._write(_dumps(meta) + "\n")

    def event(self, t: float, ev: str, ch: int, dev: str, frame: Frame, reason: str | None,
              fifo: int | None, dist: float | None, implicit: bool = False) -> None:
        t = round(t, 9)
        d = dop = lv = None
        plain = 1e-4 <= t < 1e15 or t == 0.0                   # _plain, inlined (per event)
        if dist is not None:
            d = round(float(dist), 3)
            dop = rx_doppler(dist)
            lv = level(dist)
            plain = plain and _plain(d) and (dop is None or _plain(dop)) and (lv is None or _plain(abs(lv)))
        if not plain:
            self(record(t, ev, ch, dev, frame, reason, fifo, dist, implicit))
            return
        buf = self._buf
        buf.append(_Line(t, ev, ch, dev, frame.src, frame.dst, frame.seq, frame.size, frame.flow, frame.kind,
                         reason, fifo, d, dop, lv, bool(implicit)))
        if len(buf) >= self._batch:
            self.flush()

    def flush(self) -> None:
        buf = self._buf
        if buf:
            data = self._encode_lines(buf)
            buf.clear()
            self._fh.write(data if self._binary else data.decode("utf-8"))  # type: ignore[arg-type]

    close = flush

    def write_batch(self, b: Batch) -> None:
        """A batch consumer (`tracer.consume(sink.write_batch)`): the batch's lines, written at once.  The
        same bytes as `event()` on each of its events: one msgspec struct per event made from its row with
        its record's time and distance (`tracer.lines`, compiled with the engine), and the few lines msgspec
        would write otherwise than Python's json (`_plain`) written by the reference encoder in their place."""
        self.flush()
        rows = b.rows
        if not rows:
            return
        t9 = b.t9
        lines, odd = make_lines(rows, t9, _Line)
        write = self._fh.write
        binary = self._binary
        if not odd:
            data = self._encode_lines(lines)
            write(data if binary else data.decode("utf-8"))  # type: ignore[arg-type]
            return
        start = 0
        for i in odd:
            if i > start:
                data = self._encode_lines(lines[start:i])
                write(data if binary else data.decode("utf-8"))  # type: ignore[arg-type]
            self._write(_dumps(row_record(t9[i], rows[i])) + "\n")
            start = i + 1
        if start < len(lines):
            data = self._encode_lines(lines[start:])
            write(data if binary else data.decode("utf-8"))  # type: ignore[arg-type]


class ArrowSink(Listener):
    """The columnar trace (optional, `pip install uwsimnet-zenoh[columnar]`): the same events as the JSONL
    trace, one column per field, written to an Arrow IPC file in record batches of `batch` rows.  The meta
    record is the schema's metadata (key `uwsimnet.meta`, its JSON).  Read back by `analysis.read_trace`
    (and so by `uwsimnet report` and `plot`) when the file name ends in `.arrow`."""

    COLUMNS = ("t", "ev", "ch", "dev", "src", "dst", "seq", "size", "flow", "kind", "reason", "fifo", "dist",
               "implicit", "doppler", "level")

    def __init__(self, path: Any, meta: Record, batch: int = 65536) -> None:
        try:
            import pyarrow as pa
        except ImportError:
            raise ValueError("a columnar (.arrow) trace needs pyarrow: pip install 'uwsimnet-zenoh[columnar]'") \
                from None
        self._pa = pa
        s, i, f = pa.string(), pa.int64(), pa.float64()
        d = pa.dictionary(pa.int32(), s)
        types = (f, d, i, d, i, i, i, i, d, d, d, i, f, pa.bool_(), f, f)
        self._types = types
        self.schema = pa.schema([pa.field(n, ty) for n, ty in zip(self.COLUMNS, types, strict=True)],
                                metadata={"uwsimnet.meta": _dumps(meta)})
        self._writer = pa.ipc.new_file(str(path), self.schema)
        self._batch = batch
        self._cols: list[list[Any]] = [[] for _ in self.COLUMNS]

    def event(self, t: float, ev: str, ch: int, dev: str, frame: Frame, reason: str | None,
              fifo: int | None, dist: float | None, implicit: bool = False) -> None:
        c = self._cols
        c[0].append(round(t, 9))
        c[1].append(ev)
        c[2].append(ch)
        c[3].append(dev)
        c[4].append(frame.src)
        c[5].append(frame.dst)
        c[6].append(frame.seq)
        c[7].append(frame.size)
        c[8].append(frame.flow)
        c[9].append(frame.kind)
        c[10].append(reason)
        c[11].append(fifo)
        c[12].append(None if dist is None else round(float(dist), 3))
        c[13].append(bool(implicit))
        c[14].append(None if dist is None else rx_doppler(dist))
        c[15].append(None if dist is None else level(dist))
        if len(c[0]) >= self._batch:
            self.flush()

    def write_batch(self, b: Batch) -> None:
        """A batch consumer (`tracer.consume(sink.write_batch)`): the same columns as `event()` per event."""
        if not b.rows:
            return
        cols = b.columns()
        c = self._cols
        c[0].extend(b.t9)
        for i in range(1, 12):
            c[i].extend(cols[i])
        dist = cols[12]
        c[12].extend(None if d is None else round(float(d), 3) for d in dist)
        c[13].extend(map(bool, cols[13]))
        c[14].extend(None if d is None else rx_doppler(d) for d in dist)
        c[15].extend(None if d is None else level(d) for d in dist)
        if len(c[0]) >= self._batch:
            self.flush()

    def flush(self) -> None:
        c = self._cols
        if not c[0]:
            return
        pa = self._pa
        arrays = []
        for col, ty in zip(c, self._types, strict=True):
            if pa.types.is_dictionary(ty):
                arrays.append(pa.array(col, pa.string()).dictionary_encode())
            else:
                arrays.append(pa.array(col, ty))
        self._writer.write_batch(pa.record_batch(arrays, schema=self.schema))
        self._cols = [[] for _ in self.COLUMNS]

    def close(self) -> None:
        self.flush()
        self._writer.close()


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
                import logging  # noqa: PLC0415 - only here: nothing else on a run's path logs

                logging.getLogger("uwsimnet.trace").error(
                    "tracing class %s raised %s in on_%s at t=%s; it is disabled for the rest of the run",
                    self.name, type(e).__name__, rec["ev"], rec.get("t"), exc_info=e)


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

