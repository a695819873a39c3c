"""Table 1 found, not configured (issue #16): the highest rate each MAC sustains per channel of the
TWINBOT scene, searched with app/saturation.py over several seeds.

    uwsimnet experiment table1 --seeds 1-3 --out out/table1

The paper set one rate per protocol and channel ("the maximum value allowed for each protocol"): the
leader and the follower share the RF rate, the four explorers the acoustic one.  So the search scales
leader+follower together (RF) and E0..E3 together (acoustic), the other flows (support, buoy: 4 B/s)
keeping their Table 1 rates.  A rate is sustained when every flow of the group delivers at least
(1 - TOLERANCE) of what it offers and its 95th-percentile delay stays under MAX_DELAY over the 600 s run.
"""

from __future__ import annotations

import json
from pathlib import Path

from ..analysis.intervals import label, mean_ci, ratio_ci
from . import sidecar, twinbot

TOLERANCE = 0.05
MAX_DELAY = 30.0        # s: a queue that grows over 600 s exceeds it; a 400 B exchange takes ~2 s
STEPS = 5               # geometric bisections after the doubling bracket: about 2 % resolution
GROUPS = {              # channel: (flow searched, flows scaled with it, lowest probe in frames/s)
    "RF": ("leader", ("follower",), 0.5),
    "acoustic": ("E0", ("E1", "E2", "E3"), 0.01),
}
PROTOCOLS = ("aloha", "sfama")


def original_overrides(protocol: str) -> dict[str, object]:
    """The original experiment's set-up as scene overrides: `twinbot.profile_overrides(protocol,
    "original")` (dccomms_examples testing/mac_twinbot.sh, twinbot.xml; Aqua-Sim NG's S-FAMA rules)."""
    return twinbot.profile_overrides(protocol, "original")


def run(out: Path, seeds: list[int] | tuple[int, ...] = (1, 2, 3), progress: bool = True,
        profile: str = "default") -> dict:
    from ..app.saturation import saturate
    from ..scene.load import load_scene

    out.mkdir(parents=True, exist_ok=True)
    res: dict = {"tolerance": TOLERANCE, "max_delay": MAX_DELAY, "seeds": list(seeds), "profile": profile,
                 "found": {}}
    for p in PROTOCOLS:
        sc = load_scene(twinbot.scene_path(p), on_warning=lambda *_: None)
        res["found"][p] = {}
        for ch, (flow, together, low) in GROUPS.items():
            s = saturate(sc, flow, seeds=seeds, tolerance=TOLERANCE, max_delay=MAX_DELAY, low=low,
                         steps=STEPS, together=together,
                         overrides=twinbot.profile_overrides(p, profile) or None)
            bps = {k: v * s.size for k, v in s.per_seed.items()}
            iv = mean_ci(list(bps.values()))
            res["found"][p][ch] = {"flow": flow, "together": list(together), "per_seed_Bps": bps,
                                   "mean_Bps": iv.mean, "half_Bps": iv.half,
                                   "paper_Bps": twinbot.PAPER_TABLE1[p][flow], "probes": len(s.probes)}
            if progress:
                print(f"{p} {ch}: {iv.mean:.1f} B/s" + ("" if iv.half is None else f" +- {iv.half:.1f}")
                      + f" (paper {twinbot.PAPER_TABLE1[p][flow]:g}), {len(s.probes)} runs", flush=True)
    (out / "summary.json").write_text(json.dumps(res, indent=2))
    (out / "summary.md").write_text(markdown(res))
    plot(res, out)
    return res


def plot(res: dict, out: Path) -> Path:
    """table1-found.png: per channel, each MAC's found maximum (mean and 95 % interval over the seeds, the
    seeds as dots) next to the paper's Table 1 rate (a black bar)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from ..analysis.figures import protocol_colour

    fig = Figure(figsize=(9, 3.8))
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, len(GROUPS))
    for ax, ch in zip(axes, GROUPS, strict=True):
        for i, p in enumerate(res["found"]):
            c = res["found"][p][ch]
            half = c["half_Bps"] or 0.0
            ax.bar(i, c["mean_Bps"], 0.6, yerr=half, capsize=6, color=protocol_colour(p), alpha=0.85,
                   label="found (mean, 95 % interval)" if i == 0 else None)
            seeds = list(c["per_seed_Bps"].values())
            ax.plot([i + 0.12] * len(seeds), seeds, "o", ms=4, color="black", alpha=0.5,
                    label="per seed" if i == 0 else None)
            ax.hlines(c["paper_Bps"], i - 0.35, i + 0.35, colors="black", linewidth=2.5,
                      label="paper's Table 1" if i == 0 else None)
        ax.set_xticks(range(len(res["found"])), [twinbot.PROTOCOLS[p][1] for p in res["found"]])
        ax.set_title(f"{ch} ({GROUPS[ch][0]}+{'+'.join(GROUPS[ch][1])})", fontsize=10)
        ax.set_ylabel("highest sustained rate (payload B/s per flow)")
        ax.set_ylim(bottom=0)
    axes[0].legend(fontsize=8, loc="lower left")
    fig.suptitle(f"Table 1 found by saturation search, profile {res.get('profile', 'default')},"
                 f" seeds {res['seeds'][0]}-{res['seeds'][-1]}", fontsize=11)
    fig.tight_layout()
    path = out / "table1-found.png"
    fig.savefig(path, dpi=110)
    sidecar.write(path, numbers(res))
    return path


def numbers(res: dict) -> dict:
    """What table1-found.png shows and docs/paper-twinbot.md states of it: the maxima per seed with their
    intervals, and the CS-ALOHA / S-FAMA ratio per channel as the interval of the per-seed ratios with the
    label it gives the paper's ratio (analysis/intervals.py)."""
    found = {p: {ch: {k: c[k] for k in ("per_seed_Bps", "mean_Bps", "half_Bps", "paper_Bps")}
                 for ch, c in chans.items()} for p, chans in res["found"].items()}
    out: dict = {"profile": res.get("profile", "default"), "seeds": res["seeds"], "tolerance": res["tolerance"],
                 "max_delay": res["max_delay"], "found": found, "ratios": {}}
    if all(p in found for p in PROTOCOLS):
        for ch in GROUPS:
            a, s = found["aloha"][ch]["per_seed_Bps"], found["sfama"][ch]["per_seed_Bps"]
            seeds = [k for k in a if k in s]
            iv = ratio_ci([a[k] for k in seeds], [s[k] for k in seeds])
            paper = found["aloha"][ch]["paper_Bps"] / found["sfama"][ch]["paper_Bps"]
            if iv is not None:
                out["ratios"][ch] = {"mean": iv.mean, "half": iv.half, "paper": paper, "label": label(iv, paper)}
    return out


if __name__ == "__main__":
    import sys

    if len(sys.argv) == 3 and sys.argv[1] == "--plot":      # redraw from a run's summary.json
        d = Path(sys.argv[2])
        print(plot(json.loads((d / "summary.json").read_text()), d))
    else:
        print("usage: python -m uwsimnet_zenoh.experiments.table1 --plot OUTDIR"
              " (runs: uwsimnet experiment table1)")


def markdown(res: dict) -> str:
    lines = ["# Table 1 as found maxima (saturation search, TWINBOT scene)", "",
             f"Sustained: throughput >= {1 - res['tolerance']:.0%} of offered for every flow of the group and"
             f" p95 delay <= {res['max_delay']:g} s; seeds {res['seeds']}; 95 % intervals (t) over the seeds;"
             f" profile {res.get('profile', 'default')}; payload B/s per flow.",
             "", "| protocol | RF (leader+follower) B/s | paper | acoustic (E0-E3) B/s | paper |",
             "|---|---|---|---|---|"]
    for p, chans in res["found"].items():
        cells = []
        for ch in GROUPS:
            c = chans[ch]
            half = "" if c["half_Bps"] is None else f" ± {c['half_Bps']:.1f}"
            cells += [f"{c['mean_Bps']:.1f}{half}", f"{c['paper_Bps']:g}"]
        lines.append(f"| {twinbot.PROTOCOLS[p][1]} | " + " | ".join(cells) + " |")
    f = res["found"]
    if all(p in f for p in PROTOCOLS):
        rf = f["aloha"]["RF"]["mean_Bps"] / f["sfama"]["RF"]["mean_Bps"]
        ac = f["aloha"]["acoustic"]["mean_Bps"] / f["sfama"]["acoustic"]["mean_Bps"]
        lines += ["", f"Ratios CS-ALOHA / S-FAMA: RF {rf:.2f} (paper {62.5 / 27.5:.2f}), acoustic {ac:.2f}"
                  f" (paper {30 / 27.5:.2f})."]
    return "\n".join(lines) + "\n"


# -- Table 1 under several sustain criteria, on a grid (issue #39.6) --------------------------------------
CRITERIA = {"loose": (0.10, 60.0), "default": (TOLERANCE, MAX_DELAY), "strict": (0.01, 10.0)}
"""name: (tolerance, max p95 delay s).  `default` is the bisection's; `strict` asks >= 99 % and p95 <= 10 s."""
GRID_BPS = {("aloha", "RF"): range(24, 88, 4), ("sfama", "RF"): range(14, 40, 2),
            ("aloha", "acoustic"): range(4, 48, 2), ("sfama", "acoustic"): range(4, 44, 2)}
"""Payload B/s per flow of the group tried, every step: one run per rate and seed, read under every criterion."""


def read_grid(rows: list[tuple[float, float | None, float | None]], tolerance: float,
              max_delay: float) -> tuple[float | None, bool]:
    """(rate, delivered/offered, p95 delay) rows in increasing rate -> the highest rate sustained (None: none)
    and whether sustainment is monotone (no failing rate below a sustained one)."""
    ok = [r is not None and r >= 1 - tolerance and d is not None and d <= max_delay for _, r, d in rows]
    best = max((b for (b, _, _), o in zip(rows, ok, strict=True) if o), default=None)
    first_fail = next((b for (b, _, _), o in zip(rows, ok, strict=True) if not o), None)
    return best, best is None or first_fail is None or first_fail > best


def criteria_grid(seeds: list[int] | tuple[int, ...] = (1, 2, 3), profile: str = "default") -> dict:
    """Per protocol, channel and seed: the probes of GRID_BPS, the highest rate each criterion sustains, and
    whether sustainment is monotone in the rate (the bisection of `run` assumes it: a failing rate below a
    sustained one is where it can go wrong)."""
    from ..app.saturation import sustained
    from ..scene.load import load_scene

    res: dict = {"profile": profile, "seeds": list(seeds), "criteria": CRITERIA, "cells": {}}
    for p in PROTOCOLS:
        sc = load_scene(twinbot.scene_path(p), on_warning=lambda *_: None)
        ov = twinbot.profile_overrides(p, profile)
        for ch, (flow, together, _low) in GROUPS.items():
            size = next(f.size for f in twinbot.FLOWS if f.name == flow)
            cell: dict = {"seeds": {}}
            for seed in seeds:
                probes = [sustained(sc, flow, bps / size, seed, tolerance=1.0, max_delay=float("inf"), duration=None,
                                    overrides=ov, together=dict.fromkeys(together, 1.0))
                          for bps in GRID_BPS[(p, ch)]]
                rows = [(bps, pr.throughput_ratio, pr.delay_p95) for bps, pr in zip(GRID_BPS[(p, ch)], probes,
                                                                                     strict=True)]
                per = {name: dict(zip(("max_Bps", "monotone"), read_grid(rows, tol, dmax), strict=True))
                       for name, (tol, dmax) in CRITERIA.items()}
                cell["seeds"][seed] = {"probes": rows, "criteria": per}
            for name in CRITERIA:
                vals = [cell["seeds"][s]["criteria"][name]["max_Bps"] for s in seeds]
                iv = mean_ci([v for v in vals if v is not None])
                cell[name] = {"per_seed": vals, "mean": None if iv is None else iv.mean,
                              "half": None if iv is None else iv.half,
                              "monotone": all(cell["seeds"][s]["criteria"][name]["monotone"] for s in seeds)}
            res["cells"][f"{p}/{ch}"] = cell
    return res
