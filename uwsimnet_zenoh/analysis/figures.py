"""Figures from traces, after the seed paper's Figures 3, 4 and 7 (docs/trace-format.md).

    plot_trace("run.jsonl", "figs/")     -> fig3-packets.png, fig4-delay.png
    plot_compare({"NOMAC": "nomac.jsonl", "ALOHA": "aloha.jsonl", "SFAMA": "sfama.jsonl"}, "figs/")
                                         -> fig7-mac-comparison.png

Matplotlib is driven through `Figure` objects and the Agg canvas only (no pyplot, no display, no global
backend switch), so plotting is safe from any thread and in headless runs.  Panels without data are
left out; a figure without any panel is not written.
"""

from __future__ import annotations

from array import array
from collections.abc import Callable, Mapping
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from rich.table import Table

from . import (
    EVENTS,
    DeviceMap,
    FlowMetrics,
    Source,
    flow_metrics,
    flow_name,
    markdown_table,
    read_trace,
)

DPI = 120

# Fig. 3 dot rows, top to bottom: (key, label, colour)
ROWS: tuple[tuple[str, str, str], ...] = (
    ("tx", "tx", "tab:blue"),
    ("rx", "rx", "tab:green"),
    ("prop", "err(PROP)", "black"),
    ("col", "err(COL)", "red"),
    ("mult", "err(MULT)", "orange"),
    ("range", "err(RANGE)", "grey"),
    ("fifo", "fifo drop", "purple"),
)
OTHER = ("other", "other drop", "saddlebrown")
_ROW_KEYS = {k for k, _, _ in ROWS}


class _Series:
    __slots__ = ("t", "y")

    def __init__(self) -> None:
        self.t = array("d")
        self.y = array("d")

    def add(self, t: float, y: float) -> None:
        self.t.append(t)
        self.y.append(y)

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        return np.frombuffer(self.t, dtype=np.float64), np.frombuffer(self.y, dtype=np.float64)

    def __len__(self) -> int:
        return len(self.t)


class _Collected:
    """What the figures of one trace need, gathered in one pass."""

    def __init__(self) -> None:
        self.meta: dict[str, Any] = {}
        self.flows: list[str] = []
        self.dist: dict[tuple[str, str, str], _Series] = {}       # (flow, tx dev, rx dev)
        self.dots: dict[str, dict[str, array]] = {}                # flow -> row key -> times
        self.other_reasons: dict[str, set[str]] = {}
        self.fifo: dict[str, _Series] = {}                         # tx dev -> occupancy (bytes)
        self.delay: dict[str, _Series] = {}                        # flow -> (t rx, e2e delay)
        self.t_max = 0.0


def _collect(path: str | PathLike[str]) -> _Collected:
    c = _Collected()
    meta, events = read_trace(path)
    c.meta = meta
    flows = meta.get("flows")
    seen: dict[str, None] = dict.fromkeys(flows) if isinstance(flows, Mapping) else {}
    devs = DeviceMap(meta)
    t_enq: dict[tuple[str, int], float] = {}
    for rec in events:
        ev = rec["ev"]
        if ev not in EVENTS:
            continue
        t = rec["t"]
        if t > c.t_max:
            c.t_max = t
        tx_dev, at_tx = devs.transmitter(rec)
        if at_tx and "fifo" in rec and isinstance(rec["fifo"], int | float):
            s = c.fifo.get(tx_dev)
            if s is None:
                s = c.fifo[tx_dev] = _Series()
            s.add(t, rec["fifo"])
        if rec.get("kind", "data") != "data":
            continue
        flow = flow_name(rec.get("flow"), tx_dev)
        seen.setdefault(flow, None)
        if ev == "enq":
            t_enq.setdefault((tx_dev, rec["seq"]), t)
            continue
        if ev == "tx":
            key = "tx"
        elif ev == "rx":
            key = "rx"
            t0 = t_enq.get((tx_dev, rec["seq"]))
            if t0 is not None:
                s = c.delay.get(flow)
                if s is None:
                    s = c.delay[flow] = _Series()
                s.add(t, t - t0)
        else:
            reason = rec["reason"]
            key = reason if reason in _ROW_KEYS else "other"
            if key == "other":
                c.other_reasons.setdefault(flow, set()).add(reason)
        rows = c.dots.get(flow)
        if rows is None:
            rows = c.dots[flow] = {}
        ts = rows.get(key)
        if ts is None:
            ts = rows[key] = array("d")
        ts.append(t)
        dist = rec.get("dist")
        if not at_tx and ev != "tx" and isinstance(dist, int | float):
            k3 = (flow, tx_dev, rec["dev"])
            s = c.dist.get(k3)
            if s is None:
                s = c.dist[k3] = _Series()
            s.add(t, dist)
    c.flows = list(seen)
    return c


def _save(fig: Figure, path: Path) -> Path:
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=DPI)
    return path


def _xlim(c: _Collected) -> tuple[float, float]:
    dur = c.meta.get("duration")
    hi = max(c.t_max, float(dur) if isinstance(dur, int | float) and dur > 0 else 0.0)
    return 0.0, hi if hi > 0 else 1.0


def _legend(ax: Axes, max_entries: int = 16) -> None:
    handles, labels = ax.get_legend_handles_labels()
    if handles and len(handles) <= max_entries:
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)


def _panel_distance(ax: Axes, c: _Collected) -> None:
    for (flow, txd, rxd), s in sorted(c.dist.items()):
        t, d = s.arrays()
        order = np.argsort(t, kind="stable")
        ax.plot(t[order], d[order], marker=".", ms=3, lw=1, label=f"{flow} ({txd} → {rxd})", rasterized=True)
    ax.set_ylabel("distance (m)")
    ax.set_title("distance between transmitter and receiver", fontsize=10, loc="left")
    ax.grid(True, alpha=0.3)
    _legend(ax)


def _panel_flow(ax: Axes, c: _Collected, flow: str) -> None:
    rows = c.dots.get(flow, {})
    layout = list(ROWS)
    if "other" in rows:
        reasons = ", ".join(sorted(c.other_reasons.get(flow, ())))
        layout.append((OTHER[0], f"drop ({reasons})" if reasons else OTHER[1], OTHER[2]))
    n = len(layout)
    for i, (key, label, colour) in enumerate(layout):
        y = n - 1 - i
        ts = rows.get(key)
        if ts:
            t = np.frombuffer(ts, dtype=np.float64)
            ax.plot(t, np.full(len(t), y), linestyle="none", marker="o", ms=3, color=colour,
                    label=f"{label} ({len(t)})", rasterized=True)
    ax.set_yticks(range(n))
    ax.set_yticklabels([label for _, label, _ in reversed(layout)], fontsize=8)
    ax.set_ylim(-0.7, n - 0.3)
    ax.grid(True, axis="x", alpha=0.3)
    ax.set_title(f"packets of flow {flow}", fontsize=10, loc="left")
    _legend(ax)


def _panel_fifo(ax: Axes, c: _Collected) -> None:
    for dev, s in sorted(c.fifo.items()):
        t, f = s.arrays()
        ax.step(t, f, where="post", lw=1.0, alpha=0.8, label=dev)
    ax.set_ylabel("tx FIFO (bytes)")
    ax.set_title("occupancy of the transmission FIFO", fontsize=10, loc="left")
    ax.grid(True, alpha=0.3)
    _legend(ax)


def plot_trace(path: str | PathLike[str], out_dir: str | PathLike[str]) -> list[Path]:
    """Write `fig3-packets.png` and `fig4-delay.png` for a trace into `out_dir` (created if needed).

    Fig. 3: (a) transmitter-receiver distance over time per flow, one dot-row panel per flow (tx, rx,
    err(PROP|COL|MULT|RANGE), fifo drop, other drops), and the tx FIFO occupancy per transmitting device.
    Fig. 4: end-to-end delay over time per flow.  Returns the files written (figures or panels without
    data are skipped).
    """
    c = _collect(path)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    x0, x1 = _xlim(c)
    scene = c.meta.get("scene")
    suffix = f" — {scene}" if isinstance(scene, str) and scene else ""

    panels: list[tuple[float, Callable[[Axes], None]]] = []
    if c.dist:
        panels.append((2.4, lambda ax: _panel_distance(ax, c)))
    for flow in c.flows:
        if c.dots.get(flow):
            panels.append((2.2 + 0.1 * len(ROWS), lambda ax, f=flow: _panel_flow(ax, c, f)))
    if c.fifo:
        panels.append((2.4, lambda ax: _panel_fifo(ax, c)))
    if panels:
        fig = Figure(figsize=(12, 0.6 + sum(h for h, _ in panels)), layout="constrained")
        axes = fig.subplots(len(panels), 1, sharex=True, squeeze=False,
                            height_ratios=[h for h, _ in panels])[:, 0]
        for i, ((_, draw), ax) in enumerate(zip(panels, axes, strict=True)):
            draw(ax)
            ax.set_title(f"({chr(ord('a') + i)}) {ax.get_title(loc='left')}", fontsize=10, loc="left")
            ax.set_xlim(x0, x1)
        axes[-1].set_xlabel("time (s)")
        fig.suptitle(f"Packet flows{suffix}", fontsize=12)
        written.append(_save(fig, out / "fig3-packets.png"))

    if any(len(s) for s in c.delay.values()):
        fig = Figure(figsize=(11, 4.5), layout="constrained")
        ax = fig.add_subplot()
        for flow in c.flows:
            s = c.delay.get(flow)
            if s is None or not len(s):
                continue
            t, d = s.arrays()
            ax.plot(t, d, marker="o", ms=3, lw=0.8, label=f"{flow} ({len(t)})", rasterized=True)
        ax.set_xlim(x0, x1)
        ax.set_xlabel("time of reception (s)")
        ax.set_ylabel("end-to-end delay (s)")
        ax.set_title(f"End-to-end delay{suffix}", fontsize=12)
        ax.grid(True, alpha=0.3)
        _legend(ax)
        written.append(_save(fig, out / "fig4-delay.png"))
    return written


# -- comparing runs (Fig. 7) --------------------------------------------------------------------
TraceOrMetrics = Source | Mapping[str, FlowMetrics]

# (label, value of a FlowMetrics, unit label)
METRICS: tuple[tuple[str, Callable[[FlowMetrics], float | None], str], ...] = (
    ("throughput", lambda m: m.throughput, "B/s"),
    ("efficiency", lambda m: None if m.efficiency is None else 100.0 * m.efficiency, "%"),
    ("end-to-end delay", lambda m: m.delay_mean, "s"),
    ("jitter", lambda m: m.jitter, "s"),
)


def compare_metrics(traces: Mapping[str, TraceOrMetrics]) -> dict[str, dict[str, FlowMetrics]]:
    """label -> flow -> FlowMetrics; a value may be a trace (path / records) or metrics already computed."""
    out: dict[str, dict[str, FlowMetrics]] = {}
    for label, src in traces.items():
        if isinstance(src, Mapping) and all(isinstance(v, FlowMetrics) for v in src.values()):
            out[label] = dict(src)
        else:
            out[label] = flow_metrics(src)   # type: ignore[arg-type]
    return out


def _flow_union(per_label: Mapping[str, Mapping[str, FlowMetrics]]) -> list[str]:
    seen: dict[str, None] = {}
    for flows in per_label.values():
        for name in flows:
            seen.setdefault(name, None)
    return list(seen)


def plot_compare(traces: Mapping[str, TraceOrMetrics], out_dir: str | PathLike[str],
                 title: str | None = None) -> list[Path]:
    """Write `fig7-mac-comparison.png`: throughput (B/s), efficiency (%), mean end-to-end delay (s) and
    jitter (s) per flow, one bar per label (e.g. NOMAC / ALOHA / SFAMA).  Missing values get no bar."""
    per_label = compare_metrics(traces)
    flows = _flow_union(per_label)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if not flows or not per_label:
        return []
    labels = list(per_label)
    n = len(labels)
    width = 0.8 / n
    x = np.arange(len(flows), dtype=float)
    fig = Figure(figsize=(max(10.0, 1.1 * len(flows) * max(1, n / 2) + 3), 8), layout="constrained")
    axes = fig.subplots(2, 2, squeeze=False).ravel()
    for p, ((name, get, unit), ax) in enumerate(zip(METRICS, axes, strict=True)):
        any_value = False
        for i, label in enumerate(labels):
            vals = []
            for f in flows:
                m = per_label[label].get(f)
                v = get(m) if m is not None else None
                vals.append(np.nan if v is None else float(v))
                any_value = any_value or v is not None
            ax.bar(x + (i - (n - 1) / 2) * width, vals, width, label=label, color=f"C{i}")
        ax.set_xticks(x)
        crowded = len(flows) > 6
        ax.set_xticklabels(flows, rotation=30 if crowded else 0, ha="right" if crowded else "center",
                           fontsize=9)
        ax.set_ylabel(f"{name} ({unit})")
        ax.set_title(f"({chr(ord('a') + p)}) {name} ({unit})", fontsize=10, loc="left")
        ax.grid(True, axis="y", alpha=0.3)
        if not any_value:
            ax.text(0.5, 0.5, "no data", transform=ax.transAxes, ha="center", va="center", color="grey")
        if p == 0:
            ax.legend(fontsize=9)
    fig.suptitle(title or "MAC comparison per flow", fontsize=12)
    return [_save(fig, out / "fig7-mac-comparison.png")]


def _fmt(v: float | None, unit: str) -> str:
    if v is None:
        return "-"
    return f"{v:.1f}" if unit == "%" else (f"{v:.2f}" if unit == "B/s" else f"{v:.3f}")


def _compare_rows(per_label: Mapping[str, Mapping[str, FlowMetrics]]) -> tuple[list[str], list[list[str]]]:
    header = ["flow"] + [f"{label} {name} ({unit})" for label in per_label for name, _, unit in METRICS]
    rows = []
    for f in _flow_union(per_label):
        row = [f]
        for flows in per_label.values():
            m = flows.get(f)
            row += [_fmt(get(m) if m is not None else None, unit) for _, get, unit in METRICS]
        rows.append(row)
    return header, rows


def compare_table(traces: Mapping[str, TraceOrMetrics], title: str | None = None) -> Table:
    """A rich Table: one row per flow, columns label × (throughput, efficiency, delay, jitter)."""
    header, rows = _compare_rows(compare_metrics(traces))
    table = Table(title=title)
    for i, h in enumerate(header):
        table.add_column(h, justify="left" if i == 0 else "right")
    for r in rows:
        table.add_row(*r)
    return table


def compare_markdown(traces: Mapping[str, TraceOrMetrics]) -> str:
    """The comparison table as GitHub-flavoured markdown (for docs)."""
    header, rows = _compare_rows(compare_metrics(traces))
    return markdown_table(header, rows)
