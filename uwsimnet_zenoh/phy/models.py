"""The channel-model port (as ns-3's UanPropModel / WOSS): what a receiver sees of a transmission.

A model is built per transmitting device (the engine's build step gives it the device, its channel and its
parameters) and asked once per transmission, for every receiver the channel needs an outcome for, at the
transmission's first bit:

    answer(q: Query) -> Answer          the vector call (the channel's per-frame path)
    reception(tx, rx, distance, t, frame)  the per-pair call; a simple plug-in implements only this and the
                                        default `answer` loops over the receivers

An `Answer` gives, per receiver in the query's order, the probability that the frame is lost ("prop"; the
channel draws it from the sender's loss stream, so a run stays reproducible from (scene, seed)), and
optionally the propagation delay (s; None: the channel's straight path, min_prop + d * per_m) and the
received level (dB).  The channel still owns range (min/maxDistance), collisions and duplex.

A channel that decides collisions by SINR (capture) also needs a model's `received_power`, `noise_power`
and `per_from_sinr` for every listener; `DistanceModel` subclasses that have them (phy.acoustic) declare
`reports_power = True` and the build step refuses other models on such a channel.

Why a plain-Python base with no compiler rules: the channel is compiled, the models are leaves it calls
(docs/channel-models.md).
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any, NamedTuple

if TYPE_CHECKING:
    from ..kernel.frame import Frame
    from ..mobility.trajectory import PoseTable

__all__ = ["Answer", "ChannelModel", "DistanceModel", "ModelContext", "Query", "Reception", "State"]

Vec = tuple[float, float, float]


class State(NamedTuple):
    """One end of a link at the first bit: position (x, y, z m; z up) and velocity (m/s)."""

    position: Vec
    velocity: Vec = (0.0, 0.0, 0.0)


class Reception(NamedTuple):
    """What `reception` returns for one receiver."""

    per: float
    """Probability in [0, 1] that the frame is lost (reason "prop")."""
    delay: float | None = None
    """Propagation delay, s (None: the channel's straight path)."""
    level_db: float | None = None
    """Received level, dB (re 1 uPa for acoustic models), if the model has one."""
    doppler: float | None = None
    """Doppler factor f_received / f_sent, if the model has one."""


class Answer(NamedTuple):
    """What `answer` returns: one value per receiver of the query, in its order."""

    per: Sequence[float]
    delay: Sequence[float] | None = None
    level_db: Sequence[float] | None = None
    doppler: Sequence[float] | None = None


class Query:
    """One transmission's question: the receivers (channel slots), their distances at the first bit, the
    time and the frame.  Positions and velocities are computed only when a model asks for them."""

    __slots__ = ("t", "frame", "size", "distances", "slots", "_poses", "_sender", "_vehicles")

    def __init__(self, t: float, frame: Frame, distances: Sequence[float], slots: Sequence[int],
                 poses: PoseTable | None = None, sender: int = -1, vehicles: Sequence[int] = ()) -> None:
        self.t = t
        self.frame = frame
        self.size = frame.size
        """Bytes on air."""
        self.distances = distances
        """Straight-line distance to each receiver, m (a list on a small channel, else a numpy array)."""
        self.slots = slots
        self._poses = poses
        self._sender = sender
        self._vehicles = vehicles

    def _state(self, v: int) -> State:
        poses = self._poses
        if poses is None:
            raise ValueError("this query carries distances only (no pose table)")
        return State(poses.points(self.t)[v], poses.velocity(v, self.t))

    @property
    def sender(self) -> State:
        return self._state(self._sender)

    @property
    def receivers(self) -> list[State]:
        return [self._state(self._vehicles[s]) for s in self.slots]


class ModelContext:
    """What the build step hands a model (`ChannelModel.from_context`): the transmitting device and its
    channel (scene specs: `device.dccomms_id`, `device.bitrate`, `channel.id`...), a random stream of its
    own, and the built-in models of this device (`builtin("expression")`, `builtin("acoustic")`, `base`:
    the one it would use without a `<channelModel>`), which a model may wrap."""

    def __init__(self, device: Any, channel: Any, seed: int, builtins: Mapping[str, Callable[[], ChannelModel]],
                 default: str, environment: Any = None, positions: Sequence[Sequence[float]] = ()) -> None:
        self.device = device
        self.channel = channel
        self.environment = environment
        """The scene's `<environment>` (scene.model.Environment: origin, sound speed, bathymetry), or None."""
        self.positions = tuple(tuple(float(v) for v in p) for p in positions)
        """Where the scene puts the device's vehicle (x, y, z): its position, or its trajectory's waypoints; empty
        when unknown (a model that needs the sender's place before a run, as bellhop over a slope, reads it)."""
        self.seed = seed
        self.default = default
        self._builtins = builtins
        self._random: random.Random | None = None

    @property
    def random(self) -> random.Random:
        """A random stream for this model, from (run seed, device): reproducible, shared with nothing."""
        if self._random is None:
            self._random = random.Random(self.seed)
        return self._random

    def builtin(self, name: str) -> ChannelModel:
        """The device's built-in model `name` (raises ValueError with the reason if it does not fit)."""
        make = self._builtins.get(name)
        if make is None:
            raise ValueError(f"no built-in channel model {name!r}")
        return make()

    @property
    def base(self) -> ChannelModel:
        return self.builtin(self.default)


class ChannelModel:
    """Base of every channel model.  Subclass it and implement `reception` (simple) or `answer` (fast), then
    name the class in a channel's `<channelModel><name>` as `module:Class` or as an entry point of group
    `uwsimnet.channel_models` (docs/channel-models.md)."""

    __slots__ = ()

    by_distance = False
    """True if the loss depends on the distance and the frame size only: the channel then calls
    `losses(distances, size)` and builds no `Query` (a `DistanceModel`; the built-ins' per-frame path)."""
    reports_power = False
    """True if the model gives `received_power`, `noise_power` and `per_from_sinr` (a SINR channel needs them)."""
    params_known: tuple[str, ...] = ()
    """Parameters read after construction (the build step refuses parameters nobody reads)."""

    @classmethod
    def from_context(cls, params: Any, ctx: ModelContext) -> ChannelModel:
        """The model for one transmitting device: `params` the scene's parameters (str values, a mapping),
        `ctx` the device, its channel, a random stream and the built-in models.  Default: cls(params, ctx)."""
        return cls(params, ctx)  # type: ignore[call-arg]

    def reception(self, tx: State, rx: State, distance: float, t: float, frame: Frame) -> Reception:
        """One receiver's reception of `frame` sent at `t` (override this, or `answer`)."""
        raise NotImplementedError(f"{type(self).__name__} implements neither reception() nor answer()")

    def answer(self, q: Query) -> Answer:
        """Every receiver of `q` at once; by default `reception` for each of them."""
        tx = q.sender
        out = [self.reception(tx, rx, float(d), q.t, q.frame) for rx, d in zip(q.receivers, q.distances, strict=True)]
        per = [_probability(r.per) for r in out]
        delay = None if all(r.delay is None for r in out) else [_delay(r.delay, d) for r, d in
                                                                  zip(out, q.distances, strict=True)]
        level = None if all(r.level_db is None for r in out) else [
            math.nan if r.level_db is None else float(r.level_db) for r in out]
        doppler = None if all(r.doppler is None for r in out) else [
            math.nan if r.doppler is None else float(r.doppler) for r in out]
        return Answer(per, delay, level, doppler)

    # -- what a SINR channel also asks (reports_power = True; phy.acoustic's links have it) --------------
    def received_power(self, distance_m: Any) -> Any:
        """Received power (linear) at each distance: the interference a frame adds at every listener."""
        raise NotImplementedError(f"{type(self).__name__} reports no received power")

    @property
    def noise_power(self) -> float:
        """Noise power at a receiver, linear, in the unit of `received_power`."""
        raise NotImplementedError(f"{type(self).__name__} reports no noise power")

    def per_from_sinr(self, sinr_db: float, size_bytes: int) -> Any:
        """PER of a frame received at `sinr_db` (interference treated as noise)."""
        raise NotImplementedError(f"{type(self).__name__} gives no PER from SINR")

    def per(self, distance_m: Any, size_bytes: int) -> Any:
        """PER at each distance on a horizontal line at the surface, both ends still, at t = 0 (the view's
        curves): one `answer` with the sender at the origin and a receiver at each distance along x."""
        import numpy as np

        from ..kernel.frame import Frame
        from ..mobility.trajectory import PoseTable

        d = np.atleast_1d(np.asarray(distance_m, dtype=float)).ravel()
        poses = PoseTable(["tx"] + [f"rx{i}" for i in range(len(d))])
        for i, x in enumerate(d.tolist()):
            poses.set_static(f"rx{i}", (x, 0.0, 0.0))
        f = Frame(0, 0, 0, int(size_bytes), int(size_bytes))
        n = len(d)
        ans = self.answer(Query(0.0, f, d.tolist(), list(range(n)), poses, 0, list(range(1, n + 1))))
        return np.array([float(p) for p in ans.per], dtype=float).reshape(np.shape(distance_m))


class DistanceModel(ChannelModel):
    """A model whose loss depends on the distance and the frame size only (`per(distances, size)`): the
    vector call is one `per` (the built-in rateErrorModel and acoustic models)."""

    __slots__ = ()

    family = ""
    """The built-in name of this model (phy.registry)."""

    @classmethod
    def from_context(cls, params: Any, ctx: ModelContext) -> ChannelModel:
        """A built-in named in `<channelModel>`: the build step makes it from the device (ctx.builtin)."""
        return ctx.builtin(cls.family)

    by_distance = True

    def losses(self, distances: Sequence[float], size: int) -> Sequence[float]:
        """The loss probability at each distance for a frame of `size` bytes on air (default: `per`)."""
        return self.per(distances, size)

    def levels(self, distances: Sequence[float]) -> Sequence[float] | None:
        """The received level (dB) at each distance, or None if the model has none (default): the channel
        hands it on with each reception (kernel.rx), and the trace writes it (docs/trace-format.md)."""
        return None

    def answer(self, q: Query) -> Answer:
        return Answer(self.losses(q.distances, q.size), None, self.levels(q.distances))

    def reception(self, tx: State, rx: State, distance: float, t: float, frame: Frame) -> Reception:
        lv = self.levels([distance])
        return Reception(float(self.losses([distance], frame.size)[0]), None,
                         None if lv is None else float(lv[0]))


def _probability(p: float) -> float:
    p = float(p)
    if not 0.0 <= p <= 1.0:                     # nan fails both: a model that cannot say loses the frame
        raise ValueError(f"a channel model returned loss probability {p!r}, not in [0, 1]")
    return p


def _delay(v: float | None, d: float) -> float:
    if v is None:
        return math.nan                         # the channel's own straight path
    v = float(v)
    if not 0.0 <= v < math.inf:
        raise ValueError(f"a channel model returned propagation delay {v!r} s at {float(d):g} m")
    return v

