"""A campaign's results: one row per run to a columnar file, a summary with 95 % intervals, figures.

    OUT/results.parquet   one row per run: key, scene, seed, version, status, error, param.<path>..., metrics
    OUT/results.csv       the same rows, for tools without Parquet
    OUT/summary.json      per parameter point and metric: n, mean, half-width of the 95 % t interval
    OUT/summary.md        tables (flows x parameter points) of throughput, delay, efficiency, delivery ratio,
                          frames left in the FIFO and FIFO drops: mean ± CI
    OUT/figures/*.png     the same as bar charts with error bars (delay on a log axis); a line with error bars
                          per flow when a single numeric parameter is swept
"""

from __future__ import annotations

import csv
import json
import math
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from .intervals import Interval, mean_ci
from .tables import markdown_table

TABLES = (("throughput", "throughput (B/s)"), ("delay_mean", "mean end-to-end delay (s)"),
          ("efficiency", "efficiency"), ("delivery_ratio", "delivery ratio (of the frames sent)"),
          ("left_in_fifo", "frames left in the FIFO at the end"), ("fifo_drops", "frames dropped at a full FIFO"))
"""summary.md's tables and the bar figures.  The FIFO's two show a MAC that cannot carry its load, which the
delivery ratio (frames that went on air) does not."""
LOG_AXIS = ("delay_mean",)
"""Metrics drawn on a log axis: delays of MACs differ by orders of magnitude, and a linear axis flattens all
but the largest."""


def _point(row: dict[str, Any], params: Sequence[str], multi_scene: bool) -> str:
    parts = [row["scene"]] if multi_scene else []
    parts += [f"{p}={row.get(f'param.{p}')}" for p in params]
    return ", ".join(parts) or "all runs"


def _columns(rows: list[dict[str, Any]]) -> list[str]:
    head = ["key", "scene", "seed", "version", "status", "error"]
    params = sorted({k for r in rows for k in r if k.startswith("param.")})
    rest = sorted({k for r in rows for k in r} - set(head) - set(params))
    return head + params + rest


def _write_table(rows: list[dict[str, Any]], out: Path) -> list[Path]:
    cols = _columns(rows)
    paths = []
    with open(out / "results.csv", "w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=cols)
        w.writeheader()
        for r in rows:
            w.writerow({c: r.get(c) for c in cols})
    paths.append(out / "results.csv")
    try:
        import pyarrow as pa  # noqa: PLC0415
        import pyarrow.parquet as pq  # noqa: PLC0415
    except ImportError:
        return paths
    data: dict[str, list[Any]] = {c: [r.get(c) for r in rows] for c in cols}
    fields = []
    for c in cols:
        vals = [v for v in data[c] if v is not None]
        if vals and all(isinstance(v, int | float) and not isinstance(v, bool) for v in vals):
            typ = pa.int64() if all(isinstance(v, int) for v in vals) else pa.float64()
        else:
            typ = pa.string()
            data[c] = [None if v is None else str(v) for v in data[c]]
        fields.append(pa.field(c, typ))
    pq.write_table(pa.table(data, schema=pa.schema(fields)), out / "results.parquet")
    paths.append(out / "results.parquet")
    return paths


def summarise(rows: list[dict[str, Any]], params: Sequence[str], multi_scene: bool) -> dict[str, dict[str, Any]]:
    """{point: {metric: Interval}} over the rows that ran (status ok)."""
    groups: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for r in rows:
        if r.get("status") == "ok":
            groups[_point(r, params, multi_scene)].append(r)
    out: dict[str, dict[str, Any]] = {}
    for point, rs in groups.items():
        metrics = sorted({k for r in rs for k, v in r.items()
                          if (k.startswith("flow.") or k.startswith("channel.")) and isinstance(v, int | float)})
        out[point] = {m: mean_ci([r.get(m) for r in rs if isinstance(r.get(m), int | float)]) for m in metrics}
    return out


def _flows(summary: dict[str, dict[str, Any]], metric: str) -> list[str]:
    return sorted({k.split(".")[1] for s in summary.values() for k in s
                   if k.startswith("flow.") and k.endswith(f".{metric}")})


def _md(summary: dict[str, dict[str, Any]]) -> str:
    points = list(summary)
    text = []
    for metric, title in TABLES:
        flows = _flows(summary, metric)
        if not flows:
            continue
        rows = []
        for f in flows:
            cells = []
            for p in points:
                iv: Interval | None = summary[p].get(f"flow.{f}.{metric}")
                cells.append("-" if iv is None else iv.text())
            rows.append([f, *cells])
        text.append(f"### {title}\n\n" + markdown_table(["flow", *points], rows))
    return "\n\n".join(text)


def _is_number(v: Any) -> bool:
    try:
        return math.isfinite(float(v))
    except (TypeError, ValueError):
        return False


def _figures(summary: dict[str, dict[str, Any]], rows: list[dict[str, Any]], params: Sequence[str],
             out: Path) -> list[Path]:
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: PLC0415
    from matplotlib.figure import Figure  # noqa: PLC0415

    figs = []
    out.mkdir(parents=True, exist_ok=True)
    points = list(summary)
    for metric, title in TABLES:
        flows = _flows(summary, metric)
        if not flows or not points:
            continue
        fig = Figure(figsize=(max(6.0, 0.9 * len(flows) * max(1, len(points)) / 2 + 3), 4.2))
        FigureCanvasAgg(fig)
        ax = fig.add_subplot(1, 1, 1)
        width = 0.8 / len(points)
        for i, p in enumerate(points):
            means, errs = [], []
            for f in flows:
                iv = summary[p].get(f"flow.{f}.{metric}")
                means.append(float("nan") if iv is None else iv.mean)
                errs.append(0.0 if iv is None or iv.half is None else iv.half)
            xs = [j + (i - (len(points) - 1) / 2) * width for j in range(len(flows))]
            ax.bar(xs, means, width, yerr=errs, capsize=3, label=p)
        ax.set_xticks(range(len(flows)), flows, rotation=30, ha="right")
        if metric in LOG_AXIS and any(iv is not None and iv.mean > 0 for s in summary.values()
                                      for k, iv in s.items() if k.endswith(f".{metric}")):
            ax.set_yscale("log")
        ax.set_ylabel(title + (", log scale" if ax.get_yscale() == "log" else ""))
        n = max((iv.n for s in summary.values() for iv in s.values() if iv is not None), default=0)
        ax.set_title(f"{title}: mean and 95 % interval over {n} seeds")
        ax.legend(fontsize="small")
        fig.tight_layout()
        path = out / f"{metric}.png"
        fig.savefig(path, dpi=110)
        figs.append(path)
    numeric = [p for p in params if all(_is_number(r.get(f"param.{p}")) for r in rows)]
    if len(params) == 1 and numeric:
        p = numeric[0]
        flows = _flows(summary, "throughput")
        fig = Figure(figsize=(6.5, 4.2))
        FigureCanvasAgg(fig)
        ax = fig.add_subplot(1, 1, 1)
        xs = sorted({float(r[f"param.{p}"]) for r in rows}, key=float)
        for f in flows:
            ys, es = [], []
            for x in xs:
                iv = next((s.get(f"flow.{f}.throughput") for k, s in summary.items()
                           if _is_number(k.split("=")[-1]) and float(k.split("=")[-1]) == x), None)
                ys.append(float("nan") if iv is None else iv.mean)
                es.append(0.0 if iv is None or iv.half is None else iv.half)
            ax.errorbar(xs, ys, yerr=es, marker="o", capsize=3, label=f)
        ax.set_xlabel(p)
        ax.set_ylabel("throughput (B/s)")
        ax.set_title(f"throughput vs {p} (95 % intervals)")
        ax.legend(fontsize="small")
        fig.tight_layout()
        path = out / f"throughput-vs-{p.replace('*', 'all').replace('/', '_')}.png"
        fig.savefig(path, dpi=110)
        figs.append(path)
    return figs


def write_results(rows: list[dict[str, Any]], out: Path, params: Sequence[str], *,
                  multi_scene: bool = False) -> dict[str, Any]:
    """Write the campaign's files (module docstring); returns what was written and the summary."""
    out.mkdir(parents=True, exist_ok=True)
    files = _write_table(rows, out)
    summary = summarise(rows, params, multi_scene)
    as_json = {p: {m: None if iv is None else {"n": iv.n, "mean": iv.mean, "ci95": iv.half}
                   for m, iv in s.items()} for p, s in summary.items()}
    (out / "summary.json").write_text(json.dumps(as_json, indent=1, sort_keys=True, allow_nan=False))
    failed = [r for r in rows if r.get("status") != "ok"]
    md = [f"# Campaign: {len(rows)} runs ({len(rows) - len(failed)} ok, {len(failed)} failed)", "",
          "Mean ± half-width of the 95 % Student-t interval over seeds.", "", _md(summary)]
    if failed:
        md += ["", "## Failed runs", "", markdown_table(["scene", "seed", "error"],
                                                         [[r["scene"], str(r["seed"]), str(r.get("error"))]
                                                          for r in failed])]
    (out / "summary.md").write_text("\n".join(md) + "\n")
    files += [out / "summary.json", out / "summary.md"]
    files += _figures(summary, rows, params, out / "figures")
    return {"files": [str(f) for f in files], "failed": len(failed), "summary": as_json}
