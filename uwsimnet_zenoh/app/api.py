"""`uwsimnet_zenoh.run`: one virtual-time run as a function a notebook or a campaign worker calls.

    import uwsimnet_zenoh as uw
    r = uw.run("scenes/paper/twinbot-aloha.xml", seed=3, duration=120, overrides={"device.*.mac": "sfama"})
    r.flows["leader-follower"]["throughput"], r.channels[1]["collisions"], r.row()

The metrics are those of `uwsimnet report` (analysis.metrics, one definition); `trace=True` keeps the
records too, `trace_path=` writes the trace file `uwsimnet run --trace` writes.  The scene's tracing class
(`netTracingScript className`, the paper's NetTracing scripts) is made afresh for every run and sees every
event, as in `uwsimnet run`, so a user's callbacks run in campaigns too; one that raises ends the call with
UserError after the run (its metrics would be of a run whose tracing stopped half-way).  A run is
reproducible from (scene, overrides, seed): the same arguments give the same result in any process, in any
order.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

from ..analysis import analyse
from ..analysis.channels import channel_metrics
from ..assembly.outputs import Outputs
from ..errors import UserError
from ..scene.model import Scene
from .checks import build_network, plugin_failure, tracing_sink
from .overrides import apply
from .virtual import load_scene_file

FLOW_METRICS = ("throughput", "offered", "efficiency", "delivery_ratio", "delay_mean", "delay_median", "delay_p95",
                "jitter", "enqueued", "sent", "delivered", "fifo_drops", "left_in_fifo")
"""Per-flow numbers a result row carries (`flow.<name>.<metric>`)."""


def _queue_metrics(m: dict[str, Any]) -> dict[str, Any]:
    """`fifo_drops` (frames refused by a full FIFO) and `left_in_fifo` (frames enqueued that by the end were
    neither on air nor dropped: still waiting at the modem).  The delivery ratio counts only frames that went
    on air, so a MAC that cannot carry its load shows 1.0 there and its backlog only here."""
    drops = m.get("drops") or {}
    fifo = int(drops.get("fifo", 0))
    left = m["enqueued"] - m["unique_sent"] - fifo - int(drops.get("stopped", 0))
    return {**m, "fifo_drops": fifo, "left_in_fifo": max(0, left)}


@lru_cache(maxsize=1)
def version() -> str:
    """The code a run ran: the package's version and a hash of its sources (uwsimnet_zenoh and the wire's
    uwsimnet_gli, every .py file by path and bytes), so a campaign re-runs, rather than reuses, its rows after
    any change of the code (the version string alone stays 0.1.0 from commit to commit; ns-3 SEM records the
    commit for the same reason).  Part of every campaign run's key."""
    from importlib.metadata import PackageNotFoundError  # noqa: PLC0415
    from importlib.metadata import version as _v  # noqa: PLC0415

    import uwsimnet_gli  # noqa: PLC0415

    try:
        base = _v("uwsimnet-zenoh")
    except PackageNotFoundError:  # pragma: no cover - running from a source tree
        base = "0+unknown"
    pkgs = (Path(__file__).resolve().parents[1], Path(uwsimnet_gli.__file__).resolve().parent)
    return f"{base}+src.{sources_digest(pkgs)[:12]}"


def sources_digest(packages: Iterable[Path]) -> str:
    """sha256 of the .py files under `packages`, by path (relative to each package's parent) and bytes."""
    h = hashlib.sha256()
    for pkg in packages:
        for f in sorted(pkg.rglob("*.py")):
            h.update(f"{pkg.name}/{f.relative_to(pkg).as_posix()}\0".encode())
            h.update(f.read_bytes())
    return h.hexdigest()


@dataclass
class RunResult:
    """What one run gives back: per-flow and per-channel metrics, the run's identity, and its trace if asked."""

    scene: str
    seed: int
    duration: float
    overrides: dict[str, Any]
    flows: dict[str, dict[str, Any]]
    channels: dict[int, dict[str, Any]]
    events: int
    conservation_violations: int
    trace: list[dict[str, Any]] | None = field(default=None, repr=False)

    def row(self) -> dict[str, Any]:
        """One flat row: `flow.<name>.<metric>` (`uwsimnet report`'s, and the FIFO's two) and
        `channel.<id>.<metric>` columns."""
        out: dict[str, Any] = {"events": self.events, "conservation_violations": self.conservation_violations}
        for name, m in sorted(self.flows.items()):
            m = _queue_metrics(m)
            for k in FLOW_METRICS:
                out[f"flow.{name}.{k}"] = m.get(k)
        for ch, m in sorted(self.channels.items()):
            for k, v in m.items():
                out[f"channel.{ch}.{k}"] = v
        return out


def _scene(scene: Scene | str | os.PathLike[str]) -> Scene:
    return scene if isinstance(scene, Scene) else load_scene_file(os.fspath(scene))


def run(scene: Scene | str | os.PathLike[str], *, seed: int | None = None, duration: float | None = None,
        overrides: Mapping[str, Any] | None = None, trace: bool = False,
        trace_path: str | os.PathLike[str] | None = None) -> RunResult:
    """Run `scene` (a Scene or a file) in virtual time and return its metrics (see the module docstring)."""
    sc = apply(_scene(scene), overrides)
    if duration is not None and not (isinstance(duration, int | float) and 0 < duration < float("inf")):
        raise UserError(f"duration must be a number of seconds > 0, got {duration!r}")
    if duration is not None:
        duration = float(duration)              # 20 and 20.0: the same run, the same trace
    net = build_network(sc, seed=seed, duration=duration)
    plugin = tracing_sink(sc)
    records: list[dict[str, Any]] = []
    net.tracer.add(records.append)
    meta = net.meta()
    with Outputs(net, meta, trace_path, metrics=False, plugin=plugin) as out:
        net.run()
        out.finish(net.end)
    failed = plugin_failure(plugin)
    if failed is not None:
        raise UserError(f"{sc.source}:{sc.tracing.line}: {failed}")
    a = analyse(records, meta)
    return RunResult(scene=sc.name, seed=net.seed, duration=net.duration, overrides=dict(overrides or {}),
                     flows={n: m.to_dict() for n, m in a.flows.items()},
                     channels=channel_metrics(records, meta), events=net.sched.events_run,
                     conservation_violations=a.conservation.total,
                     trace=records if trace else None)


def scene_digest(path: str | os.PathLike[str]) -> str:
    """sha256 of a scene file's bytes: part of a campaign run's key."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def run_key(scene_hash: str, overrides: Mapping[str, Any], seed: int, ver: str,
            duration: float | None = None) -> str:
    """The identity of one run: (scene bytes, overrides, seed, version, duration) -> a short stable hex key.
    The duration is part of it: a sweep with another --duration into the same folder runs again."""
    blob = json.dumps({"scene": scene_hash, "overrides": dict(sorted(overrides.items())), "seed": seed,
                       "version": ver, "duration": None if duration is None else float(duration)},
                      sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:20]
