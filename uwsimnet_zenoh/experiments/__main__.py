"""`python -m uwsimnet_zenoh.experiments NAME --out DIR`: the paper's experiments with embedded defaults."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="uwsimnet-experiments")
    ap.add_argument("name", choices=["phy-layer", "twinbot", "hil-formation"])
    ap.add_argument("--out", default=None, help="output folder (default out/NAME)")
    a = ap.parse_args(argv)
    out = Path(a.out or f"out/{a.name}")
    if a.name == "phy-layer":
        from . import phy_layer as experiment
    elif a.name == "hil-formation":
        from . import hil_formation as experiment
    else:
        from . import twinbot as experiment
    experiment.run(out)
    print((out / "summary.md").read_text())
    print(f"figures and traces in {out}/")
    return 0


if __name__ == "__main__":
    sys.exit(main())
