"""Campaigns: scenes x parameter values x seeds, run in worker processes or on a Dask cluster, resumable.

    c = Campaign(scenes=["a.xml"], sets={"device.*.mac": ["aloha", "sfama"]}, seeds=range(1, 11),
                 out=Path("out/sweep"), workers=2)
    execute(c)                 # runs what is missing, then writes results.parquet, summary.md, figures

Every run is keyed by (scene bytes, overrides, seed, version, duration) (`api.run_key`); its row is written to
`OUT/rows/<key>.json` as soon as it finishes (atomically), so a campaign stopped by Ctrl-C or a crash resumes
with only the missing runs.  With `keep_traces` the run's trace goes beside it, `OUT/rows/<key>.jsonl.gz`:
the worker returns it compressed (gzip without a time stamp, so the file is the same wherever it ran) and
the driver writes it, as it writes the rows, so remote Dask workers need no shared folder.  Each run makes
the scene's tracing class afresh (api.run), in whichever process runs it.  A run that raises is recorded
with its error (status `error`) and the others go on; runs are deterministic, so a failed run is not retried.
Where a run executes (1 process, N processes, a Dask cluster) never changes its row: rows hold no wall-clock
data.
"""

from __future__ import annotations

import gzip
import io
import itertools
import json
import os
import shutil
import sys
import tempfile
import tomllib
import traceback
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import UserError
from .api import run, run_key, scene_digest, version
from .checks import tracing_sink
from .grids import precompute
from .overrides import apply
from .virtual import load_scene_file

MAX_SEEDS = 100_000
"""At most this many seeds per setting: a campaign, not a typo of ten digits (which would build the list first)."""


def parse_seeds(text: str) -> list[int]:
    """`1-20`, `1,3,5` or `1-5,10`: the seeds (integers >= 0), in order, without repeats."""
    out: list[int] = []
    for part in str(text).split(","):
        lo, dash, hi = part.strip().partition("-")
        if not lo.isdigit() or (dash and not hi.isdigit()) or (dash and int(hi) < int(lo)):
            raise UserError(f"--seeds {text!r}: expected N, A-B (A <= B) or a comma list of them")
        if dash and int(hi) - int(lo) + 1 + len(out) > MAX_SEEDS:
            raise UserError(f"--seeds {text!r}: more than {MAX_SEEDS} runs per setting; give fewer seeds")
        out += range(int(lo), int(hi) + 1) if dash else [int(lo)]
    seen: set[int] = set()
    return [x for x in out if not (x in seen or seen.add(x))]


def parse_set(text: str) -> tuple[str, list[str]]:
    """`PATH=V1,V2,...` -> (path, [values])."""
    path, eq, values = text.partition("=")
    if not eq or not path.strip() or not values.strip():
        raise UserError(f"--set {text!r}: expected PATH=V1,V2,... (docs/campaigns.md)")
    return path.strip(), [v.strip() for v in values.split(",")]


@dataclass
class Campaign:
    scenes: list[str]
    sets: dict[str, list[Any]] = field(default_factory=dict)
    seeds: list[int] = field(default_factory=lambda: [1])
    out: Path = Path("out/sweep")
    duration: float | None = None
    workers: int = 1
    scheduler: str | None = None
    """None: local worker processes; "local": a Dask LocalCluster; anything else: a Dask scheduler address."""
    keep_traces: bool = False
    """Keep each run's trace as OUT/rows/<key>.jsonl.gz (a run with a row but no trace runs again)."""


def load_campaign(path: str | os.PathLike[str]) -> Campaign:
    """A campaign file (TOML): scenes, [set] PATH = [values], seeds, duration, workers, scheduler, out."""
    p = Path(path)
    try:
        doc = tomllib.loads(p.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as e:
        raise UserError(f"{p}: cannot read campaign file: {e}") from None
    except tomllib.TOMLDecodeError as e:
        raise UserError(f"{p}: {e}") from None
    known = {"scenes", "scene", "set", "seeds", "duration", "workers", "scheduler", "out", "keep_traces"}
    bad = sorted(set(doc) - known)
    if bad:
        raise UserError(f"{p}: unknown key(s) {', '.join(bad)} (allowed: {', '.join(sorted(known))})")
    scenes = doc.get("scenes", doc.get("scene"))
    if isinstance(scenes, str):
        scenes = [scenes]
    if not isinstance(scenes, list) or not scenes or not all(isinstance(s, str) for s in scenes):
        raise UserError(f"{p}: scenes must be a file or a list of files")
    base = p.parent
    sets = doc.get("set", {})
    if not isinstance(sets, dict) or not all(isinstance(v, list) and v for v in sets.values()):
        raise UserError(f"{p}: [set] must map override paths to non-empty lists of values")
    seeds = doc.get("seeds", [1])
    seeds = parse_seeds(seeds) if isinstance(seeds, str) else seeds
    if not isinstance(seeds, list) or not seeds or not all(isinstance(s, int) for s in seeds):
        raise UserError(f"{p}: seeds must be a list of integers or a string like \"1-20\"")
    keep = doc.get("keep_traces", False)
    if not isinstance(keep, bool):
        raise UserError(f"{p}: keep_traces must be true or false")
    return Campaign(scenes=[str((base / s) if not Path(s).is_absolute() else s) for s in scenes],
                    sets={k: list(v) for k, v in sets.items()}, seeds=seeds,
                    out=base / str(doc.get("out", "out/sweep")), duration=doc.get("duration"),
                    workers=int(doc.get("workers", 1)), scheduler=doc.get("scheduler"), keep_traces=keep)


# -- the runs ----------------------------------------------------------------------------------------
def specs(c: Campaign) -> list[dict[str, Any]]:
    """Every run of the campaign, checked before anything runs: overrides applied to each scene once, the
    scene's tracing class loaded once (it must import here as in the workers)."""
    if c.duration is not None and not (isinstance(c.duration, int | float) and 0 < c.duration < float("inf")):
        raise UserError(f"duration must be a number of seconds > 0, got {c.duration!r}")
    ver = version()
    out = []
    names = list(c.sets)
    combos = list(itertools.product(*(c.sets[n] for n in names))) if names else [()]
    for scene in c.scenes:
        sc = load_scene_file(scene)
        digest = scene_digest(scene)
        tracing_sink(sc)                            # a tracing class that does not load: file:line, nothing run
        for combo in combos:
            overrides = dict(zip(names, combo, strict=True))
            apply(sc, overrides)                    # refuses a bad path or value now, nothing run
            for seed in c.seeds:
                out.append({"key": run_key(digest, overrides, seed, ver, c.duration), "scene": scene,
                            "scene_name": sc.name, "overrides": overrides, "seed": seed, "version": ver,
                            "duration": c.duration, "keep_trace": c.keep_traces})
    return out


def run_one(spec: Mapping[str, Any]) -> dict[str, Any]:
    """A campaign worker's job: one run to one row (never raises: a failure is a row with its error).  With
    `keep_trace` the row carries the run's trace, gzip-compressed, under TRACE (the driver writes it)."""
    row: dict[str, Any] = {"key": spec["key"], "scene": spec["scene_name"], "seed": spec["seed"],
                           "version": spec["version"]}
    row.update({f"param.{k}": str(v) for k, v in spec["overrides"].items()})
    try:
        with tempfile.TemporaryDirectory(prefix="uwsimnet-run-") as tmp:
            path = Path(tmp) / "trace.jsonl" if spec.get("keep_trace") else None
            r = run(spec["scene"], seed=spec["seed"], duration=spec["duration"], overrides=spec["overrides"],
                    trace_path=path)
            if path is not None:
                row[TRACE] = _gzipped(path)
    except Exception as e:  # noqa: BLE001 - recorded, the campaign goes on
        last = traceback.extract_tb(e.__traceback__)[-1] if e.__traceback__ else None
        where = f" ({Path(last.filename).name}:{last.lineno})" if last else ""
        row.update(status="error", error=f"{type(e).__name__}: {' '.join(str(e).split())}{where}")
        return row
    row.update(status="ok", error=None, duration=r.duration)
    row.update(r.row())
    return row


def _gzipped(path: Path) -> bytes:
    """The file gzip-compressed without a time stamp or a name (the same bytes wherever it is made), streamed
    so that only the compressed trace is held in memory."""
    buf = io.BytesIO()
    with open(path, "rb") as src, gzip.GzipFile(fileobj=buf, mode="wb", mtime=0) as gz:
        shutil.copyfileobj(src, gz, 1 << 20)
    return buf.getvalue()


TRACE = "_trace"
"""The key of a row that carries its run's compressed trace from a worker to the driver (not a column)."""


def _write_row(rows_dir: Path, row: dict[str, Any]) -> None:
    trace = row.pop(TRACE, None)
    if trace is not None:                           # the trace first: a row without its trace runs again
        tmp = rows_dir / f".{row['key']}.trace.tmp"
        tmp.write_bytes(trace)
        os.replace(tmp, trace_file(rows_dir, row["key"]))
    tmp = rows_dir / f".{row['key']}.tmp"
    tmp.write_text(json.dumps(row, sort_keys=True, allow_nan=False, default=_finite))
    os.replace(tmp, rows_dir / f"{row['key']}.json")


def _finite(x: Any) -> Any:
    raise TypeError(f"not JSON: {x!r}")


def trace_file(rows_dir: Path, key: str) -> Path:
    return rows_dir / f"{key}.jsonl.gz"


def done_keys(rows_dir: Path, keep_traces: bool = False) -> set[str]:
    """Keys with a row (and, when traces are kept, with the trace of a successful run too)."""
    keys = {p.stem for p in rows_dir.glob("*.json")}
    if not keep_traces:
        return keys
    traced = {k for k in keys if trace_file(rows_dir, k).is_file()}
    return traced | {k for k in keys - traced                      # a failed run has no trace to keep
                     if json.loads((rows_dir / f"{k}.json").read_text()).get("status") != "ok"}


def _local(jobs: list[dict[str, Any]], workers: int) -> Iterable[dict[str, Any]]:
    if workers <= 1:
        for j in jobs:
            yield run_one(j)
        return
    import multiprocessing  # noqa: PLC0415
    from concurrent.futures import ProcessPoolExecutor, as_completed  # noqa: PLC0415

    with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn")) as ex:
        precompute(jobs, ex)                    # Bellhop grids first, on these workers (app/grids.py)
        futs = [ex.submit(run_one, j) for j in jobs]
        try:
            for f in as_completed(futs):
                yield f.result()
        except BaseException:
            for f in futs:
                f.cancel()
            raise


def _dask(jobs: list[dict[str, Any]], workers: int, address: str) -> Iterable[dict[str, Any]]:
    try:
        from dask.distributed import Client, LocalCluster, as_completed  # noqa: PLC0415
    except ImportError:
        raise UserError("--scheduler needs dask.distributed: pip install 'uwsimnet-zenoh[campaigns]'") from None
    cluster = None
    try:
        if address == "local":
            cluster = LocalCluster(n_workers=max(1, workers), threads_per_worker=1, processes=True,
                                   dashboard_address=None)
            client = Client(cluster)
        else:
            client = Client(address, timeout="10s")
    except (OSError, TimeoutError) as e:
        if cluster is not None:
            cluster.close()
        raise UserError(f"--scheduler {address}: cannot connect ({' '.join(str(e).split())})") from None
    try:
        precompute(jobs, client.get_executor(pure=False))   # Bellhop grids first, on the cluster (app/grids.py)
        futs = client.map(run_one, jobs, pure=False)
        for f in as_completed(futs):
            yield f.result()
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def execute(c: Campaign, on_progress: Callable[[int, int, dict[str, Any]], None] | None = None) -> dict[str, Any]:
    """Run what is missing of `c`, then write the results (see the module docstring); returns the report."""
    all_specs = specs(c)
    rows_dir = c.out / "rows"
    rows_dir.mkdir(parents=True, exist_ok=True)
    have = done_keys(rows_dir, c.keep_traces)
    todo = [s for s in all_specs if s["key"] not in have]
    total = len(todo)
    source = _dask(todo, c.workers, c.scheduler) if c.scheduler else _local(todo, c.workers)
    for n, row in enumerate(source, 1):
        _write_row(rows_dir, row)
        if on_progress is not None:
            on_progress(n, total, row)
    from ..analysis.campaign import write_results  # noqa: PLC0415 - pyarrow/matplotlib only now

    keys = list(dict.fromkeys(s["key"] for s in all_specs))          # the campaign's order, each run once
    rows = [json.loads((rows_dir / f"{k}.json").read_text()) for k in keys]
    report = write_results(rows, c.out, list(c.sets), multi_scene=len(c.scenes) > 1)
    report.update(ran=total, reused=len(all_specs) - total, runs=len(all_specs))
    return report


def plain_progress(n: int, total: int, row: dict[str, Any]) -> None:
    """Progress as plain lines (piped output, CI logs)."""
    state = "ok" if row.get("status") == "ok" else f"ERROR {row.get('error')}"
    params = " ".join(f"{k[6:]}={v}" for k, v in row.items() if k.startswith("param."))
    # One write, newline included: print() writes the end separately, and a Ctrl-C between the two writes left
    # the interrupt message glued to a progress line.
    sys.stderr.write(f"sweep: {n}/{total} {row['scene']} seed {row['seed']} {params} {state}\n")
    sys.stderr.flush()
