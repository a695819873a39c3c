"""The channel model "ocean" (docs/ocean.md): a straight path through the scene's water, solved with both
ends moving, with the device's own loss model (its rateErrorModel or acoustic physics) at the distance the
sound travelled.

Per receiver, at the transmission's first bit t0 (sender at p_s with velocity v_s, receiver at p_r with v_r):
    c      the harmonic mean of the environment's sound-speed profile between the two depths (no
           environment: 1 / the channel's propTimeIncPerMeter)
    tau    the wavefront, leaving p_s at t0, meets the receiver at p_r + v_r tau (phy.ocean.intercept_delay)
    delay  minPropTime + tau
    PER    the device's built-in model at the path length c tau
    D      (c - v_r.u) / (c - v_s.u), u from p_s to the receiver at arrival (phy.ocean.doppler_factor)
    lost   if `dopplerTolerance` (m/s) is given and the radial speed |v_s.u - v_r.u| exceeds it (a modem
           that cannot track that much Doppler: the frame is lost, reason prop)
Refraction, multipath and shadow zones are not modelled here (Bellhop's work, docs/ocean.md).
"""

from __future__ import annotations

import math
from typing import Any

from .models import Answer, ChannelModel, ModelContext, Query
from .ocean import doppler_factor, intercept_delay


class OceanModel(ChannelModel):
    """Motion during flight over a straight path in the scene's water; loss by the device's own model."""

    family = "ocean"

    def __init__(self, params: Any, ctx: ModelContext) -> None:
        self.base = ctx.base
        self.min_prop_s = float(getattr(ctx.channel, "min_prop_s", 0.0))
        env = ctx.environment
        self.profile = env.sound_speed() if env is not None else None
        per_m = float(getattr(ctx.channel, "prop_s_per_m", 0.0))
        if self.profile is None and not per_m > 0:
            raise ValueError("needs a sound speed: an <environment> or a propTimeIncPerMeter > 0")
        self.c = 1.0 / per_m if per_m > 0 else math.nan
        self.reports_power = bool(self.base.reports_power)
        tol = params.get("dopplerTolerance")
        self.tolerance = math.inf if tol is None else float(tol)
        if not self.tolerance > 0:
            raise ValueError(f"dopplerTolerance must be > 0 m/s, got {tol}")

    def speed(self, z_tx: float, z_rx: float) -> float:
        """The path's sound speed, m/s, between two heights z (m, up; depth = -z)."""
        if self.profile is None:
            return self.c
        return self.profile.mean_speed(max(0.0, -z_tx), max(0.0, -z_rx))

    def answer(self, q: Query) -> Answer:
        tx = q.sender
        delays: list[float] = []
        paths: list[float] = []
        dopplers: list[float] = []
        for rx in q.receivers:
            c = self.speed(tx.position[2], rx.position[2])
            tau = intercept_delay(tx.position, rx.position, rx.velocity, c)
            at = [p + v * tau for p, v in zip(rx.position, rx.velocity, strict=True)]
            delays.append(self.min_prop_s + tau)
            paths.append(c * tau)
            dopplers.append(doppler_factor(tx.position, at, tx.velocity, rx.velocity, c))
        base = self.base
        per = base.losses(paths, q.size) if base.by_distance else base.answer(q).per
        if self.tolerance < math.inf:
            per = [1.0 if self._radial(tx, rx, d) > self.tolerance else float(p)
                   for p, rx, d in zip(per, q.receivers, delays, strict=True)]
        return Answer(per, delays, None, dopplers)

    def _radial(self, tx: Any, rx: Any, delay: float) -> float:
        """|v_s.u - v_r.u|, m/s: the closing (or opening) speed along the path."""
        tau = delay - self.min_prop_s
        at = [p + v * tau for p, v in zip(rx.position, rx.velocity, strict=True)]
        d = [a - b for a, b in zip(at, tx.position, strict=True)]
        n = math.sqrt(sum(x * x for x in d)) or 1.0
        return abs(sum((vs - vr) * x / n for vs, vr, x in zip(tx.velocity, rx.velocity, d, strict=True)))

    # a SINR channel: the base model's powers (at the straight distance at the first bit)
    def received_power(self, distance_m: Any) -> Any:
        return self.base.received_power(distance_m)

    @property
    def noise_power(self) -> float:
        return self.base.noise_power

    def per_from_sinr(self, sinr_db: float, size_bytes: int) -> Any:
        return self.base.per_from_sinr(sinr_db, size_bytes)
