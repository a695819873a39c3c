"""The per-flow table fits the terminal: at 80 columns (and the 120 of a real-time summary) it wraps
into parts or stacks per flow, never cutting a cell to "..." (issue #20)."""

from __future__ import annotations

import io
import re

import pytest
from rich.console import Console

from uwsimnet_zenoh.analysis.metrics import FlowMetrics
from uwsimnet_zenoh.analysis.tables import _COLUMNS, _row, format_report, format_text


def metrics(name_len: int = 12, drops: int = 4) -> dict[str, FlowMetrics]:
    out = {}
    for k in range(3):
        name = (f"flow{k}-" + "x" * name_len)[:max(name_len, 6)]
        m = FlowMetrics(name=name, src=f"{name}-modem", dst=k + 1)
        m.enqueued, m.sent, m.unique_sent, m.delivered = 123456, 123400, 123000, 120001
        m.drops = {r: 1000 + k for r in ("col", "prop", "fifo", "range", "mult")[:drops]}
        out[name] = m
    return out


def squeezed(text: str) -> str:
    """The text without box characters and whitespace (a folded cell's pieces join up again)."""
    return re.sub(r"[\s\u2500-\u257f]", "", text)


def render(renderable, width: int) -> str:
    buf = io.StringIO()
    Console(file=buf, width=width, force_terminal=True, color_system=None, legacy_windows=False).print(renderable)
    return buf.getvalue()


@pytest.mark.parametrize("width", [40, 60, 80, 100, 120, 200])
@pytest.mark.parametrize("name_len,drops", [(6, 0), (12, 4), (30, 5)])
def test_rich_report_fits_and_never_cuts(width, name_len, drops):
    ms = metrics(name_len, drops)
    text = render(format_report(ms), width)
    assert "…" not in text and "..." not in text
    assert max(len(line) for line in text.splitlines()) <= width, text
    for m in ms.values():                      # every cell is there, whole (a long one wraps at spaces)
        for cell in _row(m):
            for word in cell.split():
                assert word in text or word in squeezed(text), (word, text)
    for c in _COLUMNS:
        assert c in text


def test_wide_terminal_keeps_one_table_and_narrow_stacks():
    ms = metrics(6, 0)
    assert "(1/" not in render(format_report(ms), 250)
    assert "(1/" in render(format_report(ms), 80)
    narrow = render(format_report(ms), 34)
    assert "Per-flow metrics: flow0-" in narrow.replace("\n", " ").replace("  ", " ") or "flow0-" in narrow


@pytest.mark.parametrize("width", [60, 80])
def test_plain_text_splits_to_a_width(width):
    ms = metrics(12, 4)
    text = format_text(ms, width)
    assert max(len(line) for line in text.splitlines()) <= width, text
    assert format_text(ms).count("\n") == 5                    # no width: one table, as before
    for m in ms.values():
        for cell in _row(m):
            assert cell in text
