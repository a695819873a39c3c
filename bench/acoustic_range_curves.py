"""PER versus distance for every acoustic modem preset (uwsimnet_zenoh.phy.acoustic.PRESETS).

Writes <out>/acoustic-per-vs-distance.png: 64-byte frames, default channel (Thorp, k = 1.5, shipping 0.5,
wind 0 m/s), log distance axis.  Solid lines are the presets as shipped (receiver margin calibrated to the
rated range, marked with a dot); dashed lines are the same modems on an ideal AWGN link (margin 0 dB).
Also prints a table of the distances at which PER reaches 10 % and 50 %.

Run: .venv/bin/python bench/acoustic_range_curves.py        # -> out/acoustic/ (docs/figures/ holds the
copy the documentation shows; replace it by hand when the model changes)
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402

from uwsimnet_zenoh.phy.acoustic import PRESETS, AcousticChannelParams, AcousticLink  # noqa: E402

FRAME_BYTES = 64


def main(argv: list[str] | None = None) -> Path:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--out", default="out/acoustic", help="output directory (default out/acoustic)")
    ap.add_argument("--size", type=int, default=FRAME_BYTES, help="frame size in bytes (default 64)")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    channel = AcousticChannelParams()
    d = np.logspace(2, np.log10(50_000), 4000)      # 100 m .. 50 km
    fig, ax = plt.subplots(figsize=(10, 7.2), dpi=130)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]

    print(f"{'preset':<26} {'rated m':>8} {'PER10% m':>9} {'PER50% m':>9} {'ideal PER50% m':>15} "
          f"{'margin dB':>15}")
    for colour, (key, modem) in zip(colours, PRESETS.items(), strict=False):
        link = AcousticLink(channel, modem)
        ideal = AcousticLink(channel, replace(modem, margin_db=0.0))
        label = (f"{modem.name}: {modem.carrier_khz:g} kHz, {modem.bitrate_bps:g} bit/s, "
                 f"SL {modem.sl_db:.0f} dB, rated {modem.rated_range_m / 1000:g} km")
        ax.plot(d, link.per(d, args.size), color=colour, lw=2.2, label=label)
        ax.plot(d, ideal.per(d, args.size), color=colour, lw=1.1, ls="--", alpha=0.75)
        r = modem.rated_range_m
        ax.plot([r], [float(link.per(r, args.size))], "o", color=colour, ms=8, mec="black", mew=0.9, zorder=5)
        r10, r50 = link.distance_for_per(0.1, args.size), link.distance_for_per(0.5, args.size)
        print(f"{key:<26} {r:>8.0f} {r10:>9.0f} {r50:>9.0f} {ideal.distance_for_per(0.5, args.size):>15.0f} "
              f"{modem.margin_db:>15.1f}")

    ax.set_xscale("log")
    ax.set_xlim(d[0], d[-1])
    ax.set_ylim(-0.02, 1.02)
    ax.set_xlabel("distance (m)", fontsize=12)
    ax.set_ylabel(f"packet error rate, {args.size}-byte frames", fontsize=12)
    ax.set_title("Acoustic modem presets: PER vs distance\n"
                 "Thorp absorption, k = 1.5, Wenz/Coates noise (shipping 0.5, wind 0 m/s)", fontsize=12)
    ax.grid(True, which="major", alpha=0.5)
    ax.grid(True, which="minor", alpha=0.15)
    first = ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.11), ncol=1, fontsize=9, framealpha=0.95,
                      title="presets", title_fontsize=9.5)
    ax.add_artist(first)
    style = [Line2D([], [], color="grey", lw=2.2, label="preset as shipped"),
             Line2D([], [], color="grey", lw=1.1, ls="--", label="ideal AWGN link\n(margin 0 dB)"),
             Line2D([], [], color="grey", marker="o", ls="", mec="black",
                    label="rated range\n(calibrated to PER 10 %)")]
    ax.legend(handles=style, loc="upper left", fontsize=9, framealpha=0.95)
    fig.tight_layout()
    path = out / "acoustic-per-vs-distance.png"
    fig.savefig(path, bbox_inches="tight")
    plt.close(fig)
    print(f"wrote {path}")
    return path


if __name__ == "__main__":
    main()
