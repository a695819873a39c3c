"""Per-flow metrics as tables: rich on a terminal, aligned plain text, markdown and JSON."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from rich.table import Table

from ..trace.events import finite
from .metrics import FlowMetrics

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


def format_report(metrics: Mapping[str, FlowMetrics], title: str | None = "Per-flow metrics") -> Table:
    """A rich Table of the per-flow metrics."""
    table = Table(title=title)
    for i, c in enumerate(_COLUMNS):
        table.add_column(c, justify="left" if i < 2 or i == len(_COLUMNS) - 1 else "right",
                         no_wrap=i < len(_COLUMNS) - 1)
    for m in metrics.values():
        table.add_row(*_row(m))
    return table


def _plain(header: list[str] | tuple[str, ...], rows: list[list[str]], left: set[int]) -> str:
    widths = [max([len(h)] + [len(r[i]) for r in rows]) for i, h in enumerate(header)]

    def line(cells: list[str] | tuple[str, ...]) -> str:
        return "  ".join(c.ljust(w) if i in left else c.rjust(w)
                         for i, (c, w) in enumerate(zip(cells, widths, strict=True))).rstrip()

    return "\n".join([line(header), "  ".join("-" * w for w in widths)] + [line(r) for r in rows]) + "\n"


def format_text(metrics: Mapping[str, FlowMetrics]) -> str:
    """The per-flow metrics as a plain-text table (no colours, no box characters)."""
    return _plain(_COLUMNS, [_row(m) for m in metrics.values()], {0, 1, len(_COLUMNS) - 1})


def report_json(metrics: Mapping[str, FlowMetrics]) -> dict[str, Any]:
    """JSON-ready report: `{"version": 1, "flows": {name: FlowMetrics.to_dict()}}`."""
    return finite({"version": 1, "flows": {name: m.to_dict() for name, m in metrics.items()}})


def markdown_table(header: list[str], rows: list[list[str]]) -> str:
    """A GitHub-flavoured markdown table (pipes in cells escaped)."""
    def cells(r: list[str]) -> str:
        return "| " + " | ".join(c.replace("|", "\\|") for c in r) + " |"
    rule = "|" + "|".join("---" for _ in header) + "|"
    return "\n".join([cells(header), rule] + [cells(r) for r in rows]) + "\n"


def format_markdown(metrics: Mapping[str, FlowMetrics]) -> str:
    """The per-flow metrics as a markdown table."""
    return markdown_table(list(_COLUMNS), [_row(m) for m in metrics.values()])
