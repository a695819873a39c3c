"""Capture on a line (issue #5): pure-ALOHA throughput to a sink, binary rule vs SINR capture.

The scenario is uwsimnet_zenoh.experiments.capture: N sensors every 200 m on a line, the sink at one end,
ns-3-like FSK PHY (1000 bit/s, 22 kHz, 4 kHz band, SL 190 dB), Thorp absorption, k = 1.5, 40-byte frames,
Poisson traffic, no MAC and no queue.  Writes <out>/capture-throughput.png (throughput vs offered load;
success probability per sensor position at one load) and prints a markdown table with the ns-3 UAN
column.  The ns-3 points (bench/reference/ns3_capture.json, written by bench/ns3_capture.py against the
ns-3.44 wheel) are in the repository and drawn on the same axes; --ns3 FILE uses another run of it,
--ns3 none draws none.

Run: .venv/bin/python bench/capture_line.py            # -> out/capture/ (never docs/: the documented
                                                       #    figure is replaced by hand, cp out/capture/...)
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from uwsimnet_zenoh.experiments import capture as C  # noqa: E402

HERE = Path(__file__).resolve().parent
NS3_REFERENCE = HERE / "reference" / "ns3_capture.json"
"""ns-3.44 UAN on the same scenario (bench/ns3_capture.py; N = 16, 20 000 frame-times per point, seed 1)."""

LOADS = (0.1, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 4.0)
LABELS = {"binary": "binary rule (any overlap loses both)",
          "threshold": f"capture any: min SINR >= {C.THRESHOLD_DB:g} dB",
          "per": "capture any: PER from min SINR (non-coherent BFSK)",
          "first": f"capture first: lock at SINR > {C.ACQUIRE_DB:g} dB, min SINR >= {C.THRESHOLD_DB:g} dB"
                   " (ns-3 rules)"}
COLOURS = {"binary": "tab:grey", "threshold": "tab:blue", "per": "tab:orange", "first": "tab:green"}


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--out", default="out/capture", help="output folder (default out/capture)")
    ap.add_argument("--nodes", type=int, default=16)
    ap.add_argument("--frames", type=float, default=20000.0, help="simulated time in frame-times per point")
    ap.add_argument("--loads", default=",".join(map(str, LOADS)))
    ap.add_argument("--detail-load", type=float, default=1.0, help="load of the per-sensor panel")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--ns3", default=str(NS3_REFERENCE),
                    help="JSON results of bench/ns3_capture.py to overlay (default: the reference run in the"
                         " repository; 'none': no overlay)")
    ap.add_argument("--json", help="also write the results here")
    a = ap.parse_args(argv)
    loads = [float(x) for x in a.loads.split(",")]
    if a.detail_load not in loads:
        loads.append(a.detail_load)
        loads.sort()
    duration = a.frames * C.FRAME_TIME
    t0 = time.perf_counter()
    res = {rule: {g: C.run(a.nodes, g, duration, rule, a.seed) for g in loads} for rule in C.RULES}
    wall = time.perf_counter() - t0
    ns3 = json.loads(Path(a.ns3).read_text()) if a.ns3 and a.ns3 != "none" else None
    if ns3 is not None and (ns3.get("nodes") != a.nodes or a.seed != ns3.get("seed")):
        print(f"note: the ns-3 points are for N = {ns3.get('nodes')}, seed {ns3.get('seed')}")

    print(f"# capture on a line: N = {a.nodes}, spacing {C.SPACING_M:g} m, {a.frames:g} frame-times per point,"
          f" seed {a.seed} ({wall:.0f} s wall)")
    pts = {float(k): v for k, v in ns3["points"].items()} if ns3 else {}
    hdr = ("| G | binary | ALOHA theory | capture any, 8 dB | capture any, PER(SINR) | capture first |"
           " ns-3 UanPhyGen | gain: any 8 dB | any PER | first |")
    print(hdr)
    print("|" + "---|" * (hdr.count("|") - 1))
    for g in loads:
        sb, st, sp, sf = (res[r][g]["S"] for r in C.RULES)
        n3 = f"{pts[g]['S']:.3f}" if g in pts else "-"
        print(f"| {g:g} | {sb:.3f} | {C.theory_binary(a.nodes, g):.3f} | {st:.3f} | {sp:.3f} | {sf:.3f} | {n3} |"
              f" {st / sb:.2f}x | {sp / sb:.2f}x | {sf / sb:.2f}x |")

    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(13, 5.2), dpi=130, gridspec_kw={"width_ratios": [1.25, 1]})
    gg = np.linspace(0.02, max(loads), 300)
    ax.plot(gg, [C.theory_binary(a.nodes, g) for g in gg], color="black", lw=1, ls=":",
            label=f"pure ALOHA theory, N = {a.nodes}")
    for rule in C.RULES:
        ax.plot(loads, [res[rule][g]["S"] for g in loads], "o-", color=COLOURS[rule], lw=2, ms=5,
                label=LABELS[rule])
    if pts:
        ax.plot(sorted(pts), [pts[g]["S"] for g in sorted(pts)], "s", mfc="none", mec="black", ms=10, mew=1.4,
                label="ns-3.44 UAN (UanPhyGen, UanPropModelThorp), same scenario")
    ax.set_xlabel("offered load G (frame-times per frame-time)")
    ax.set_ylabel("throughput S at the sink (frames per frame-time)")
    ax.set_title(f"Pure ALOHA to a sink at the end of a line of {a.nodes} sensors, 200 m apart")
    ax.set_xlim(0, max(loads) * 1.02)
    ax.set_ylim(0, None)
    ax.grid(alpha=0.4)
    ax.legend(fontsize=8.5, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=2)

    g = a.detail_load
    x = [(i + 1) * C.SPACING_M for i in range(a.nodes)]
    for rule in C.RULES:
        r = res[rule][g]
        ok = [rx / tx if tx else float("nan") for rx, tx in zip(r["received"], r["sent"], strict=True)]
        bx.plot(x, ok, "o-", color=COLOURS[rule], lw=2, ms=4, label=LABELS[rule].split(":")[0] +
                (f", {C.THRESHOLD_DB:g} dB" if rule == "threshold" else ", PER" if rule == "per" else ""))
    if g in pts:
        p = pts[g]
        bx.plot(x, [rx / tx if tx else float("nan") for rx, tx in zip(p["received"], p["sent"], strict=True)],
                "s", mfc="none", mec="black", ms=8, mew=1.2, label="ns-3 UanPhyGen")
    bx.set_xlabel("sensor distance to the sink (m)")
    bx.set_ylabel("fraction of its frames received")
    bx.set_title(f"Who wins, G = {g:g}: near senders capture the sink")
    bx.set_ylim(0, 1.02)
    bx.grid(alpha=0.4)
    bx.legend(fontsize=8.5, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=2)
    fig.tight_layout()
    path = out / "capture-throughput.png"
    fig.savefig(path, bbox_inches="tight")
    plt.close(fig)
    print(f"wrote {path}")
    if a.json:
        Path(a.json).write_text(json.dumps({r: {str(k): v for k, v in d.items()} for r, d in res.items()}))
    return res


if __name__ == "__main__":
    main()
