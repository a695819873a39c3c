"""`uwsimnet experiment NAME [--out DIR]`: the paper's experiments with embedded defaults.

hil-formation runs in real time as separate processes over Zenoh (about 4 minutes); `--virtual` runs
its virtual-time model alone (seeds 1-5, about 10 s); `--traffic paper|control` (default paper: the Sec. 3.2
image flows too).  phy-layer `--reading` chooses how the paper's '1500 bps' is read (default stated)."""

from __future__ import annotations

import argparse
import signal
import sys
from pathlib import Path

from ..app.campaign import Campaign, execute, parse_seeds, plain_progress
from ..errors import UserError
from .limits import SPEED_RANGE


def _twinbot_seeds(a: argparse.Namespace, out: Path) -> int:
    """Table 1 / Fig. 7 with intervals: the three TWINBOT scenes as a campaign over the seeds."""
    from ..experiments import twinbot

    c = Campaign(scenes=[str(twinbot.scene_path(p)) for p in twinbot.PROTOCOLS], seeds=parse_seeds(a.seeds),
                 out=out / "seeds", workers=a.workers)
    report = execute(c, on_progress=plain_progress)
    print((c.out / "summary.md").read_text())
    print(f"figures (bars with 95 % intervals) and results in {c.out}/")
    return 1 if report["failed"] else 0

NAMES = ("phy-layer", "twinbot", "hil-formation", "table1", "twinbot-ocean")


def add_commands(sub: argparse._SubParsersAction) -> None:
    """`uwsimnet experiment NAME`."""
    ap = sub.add_parser("experiment", help="run one of the paper's experiments (figures + summary in --out)",
                        description=__doc__.split("\n")[0])
    ap.add_argument("name", choices=NAMES)
    ap.add_argument("--out", default=None, help="output folder (default out/NAME)")
    ap.add_argument("--duration", type=float, help="hil-formation: seconds to run (default 240)")
    ap.add_argument("--virtual", action="store_true", help="hil-formation: the virtual-time model only")
    ap.add_argument("--speed", type=float, help="hil-formation: simulated seconds per wall second (default 1)")
    ap.add_argument("--seeds", help="phy-layer: PER per distance bin over these seeds (Wilson intervals);"
                                    " twinbot: the three MACs over these seeds with 95 %% intervals;"
                                    " table1: the saturation search over these seeds (default 1-3);"
                                    " twinbot-ocean: the runs per MAC and channel model (default 1-10)")
    ap.add_argument("--profile", choices=("default", "original", "original-ackwait"), default="default",
                    help="twinbot, table1: 'original' = the original experiment's set-up: framing and Aqua-Sim's"
                         " MAC header (+10 B on DATA, headerBytes), 500 B FIFO, no retry limit, unicast"
                         " support/buoy, Aqua-Sim's S-FAMA rules; 'original-ackwait': and its S-FAMA ACK wait"
                         " (docs/paper-twinbot.md)")
    ap.add_argument("--traffic", choices=("paper", "control"), default=None,
                    help="hil-formation: 'paper' (default) = the control frames plus the Sec. 3.2 image flows, as the"
                         " paper states; 'control' = the control frames only (the lighter variant)")
    ap.add_argument("--reading", default=None,
                    help="phy-layer: how to read the paper's '1500 bps' (docs/paper-phy-layer.md): 'stated' (default),"
                         " 'original-app', 'modem-1500'")
    ap.add_argument("--workers", type=int, default=1, help="twinbot --seeds: worker processes")
    ap.set_defaults(fn=run)


def run(a: argparse.Namespace) -> int:
    if a.name != "hil-formation" and (a.duration is not None or a.virtual or a.speed is not None):
        raise UserError("uwsimnet experiment: --duration, --speed and --virtual apply to hil-formation only")
    if a.duration is not None and not 0 < a.duration < 1e6:
        raise UserError("uwsimnet experiment: --duration: seconds, a number > 0")
    lo, hi = SPEED_RANGE
    if a.speed is not None and (a.virtual or not lo <= a.speed <= hi):
        raise UserError(f"uwsimnet experiment: --speed: a number from {lo:g} to {hi:g}, for the real-time run")
    if a.traffic is not None and a.name != "hil-formation":
        raise UserError("uwsimnet experiment: --traffic applies to hil-formation only")
    if a.reading is not None and a.name != "phy-layer":
        raise UserError("uwsimnet experiment: --reading applies to phy-layer only")
    if a.seeds is not None and a.name == "hil-formation":
        raise UserError("uwsimnet experiment: --seeds applies to phy-layer, twinbot and table1")
    if a.profile != "default" and a.name not in ("twinbot", "table1"):
        raise UserError("uwsimnet experiment: --profile applies to twinbot and table1")
    if a.profile != "default" and a.name == "twinbot" and a.seeds is not None:
        raise UserError("uwsimnet experiment: twinbot --seeds runs the default profile only"
                        " (table1 --profile original --seeds N gives intervals with the original's set-up)")
    out = Path(a.out or f"out/{a.name}")
    if a.seeds is not None and a.name == "twinbot":
        return _twinbot_seeds(a, out)
    if a.name == "twinbot-ocean":                # the acoustic group in a thermocline (issue #37)
        from ..experiments import twinbot_ocean
        twinbot_ocean.run(out, seeds=parse_seeds(a.seeds or "1-10"))
        print((out / "summary.md").read_text())
        print(f"figures and traces in {out}/")
        return 0
    if a.name == "table1":                       # the saturation search of Table 1 (issue #16)
        from ..experiments import table1
        table1.run(out, seeds=parse_seeds(a.seeds or "1-3"), profile=a.profile)
        print((out / "summary.md").read_text())
        return 0
    kw: dict[str, object] = {} if a.duration is None else {"duration": a.duration}
    if a.speed is not None:
        kw["speed"] = a.speed
    if a.seeds is not None:
        kw["seeds"] = parse_seeds(a.seeds)
    if a.traffic is not None:
        kw["traffic"] = a.traffic
    if a.reading is not None:
        from ..experiments.phy_layer import READINGS
        if a.reading not in READINGS:
            raise UserError(f"uwsimnet experiment: --reading: one of {', '.join(READINGS)}, got {a.reading!r}")
        kw["reading"] = a.reading
    if a.name == "phy-layer":
        from ..experiments import phy_layer as experiment
    elif a.name == "hil-formation" and a.virtual:
        from ..experiments import hil_formation as experiment
    elif a.name == "hil-formation":
        from ..experiments import hil_realtime as experiment
    else:
        from ..experiments import twinbot as experiment
        kw["profile"] = a.profile

    def interrupt(*_: object) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, interrupt)     # like Ctrl-C: the child processes are stopped, not orphaned
    try:
        experiment.run(out, **kw)
    except RuntimeError as e:                    # a child process failed: its log tail says why
        print(f"uwsimnet experiment: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:                    # child processes were stopped on the way out
        print("uwsimnet experiment: interrupted", file=sys.stderr)
        return 130
    print((out / "summary.md").read_text())
    print(f"figures and traces in {out}/")
    return 0

