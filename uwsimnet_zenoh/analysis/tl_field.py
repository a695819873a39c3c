"""The transmission-loss field of a link (docs/ocean.md): for every flow whose sender uses the channel model
`bellhop`, Bellhop's TL over range and depth from the sender (its cached grid, at the grid's source depth
nearest the sender's; over a sloping bottom, the grid of the sender's cell and of the bearing to the flow's
destination at the flow's start), with the receiver where each of the flow's frames reached it (delivered: a dot,
lost: a cross).  `uwsimnet plot TRACE --scene SCENE` draws them beside the trace's figures."""

from __future__ import annotations

import json
import math
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["plot_tl_field"]


def _outcomes(trace: str | PathLike[str]) -> list[dict[str, Any]]:
    """The trace's tx, rx and drop records (rx/drop with the time of their frame's tx as `t_tx`)."""
    tx: dict[tuple[str, int, int], float] = {}
    out = []
    with open(trace, encoding="utf-8") as fh:
        for line in fh:
            r = json.loads(line)
            ev = r.get("ev")
            if ev == "tx":
                tx[(r.get("flow") or "", r.get("src"), r.get("seq"))] = r["t"]
            elif ev in ("rx", "drop") and r.get("reason") not in ("fifo", "retry", "stopped"):
                t0 = tx.get((r.get("flow") or "", r.get("src"), r.get("seq")))
                if t0 is not None:
                    out.append({**r, "t_tx": t0})
    return out


def plot_tl_field(net: Any, trace: str | PathLike[str], out_dir: str | PathLike[str]) -> list[Path]:
    """One PNG per flow whose sender's model is `bellhop` (none: an empty list).  `net` is the run's network
    as the engine builds it from the scene (engine.Network: its scene, modems and pose table), which the
    caller makes (analysis does not import the engine)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..phy.bellhop import BellhopModel

    scene = net.scene
    records = _outcomes(trace)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = []
    for flow in scene.flows:
        sender = net.modems[flow.src]
        model = sender.error
        if not isinstance(model, BellhopModel):
            continue
        at = net.poses.points(flow.start)
        dst = next((m for m in net.modems.values() if m.address == flow.dst and m is not sender), None)
        g = model.grid_for(at[sender.vehicle_index], at[dst.vehicle_index]) if dst is not None else model.grid
        i = int(np.argmin(np.abs(g.sd - (-at[sender.vehicle_index][2]))))
        fig, ax = plt.subplots(figsize=(8, 4.5))
        mesh = ax.pcolormesh(g.rr, g.rd, np.clip(g.tl[i], 30, 110), shading="auto", cmap="viridis_r")
        fig.colorbar(mesh, ax=ax, label="transmission loss (dB)")
        marks: dict[str, list[tuple[float, float]]] = {"rx": [], "lost": []}
        for r in records:
            if r.get("flow") != flow.name or r["dev"] not in net.modems:
                continue
            pts = net.poses.points(r["t_tx"])
            s, d = pts[sender.vehicle_index], pts[net.modems[r["dev"]].vehicle_index]
            marks["rx" if r["ev"] == "rx" else "lost"].append((math.hypot(d[0] - s[0], d[1] - s[1]), -d[2]))
        for kind, style in (("rx", dict(marker="o", color="white", edgecolors="black")),
                            ("lost", dict(marker="x", color="red"))):
            if marks[kind]:
                xs, ys = zip(*marks[kind], strict=True)
                ax.scatter(xs, ys, s=18, label=f"{kind} ({len(xs)})", **style)
        ax.invert_yaxis()
        ax.set_xlabel("range from the sender (m)")
        ax.set_ylabel("depth (m)")
        toward = ""
        if model.sectors and dst is not None:             # a sloping bottom: the sector this field is along
            s, d = at[sender.vehicle_index], at[dst.vehicle_index]
            toward = f", bearing {math.degrees(math.atan2(d[1] - s[1], d[0] - s[0])) % 360:.0f} deg"
        ax.set_title(f"{flow.name}: TL from {flow.src} at {g.sd[i]:g} m, {model.freq_hz / 1e3:g} kHz{toward}"
                     " (Bellhop)")
        if marks["rx"] or marks["lost"]:
            ax.legend(loc="lower right")
        path = out / f"tl-field-{flow.name}.png"
        fig.savefig(path, dpi=110, bbox_inches="tight")
        plt.close(fig)
        files.append(path)
    return files
