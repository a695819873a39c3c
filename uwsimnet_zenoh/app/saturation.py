"""The highest rate a flow sustains (what the paper's Table 1 calls "the maximum value allowed").

    r = saturate("link.xml", "a-to-b", seeds=[1, 2, 3], tolerance=0.05, max_delay=2.0)
    r.rate.mean, r.rate.half          # frames/s, mean and 95 % interval over the seeds

A rate is *sustained* in one run when the flow delivers at least (1 - tolerance) of what it offers and its
95th-percentile end-to-end delay stays under `max_delay` (a queue that grows fails the second test even
when the run ends before it overflows).  Per seed, the search brackets the largest sustained rate by
doubling from `low`, then bisects the bracket `steps` times; the result per seed is the lower end of the
final bracket (a rate that was sustained), and the seeds give the interval.  Other flows keep their rates
(`overrides` may change them), unless `together` names flows that scale with it: the paper set one rate
for all flows of a channel and protocol (e.g. the four explorers), so `together=["E1", "E2", "E3"]` with
flow "E0" probes every one of them at the same rate (frames/s, scaled by each flow's size so that all
offer the same B/s), and a rate is sustained only when every flow of the group sustains it.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from ..analysis.intervals import Interval, mean_ci
from ..errors import UserError
from ..scene.model import Scene
from .api import run
from .virtual import load_scene_file


@dataclass
class Probe:
    rate: float
    seed: int
    throughput_ratio: float | None
    delay_p95: float | None
    sustained: bool


@dataclass
class Saturation:
    flow: str
    rate: Interval
    """Frames/s: the largest sustained rate, mean and 95 % interval over the seeds."""
    per_seed: dict[int, float]
    size: int
    """Payload bytes per frame (rate x size = the flow's payload throughput at saturation, B/s)."""
    probes: list[Probe] = field(default_factory=list)

    @property
    def throughput(self) -> Interval:
        return Interval(self.rate.n, self.rate.mean * self.size,
                        None if self.rate.half is None else self.rate.half * self.size)


def sustained(scene: Scene, flow: str, rate: float, seed: int, *, tolerance: float, max_delay: float,
              duration: float | None, overrides: Mapping[str, Any],
              together: Mapping[str, float] | None = None) -> Probe:
    """One run at `rate` (frames/s of `flow`; each flow of `together` at rate x its factor).  The
    probe's ratio is the worst throughput/offered and its delay the worst p95 over the group."""
    group = {flow: 1.0, **(together or {})}
    ov = {**overrides, **{f"flow.{n}.rate": rate * k for n, k in group.items()}}
    r = run(scene, seed=seed, duration=duration, overrides=ov)
    ratios: list[float | None] = []
    p95s: list[float | None] = []
    for n in group:
        m = r.flows.get(n)
        if m is None:
            raise UserError(f"flow {n!r}: not in the run's metrics (flows: {', '.join(r.flows) or 'none'})")
        offered, thr = m.get("offered"), m.get("throughput")
        ratios.append(thr / offered if offered and thr is not None else None)
        p95s.append(m.get("delay_p95"))
    ratio = None if None in ratios else min(x for x in ratios if x is not None)
    p95 = None if None in p95s else max(x for x in p95s if x is not None)
    ok = ratio is not None and ratio >= 1.0 - tolerance and p95 is not None and p95 <= max_delay
    return Probe(rate, seed, ratio, p95, ok)


def saturate(scene: Scene | str | os.PathLike[str], flow: str, *, seeds: Sequence[int] = (1,),
             tolerance: float = 0.05, max_delay: float = 10.0, low: float = 0.01, steps: int = 12,
             max_rate: float = 1e4, duration: float | None = None,
             overrides: Mapping[str, Any] | None = None, together: Sequence[str] = ()) -> Saturation:
    sc = scene if isinstance(scene, Scene) else load_scene_file(os.fspath(scene))
    sizes = {f.name: f.size for f in sc.flows}
    for n in (flow, *together):
        if n not in sizes:
            raise UserError(f"flow {n!r}: no such flow (the scene has: {', '.join(sizes) or 'none'})")
    spec = next(f for f in sc.flows if f.name == flow)
    group = {n: spec.size / sizes[n] for n in together if n != flow}   # same B/s for every flow of the group
    if not (0 <= tolerance < 1 and max_delay > 0 and 0 < low < max_rate and steps >= 1):
        raise UserError("saturate: need 0 <= tolerance < 1, max_delay > 0, 0 < low < max_rate, steps >= 1")
    ov = dict(overrides or {})
    probes: list[Probe] = []
    per_seed: dict[int, float] = {}

    def test(rate: float, seed: int) -> bool:
        p = sustained(sc, flow, rate, seed, tolerance=tolerance, max_delay=max_delay, duration=duration,
                      overrides=ov, together=group)
        probes.append(p)
        return p.sustained

    for seed in seeds:
        lo, hi = low, low
        if not test(lo, seed):
            raise UserError(f"flow {flow!r}: not even {low:g} frames/s is sustained (seed {seed}); lower --low")
        while True:                                    # bracket: lo sustained, hi not
            hi = lo * 2
            if hi > max_rate:
                raise UserError(f"flow {flow!r}: still sustained at {lo:g} frames/s (raise max_rate)")
            if not test(hi, seed):
                break
            lo = hi
        for _ in range(steps):                         # geometric bisection: rates span decades
            mid = math.sqrt(lo * hi)
            if test(mid, seed):
                lo = mid
            else:
                hi = mid
        per_seed[seed] = lo
    iv = mean_ci(list(per_seed.values()))
    assert iv is not None
    return Saturation(flow, iv, per_seed, spec.size, probes)
