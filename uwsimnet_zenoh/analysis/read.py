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
import zlib
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
INT_MAX = 2**63
"""Integers of a trace (addresses, sequence numbers, sizes) are below this in magnitude."""
MAX_LINE = 1 << 20
"""Longest trace line read (bytes of text); a trace line is a few hundred."""
MAX_DEPTH = 32
"""Deepest nesting of arrays/objects in a trace line (the format nests 3 levels)."""
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


def _finite(x: Any) -> bool:
    """A JSON number that is a finite float (an integer too large for a float is not)."""
    if not is_num(x):
        return False
    try:
        return math.isfinite(x)
    except OverflowError:
        return False


def _small_int(x: Any) -> bool:
    return is_int(x) and -INT_MAX <= x < INT_MAX


def _opt(m: dict, key: str, ok: Any, what: str, where: str) -> None:
    if key in m and m[key] is not None and not ok(m[key]):
        raise TraceError(f"{where}: meta {what}")


def check_meta(meta: dict[str, Any], where: str) -> dict[str, Any]:
    """The meta record if the fields readers use have their documented types (docs/trace-format.md);
    absent fields are fine (older traces), mistyped ones a one-line TraceError."""
    _opt(meta, "duration", lambda d: _finite(d) and d >= 0, "'duration' must be a number >= 0 or null", where)
    _opt(meta, "t", _finite, "'t' must be a number", where)
    _opt(meta, "seed", _small_int, "'seed' must be an integer", where)
    _opt(meta, "version", _small_int, "'version' must be an integer", where)
    _opt(meta, "scene", lambda v: isinstance(v, str), "'scene' must be a string", where)
    for key, fields in (("flows", _FLOW_FIELDS), ("devices", _DEVICE_FIELDS)):
        group = meta.get(key)
        if group is None:
            continue
        if not isinstance(group, dict):
            raise TraceError(f"{where}: meta {key!r} must be an object (name -> object)")
        for name, d in group.items():
            if not isinstance(d, dict):
                raise TraceError(f"{where}: meta {key}[{name!r}] must be an object")
            for f, (ok, what) in fields.items():
                _opt(d, f, ok, f"{key}[{name!r}].{f} must be {what}", where)
    return meta


_FLOW_FIELDS = {
    "src": (lambda v: isinstance(v, str), "a string"),
    "dst": (lambda v: _small_int(v) and v >= 0, "an integer address"),
    "size": (lambda v: _small_int(v) and v >= 0, "an integer >= 0"),
    "interval": (lambda v: _finite(v) and v > 0, "a number > 0"),
    "start": (lambda v: _finite(v) and v >= 0, "a number >= 0"),
    "stop": (_finite, "a number or null"),
}
_DEVICE_FIELDS = {
    "address": (lambda v: _small_int(v) and v >= 0, "an integer address"),
    "tx_channel": (lambda v: _small_int(v) or isinstance(v, str), "a channel id"),
    "rx_channel": (lambda v: _small_int(v) or isinstance(v, str), "a channel id"),
    "bitrate": (lambda v: _finite(v) and v > 0, "a number > 0"),
    "header_bytes": (lambda v: _small_int(v) and v >= 0, "an integer >= 0"),
}


def _check(rec: Any, where: str) -> dict[str, Any]:
    """The record if it is a usable trace record, else TraceError naming `where`."""
    if not isinstance(rec, dict):
        raise TraceError(f"{where}: expected a JSON object, got {type(rec).__name__}")
    ev = rec.get("ev")
    if not isinstance(ev, str):
        raise TraceError(f"{where}: missing or non-string 'ev'")
    if ev in EVENTS:
        t = rec.get("t")
        if not _finite(t):
            raise TraceError(f"{where}: {ev} event: missing or non-numeric 't'")
        for k in ("src", "seq", "size"):
            if not is_int(rec.get(k)):
                raise TraceError(f"{where}: {ev} event: missing or non-integer {k!r}")
            if not _small_int(rec[k]):
                raise TraceError(f"{where}: {ev} event: {k!r} out of range (|{k}| < 2**63)")
        if not isinstance(rec.get("dev"), str):
            raise TraceError(f"{where}: {ev} event: missing or non-string 'dev'")
        if "ch" not in rec or not isinstance(rec["ch"], int | str) or isinstance(rec["ch"], bool):
            raise TraceError(f"{where}: {ev} event: missing 'ch'")
        if is_int(rec["ch"]) and not _small_int(rec["ch"]):
            raise TraceError(f"{where}: {ev} event: 'ch' out of range")
        if "dst" in rec and not _small_int(rec["dst"]):
            raise TraceError(f"{where}: {ev} event: non-integer 'dst'")
        flow = rec.get("flow")
        if flow is not None and not isinstance(flow, str):
            raise TraceError(f"{where}: {ev} event: 'flow' must be a string or null")
        if ev == "drop" and not isinstance(rec.get("reason"), str):
            raise TraceError(f"{where}: drop event without a string 'reason'")
        if rec.get("kind") is not None and not isinstance(rec["kind"], str):
            raise TraceError(f"{where}: {ev} event: 'kind' must be a string")
    return rec


def _depth_ok(line: str) -> bool:
    """Nesting of [ and { at most MAX_DEPTH (a cheap bound before json.loads, whose recursion a deeply
    nested line would exhaust); brackets inside strings count too, which only errs on the safe side."""
    depth = 0
    for ch in line:
        if ch in "[{":
            depth += 1
            if depth > MAX_DEPTH:
                return False
        elif ch in "]}":
            depth -= 1
    return True


def _parse(line: str, path: Path | str, lineno: int) -> dict[str, Any]:
    where = f"{path}:{lineno}"
    if len(line) > MAX_LINE:
        raise TraceError(f"{where}: line longer than {MAX_LINE} characters")
    if ("[" in line or "{" in line) and line.count("[") + line.count("{") > MAX_DEPTH and not _depth_ok(line):
        raise TraceError(f"{where}: JSON nested deeper than {MAX_DEPTH} levels")
    try:
        rec = json.loads(line, parse_constant=_no_constant)
    except json.JSONDecodeError as e:
        raise TraceError(f"{where}: invalid JSON: {e.msg} (column {e.colno})") from None
    except (ValueError, RecursionError) as e:      # integers over Python's digit limit, NaN/Infinity
        raise TraceError(f"{where}: invalid JSON: {' '.join(str(e).split()[:12])}") from None
    rec = _check(rec, where)
    if rec.get("ev") == "meta":
        check_meta(rec, where)
    return rec


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not JSON (the trace format writes null for a non-finite number)")


def _events(path: Path, skip: int) -> Iterator[dict[str, Any]]:
    try:
        with _open(path) as fh:
            for lineno, line in enumerate(fh, 1):
                if lineno == skip or not line.strip():
                    continue
                yield _parse(line, path, lineno)
    except (OSError, UnicodeDecodeError, EOFError, zlib.error) as e:
        raise TraceError(f"{path}: cannot read: {_why(e)}") from None


def _why(e: BaseException) -> str:
    if isinstance(e, EOFError):
        return "truncated (the compressed stream ends early)"
    return " ".join(str(e).split()) or type(e).__name__


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
    cols = {c: table.column(c).to_pylist() for c in COLUMNS}
    n = table.num_rows       # `doppler`, `level` (optional: traces written before them have none)
    for c in ("doppler", "level"):
        cols[c] = table.column(c).to_pylist() if c in table.column_names else [None] * n
    return meta, cols


def _column_events(cols: dict[str, list[Any]]) -> Iterator[dict[str, Any]]:
    """The records of a columnar trace, as the JSONL trace has them (optional keys only when set)."""
    keys = REQUIRED[:8] + ("flow", "kind")
    for row in zip(*(cols[k] for k in keys), cols["reason"], cols["fifo"], cols["dist"], cols["doppler"],
                   cols["level"], cols["implicit"], strict=True):
        rec = dict(zip(keys, row[:10], strict=True))
        for k, v in zip(("reason", "fifo", "dist", "doppler", "level"), row[10:15], strict=True):
            if v is not None:
                rec[k] = v
        if row[15]:
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
    except (OSError, UnicodeDecodeError, EOFError, zlib.error) as e:
        raise TraceError(f"{p}: cannot read: {_why(e)}") from None
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


