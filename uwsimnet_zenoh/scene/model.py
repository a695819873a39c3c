"""The scene as plain, validated data (pydantic), in SI units.

The XML speaks the original's units (milliseconds, bits per second); the loader converts once, so that
nothing past this module ever wonders whether a delay is in ms or s.  Every element keeps the source
line it came from so that errors found later (unknown flow source, duplicate address) still point at
`file:line`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from ..kernel.frame import BROADCAST
from .ros2_link import LinkSpec

if TYPE_CHECKING:
    from ..phy.acoustic import AcousticChannelParams
    from ..phy.ocean import Bathymetry, SoundSpeedProfile
# phy.acoustic is imported by the acoustic models' methods: a scene without acoustic devices never needs it
# (start-up time)


class _Model(BaseModel):
    # defer_build: a model's validator is built when it is first used, not at import; a run builds only
    # those of the elements its scene has (~30 ms of a `uwsimnet run`'s start-up)
    model_config = ConfigDict(extra="forbid", frozen=True, defer_build=True)
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


class ModelSpec(_Model):
    """`channelModel` of a channel: a channel model by name (built-in, entry point of group
    `uwsimnet.channel_models`, or `module:Class`) with its parameters (docs/channel-models.md)."""

    name: str
    params: dict[str, str] = Field(default_factory=dict)


# ---------------------------------------------------------------------------------------------------
# Acoustic physics (AcousticCommsChannel / AcousticCommsDevice); docs/acoustic.md, docs/scene-format.md
# Defined before the models holding them, so that every model is built once, by its class statement (no
# failed first build and model_rebuild: start-up time)
# ---------------------------------------------------------------------------------------------------
Modulation = Literal["bpsk", "bfsk_coherent", "bfsk_noncoherent", "dpsk", "bpsk_rayleigh"]
"""Keys of `phy.acoustic.MODULATIONS` (bit error rate formulas)."""


class AcousticChannelSpec(_Model):
    """The water of an `AcousticCommsChannel`, its ambient noise and its interference rule (SI units)."""

    bandwidth_hz: float = Field(default=4096.0, gt=0)
    """Receiver band, Hz, for devices that give neither a bandwidth nor a preset (legacy, default 4096)."""
    temperature_c: float = Field(default=25.0, ge=-5, le=50)
    salinity_ppt: float = Field(default=35.0, ge=0, le=50)
    depth_m: float = Field(default=0.0, ge=0, le=12_000)
    ph: float = Field(default=8.0, gt=0, lt=14)
    spreading_k: float = Field(default=1.5, gt=0, le=4)
    absorption: Literal["thorp", "francois-garrison"] | float = "thorp"
    """Thorp (1967), Francois-Garrison (1982, uses T, S, depth, pH) or a constant in dB/km."""
    shipping: float = Field(default=0.5, ge=0, le=1)
    wind_mps: float = Field(default=0.0, ge=0, le=60)
    noise_level_db: float | None = None
    """Fixed in-band noise level, dB re 1 uPa (legacy noiseLvl; replaces the Wenz/Coates model)."""
    noise_psd_db: float | None = None
    """Fixed noise spectral density, dB re 1 uPa^2/Hz (replaces the Wenz/Coates model)."""
    sound_speed_mps: float | None = Field(default=None, gt=0)
    """Fixed sound speed, m/s, instead of Mackenzie (1981) at (temperature, salinity, depth)."""
    interference: Literal["binary", "sinr"] = "binary"
    """binary: any overlap loses both frames (as a CustomCommsChannel); sinr: capture by minimum SINR."""
    sinr_threshold_db: float | None = None
    """sinr mode: a frame that overlapped others survives iff its minimum SINR >= this (ns-3 UanPhyGen
    default: 8 dB); None: PER from the SINR with the sender's modulation."""
    capture: Literal["any", "first"] = "any"
    """sinr mode: any = any frame whose SINR suffices is received; first = a receiver locks onto the first
    frame whose SINR at its arrival exceeds acquire_threshold_db and misses every frame that arrives
    while it receives that one (ns-3 UanPhyGen)."""
    acquire_threshold_db: float = 10.0
    """capture first: SINR at arrival needed to lock onto a frame, dB (ns-3 UanPhyGen RxThreshold)."""

    def params(self, spreading_k: float | None = None) -> AcousticChannelParams:
        """This water as physics (`spreading_k` overrides the channel's, for a device's K)."""
        from ..phy.acoustic import AcousticChannelParams  # noqa: PLC0415 - see the imports

        return AcousticChannelParams(
            temperature_c=self.temperature_c, salinity_ppt=self.salinity_ppt, depth_m=self.depth_m, ph=self.ph,
            spreading_k=self.spreading_k if spreading_k is None else spreading_k, absorption=self.absorption,
            shipping=self.shipping, wind_mps=self.wind_mps, noise_psd_db=self.noise_psd_db,
            noise_level_db=self.noise_level_db, sound_speed_mps=self.sound_speed_mps)

    @field_validator("absorption")
    @classmethod
    def _absorption_nonnegative(cls, a: str | float) -> str | float:
        if not isinstance(a, str) and (a < 0 or a != a or a == float("inf")):
            raise ValueError(f"must be thorp, francois-garrison or a number >= 0 (dB/km), got {a:g}")
        return a

    @model_validator(mode="after")
    def _threshold_needs_sinr(self) -> AcousticChannelSpec:
        if self.sinr_threshold_db is not None and self.interference != "sinr":
            raise ValueError("sinrThreshold needs interference sinr")
        if self.capture != "any" and self.interference != "sinr":
            raise ValueError("capture first needs interference sinr")
        return self


class AcousticDeviceSpec(_Model):
    """The modem of an `AcousticCommsDevice`: a preset and/or explicit physics (SI units).

    Anything not given comes from the preset, else from the defaults of the original's AcousticROSCommsDevice
    (25 kHz, 0.2818 W) and the channel (bandwidth); the bit rate is `Device.bitrate`.
    """

    preset: str | None = None
    """A key of `phy.acoustic.PRESETS` (e.g. "evologics-s2cr-18-34")."""
    carrier_khz: float | None = Field(default=None, gt=0, le=1000)
    bandwidth_hz: float | None = Field(default=None, gt=0)
    source_level_db: float | None = Field(default=None, gt=0, lt=300)
    """dB re 1 uPa @ 1 m."""
    power_w: float | None = Field(default=None, gt=0)
    """Radiated acoustic power, W: SL = 170.8 + 10 log10(P)."""
    modulation: Modulation | None = None
    bit_error_rate: float | None = Field(default=None, ge=0, le=1)
    """Legacy bitErrorRate: a fixed BER replacing the physics one (interference still uses the physics)."""
    spreading_k: float | None = Field(default=None, gt=0, le=4)
    """Legacy K: spreading exponent of this transmitter's signal, instead of the channel's."""
    directivity_index_db: float = 0.0
    implementation_loss_db: float = 0.0
    margin_db: float | None = None
    """Receiver margin against noise, dB (None: the preset's, 0 without a preset)."""

    @field_validator("preset")
    @classmethod
    def _known_preset(cls, name: str | None) -> str | None:
        if name is None:
            return name
        from ..phy.acoustic import PRESETS  # noqa: PLC0415 - see the imports

        if name not in PRESETS:
            raise ValueError(f"unknown preset {name!r} (known: {', '.join(sorted(PRESETS))})")
        return name

    @model_validator(mode="after")
    def _one_level(self) -> AcousticDeviceSpec:
        if self.source_level_db is not None and self.power_w is not None:
            raise ValueError("give either a source level or a power, not both")
        return self


# ---------------------------------------------------------------------------------------------------
# The scene: channels, devices on vehicles, flows
# ---------------------------------------------------------------------------------------------------
class Channel(_Model):
    """`CustomCommsChannel`: propagation delay = min_prop_s + prop_s_per_m * distance."""

    id: int
    prop_s_per_m: float = Field(default=0.66667e-3, ge=0)
    min_prop_s: float = Field(default=0.0, ge=0)
    acoustic: AcousticChannelSpec | None = None
    """Set for an `AcousticCommsChannel`: its water, noise and interference rule.  Unless given explicitly,
    prop_s_per_m is then 1 / sound speed (Mackenzie or the fixed soundSpeed)."""
    model: ModelSpec | None = None
    """`<channelModel>`: the model every transmitter on this channel uses; None: each device's default."""

    @model_validator(mode="before")
    @classmethod
    def _acoustic_delay(cls, data: object) -> object:
        if isinstance(data, dict) and data.get("acoustic") is not None and "prop_s_per_m" not in data:
            try:
                spec = AcousticChannelSpec.model_validate(data["acoustic"])
            except ValueError:
                return data      # the field's own validation reports it
            data = {**data, "prop_s_per_m": 1.0 / spec.params().sound_speed()}
        return data


class Device(_Model):
    """`CustomCommsDevice`: a modem on a vehicle.  The same checks hold for a scene file and for a device
    added at runtime (control `add_device`): finite numbers, minimum distance not above the maximum."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False, defer_build=True)

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
    tx_framing: str | None = None
    """`txPacketBuilder/className`: the dccomms framing of what this device sends (phy.framing.builder
    name); the framed size goes on air.  None: no framing (payload + headerBytes on air)."""
    rx_framing: str | None = None
    """`rxPacketBuilder/className`: the framing the device's applications read (default: tx_framing)."""
    acoustic: AcousticDeviceSpec | None = None
    """Set for an `AcousticCommsDevice`: its loss model comes from the acoustic physics (phy.acoustic) and
    `error` is not used.  Unless given explicitly, bitrate is then the preset's bit rate."""

    @model_validator(mode="before")
    @classmethod
    def _acoustic_bitrate(cls, data: object) -> object:
        if isinstance(data, dict) and data.get("acoustic") is not None and "bitrate" not in data:
            try:
                spec = AcousticDeviceSpec.model_validate(data["acoustic"])
            except ValueError:
                return data
            from ..phy.acoustic import PRESETS  # noqa: PLC0415 - see the imports

            rate = PRESETS[spec.preset].bitrate_bps if spec.preset is not None else None
            if rate is not None:
                data = {**data, "bitrate": rate}
        return data

    @field_validator("address")
    @classmethod
    def _not_broadcast(cls, a: int) -> int:
        if a == BROADCAST:
            raise ValueError("address 255 is the broadcast address")
        return a

    @model_validator(mode="after")
    def _distances(self) -> Device:
        if self.min_distance > self.max_distance:
            raise ValueError(f"min_distance {self.min_distance:g} is larger than max_distance"
                             f" {self.max_distance:g}")
        return self

    @property
    def half_duplex(self) -> bool:
        return self.tx_channel == self.rx_channel

    @property
    def default_model(self) -> str:
        """The channel model the device uses where its channel names none (phy.registry)."""
        return "expression" if self.acoustic is None else "acoustic"


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
    ros_pose: str | None = None           # under --ros2, for poseSource zenoh: odom:TOPIC | pose:TOPIC | tf:FRAME
    devices: tuple[Device, ...] = ()
    ros2_link: LinkSpec | None = None     # <ros2Link>: this robot's ROS 2 topics across its modem (--ros2)

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


class Environment(_Model):
    """`<environment>`: the water of the scene (docs/ocean.md): origin, sound-speed profile, bathymetry, seabed."""

    origin: tuple[float, float] | None = None
    """(latitude, longitude), degrees WGS-84, of the local frame's origin (x east, y north, z up)."""
    profile: tuple[tuple[float, float], ...] = ((0.0, 1500.0),)
    """Sound speed: (depth m, speed m/s) points, linear in between."""
    profile_name: str = "isovelocity"
    bathymetry: Literal["flat", "slope", "grid"] = "flat"
    depth_m: float = Field(default=100.0, gt=0)
    """Water depth at the origin (flat, slope), m."""
    gradient: tuple[float, float] = (0.0, 0.0)
    """slope: depth change per metre east and north."""
    grid_file: str | None = None
    seabed_speed_mps: float = Field(default=1600.0, gt=0)
    seabed_density: float = Field(default=1.8, gt=0)
    """g/cm^3"""
    seabed_attenuation: float = Field(default=0.8, ge=0)
    """dB per wavelength"""

    def sound_speed(self) -> SoundSpeedProfile:
        from ..phy.ocean import SoundSpeedProfile  # noqa: PLC0415 - see the imports

        return SoundSpeedProfile(self.profile, self.profile_name)

    def seafloor(self) -> Bathymetry:
        from ..phy.ocean import Bathymetry  # noqa: PLC0415 - see the imports

        if self.bathymetry == "grid" and self.grid_file is not None:
            return Bathymetry.read_grid(self.grid_file)
        return Bathymetry(self.bathymetry, self.depth_m, self.gradient)


class Scene(_Model):
    name: str = "scene"
    source: str = "<memory>"
    simulation: Simulation = Field(default_factory=Simulation)
    tracing: Tracing = Field(default_factory=Tracing)
    channels: tuple[Channel, ...] = ()
    vehicles: tuple[Vehicle, ...] = ()
    flows: tuple[Flow, ...] = ()
    environment: Environment | None = None

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
