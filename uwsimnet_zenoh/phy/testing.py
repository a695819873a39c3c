"""Drive a channel model with no channel, no modem and no scene: geometry in, answers out.

    from uwsimnet_zenoh.phy import testing
    h = testing.Harness("mypkg.fading:Rician", {"K": "4"})      # a model by name or class, on a fake device
    r = h.reception((800.0, 0.0, -10.0), size=64)              # one receiver: a phy.models.Reception
    a = h.answer([(500.0, 0, 0), (900.0, 0, 0)], size=64)       # the vector call the channel makes
    p = h.delivery((800.0, 0, 0), frames=2000, size=64)        # fraction delivered, drawn as the channel does
    assert h.check() == []                                      # the port's contract, at a few geometries

The model is built as the engine's build step builds it (`from_context(params, ModelContext)`, parameters
nobody reads refused) for a device you describe with keywords (`bitrate`, `expr`/`unit` of its
rateErrorModel, `address`), on a channel (`prop_s_per_m`, `min_prop_s`) in an `environment`
(scene.model.Environment, or None); the positions and velocities reach it through a real `PoseTable`, as in a run.
docs/channel-models.md shows a whole plug-in tested this way.
"""

from __future__ import annotations

import math
import random
from collections.abc import Mapping, Sequence
from types import SimpleNamespace
from typing import Any

from ..kernel.frame import Frame
from ..mobility.trajectory import PoseTable
from .error import RateErrorModel
from .models import Answer, ChannelModel, ModelContext, Query, Reception
from .registry import resolve

Vec = tuple[float, float, float]
ORIGIN: Vec = (0.0, 0.0, 0.0)


class Harness:
    """One channel model for one (fake) transmitting device."""

    def __init__(self, model: str | type[ChannelModel] | ChannelModel, params: Mapping[str, str] | None = None,
                 *, bitrate: float = 1000.0, expr: str = "0", unit: str = "packet", address: int = 1,
                 seed: int = 1, prop_s_per_m: float = 1 / 1500, min_prop_s: float = 0.0,
                 environment: Any = None) -> None:
        self.device = SimpleNamespace(dccomms_id="tx", address=address, bitrate=float(bitrate),
                                      error=SimpleNamespace(expr=expr, unit=unit), acoustic=None)
        self.channel = SimpleNamespace(id=0, model=None, acoustic=None, prop_s_per_m=prop_s_per_m,
                                       min_prop_s=min_prop_s)
        self.ctx = ModelContext(self.device, self.channel, seed,
                                {"expression": lambda: RateErrorModel(expr, unit)}, "expression",  # type: ignore[arg-type]
                                environment)
        self.draws = random.Random(seed + 1).random
        """The loss draws of `delivery` (the channel draws from the sender's own stream alike)."""
        if isinstance(model, ChannelModel):
            self.model = model
            return
        cls = resolve(model) if isinstance(model, str) else model
        given = dict(params or {})
        read: set[str] = set()

        class _Params(dict):
            def get(self, key, default=None):  # noqa: ANN001, ANN201
                read.add(key)
                return super().get(key, default)

            def __getitem__(self, key):  # noqa: ANN001, ANN204
                read.add(key)
                return super().__getitem__(key)

        self.model = cls.from_context(_Params(given), self.ctx)
        unknown = set(given) - read - set(cls.params_known)
        if unknown:
            raise ValueError(f"unknown parameter(s) {', '.join(sorted(unknown))}")

    def answer(self, receivers: Sequence[Sequence[float]], *, tx: Sequence[float] = ORIGIN, size: int = 64,
               t: float = 0.0, tx_velocity: Sequence[float] = ORIGIN,
               rx_velocities: Sequence[Sequence[float]] | None = None) -> Answer:
        """What the channel asks at a transmission's first bit: every receiver at once."""
        poses = PoseTable(["tx"] + [f"rx{i}" for i in range(len(receivers))])
        vel = rx_velocities or [ORIGIN] * len(receivers)
        for name, p, v in [("tx", tx, tx_velocity)] + [(f"rx{i}", r, vel[i]) for i, r in enumerate(receivers)]:
            poses.set_external(name)
            poses.update(name, t, p, v)
        dist = [math.dist(tx, r) for r in receivers]
        frame = Frame(self.device.address, 2, 0, size, size)
        ans = self.model.answer(Query(t, frame, dist, list(range(len(receivers))), poses, 0,
                                      list(range(1, len(receivers) + 1))))
        return ans

    def reception(self, rx: Sequence[float], **kw: Any) -> Reception:
        """One receiver, through the vector call: a `Reception`."""
        a = self.answer([rx], **kw)
        return Reception(float(a.per[0]), None if a.delay is None else float(a.delay[0]),
                         None if a.level_db is None else float(a.level_db[0]))

    def delivery(self, rx: Sequence[float], frames: int = 1000, **kw: Any) -> float:
        """The fraction of `frames` transmissions delivered to `rx`, each lost with the answered probability
        (a fresh answer per frame, so a fading model draws anew)."""
        ok = sum(self.draws() >= float(self.answer([rx], **kw).per[0]) for _ in range(frames))
        return ok / frames

    def check(self, size: int = 64) -> list[str]:
        """The port's contract at a few geometries: one value per receiver, probabilities in [0, 1], delays
        finite and >= 0 (or nan: the straight path).  Returns the problems found (empty: none)."""
        problems: list[str] = []
        rxs = [(1.0, 0.0, 0.0), (100.0, 0.0, -5.0), (1000.0, 50.0, -20.0), (5000.0, 0.0, 0.0)]
        for n in (1, len(rxs)):
            try:
                a = self.answer(rxs[:n], size=size)
            except Exception as e:  # noqa: BLE001 - reported, not raised: a checklist
                problems.append(f"answer raised {type(e).__name__}: {e}")
                continue
            for what, vals in (("per", a.per), ("delay", a.delay), ("level_db", a.level_db)):
                if vals is not None and len(vals) != n:
                    problems.append(f"{what}: {len(vals)} values for {n} receivers")
            for p in a.per:
                if not 0.0 <= float(p) <= 1.0:
                    problems.append(f"per {float(p)!r} not in [0, 1]")
            for d in a.delay or ():
                if not (math.isnan(float(d)) or 0.0 <= float(d) < math.inf):
                    problems.append(f"delay {float(d)!r} s is not finite and >= 0")
        return problems
