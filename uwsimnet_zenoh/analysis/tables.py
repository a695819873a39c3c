"""Per-flow metrics as tables: rich on a terminal, aligned plain text, markdown and JSON; `show_metrics` prints
one (`uwsimnet run` and `uwsimnet report`)."""

from __future__ import annotations

import sys
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

from ..trace.events import finite
from .levels import LinkLevel
from .metrics import FlowMetrics

if TYPE_CHECKING:
    from rich.table import Table

# -- rendering ----------------------------------------------------------------------------------
_COLUMNS = ("flow", "src", "dst", "enq", "sent", "uniq", "dlvd", "ratio", "thr B/s", "offer B/s", "eff %",
            "delay s", "median s", "p95 s", "jitter s", "drops (final)")


def _f(x: float | None, digits: int = 3) -> str:
    if x is None:
        return "-"
    return f"{x:.{digits}f}"


def _drops_str(d: Mapping[str, int]) -> str:
    return " ".join(f"{r}:{n}" for r, n in d.items()) or "-"


def _row(m: FlowMetrics) -> list[str]:
    return [m.name, m.src or "-", "-" if m.dst is None else ("bcast" if m.broadcast else str(m.dst)),
            str(m.enqueued), str(m.sent), str(m.unique_sent), str(m.delivered), _f(m.delivery_ratio),
            _f(m.throughput, 2), _f(m.offered, 2),
            _f(None if m.efficiency is None else 100.0 * m.efficiency, 1),
            _f(m.delay_mean), _f(m.delay_median), _f(m.delay_p95), _f(m.jitter), _drops_str(m.drops)]


_LEFT = {0, 1, len(_COLUMNS) - 1}
_KEY = 1
"""Columns repeated in every part of a split table (flow), so each part reads on its own."""


def _groups(widths: list[int], fit: int, cost: int) -> list[list[int]]:
    """Column indices in parts whose width (each column `w + cost`, plus one) fits in `fit`; the key
    columns (the flow) start every part; None if even key + one column does not fit."""
    key = list(range(_KEY))
    base = 1 + sum(widths[i] + cost for i in key)
    parts: list[list[int]] = []
    cur: list[int] = []
    used = base
    for i in range(_KEY, len(widths)):
        w = widths[i] + cost
        if cur and used + w > fit:
            parts.append(key + cur)
            cur, used = [], base
        cur.append(i)
        used += w
    if cur:
        parts.append(key + cur)
    return parts


class FlowTable:
    """The per-flow table as a rich renderable that fits the width it is given: one table when it
    fits; else several tables, each with the flow column and as many of the others as fit (wrapped);
    on a width too narrow for even that, one two-column table (metric, value) per flow (stacked).
    Cells are never cut ("..."): every column is as wide as its longest cell."""

    def __init__(self, metrics: Mapping[str, FlowMetrics], title: str | None = "Per-flow metrics") -> None:
        self.rows = [_row(m) for m in metrics.values()]
        self.title = title

    def _table(self, cols: list[int], title: str | None) -> Table:
        from rich.table import Table  # noqa: PLC0415 - a terminal only (start-up time of a piped run)

        t = Table(title=title)
        for i in cols:
            t.add_column(_COLUMNS[i], justify="left" if i in _LEFT else "right", no_wrap=True, overflow="fold")
        for r in self.rows:
            t.add_row(*(r[i] for i in cols))
        return t

    def layout(self, width: int) -> list[Table]:
        widths = [max([len(h)] + [len(r[i]) for r in self.rows]) for i, h in enumerate(_COLUMNS)]
        cost = 3                                            # rich's box: a rule and one space each side
        if 1 + sum(w + cost for w in widths) <= width:
            return [self._table(list(range(len(_COLUMNS))), self.title)]
        parts = _groups(widths, width, cost)
        if all(1 + sum(widths[i] + cost for i in p) <= width for p in parts):
            n = len(parts)
            return [self._table(p, f"{self.title} ({k}/{n})" if self.title else None)
                    for k, p in enumerate(parts, 1)]
        from rich.table import Table  # noqa: PLC0415

        out = []
        for r in self.rows:                                 # stacked: metric | value, one table per flow
            t = Table(title=f"{self.title}: {r[0]}" if self.title else r[0], show_header=False)
            t.add_column(overflow="fold")
            t.add_column(justify="right", overflow="fold")
            for i in range(1, len(_COLUMNS)):
                t.add_row(_COLUMNS[i], r[i])
            out.append(t)
        return out

    def __rich_console__(self, console: Any, options: Any) -> Any:
        yield from self.layout(options.max_width)


def format_report(metrics: Mapping[str, FlowMetrics], title: str | None = "Per-flow metrics") -> FlowTable:
    """A rich renderable of the per-flow metrics that fits the console's width (see FlowTable)."""
    return FlowTable(metrics, title)


def show_metrics(metrics: Mapping[str, FlowMetrics], links: Sequence[LinkLevel] = ()) -> None:
    """The per-flow table on stdout: rich on a terminal, plain aligned text when piped (rich would squeeze it);
    then the received level per link, if there are levels."""
    if sys.stdout.isatty():
        from rich.console import Console  # noqa: PLC0415 - a terminal only (start-up time)

        Console().print(format_report(metrics))
    else:
        print(format_text(metrics))
    if links:
        print(format_links(links))


_LINK_COLUMNS = ("ch", "src", "dev", "rx", "level dB", "min dB", "max dB")


def format_links(links: Sequence[LinkLevel]) -> str:
    """The mean received level per link (its rx records with a `level`) as a plain-text table."""
    rows = [[str(x.ch), x.src, x.dev, str(x.received), _f(x.mean_db), _f(x.min_db), _f(x.max_db)] for x in links]
    return _plain(_LINK_COLUMNS, rows, {1, 2})


def _plain(header: list[str] | tuple[str, ...], rows: list[list[str]], left: set[int]) -> str:
    widths = [max([len(h)] + [len(r[i]) for r in rows]) for i, h in enumerate(header)]

    def line(cells: list[str] | tuple[str, ...]) -> str:
        return "  ".join(c.ljust(w) if i in left else c.rjust(w)
                         for i, (c, w) in enumerate(zip(cells, widths, strict=True))).rstrip()

    return "\n".join([line(header), "  ".join("-" * w for w in widths)] + [line(r) for r in rows]) + "\n"


def format_text(metrics: Mapping[str, FlowMetrics], width: int | None = None) -> str:
    """The per-flow metrics as a plain-text table (no colours, no box characters); with `width`, split
    into parts that fit it (each with the flow column), never cutting a cell."""
    rows = [_row(m) for m in metrics.values()]
    if width is None:
        return _plain(_COLUMNS, rows, _LEFT)
    widths = [max([len(h)] + [len(r[i]) for r in rows]) for i, h in enumerate(_COLUMNS)]
    if sum(w + 2 for w in widths) - 2 <= width:
        return _plain(_COLUMNS, rows, _LEFT)
    parts = _groups(widths, width + 1, 2)
    return "\n".join(_plain([_COLUMNS[i] for i in p], [[r[i] for i in p] for r in rows],
                            {k for k, i in enumerate(p) if i in _LEFT}) for p in parts)


def report_json(metrics: Mapping[str, FlowMetrics], links: Sequence[LinkLevel] = ()) -> dict[str, Any]:
    """JSON-ready report: `{"version": 1, "flows": {name: FlowMetrics.to_dict()}}`, and `"links"`: [LinkLevel
    as a dict] when the trace has received levels."""
    out: dict[str, Any] = {"version": 1, "flows": {name: m.to_dict() for name, m in metrics.items()}}
    if links:
        out["links"] = [x.to_dict() for x in links]
    return finite(out)


def markdown_table(header: list[str], rows: list[list[str]]) -> str:
    """A GitHub-flavoured markdown table (pipes in cells escaped)."""
    def cells(r: list[str]) -> str:
        return "| " + " | ".join(c.replace("|", "\\|") for c in r) + " |"
    rule = "|" + "|".join("---" for _ in header) + "|"
    return "\n".join([cells(header), rule] + [cells(r) for r in rows]) + "\n"


def format_markdown(metrics: Mapping[str, FlowMetrics]) -> str:
    """The per-flow metrics as a markdown table."""
    return markdown_table(list(_COLUMNS), [_row(m) for m in metrics.values()])
