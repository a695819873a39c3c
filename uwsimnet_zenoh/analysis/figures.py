"""Figures from traces, after the seed paper's Figures 3, 4 and 7 (docs/trace-format.md).

    plot_trace("run.jsonl", "figs/")     -> fig3-packets.png, fig4-delay.png
    plot_compare({"NOMAC": "nomac.jsonl", "ALOHA": "aloha.jsonl", "SFAMA": "sfama.jsonl"}, "figs/")
                                         -> fig7-mac-comparison.png

Matplotlib is driven through `Figure` objects and the Agg canvas only (no pyplot, no display, no global
backend switch), so plotting is safe from any thread and in headless runs.  Panels without data are
left out; a figure without any panel is not written.
"""

from __future__ import annotations

import json
from array import array
from collections.abc import Callable, Mapping, Sequence
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

# One colour per MAC protocol in every figure (Fig. 7 and its variants, Fig. 9), whatever the labels
# present or their order; labels are matched case-insensitively without '-', '_' and spaces.
PROTOCOL_COLOURS: dict[str, str] = {
    "nomac": "tab:blue", "none": "tab:blue",
    "aloha": "tab:orange", "csaloha": "tab:orange",
    "sfama": "tab:green", "slottedfama": "tab:green",
    "slottedaloha": "tab:purple",
}
_SPARE_COLOURS = ("tab:red", "tab:brown", "tab:pink", "tab:olive", "tab:cyan", "tab:grey")
FIFO_BINS = 100
"""A FIFO series with more than 2 x this many steps is drawn per time bin (mean, and the max as a light
band) instead of step by step: many 0 -> full -> 0 steps per pixel otherwise fill the panel as a solid
block."""


def protocol_colour(label: str, others: list[str] | None = None) -> str:
    """The fixed colour of a protocol label; an unknown label gets a spare colour by its position in
    `others` (the unknown labels of the same figure, in order)."""
    key = "".join(ch for ch in label.lower() if ch.isalnum())
    if key in PROTOCOL_COLOURS:
        return PROTOCOL_COLOURS[key]
    i = others.index(label) if others and label in others else 0
    return _SPARE_COLOURS[i % len(_SPARE_COLOURS)]
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


def _save(fig: Figure, path: Path, numbers: Mapping[str, object] | None = None) -> Path:
    """Write a PNG; `numbers` (what the figure shows, as JSON) go in its text chunk `uwsimnet`, so a test can
    check a committed figure against a new run by its numbers, not its pixels (`figure_numbers`)."""
    FigureCanvasAgg(fig)
    meta = {"uwsimnet": json.dumps(numbers, sort_keys=True)} if numbers is not None else None
    fig.savefig(path, dpi=DPI, metadata=meta)
    return path


def figure_numbers(path: str | PathLike[str]) -> dict:
    """The numbers `_save` wrote into a PNG ({} if none)."""
    from PIL import Image

    with Image.open(path) as im:
        raw = im.info.get("uwsimnet")
    return json.loads(raw) if raw else {}


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


def fifo_bins(t: np.ndarray, f: np.ndarray, x0: float, x1: float, n: int = FIFO_BINS
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(bin starts, time-weighted mean, max) of the step function f (value f[k] from t[k] to t[k+1],
    0 before t[0]) over `n` equal bins of [x0, x1]."""
    order = np.argsort(t, kind="stable")
    t, f = t[order], f[order].astype(float)
    edges = np.linspace(x0, x1, n + 1)
    # integral of the step function up to each edge
    tt = np.concatenate(([min(x0, t[0])], t))
    ff = np.concatenate(([0.0], f))
    cum = np.concatenate(([0.0], np.cumsum(ff[:-1] * np.diff(tt))))
    k = np.clip(np.searchsorted(tt, edges, side="right") - 1, 0, len(tt) - 1)
    area = cum[k] + ff[k] * (edges - tt[k])
    width = np.diff(edges)
    mean = np.diff(area) / np.where(width > 0, width, 1.0)
    # max: the value carried into the bin, and every value set inside it
    carried = ff[k[:-1]]
    lo = np.searchsorted(tt, edges[:-1], side="left")      # the steps inside [edge i, edge i+1)
    hi = np.searchsorted(tt, edges[1:], side="left")
    mx = carried.copy()
    for j in np.flatnonzero(hi > lo):           # n bins at most: a loop is cheap
        mx[j] = max(mx[j], float(ff[lo[j]:hi[j]].max()))
    return edges[:-1], mean, mx


def _panel_fifo(ax: Axes, c: _Collected, x0: float = 0.0, x1: float | None = None,
                capacity: float | None = None) -> None:
    """Occupancy in bytes; with the FIFO's `capacity` the axis spans it (a dashed line at the top), so one
    frame waiting reads as the small fraction of the FIFO it is, not as a full panel."""
    peak = 0.0
    for i, (dev, s) in enumerate(sorted(c.fifo.items())):
        t, f = s.arrays()
        peak = max(peak, float(f.max()) if len(f) else 0.0)
        colour = f"C{i}"
        if len(t) <= 2 * FIFO_BINS:
            ax.step(t, f, where="post", lw=1.0, alpha=0.8, color=colour, label=dev)
            continue
        hi = x1 if x1 is not None else float(t.max())
        b, mean, mx = fifo_bins(t, f, x0, hi if hi > x0 else x0 + 1.0)
        step = (hi - x0) / FIFO_BINS if hi > x0 else 1.0
        ax.fill_between(np.append(b, b[-1] + step), np.append(mx, mx[-1]), step="post", color=colour,
                        alpha=0.18, lw=0, label=f"{dev}: max per {step:.2g} s")
        ax.step(np.append(b, b[-1] + step), np.append(mean, mean[-1]), where="post", lw=1.6, color=colour,
                label=f"{dev}: mean per {step:.2g} s")
    ax.set_ylabel("tx FIFO (bytes)")
    title = "occupancy of the transmission FIFO"
    if capacity:
        ax.axhline(capacity, ls="--", lw=1.0, color="grey", label=f"capacity {capacity:g} B")
        ax.set_ylim(0, capacity * 1.08)
        title += f" (at most {peak:g} of {capacity:g} B)"
    ax.set_title(title, fontsize=10, loc="left")
    ax.grid(True, alpha=0.3)
    _legend(ax)


def plot_trace(path: str | PathLike[str], out_dir: str | PathLike[str], *,
               delay_refs: Sequence[tuple[float, str]] = (), fifo_capacity: float | None = None) -> list[Path]:
    """Write `fig3-packets.png` and `fig4-delay.png` for a trace into `out_dir` (created if needed).

    Fig. 3: (a) transmitter-receiver distance over time per flow, one dot-row panel per flow (tx, rx,
    err(PROP|COL|MULT|RANGE), fifo drop, other drops), and the tx FIFO occupancy per transmitting device.
    Fig. 4: end-to-end delay over time per flow, its peak marked, and `delay_refs` (value s, label: e.g. the
    paper's figure where this run differs) as dashed lines.  `fifo_capacity` (bytes) scales the FIFO panel.
    Returns the files written (figures or panels without data are skipped); each carries its numbers
    (`figure_numbers`).
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
        panels.append((2.4, lambda ax: _panel_fifo(ax, c, x0, x1, fifo_capacity)))
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
        nums = {"rows": {f: {row: len(v) for row, v in sorted(c.dots.get(f, {}).items())} for f in c.flows},
                "fifo_max_bytes": {d: float(s.arrays()[1].max()) for d, s in sorted(c.fifo.items()) if len(s)}}
        written.append(_save(fig, out / "fig3-packets.png", nums))

    if any(len(s) for s in c.delay.values()):
        fig = Figure(figsize=(11, 4.5), layout="constrained")
        ax = fig.add_subplot()
        for flow in c.flows:
            s = c.delay.get(flow)
            if s is None or not len(s):
                continue
            t, d = s.arrays()
            ax.plot(t, d, marker="o", ms=3, lw=0.8, label=f"{flow} ({len(t)})", rasterized=True)
        peaks = {f: s.arrays() for f, s in c.delay.items() if len(s)}
        top_flow = max(peaks, key=lambda f: float(peaks[f][1].max()))
        tt, dd = peaks[top_flow]
        k = int(np.argmax(dd))
        ax.annotate(f"peak {dd[k] * 1e3:.0f} ms", (tt[k], dd[k]), xytext=(8, -4), textcoords="offset points",
                    fontsize=9)
        for value, text in delay_refs:
            ax.axhline(value, ls="--", lw=1.0, color="grey")
            ax.annotate(text, (x0, value), xytext=(4, 3), textcoords="offset points", fontsize=8, color="dimgrey")
        ax.set_xlim(x0, x1)
        ax.set_xlabel("time of reception (s)")
        ax.set_ylabel("end-to-end delay (s)")
        ax.set_title(f"End-to-end delay{suffix}", fontsize=12)
        ax.grid(True, alpha=0.3)
        _legend(ax)
        nums = {"received": {f: len(s) for f, s in sorted(c.delay.items())}, "peak_s": round(float(dd[k]), 6),
                "refs": [[v, text] for v, text in delay_refs]}
        written.append(_save(fig, out / "fig4-delay.png", nums))
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
    spare = [lb for lb in labels if "".join(ch for ch in lb.lower() if ch.isalnum()) not in PROTOCOL_COLOURS]
    n = len(labels)
    width = 0.8 / n
    x = np.arange(len(flows), dtype=float)
    fig = Figure(figsize=(max(10.0, 1.1 * len(flows) * max(1, n / 2) + 3), 8), layout="constrained")
    axes = fig.subplots(2, 2, squeeze=False).ravel()
    for p, ((name, get, unit), ax) in enumerate(zip(METRICS, axes, strict=True)):
        any_value = False
        for i, label in enumerate(labels):
            vals, none = [], []
            for f in flows:
                m = per_label[label].get(f)
                v = get(m) if m is not None else None
                vals.append(np.nan if v is None else float(v))
                any_value = any_value or v is not None
                # nothing delivered (or no such flow): no value, which is not a value of 0
                none.append(m is None or m.delivered == 0)
            colour = protocol_colour(label, spare)
            xs = x + (i - (n - 1) / 2) * width
            ax.bar(xs, vals, width, label=label, color=colour)
            if any(none):
                ax.plot(xs[np.array(none)], np.zeros(sum(none)), linestyle="none", marker="x", ms=7, mew=1.8,
                        color=colour, clip_on=False, zorder=3)
        ax.set_xticks(x)
        crowded = len(flows) > 6
        ax.set_xticklabels(flows, rotation=30 if crowded else 0, ha="right" if crowded else "center",
                           fontsize=9)
        ax.set_ylabel(f"{name} ({unit})")
        ax.set_title(f"({chr(ord('a') + p)}) {name} ({unit})", fontsize=10, loc="left")
        ax.grid(True, axis="y", alpha=0.3)
        if not any_value:
            ax.text(0.5, 0.5, "no data", transform=ax.transAxes, ha="center", va="center", color="grey")
        if p == 0 and any(per_label[lb].get(f) is None or per_label[lb][f].delivered == 0
                          for lb in labels for f in flows):
            ax.plot([], [], linestyle="none", marker="x", ms=7, mew=1.8, color="black",
                    label="nothing delivered (no value, not 0)")
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
