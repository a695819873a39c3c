"""`uwsimnet sweep`: a campaign of runs over parameter values and seeds (docs/campaigns.md).

    uwsimnet sweep SCENE [SCENE ...] --set PATH=V1,V2 [--set ...] --seeds 1-20 [--workers N]
                   [--scheduler local|ADDRESS] [--duration S] [--keep-traces] --out DIR
    uwsimnet sweep CAMPAIGN.toml [--workers N] [--scheduler ...] [--keep-traces] [--out DIR]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..app.campaign import Campaign, done_keys, execute, load_campaign, parse_seeds, parse_set, plain_progress, specs
from ..errors import UserError


def add_commands(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sweep", help="a campaign: scenes x --set values x seeds, on worker processes or Dask",
                       description=__doc__.split("\n")[0])
    p.add_argument("scenes", nargs="+", metavar="SCENE", help="scene files (more than one: an axis), or one .toml")
    p.add_argument("--set", action="append", default=[], metavar="PATH=V1,V2",
                   help="override values to sweep (docs/campaigns.md lists the paths)")
    p.add_argument("--seeds", help="seeds: N, A-B or a comma list (default 1)")
    p.add_argument("--duration", type=float, help="simulated seconds of every run (default: the scene's)")
    p.add_argument("--workers", type=int, help="worker processes (default 1; with --scheduler local: Dask workers)")
    p.add_argument("--scheduler", help="run on Dask: 'local' (a LocalCluster) or a scheduler address tcp://HOST:8786")
    p.add_argument("--out", help="output folder (default out/sweep; re-running resumes it)")
    p.add_argument("--keep-traces", action="store_true",
                   help="keep every run's trace as OUT/rows/<key>.jsonl.gz (campaign file: keep_traces = true)")
    p.add_argument("--dry-run", action="store_true", help="list the runs (and which have a row already); run none")
    p.set_defaults(fn=run)


def run(a: argparse.Namespace) -> int:
    if len(a.scenes) == 1 and a.scenes[0].endswith(".toml"):
        if a.set or a.seeds or a.duration is not None:
            raise UserError("uwsimnet sweep: with a campaign file, put --set/--seeds/--duration in the file")
        c = load_campaign(a.scenes[0])
        if c.scheduler not in (None, "local") and a.scheduler != c.scheduler:
            # Dask's handshake exchanges pickles: a file someone sent must not open that by itself
            raise UserError(f"{a.scenes[0]}: scheduler {c.scheduler!r}: a campaign file does not connect to a"
                            f" scheduler on its own; confirm with --scheduler {c.scheduler} (or --scheduler local)")
    else:
        sets: dict[str, list[str]] = {}
        for s in a.set:
            path, values = parse_set(s)
            if path in sets:
                raise UserError(f"--set {path}: given twice")
            sets[path] = values
        c = Campaign(scenes=list(a.scenes), sets=sets, seeds=parse_seeds(a.seeds or "1"), duration=a.duration)
    for s in c.scenes:
        if not Path(s).is_file():
            raise UserError(f"{s}: no such scene file")
    if a.workers is not None:
        c.workers = a.workers
    if a.scheduler is not None:
        c.scheduler = a.scheduler
    if a.out is not None:
        c.out = Path(a.out)
    if a.keep_traces:
        c.keep_traces = True
    if not 1 <= c.workers <= 512:
        raise UserError(f"--workers {c.workers}: expected 1..512")
    if c.duration is not None and not 0 < c.duration < float("inf"):
        raise UserError("--duration must be a number of seconds > 0")
    if a.dry_run:
        done = done_keys(c.out / "rows", c.keep_traces)
        runs = specs(c)
        for r in runs:
            params = " ".join(f"{k}={v}" for k, v in r["overrides"].items())
            state = "done" if r["key"] in done else "todo"
            print(f"{r['key']} {state} {r['scene']} seed {r['seed']} {params}".rstrip())
        print(f"uwsimnet sweep: {len(runs)} runs, {sum(r['key'] in done for r in runs)} with a row in {c.out}/rows",
              file=sys.stderr)
        return 0
    try:
        report = _execute(c)
    except KeyboardInterrupt:
        kept = len(list((c.out / "rows").glob("*.json")))
        print(f"uwsimnet sweep: interrupted; {kept} finished run(s) kept in {c.out}/rows; the same command"
              " resumes with the missing runs only", file=sys.stderr)
        return 130
    print((c.out / "summary.md").read_text())
    print(f"uwsimnet sweep: {report['runs']} runs ({report['ran']} run now, {report['reused']} from an earlier"
          f" sweep, {report['failed']} failed); results in {c.out}/", file=sys.stderr)
    return 1 if report["failed"] else 0


def _execute(c: Campaign) -> dict:
    if sys.stderr.isatty():
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

        with Progress(TextColumn("[bold]sweep"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                      transient=True) as bar:
            task = bar.add_task("runs", total=None)

            def show(n: int, total: int, row: dict) -> None:
                bar.update(task, completed=n, total=total)
            return execute(c, on_progress=show)
    return execute(c, on_progress=plain_progress)
