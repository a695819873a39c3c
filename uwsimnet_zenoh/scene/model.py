"""The scene as plain, validated data (pydantic), in SI units.

The XML speaks the original's units (milliseconds, bits per second); the loader converts once, so that
nothing past this module ever wonders whether a delay is in ms or s.  Every element keeps the source
line it came from so that errors found later (unknown flow source, duplicate address) still point at
`file:line`.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

BROADCAST = 255
"""Destination address that every modem on the channel accepts (as in dccomms)."""


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    line: int = 0
    """Source line in the scene file (0 when built in code)."""


class ErrorModel(_Model):
    """`rateErrorModel`: an error rate as a function of distance `m` (metres)."""

    unit: Literal["bit", "byte", "packet"] = "bit"
    expr: str = "0"


class MacSpec(_Model):
    """`macProtocol`: a name from the registry (case-insensitive) or `module:Class`, with its parameters."""

    name: str = "none"
    params: dict[str, str] = Field(default_factory=dict)


class Channel(_Model):
    """`CustomCommsChannel`: propagation delay = min_prop_s + prop_s_per_m * distance."""

    id: int
    prop_s_per_m: float = Field(default=0.66667e-3, ge=0)
    min_prop_s: float = Field(default=0.0, ge=0)


class Device(_Model):
    """`CustomCommsDevice`: a modem on a vehicle."""

    dccomms_id: str
    address: int = Field(ge=0, le=65535)
    """Integer MAC address (dccomms `mac`); 255 is broadcast and cannot be a modem's address."""
    tx_channel: int
    rx_channel: int
    bitrate: float = Field(default=1000.0, gt=0)
    tx_fifo_bytes: int = Field(default=500_000, ge=0)
    intrinsic_tx_s: float = Field(default=0.0, ge=0)
    intrinsic_rx_s: float = Field(default=0.0, ge=0)
    jitter_tx_s: float = Field(default=0.0, ge=0)
    jitter_rx_s: float = Field(default=0.0, ge=0)
    max_distance: float = Field(default=99_999_999.0, ge=0)
    min_distance: float = Field(default=0.0, ge=0)
    error: ErrorModel = Field(default_factory=ErrorModel)
    mac: MacSpec = Field(default_factory=MacSpec)
    header_bytes: int = Field(default=0, ge=0)
    max_frame_bytes: int = Field(default=2048, gt=0)

    @field_validator("address")
    @classmethod
    def _not_broadcast(cls, a: int) -> int:
        if a == BROADCAST:
            raise ValueError("address 255 is the broadcast address")
        return a

    @property
    def half_duplex(self) -> bool:
        return self.tx_channel == self.rx_channel


class Waypoint(_Model):
    t: float = Field(ge=0)
    x: float
    y: float
    z: float


class Vehicle(_Model):
    name: str
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    trajectory: tuple[Waypoint, ...] = ()
    pose_source: Literal["scene", "zenoh"] = "scene"
    pose_rate_hz: float = Field(default=10.0, gt=0)
    devices: tuple[Device, ...] = ()

    @field_validator("trajectory")
    @classmethod
    def _increasing(cls, wps: tuple[Waypoint, ...]) -> tuple[Waypoint, ...]:
        for a, b in zip(wps, wps[1:], strict=False):
            if b.t <= a.t:
                raise ValueError(f"waypoint times must increase (t={b.t} after t={a.t})")
        return wps


class Flow(_Model):
    """A traffic source acting like an app: `size` payload bytes from device `src` to address `dst`."""

    name: str
    src: str
    dst: int = Field(ge=0, le=65535)
    size: int = Field(gt=0)
    interval: float = Field(gt=0)
    arrival: Literal["periodic", "poisson"] = "periodic"
    start: float = Field(default=0.0, ge=0)
    stop: float | None = None


class Tracing(_Model):
    """`netTracingScript`: a user callback class (`module:Class`) and a trace file."""

    class_name: str | None = None
    log_to_file: str | None = None


class Simulation(_Model):
    duration: float | None = Field(default=None, gt=0)
    seed: int = 0
    clock: Literal["virtual", "realtime"] = "virtual"
    world: str | None = None


class Scene(_Model):
    name: str = "scene"
    source: str = "<memory>"
    simulation: Simulation = Field(default_factory=Simulation)
    tracing: Tracing = Field(default_factory=Tracing)
    channels: tuple[Channel, ...] = ()
    vehicles: tuple[Vehicle, ...] = ()
    flows: tuple[Flow, ...] = ()

    @property
    def world(self) -> str:
        return self.simulation.world or self.name

    def devices(self) -> list[tuple[Vehicle, Device]]:
        return [(v, d) for v in self.vehicles for d in v.devices]

    def end_time(self) -> float:
        """Duration if given, else the last flow stop or trajectory point (at least 1 s)."""
        if self.simulation.duration is not None:
            return self.simulation.duration
        ends = [f.stop for f in self.flows if f.stop is not None]
        ends += [v.trajectory[-1].t for v in self.vehicles if v.trajectory]
        return max(ends, default=60.0) + 1.0
