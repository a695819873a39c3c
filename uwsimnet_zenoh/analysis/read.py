"""Reading a trace back: JSONL (or .gz) to checked records, one line at a time (docs/trace-format.md);
the columnar trace (`.arrow`, Arrow IPC, optional pyarrow) as whole columns.

    meta, events = read_trace("run.jsonl")
    meta, cols = read_columns("run.arrow")      # column name -> Python list, checked once per column

Every problem is a `TraceError` whose message is one line, `file:line: what`.
"""

from __future__ import annotations

import gzip
import json
import math
from collections.abc import Iterable, Iterator
from os import PathLike
from pathlib import Path
from typing import IO, Any

from ..errors import UwsimnetError

EVENTS = frozenset({"enq", "tx", "rx", "drop"})
TX_REASONS = frozenset({"fifo", "retry", "size", "removed"})
"""Drop reasons that happen at the transmitter (used only when the trace cannot tell by itself)."""
RX_REASONS = frozenset({"prop", "col", "mult", "range", "nopose", "duplex"})
"""Drop reasons that happen at a receiver (ditto)."""
DEFAULT_HORIZON = 60.0
"""A transmitted frame with no outcome whose last tx is this close (s) to the end is in flight."""

Source = str | PathLike[str] | Iterable[dict[str, Any]]


class TraceError(UwsimnetError, ValueError):
    """A trace that cannot be read; the message is one line, `file:line: what`."""


# -- reading ------------------------------------------------------------------------------------
def _open(path: Path) -> IO[str]:
    if path.suffix == ".gz":
        return gzip.open(path, "rt", encoding="utf-8")
    return open(path, encoding="utf-8")


def is_num(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool)


def is_int(x: Any) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def _check(rec: Any, where: str) -> dict[str, Any]:
    """The record if it is a usable trace record, else TraceError naming `where`."""
    if not isinstance(rec, dict):
        raise TraceError(f"{where}: expected a JSON object, got {type(rec).__name__}")
    ev = rec.get("ev")
    if not isinstance(ev, str):
        raise TraceError(f"{where}: missing or non-string 'ev'")
    if ev in EVENTS:
        t = rec.get("t")
        if not is_num(t) or not math.isfinite(t):
            raise TraceError(f"{where}: {ev} event: missing or non-numeric 't'")
        for k in ("src", "seq", "size"):
            if not is_int(rec.get(k)):
                raise TraceError(f"{where}: {ev} event: missing or non-integer {k!r}")
        if not isinstance(rec.get("dev"), str):
            raise TraceError(f"{where}: {ev} event: missing or non-string 'dev'")
        if "ch" not in rec or not isinstance(rec["ch"], int | str):
            raise TraceError(f"{where}: {ev} event: missing 'ch'")
        if "dst" in rec and not is_int(rec["dst"]):
            raise TraceError(f"{where}: {ev} event: non-integer 'dst'")
        flow = rec.get("flow")
        if flow is not None and not isinstance(flow, str):
            raise TraceError(f"{where}: {ev} event: 'flow' must be a string or null")
        if ev == "drop" and not isinstance(rec.get("reason"), str):
            raise TraceError(f"{where}: drop event without a string 'reason'")
    return rec


def _parse(line: str, path: Path | str, lineno: int) -> dict[str, Any]:
    where = f"{path}:{lineno}"
    try:
        rec = json.loads(line)
    except json.JSONDecodeError as e:
        raise TraceError(f"{where}: invalid JSON: {e.msg} (column {e.colno})") from None
    return _check(rec, where)


def _events(path: Path, skip: int) -> Iterator[dict[str, Any]]:
    try:
        with _open(path) as fh:
            for lineno, line in enumerate(fh, 1):
                if lineno == skip or not line.strip():
                    continue
                yield _parse(line, path, lineno)
    except (OSError, UnicodeDecodeError) as e:
        raise TraceError(f"{path}: cannot read: {e}") from None


def is_columnar(src: Any) -> bool:
    return isinstance(src, str | PathLike) and Path(src).suffix == ".arrow"


REQUIRED = ("t", "ev", "ch", "dev", "src", "dst", "seq", "size", "kind", "implicit")
COLUMNS = REQUIRED + ("flow", "reason", "fifo", "dist")


def read_columns(path: str | PathLike[str]) -> tuple[dict[str, Any], dict[str, list[Any]]]:
    """(meta, columns) of a columnar `.arrow` trace (trace.events.ArrowSink): every column as a Python
    list, checked with vectorised tests (no nulls where the format requires a value, drops have reasons)."""
    p = Path(path)
    try:
        import pyarrow as pa
        import pyarrow.compute as pc
    except ImportError:
        raise TraceError(f"{p}: reading a columnar trace needs pyarrow: pip install 'uwsimnet-zenoh[columnar]'") \
            from None
    try:
        with pa.memory_map(str(p)) as src:
            table = pa.ipc.open_file(src).read_all()
    except (OSError, pa.ArrowInvalid) as e:
        raise TraceError(f"{p}: cannot read: {e}") from None
    raw = (table.schema.metadata or {}).get(b"uwsimnet.meta")
    try:
        meta = json.loads(raw) if raw else {}
    except ValueError:
        raise TraceError(f"{p}: invalid meta in the schema metadata") from None
    missing = [c for c in COLUMNS if c not in table.column_names]
    if missing:
        raise TraceError(f"{p}: missing column(s) {', '.join(missing)}")
    for c in REQUIRED:
        if table.column(c).null_count:
            raise TraceError(f"{p}: null values in column {c!r}")
    drops = pc.equal(table.column("ev"), "drop")
    if pc.any(pc.and_(drops, pc.is_null(table.column("reason")))).as_py():
        raise TraceError(f"{p}: drop event without a 'reason'")
    return meta, {c: table.column(c).to_pylist() for c in COLUMNS}


def _column_events(cols: dict[str, list[Any]]) -> Iterator[dict[str, Any]]:
    """The records of a columnar trace, as the JSONL trace has them (optional keys only when set)."""
    keys = REQUIRED[:8] + ("flow", "kind")
    for row in zip(*(cols[k] for k in keys), cols["reason"], cols["fifo"], cols["dist"], cols["implicit"],
                   strict=True):
        rec = dict(zip(keys, row[:10], strict=True))
        for k, v in zip(("reason", "fifo", "dist"), row[10:13], strict=True):
            if v is not None:
                rec[k] = v
        if row[13]:
            rec["implicit"] = True
        yield rec


def read_trace(path: str | PathLike[str]) -> tuple[dict[str, Any], Iterator[dict[str, Any]]]:
    """(meta, events) of a JSONL trace (`.gz` is read transparently).

    `meta` is the first line if it is an `ev: meta` record, else `{}`.  A `.arrow` file is the columnar
    trace: its records are rebuilt from the columns.  `events` is a lazy iterator
    over the remaining records (unknown event kinds included: consumers skip them); a malformed line
    raises `TraceError("file:line: ...")` when the iterator reaches it.
    """
    p = Path(path)
    if p.suffix == ".arrow":
        meta, cols = read_columns(p)
        return meta, _column_events(cols)
    meta: dict[str, Any] = {}
    skip = 0
    try:
        with _open(p) as fh:
            for lineno, line in enumerate(fh, 1):
                if not line.strip():
                    continue
                rec = _parse(line, p, lineno)
                if rec["ev"] == "meta":
                    meta, skip = rec, lineno
                break
    except (OSError, UnicodeDecodeError) as e:
        raise TraceError(f"{p}: cannot read: {e}") from None
    return meta, _events(p, skip)


def _iter_checked(records: Iterable[dict[str, Any]]) -> Iterator[dict[str, Any]]:
    for i, rec in enumerate(records, 1):
        yield _check(rec, f"<events>:{i}")


def open_source(src: Source, meta: dict[str, Any] | None = None) -> tuple[dict[str, Any], Iterator[dict]]:
    """(meta, events) from a path or from an iterable of records (whose first may be the meta)."""
    if isinstance(src, str | PathLike):
        m, events = read_trace(src)
        return (m if meta is None else meta), events
    it = _iter_checked(src)
    first = next(it, None)
    if first is None:
        return (meta or {}), iter(())
    if first["ev"] == "meta":
        return (first if meta is None else meta), it
    return (meta or {}), _chain(first, it)


def _chain(first: dict[str, Any], rest: Iterator[dict[str, Any]]) -> Iterator[dict[str, Any]]:
    yield first
    yield from rest


