"""The paper's TWINBOT acoustic group in a summer thermocline: ray-traced Bellhop against the straight path
(issue #37; docs/ocean.md, "TWINBOT in a summer thermocline").

    uwsimnet experiment twinbot-ocean --seeds 1-10 --out out/twinbot-ocean

The group of the paper's Section 3.2 (a surface buoy and four BlueROV explorers, 1900 bps modems, the buoy's
20-byte broadcast commands and the explorers' 400-byte images to the buoy, NOMAC, CS-ALOHA and S-FAMA), moved
out to where the water matters: three explorers survey 30 m x 30 m boxes 440-470 m from the buoy (west, south,
east), lit by the buoy; the fourth (north) surveys 650-680 m out, beyond the edge of the buoy's shadow zone
(which begins near 540 m for a 5 m source and a 15 m receiver); explorers on opposite sides (880-1150 m apart)
are in each other's shadow.  The survey is the paper's lawnmower (four 30 m legs) at a third of its speed, so that it
fills an 1800 s run.  Each (MAC, channel model, seed) is one virtual
run of `scene_xml`; per link (a flow to one receiver) the delivery ratio and the mean delay, with 95 %
intervals over the seeds (analysis/intervals.py: Wilson for the pooled ratio, Student's t for the delay).

Writes into --out: the traces, `links.png` (delivery per link, both models, every MAC), `delay.png`,
`tl-field-*.png` (Bellhop's TL with the frames' outcomes: analysis/tl_field.py, what `uwsimnet plot TRACE
--scene SCENE` draws), `summary.md` and `summary.json`.  The grid comes from Bellhop (`make bellhop`), or
from the cache (`$UWSIMNET_CACHE/bellhop`; tests/data/twinbot-ocean/bellhop/ ships it for the tests).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from ..analysis.intervals import mean_ci, wilson
from . import twinbot

SCENE = Path(__file__).resolve().parents[2] / "scenes" / "examples" / "twinbot-thermocline.xml"
MACS: dict[str, tuple[str, str]] = {"nomac": ("none", "NOMAC"), "aloha": ("aloha", "CS-ALOHA"),
                                    "sfama": ("sfama", "S-FAMA")}
MODELS = ("straight", "bellhop")
DURATION = 1800.0           # s: three times the paper's runs (more frames per link per seed)
BUOY_DEPTH = 5.0            # m: the buoy's transducer
EXPLORER_DEPTH = 15.0       # m: the paper's explorers
RANGE = 1200.0              # m: every modem's maxDistance (the farthest pair, 1151 m apart; S-FAMA's slot)
BUOY_INTERVAL = 20.0        # s: the buoy's 20-byte commands (1 B/s; the paper's 4 B/s and
IMAGE_INTERVAL = 60.0       # s: 400-byte images at 30 B/s saturate S-FAMA, whose slot at 1.2 km is 8x 100 m's)
GRID = ("<channelModel><name>bellhop</name><sources>5 15</sources><maxDepth>100</maxDepth>"
        "<depthStep>1</depthStep><maxRange>1200</maxRange><rangeStep>25</rangeStep></channelModel>")
"""The Bellhop grid: source depths of the buoy and the explorers, receivers 0.5-100 m every 1 m (every
modem's depth is a grid depth: a first arrival interpolated between a direct path and a bottom bounce is
neither, docs/ocean.md), ranges 25-1200 m every 25 m."""

_BOX = {      # explorer: twinbot._lawnmower arguments (x0, y0, along, du, dv): a 30 m box this far out
    "e0": (-440.0, -15.0, "y", -1, 1),      # west, 440-470 m
    "e1": (15.0, -440.0, "x", -1, -1),      # south, 440-470 m
    "e2": (440.0, 15.0, "y", 1, -1),        # east, 440-470 m
    "e3": (-15.0, 650.0, "x", 1, 1),        # north, 650-680 m: in the buoy's shadow zone
}
PATHS = {e: [(3 * t, x, y, z) for t, x, y, z in twinbot._lawnmower(*a, z=-EXPLORER_DEPTH)]
         for e, a in _BOX.items()}
LINKS: tuple[tuple[str, str], ...] = (*((f"E{i}", "buoy-acomm") for i in range(4)),
                                      *(("buoy", f"e{i}-acomm") for i in range(4)))
"""(flow, receiving device): the explorers' images to the buoy, the buoy's broadcast at each explorer."""


def scene_xml(mac: str = "aloha", model: str = "bellhop", seed: int = 1) -> str:
    """One run's scene: `mac` in MACS, `model` straight (the channel's acoustic physics on the straight
    path, docs/acoustic.md) or bellhop (this environment's grid)."""
    name, label = MACS[mac]
    cm = GRID if model == "bellhop" else ""
    if model not in MODELS:
        raise ValueError(f"model: one of {', '.join(MODELS)}, got {model!r}")

    def device(dev: str, addr: int) -> str:
        return (f"    <AcousticCommsDevice><dccommsId>{dev}</dccommsId><mac>{addr}</mac><txChannelId>0</txChannelId>"
                "<rxChannelId>0</rxChannelId>\n      <preset>evologics-s2cr-18-34</preset>"
                f"<bitrate>{twinbot.BITRATE}</bitrate><intrinsicDelay>{twinbot.INTRINSIC_MS}</intrinsicDelay>"
                f"<txFifoSize>{twinbot.TX_FIFO}</txFifoSize><maxDistance>{RANGE:g}</maxDistance>\n"
                f"      <macProtocol><name>{name}</name></macProtocol></AcousticCommsDevice>\n")

    vehicles = [twinbot._vehicle("buoy", [(0, 0, 0, -BUOY_DEPTH)], device("buoy-acomm", 20))]
    vehicles += [twinbot._vehicle(f"bluerov-{e}", PATHS[e], device(f"{e}-acomm", 10 + i))
                 for i, e in enumerate(PATHS)]
    flows = [f"  <flow><name>buoy</name><src>buoy-acomm</src><dst>255</dst><size>20</size>"
             f"<interval>{BUOY_INTERVAL:g}</interval><arrival>poisson</arrival></flow>\n"]
    flows += [f"  <flow><name>E{i}</name><src>e{i}-acomm</src><dst>20</dst><size>400</size>"
              f"<interval>{IMAGE_INTERVAL:g}</interval><arrival>poisson</arrival></flow>\n" for i in range(4)]
    return f"""<?xml version="1.0"?>
<!--
  The paper's TWINBOT acoustic group (Section 3.2) in a summer thermocline (docs/ocean.md): a buoy (modem
  at {BUOY_DEPTH:g} m) and four BlueROV explorers at {EXPLORER_DEPTH:g} m surveying 30 m x 30 m boxes 440-470 m
  from it (west, south, east) and 650-680 m (north: in the buoy's shadow zone), EvoLogics S2CR 18/34
  modems at the paper's {twinbot.BITRATE} bps, {label}; the buoy broadcasts
  20 B every {BUOY_INTERVAL:g} s, each explorer sends a 400 B image to the buoy every {IMAGE_INTERVAL:g} s (Poisson).
  Channel model: {'bellhop (the grid of the environment below)' if cm else 'the straight-path acoustic physics'}.
  Generated by uwsimnet_zenoh/experiments/twinbot_ocean.py (scene_xml); `uwsimnet experiment twinbot-ocean`
  runs it with each MAC and both channel models.
-->
<UWSimScene>
  <simulation><duration>{DURATION:g}</duration><seed>{seed}</seed><world>twinbot-thermocline</world></simulation>
  <environment>
    <origin>41.38 2.18</origin>
    <preset>summer-thermocline</preset>
    <bathymetry>flat 1000</bathymetry>
    <seabed><soundSpeed>1550</soundSpeed><density>1.5</density><attenuation>1.0</attenuation></seabed>
  </environment>
  <AcousticCommsChannel><id>0</id>{cm}</AcousticCommsChannel>
{''.join(vehicles)}{''.join(flows)}</UWSimScene>
"""


def link_counts(trace: Path) -> dict[tuple[str, str], dict[str, Any]]:
    """Per link: frames the flow offered (enq), delivered at the receiver (unique seq), and their delays
    (rx time minus enq time, s)."""
    enq: dict[tuple[str, int], float] = {}
    got: dict[tuple[str, str], dict[int, float]] = {}
    with open(trace, encoding="utf-8") as fh:
        for line in fh:
            r = json.loads(line)
            flow = r.get("flow")
            if flow is None or r.get("kind") != "data":
                continue
            if r["ev"] == "enq":
                enq.setdefault((flow, r["seq"]), r["t"])
            elif r["ev"] == "rx":
                got.setdefault((flow, r["dev"]), {}).setdefault(r["seq"], r["t"])
    out = {}
    for flow, dev in LINKS:
        offered = [s for (f, s) in enq if f == flow]
        rx = got.get((flow, dev), {})
        out[(flow, dev)] = {"offered": len(offered), "delivered": len(rx),
                            "delays": [t - enq[(flow, s)] for s, t in sorted(rx.items()) if (flow, s) in enq]}
    return out


def run_one(mac: str, model: str, seed: int, out: Path) -> dict[str, Any]:
    """One virtual run into out/<mac>-<model>-<seed>.trace.jsonl; its per-link counts."""
    from ..app.virtual import run_virtual
    from ..scene.load import load_scene_text

    scene = load_scene_text(scene_xml(mac, model, seed), source=f"twinbot-thermocline-{mac}-{model}.xml",
                            on_warning=lambda *_: None)
    trace = out / f"{mac}-{model}-{seed}.trace.jsonl"
    run_virtual(scene, seed=seed, duration=None, trace_path=trace, progress=False)
    return {"trace": trace, "links": link_counts(trace)}


def _label(flow: str, dev: str) -> str:
    return f"{flow}->buoy" if dev == "buoy-acomm" else f"buoy->{dev.split('-')[0].upper()}"


def aggregate(runs: dict[tuple[str, str, int], dict[str, Any]], seeds: list[int]) -> dict[str, Any]:
    """Per MAC, model and link: delivery (pooled over the seeds, Wilson 95 %) and the mean delay (Student's
    t over the seeds' means)."""
    res: dict[str, Any] = {}
    for mac in MACS:
        for model in MODELS:
            for flow, dev in LINKS:
                per = [runs[(mac, model, s)]["links"][(flow, dev)] for s in seeds]
                off, dl = sum(p["offered"] for p in per), sum(p["delivered"] for p in per)
                lo, hi = wilson(dl, off) if off else (math.nan, math.nan)
                means = [sum(p["delays"]) / len(p["delays"]) for p in per if p["delays"]]
                iv = mean_ci(means)
                res[f"{mac}/{model}/{_label(flow, dev)}"] = {
                    "offered": off, "delivered": dl, "ratio": dl / off if off else math.nan, "low": lo, "high": hi,
                    "delay": iv.mean if iv else math.nan, "delay_half": (iv.half or 0.0) if iv else math.nan}
    return res


def plot(res: dict[str, Any], out: Path) -> list[Path]:
    """links.png (delivery per link) and delay.png (mean delay per link): one panel per MAC, the two
    models side by side, 95 % intervals as error bars."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = [_label(f, d) for f, d in LINKS]
    files = []
    for what, ylabel, fname in (("ratio", "delivered / offered", "links.png"),
                                ("delay", "mean delay, enq to rx (s)", "delay.png")):
        fig, axes = plt.subplots(len(MACS), 1, figsize=(9, 2.6 * len(MACS)), sharex=True)
        for ax, (mac, (_, label)) in zip(axes, MACS.items(), strict=True):
            for k, (model, colour) in enumerate(zip(MODELS, ("tab:blue", "tab:orange"), strict=True)):
                xs = [i + (k - 0.5) * 0.38 for i in range(len(labels))]
                rows = [res[f"{mac}/{model}/{lab}"] for lab in labels]
                ys = [r[what] for r in rows]
                if what == "ratio":
                    err = [[max(0.0, r["ratio"] - r["low"]) for r in rows], [max(0.0, r["high"] - r["ratio"])
                                                                            for r in rows]]
                else:
                    err = [r["delay_half"] for r in rows]
                ax.bar(xs, ys, width=0.38, color=colour, yerr=err, capsize=2,
                       label="Bellhop, summer thermocline" if model == "bellhop" else "straight path")
            ax.set_title(label, fontsize=10, loc="left")
            ax.set_ylabel(ylabel, fontsize=8)
            if what == "ratio":
                ax.set_ylim(0, 1.05)
        axes[-1].set_xticks(range(len(labels)), labels, rotation=30, fontsize=8)
        fig.suptitle(f"TWINBOT acoustic group 440-680 m out: {'delivery' if what == 'ratio' else 'delay'} per"
                     " link (95 % intervals)", fontsize=10)
        fig.legend(*axes[0].get_legend_handles_labels(), loc="upper center", ncol=2, fontsize=8,
                   bbox_to_anchor=(0.5, 0.965))
        fig.tight_layout(rect=(0, 0, 1, 0.94))
        path = out / fname
        fig.savefig(path, dpi=110)
        plt.close(fig)
        files.append(path)
    return files


def markdown(res: dict[str, Any], seeds: list[int]) -> str:
    """The tables of docs/ocean.md: delivery % [95 % interval] and mean delay per link, both models."""
    labels = [_label(f, d) for f, d in LINKS]
    lines = [f"Seeds {seeds[0]}-{seeds[-1]} ({len(seeds)} runs of {DURATION:g} s per MAC and model). Delivery:"
             " frames delivered / offered, % [Wilson 95 %]; delay: mean of the seeds' mean delays, s ± t 95 %.", "",
             "| MAC | link | straight: delivered | Bellhop: delivered | straight: delay s | Bellhop: delay s |",
             "|---|---|---|---|---|---|"]
    for mac, (_, label) in MACS.items():
        for lab in labels:
            a, b = res[f"{mac}/straight/{lab}"], res[f"{mac}/bellhop/{lab}"]
            cells = []
            for r in (a, b):
                cells.append(f"{100 * r['ratio']:.1f} [{100 * r['low']:.1f}, {100 * r['high']:.1f}]"
                             f" ({r['delivered']}/{r['offered']})")
            delays = [f"{r['delay']:.2f} ± {r['delay_half']:.2f}" if math.isfinite(r["delay"]) else "-"
                      for r in (a, b)]
            lines.append(f"| {label} | {lab} | {cells[0]} | {cells[1]} | {delays[0]} | {delays[1]} |")
    return "\n".join(lines) + "\n"


def run(out: Path, seeds: tuple[int, ...] | list[int] = tuple(range(1, 11)), progress: bool = True) -> dict[str, Any]:
    """Every (MAC, model, seed) run, the figures and the summary into `out`; returns the summary."""
    from ..analysis.tl_field import plot_tl_field
    from ..app.checks import build_network
    from ..scene.load import load_scene_text

    out.mkdir(parents=True, exist_ok=True)
    seeds = sorted(seeds)
    net = build_network(load_scene_text(scene_xml("aloha", "bellhop", seeds[0]), source=str(SCENE),
                                        on_warning=lambda *_: None))   # the grid first: no Bellhop and no
                                                                         # cache fails here, in one line
    runs = {}
    for mac in MACS:
        for model in MODELS:
            for s in seeds:
                runs[(mac, model, s)] = run_one(mac, model, s, out)
                if progress:
                    print(f"twinbot-ocean: {mac} {model} seed {s} done", flush=True)
    res = aggregate(runs, seeds)
    figs = plot(res, out)
    figs += plot_tl_field(net, runs[("aloha", "bellhop", seeds[0])]["trace"], out)
    summary = {"seeds": seeds, "links": res, "figures": [str(f) for f in figs]}
    (out / "summary.json").write_text(json.dumps(summary, indent=1, allow_nan=True))
    (out / "summary.md").write_text(markdown(res, seeds))
    return summary


if __name__ == "__main__":          # rewrite the shipped example scene from the generator
    SCENE.write_text(scene_xml(), encoding="utf-8")
