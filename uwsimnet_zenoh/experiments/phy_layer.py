"""The paper's physical-layer experiment (Section 3.1, Figs. 3 and 4), run and checked.

Runs scenes/paper/phy-layer-rf.xml and phy-layer-acoustic.xml, writes their traces and figures, and a
summary that sets what the simulator produced beside what the paper and the formulas say.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..phy.error import RateErrorModel
from ..trace.events import finite

if TYPE_CHECKING:
    from ..scene.model import Scene

SCENES = Path(__file__).resolve().parents[2] / "scenes" / "paper"
FLOW = "rov0-to-rov1"
BACK = "rov1-to-rov0"
BER = RateErrorModel("6e-13*m^13.7", "bit")
SIZE = 30  # bytes on air: 22 payload + 8 DataLinkFrame (the 'stated' reading)
PAPER_PEAK_S = 0.430    # "when node 1 started the transmission at 37 s the end-to-end delay rose to ~430 ms"

# How to read "Both ROVs were configured to transmit at 1500 bps, which is close to the 1800 bps maximum bitrate
# of the modems" (docs/paper-phy-layer.md): scene overrides (app/overrides.py paths) on both scenes.
READINGS: dict[str, dict] = {
    "stated": {
        "what": "1500 bit/s of frames on air (22 B payload + 8 B DataLinkFrame every 0.16 s), modems at 1800 bit/s",
        "overrides": {}},
    "original-app": {
        "what": "the original's application pacing: 1500 bit/s of payload (one 50 B payload every 50*8/1500 s, as"
                " dccomms_by_examples' custom_node sleeps), VariableLength2BPacket framing (+5 B on air),"
                " a 500 B FIFO, modems at 1800 bit/s",
        "overrides": {"device.*.header_bytes": 5, "device.*.tx_fifo_bytes": 500,
                      "flow.*.size": 50, "flow.*.interval": 50 * 8 / 1500}},
    "modem-1500": {
        "what": "the modems' bit rate configured to 1500 bit/s (of the S100's 1800 maximum), 1500 bit/s of"
                " frames on air as in 'stated'",
        "overrides": {"device.*.bitrate": 1500}},
}
DEFAULT_READING = "stated"
PAYLOAD_SWEEP = (30, 40, 45, 50, 60)
"""Payloads (B) tried under the original-app pacing: the paper does not state its frame size."""


def _records(trace: Path) -> list[dict]:
    with open(trace, encoding="utf-8") as fh:
        return [json.loads(line) for line in fh][1:]


EDGES = [0.0, 1.0, 2.5, 3.5, 4.0, 4.5, 5.0, 5.5, 6.0]


def _on_air(recs: list[dict]) -> int:
    """The bytes on air of rov0's data frames (one size per run)."""
    return next((r["size"] for r in recs if r.get("flow") == FLOW and r["ev"] == "tx"), SIZE)


def _attenuation_only(recs: list[dict], t_max: float = 37.0) -> list[dict]:
    return [r for r in recs if r.get("flow") == FLOW and r["ev"] in ("rx", "drop") and r["kind"] == "data"
            and r.get("reason") in (None, "prop", "range") and r["t"] < t_max]


def loss_over_seeds(per_seed: list[list[dict]]) -> list[dict]:
    """PER by distance bin pooled over several seeds' records, with its 95 % Wilson interval, beside the
    PER the BER expression gives; `inside` says whether the expression's value lies in the interval."""
    from ..analysis.intervals import wilson

    pooled: dict[int, list[dict]] = {}
    size = _on_air(per_seed[0]) if per_seed else SIZE
    for recs in per_seed:
        for r in _attenuation_only(recs):
            if r.get("reason") == "range":
                continue
            for i, (lo, hi) in enumerate(zip(EDGES, EDGES[1:], strict=False)):
                if lo <= r["dist"] < hi:
                    pooled.setdefault(i, []).append(r)
    rows = []
    for i in sorted(pooled):
        sel = pooled[i]
        n = len(sel)
        lost = sum(1 for r in sel if r["ev"] == "drop")
        expected = float(np.mean(BER.per(np.array([r["dist"] for r in sel]), size)))
        lo, hi = wilson(lost, n)
        rows.append({"bin_m": f"{EDGES[i]:g}-{EDGES[i + 1]:g}", "seeds": len(per_seed), "frames": n,
                     "observed_per": lost / n, "ci95": [lo, hi], "expected_per": expected,
                     "inside": lo <= expected <= hi})
    return rows


def loss_vs_distance(recs: list[dict], t_max: float = 37.0) -> list[dict]:
    """Observed PER of rov0's frames before rov1 transmits (attenuation only), by distance bin."""
    out = _attenuation_only(recs, t_max)
    size = _on_air(recs)
    rows = []
    for lo, hi in zip(EDGES, EDGES[1:], strict=False):
        sel = [r for r in out if lo <= r["dist"] < hi and r.get("reason") != "range"]
        if not sel:
            continue
        n = len(sel)
        lost = sum(1 for r in sel if r["ev"] == "drop")
        expected = float(np.mean(BER.per(np.array([r["dist"] for r in sel]), size)))
        sigma = math.sqrt(max(expected * (1 - expected), 1e-12) / n)
        rows.append({"bin_m": f"{lo:g}-{hi:g}", "frames": n, "observed_per": lost / n,
                     "expected_per": expected, "z": (lost / n - expected) / sigma if sigma > 0 else 0.0})
    return rows


def phases(recs: list[dict]) -> list[dict]:
    """What happened to rov0's frames in each stage of the motion, and to rov1's while it sends."""
    stages = [("0.8 m hold", 0, 11), ("moving away", 11, 31), ("back, 4.5 m hold", 31, 37),
              ("both send, 4.5 m", 37, 46), ("both send, closing", 46, 51), ("both send, 3.3 m", 51, 58),
              ("3.3 m hold", 58, 70)]
    tx_t = {(r["src"], r["seq"]): r["t"] for r in recs if r["ev"] == "tx" and r["kind"] == "data"}
    rows = []
    for flow in (FLOW, BACK):
        for name, a, b in stages:
            sel = [r for r in recs if r.get("flow") == flow and r["ev"] in ("rx", "drop")
                   and a <= tx_t.get((r["src"], r["seq"]), -1) < b]
            if not sel:
                continue
            count = {k: 0 for k in ("rx", "prop", "col", "mult", "range", "fifo")}
            for r in sel:
                key = "rx" if r["ev"] == "rx" else r["reason"]
                count[key] = count.get(key, 0) + 1
            rows.append({"flow": flow, "stage": name, "from_s": a, "to_s": b, **count})
    return rows


STAGE_COUNTS = ("rx", "prop", "col", "mult")


def stages_over_seeds(per_seed: list[list[dict]]) -> list[dict]:
    """`phases` of several seeds' runs, per flow and stage: each count's mean and 95 % t interval (what the
    findings of docs/paper-phy-layer.md are labelled against)."""
    from ..analysis.intervals import mean_ci

    out = []
    for i, row in enumerate(per_seed[0]):
        cell = {"flow": row["flow"], "stage": row["stage"], "from_s": row["from_s"], "to_s": row["to_s"]}
        for k in STAGE_COUNTS:
            vals = [rows[i][k] for rows in per_seed]
            iv = mean_ci(vals)
            cell[k] = {"values": vals, "mean": iv.mean, "half": iv.half}
        out.append(cell)
    return out


def stages_table(rows: list[dict]) -> str:
    """`stages_over_seeds` as docs/paper-phy-layer.md's table (mean ± half-width of the 95 % t interval)."""
    from ..analysis.intervals import Interval

    lines = ["| flow | stage | rx | prop | col | mult |", "|---|---|---|---|---|---|"]
    for r in rows:
        cells = [Interval(len(r[k]["values"]), r[k]["mean"], r[k]["half"]).text() for k in STAGE_COUNTS]
        lines.append(f"| {r['flow']} | {r['stage']} ({r['from_s']:g}-{r['to_s']:g} s) | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def delay_formula(scene: Scene, flow_name: str) -> Callable[[float], float]:
    """The modelled delay of a frame of `flow_name` over d metres with no queueing, from the scene's own
    figures: tx intrinsic + propagation (min + per metre) + bytes on air / bitrate + rx intrinsic."""
    flow = next(f for f in scene.flows if f.name == flow_name)
    devices = [d for v in scene.vehicles for d in v.devices]
    tx = next(d for d in devices if d.dccomms_id == flow.src)
    rx = next(d for d in devices if d.address == flow.dst and d.rx_channel == tx.tx_channel)
    ch = next(c for c in scene.channels if c.id == tx.tx_channel)
    fixed = tx.intrinsic_tx_s + ch.min_prop_s + (flow.size + tx.header_bytes) * 8 / tx.bitrate + rx.intrinsic_rx_s
    return lambda d: fixed + ch.prop_s_per_m * d


def components(recs: list[dict], scene: Scene, flows: tuple[str, ...] = (FLOW, BACK)) -> dict:
    """Every received data frame's delay split into its parts, from the trace and the scene's figures:
    wait (enqueue to first bit on air: the intrinsic delay, plus queueing behind the FIFO and behind a
    reception it defers to), transmission (bytes on air * 8 / bitrate), propagation (min + per metre *
    distance at the receiver) and the receiver's intrinsic delay.  `max_error_s`: the largest difference
    between a frame's measured delay and the sum of its parts (the trace keeps distances to the mm)."""
    devices = {d.dccomms_id: d for v in scene.vehicles for d in v.devices}
    chans = {c.id: c for c in scene.channels}
    enq = {(r["src"], r["seq"]): r for r in recs if r["ev"] == "enq" and r["kind"] == "data"}
    tx = {}
    for r in recs:
        if r["ev"] == "tx" and r["kind"] == "data":
            tx.setdefault((r["src"], r["seq"]), r)
    rows = []
    for r in recs:
        if r["ev"] != "rx" or r["kind"] != "data" or r.get("flow") not in flows:
            continue
        k = (r["src"], r["seq"])
        e, t = enq[k], tx[k]
        src, dst = devices[e["dev"]], devices[r["dev"]]
        ch = chans[t["ch"]]
        part = {"t": r["t"], "flow": r["flow"], "delay": r["t"] - e["t"], "wait": t["t"] - e["t"],
                "queue": t["t"] - e["t"] - src.intrinsic_tx_s, "transmission": r["size"] * 8 / src.bitrate,
                "propagation": ch.min_prop_s + ch.prop_s_per_m * r["dist"], "rx_intrinsic": dst.intrinsic_rx_s,
                "fifo_frames": e.get("fifo", 0) / r["size"], "dist": r["dist"]}
        part["error"] = part["delay"] - (part["wait"] + part["transmission"] + part["propagation"]
                                         + part["rx_intrinsic"])
        rows.append(part)
    enq_fifo = [r.get("fifo", 0) / r["size"] for r in recs if r["ev"] == "enq" and r["kind"] == "data"]
    peak = max(rows, key=lambda p: p["delay"])
    return {"frames": len(rows), "max_error_s": max(abs(p["error"]) for p in rows), "peak": peak, "rows": rows,
            "queue_max_s": max(p["queue"] for p in rows),
            "fifo_max_frames": max(enq_fifo) if enq_fifo else 0.0,
            "fifo_drops": sum(1 for r in recs if r["ev"] == "drop" and r.get("reason") == "fifo")}


def delays(recs: list[dict], scene: Scene) -> dict:
    """End-to-end delay of rov0's frames: alone (formula) and once rov1 transmits too (paper: ~430 ms)."""
    enq = {(r["src"], r["seq"]): r["t"] for r in recs if r["ev"] == "enq"}
    pts = [(r["t"], r["t"] - enq[(r["src"], r["seq"])], r["dist"]) for r in recs
           if r["ev"] == "rx" and r.get("flow") == FLOW]
    alone = [(d, dist) for t, d, dist in pts if t < 37]
    after = [d for t, d, _ in pts if t >= 60]
    both = [r["t"] - enq[(r["src"], r["seq"])] for r in recs       # either flow, until the queues drain
            if r["ev"] == "rx" and r.get("flow") in (FLOW, BACK) and 37 <= r["t"] < 60]
    formula = delay_formula(scene, FLOW)                 # alone, without queueing
    formula_err = max(abs(d - formula(dist)) for d, dist in alone)
    return {"alone_min_s": min(d for d, _ in alone), "alone_max_s": max(d for d, _ in alone),
            "alone_max_formula_error_s": formula_err,
            "formula_0_8m_s": formula(0.8), "formula_5_8m_s": formula(5.8),
            "both_mean_s": float(np.mean(both)) if both else None,
            "both_max_s": max(both) if both else None,
            "after_mean_s": float(np.mean(after)) if after else None,
            "components": {k: v for k, v in components(recs, scene).items() if k != "rows"}}


def reading_scene(variant: str, reading: str = DEFAULT_READING, extra: dict | None = None) -> Scene:
    """scenes/paper/phy-layer-<variant>.xml read as `reading` (READINGS), with `extra` overrides on top."""
    from ..app.overrides import apply
    from ..scene.load import load_scene

    return apply(load_scene(SCENES / f"phy-layer-{variant}.xml"), {**READINGS[reading]["overrides"], **(extra or {})})


def figure_kw(scene: Scene, variant: str, reading: str) -> dict:
    """What plot_trace marks on this run's figures: the FIFO's capacity, and on the acoustic delay the paper's
    ~430 ms beside why this run peaks lower (docs/paper-phy-layer.md)."""
    dev = next(d for v in scene.vehicles for d in v.devices if d.dccomms_id.startswith("rov0"))
    kw: dict = {"fifo_capacity": dev.tx_fifo_bytes}
    if variant == "acoustic":
        flow = next(f for f in scene.flows if f.name == FLOW)
        on_air = flow.size + dev.header_bytes
        kw["delay_refs"] = [(PAPER_PEAK_S, f"paper: ~430 ms; here {on_air} B frames at {dev.bitrate:g} bit/s"
                                           f" ({on_air * 8 / dev.bitrate * 1e3:.0f} ms each): a frame waits at most"
                                           " one of the other node's (docs/paper-phy-layer.md)")]
    return kw


DOC_FIGURES = {("stated", "rf", "fig3-packets.png"): "paper-phy-rf-fig3.png",
               ("stated", "rf", "fig4-delay.png"): "paper-phy-rf-fig4.png",
               ("stated", "acoustic", "fig4-delay.png"): "paper-phy-acoustic-fig4.png",
               ("original-app", "acoustic", "fig4-delay.png"): "paper-phy-acoustic-fig4-original-app.png"}
"""The phy-layer figures docs/ embeds: (reading, scene, figure) -> name in docs/figures."""


def doc_figures(docs_dir: Path, work: Path) -> list[Path]:
    """Draw the figures of DOC_FIGURES into `docs_dir` (runs in `work`): one command for what docs/ shows,
    `python -m uwsimnet_zenoh.experiments.phy_layer docs/figures`."""
    import shutil

    from ..analysis.figures import plot_trace
    from ..app.virtual import run_virtual

    written = []
    for reading, variant in sorted({(r, v) for r, v, _ in DOC_FIGURES}):
        scene = reading_scene(variant, reading)
        trace = work / f"{reading}-{variant}.trace.jsonl"
        run_virtual(scene, seed=None, duration=None, trace_path=trace, progress=False)
        drawn = plot_trace(trace, work / f"{reading}-{variant}", **figure_kw(scene, variant, reading))
        figs = {p.name: p for p in drawn}
        for (r, v, name), doc in DOC_FIGURES.items():
            if (r, v) == (reading, variant):
                written.append(Path(shutil.copyfile(figs[name], docs_dir / doc)))
    return written


def reading_row(name: str, scene: Scene) -> dict:
    """One reading of the acoustic run: its frame, load and delays, measured and from the formulas."""
    from ..app.api import run as run_one

    recs = run_one(scene, trace=True).trace or []
    dev = next(d for v in scene.vehicles for d in v.devices if d.dccomms_id.startswith("rov0"))
    flow = next(f for f in scene.flows if f.name == FLOW)
    size = flow.size + dev.header_bytes
    t_frame = size * 8 / dev.bitrate
    d = delays(recs, scene)
    c = d["components"]
    return {"reading": name, "payload": flow.size, "on_air_bytes": size, "bitrate": dev.bitrate,
            "interval_s": flow.interval, "frame_s": t_frame, "load_per_node": t_frame / flow.interval,
            "fifo_bytes": dev.tx_fifo_bytes, "alone_min_s": d["alone_min_s"], "alone_max_s": d["alone_max_s"],
            "formula_0_8m_s": d["formula_0_8m_s"], "formula_5_8m_s": d["formula_5_8m_s"],
            "alone_grows": d["alone_max_s"] > d["formula_5_8m_s"] + 1e-3,
            "both_max_s": d["both_max_s"], "both_mean_s": d["both_mean_s"],
            "peak_in_frames": d["both_max_s"] / t_frame, "peak": c["peak"], "fifo_max_frames": c["fifo_max_frames"],
            "fifo_drops": c["fifo_drops"], "max_error_s": c["max_error_s"],
            "peak_vs_paper": d["both_max_s"] / PAPER_PEAK_S - 1}


def compare_readings() -> dict:
    """The acoustic run under every reading, and the original-app pacing over PAYLOAD_SWEEP."""
    rows = [reading_row(name, reading_scene("acoustic", name)) for name in READINGS]
    sweep = [reading_row(f"original-app, {p} B", reading_scene(
        "acoustic", "original-app", {"flow.*.size": p, "flow.*.interval": p * 8 / 1500})) for p in PAYLOAD_SWEEP]
    return {"readings": rows, "payload_sweep": sweep}


def run(out: Path, progress: bool = True, seeds: list[int] | None = None, reading: str = DEFAULT_READING) -> dict:
    """Run both scenes into `out`; return the summary (also written as summary.json and summary.md).
    `seeds`: also run the RF scene with each of these seeds and give the PER per distance bin pooled over
    them, with its 95 % Wilson interval.  `reading`: how the scenes read the paper's traffic (READINGS);
    the summary also compares every reading's acoustic delays (a second of runs)."""
    from ..analysis import flow_metrics, report_json
    from ..analysis.figures import plot_trace
    from ..app.virtual import run_virtual

    if reading not in READINGS:
        raise ValueError(f"reading: one of {', '.join(READINGS)}, got {reading!r}")
    out.mkdir(parents=True, exist_ok=True)
    summary: dict = {"reading": reading, "reading_what": READINGS[reading]["what"]}
    for variant in ("rf", "acoustic"):
        scene = reading_scene(variant, reading)
        trace = out / f"{variant}.trace.jsonl"
        run_virtual(scene, seed=None, duration=None, trace_path=trace, progress=progress)
        figs = plot_trace(trace, out / variant, **figure_kw(scene, variant, reading))
        recs = _records(trace)
        summary[variant] = {"trace": str(trace), "figures": [str(f) for f in figs],
                            "flows": report_json(flow_metrics(trace)), "stages": phases(recs)}
        if variant == "rf":
            summary[variant]["loss_vs_distance"] = loss_vs_distance(recs)
        else:
            summary[variant]["delay"] = delays(recs, scene)
    if seeds:
        from ..app.api import run as run_one

        rf = reading_scene("rf", reading)
        per_seed = [run_one(rf, seed=s, trace=True).trace or [] for s in seeds]
        summary["rf"]["loss_over_seeds"] = loss_over_seeds(per_seed)
        summary["rf"]["stages_over_seeds"] = stages_over_seeds([phases(recs) for recs in per_seed])
    summary["compare"] = compare_readings()
    (out / "summary.json").write_text(json.dumps(finite(summary), indent=2, allow_nan=False))
    (out / "summary.md").write_text(markdown(summary))
    return summary


def markdown(s: dict) -> str:
    lines = ["# Physical-layer experiment (paper Section 3.1)", "",
             f"Reading '{s['reading']}': {s['reading_what']}.", ""]
    lines += ["## Loss against the BER expression (rov0 alone, before 37 s)", "",
              "| distance bin (m) | frames | observed PER | PER from 6e-13 d^13.7 | z |", "|---|---|---|---|---|"]
    for r in s["rf"]["loss_vs_distance"]:
        lines.append(f"| {r['bin_m']} | {r['frames']} | {r['observed_per']:.4f} | {r['expected_per']:.4f} |"
                     f" {r['z']:+.2f} |")
    if "loss_over_seeds" in s["rf"]:
        rows = s["rf"]["loss_over_seeds"]
        lines += ["", f"## Loss over {rows[0]['seeds'] if rows else 0} seeds (95 % Wilson intervals)", "",
                  "| distance bin (m) | frames | observed PER | 95 % interval | PER from 6e-13 d^13.7 | inside |",
                  "|---|---|---|---|---|---|"]
        for r in rows:
            lines.append(f"| {r['bin_m']} | {r['frames']} | {r['observed_per']:.4f} | {r['ci95'][0]:.4f} -"
                         f" {r['ci95'][1]:.4f} | {r['expected_per']:.4f} | {'yes' if r['inside'] else 'no'} |")
    if "stages_over_seeds" in s["rf"]:
        lines += ["", "## Frames per stage over the same seeds (mean ± 95 % t interval)", "",
                  stages_table(s["rf"]["stages_over_seeds"])]
    for variant in ("rf", "acoustic"):
        lines += ["", f"## Outcomes by stage ({variant})", "",
                  "| flow | stage | rx | prop | col | mult | range | fifo |", "|---|---|---|---|---|---|---|---|"]
        for r in s[variant]["stages"]:
            lines.append(f"| {r['flow']} | {r['stage']} ({r['from_s']}-{r['to_s']} s) | {r['rx']} | {r['prop']} |"
                         f" {r['col']} | {r['mult']} | {r['range']} | {r['fifo']} |")
    d = s["acoustic"]["delay"]
    lines += ["", "## End-to-end delay (acoustic)", "",
              f"- rov0 alone: {d['alone_min_s'] * 1e3:.1f} to {d['alone_max_s'] * 1e3:.1f} ms, "
              + (f"within {d['alone_max_formula_error_s'] * 1e6:.2f} us of intrinsic + propagation + transmission"
                 " time (the trace rounds distances to the millimetre)"
                 if d["alone_max_formula_error_s"] < 1e-5 else
                 f"up to {d['alone_max_formula_error_s'] * 1e3:.1f} ms above intrinsic + propagation + transmission"
                 " time: its frames queue even with one sender"),
              f"- while both transmit (37-60 s, both flows): mean {d['both_mean_s'] * 1e3:.0f} ms, max"
              f" {d['both_max_s'] * 1e3:.0f} ms (paper: rose to about 430 ms)",
              f"- after 60 s: mean {d['after_mean_s'] * 1e3:.1f} ms (paper: back to the 3.3 m values)"]
    c = d["components"]
    pk = c["peak"]
    lines += [f"- every received frame ({c['frames']}): measured delay = wait + transmission + propagation within"
              f" {c['max_error_s'] * 1e6:.2f} us",
              f"- the longest delay of the run ({pk['flow']}, received at {pk['t']:.2f} s, {pk['dist']:.2f} m):"
              f" {pk['delay'] * 1e3:.1f} ms = wait {pk['wait'] * 1e3:.1f} (intrinsic"
              f" {(pk['wait'] - pk['queue']) * 1e3:.1f} + queueing {pk['queue'] * 1e3:.1f}) + transmission"
              f" {pk['transmission'] * 1e3:.1f} + propagation {pk['propagation'] * 1e3:.2f} ms;"
              f" {pk['fifo_frames']:.0f} frame(s) in its FIFO when it was enqueued (itself included)",
              f"- FIFO: at most {c['fifo_max_frames']:.0f} frame(s), {c['fifo_drops']} dropped", ""]
    lines += ["## The acoustic delay under each reading of '1500 bps' (docs/paper-phy-layer.md)", "",
              "transmission = bytes on air x 8 / bit rate; alone = intrinsic + transmission + distance x 0.6667 ms/m"
              " (0.8 and 5.8 m); peak = the largest delay while both send (paper: about 430 ms).", "",
              "| reading | bytes on air | bit rate | frame every (s) | transmission (ms) | load per node |"
              " alone, formula (ms) | alone, measured (ms) | peak (ms) | peak / transmission | peak vs 430 ms |"
              " FIFO max (frames) | FIFO drops |", "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in s["compare"]["readings"] + s["compare"]["payload_sweep"]:
        grows = " (grows)" if r["alone_grows"] else ""
        lines.append(f"| {r['reading']} | {r['on_air_bytes']} | {r['bitrate']:g} | {r['interval_s']:.4f} |"
                     f" {r['frame_s'] * 1e3:.1f} | {r['load_per_node']:.3f} | {r['formula_0_8m_s'] * 1e3:.1f}-"
                     f"{r['formula_5_8m_s'] * 1e3:.1f} | {r['alone_min_s'] * 1e3:.1f}-"
                     f"{r['alone_max_s'] * 1e3:.1f}{grows} |"
                     f" {r['both_max_s'] * 1e3:.0f} | {r['peak_in_frames']:.2f} | {r['peak_vs_paper']:+.0%} |"
                     f" {r['fifo_max_frames']:.0f} | {r['fifo_drops']} |")
    lines.append("")
    return "\n".join(lines)


if __name__ == "__main__":
    import sys
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        for p in doc_figures(Path(sys.argv[1] if len(sys.argv) > 1 else "docs/figures"), Path(tmp)):
            print(p)
