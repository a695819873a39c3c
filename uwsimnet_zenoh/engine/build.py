"""The build step (ns-3's helpers): a scene's device and channel specs become running parts.

`build_modem` makes one `phy.Modem` with its channel model (`build_channel_model`: the channel's
`<channelModel>` by name through phy.registry, else the device's default, the rateErrorModel expression or
the acoustic physics) and its MAC (`mac.resolve`), so models never build their collaborators.  This is
also the one place where an `AcousticCommsChannel` and an `AcousticCommsDevice` become numbers (`AcousticChannelParams`,
`AcousticModemParams`, the `AcousticLink` a modem uses as its loss model).  Sans-IO, numpy only.

Resolution of a device's parameters, first match wins:
    carrier     device frequency (kHz) > preset > 25 kHz (the original's AcousticROSCommsDevice default)
    bandwidth   device bandwidth > preset > the channel's bandwidth (legacy, default 4096 Hz)
    level       device sourceLevel or power > preset > 0.2818 W (the original's / Aqua-Sim's PT default)
    modulation  device > preset > bpsk
    margin      device > preset > 0 dB
    bit rate    always `Device.bitrate` (which defaults to the preset's)
    spreading   device K > channel spreading
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING, Any

from ..mac import Mac, resolve
from ..phy.error import RateErrorModel
from ..phy.models import ChannelModel
from ..phy.modem import Modem

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    from ..kernel.scheduler import Scheduler
    from ..phy.acoustic import AcousticChannelParams, AcousticLink, AcousticModemParams, FixedBerLink
    from ..phy.channel import Channel as PhyChannel
    from ..scene.model import AcousticChannelSpec, AcousticDeviceSpec, Channel, Device, Environment, MacSpec
    from ..trace.tracer import Tracer

__all__ = ["DEFAULT_CARRIER_KHZ", "DEFAULT_POWER_W", "BuildError", "FixedBerLink", "build_channel_model",
           "build_error_model", "build_modem",
           "channel_options", "channel_params", "default_bitrate", "make_mac", "modem_error_model",
           "modem_params", "prop_s_per_m", "sound_speed"]

DEFAULT_CARRIER_KHZ = 25.0
"""Carrier when neither the device nor a preset gives one (dccomms_ros AcousticROSCommsDevice default)."""
DEFAULT_POWER_W = 0.2818
"""Radiated power when neither the device nor a preset gives a level (the original's / Aqua-Sim's PT)."""

# phy.acoustic (the physics, numpy) is imported by the functions of acoustic devices: a scene without one
# never needs it (start-up time); `FixedBerLink` is still a name of this module


def __getattr__(name: str) -> Any:
    if name == "FixedBerLink":
        from ..phy.acoustic import FixedBerLink  # noqa: PLC0415 - see above

        return FixedBerLink
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def channel_params(spec: AcousticChannelSpec, spreading_k: float | None = None) -> AcousticChannelParams:
    """The physics of a channel spec (``spreading_k`` overrides the channel's, for a device's K)."""
    return spec.params(spreading_k)


def sound_speed(spec: AcousticChannelSpec) -> float:
    """Sound speed of the channel's water, m/s (fixed soundSpeed, else Mackenzie 1981)."""
    return channel_params(spec).sound_speed()


def prop_s_per_m(spec: AcousticChannelSpec) -> float:
    """Propagation delay per metre of the channel, s/m: 1 / sound speed."""
    return 1.0 / sound_speed(spec)


def default_bitrate(spec: AcousticDeviceSpec) -> float | None:
    """The bit rate a device gets when the scene gives none: its preset's (None without a preset)."""
    from ..phy.acoustic import PRESETS  # noqa: PLC0415 - see above

    return PRESETS[spec.preset].bitrate_bps if spec.preset is not None else None


def modem_params(dev: AcousticDeviceSpec, channel: AcousticChannelSpec, bitrate: float) -> AcousticModemParams:
    """The modem mode of a device spec on a channel, bit rate ``bitrate`` bit/s (see the module docstring)."""
    from ..phy.acoustic import PRESETS, AcousticModemParams  # noqa: PLC0415 - see above

    base = PRESETS.get(dev.preset) if dev.preset is not None else None
    if base is None:
        base = AcousticModemParams(name="custom", carrier_khz=DEFAULT_CARRIER_KHZ,
                                   bandwidth_hz=channel.bandwidth_hz, bitrate_bps=bitrate,
                                   power_w=DEFAULT_POWER_W)
    changes: dict = {"bitrate_bps": float(bitrate), "directivity_index_db": dev.directivity_index_db,
                     "implementation_loss_db": dev.implementation_loss_db}
    if dev.carrier_khz is not None:
        changes["carrier_khz"] = dev.carrier_khz
    if dev.bandwidth_hz is not None:
        changes["bandwidth_hz"] = dev.bandwidth_hz
    if dev.source_level_db is not None:
        changes.update(source_level_db=dev.source_level_db, power_w=None)
    elif dev.power_w is not None:
        changes.update(source_level_db=None, power_w=dev.power_w)
    if dev.modulation is not None:
        changes["modulation"] = dev.modulation
    if dev.margin_db is not None:
        changes["margin_db"] = dev.margin_db
    return replace(base, **changes)


def build_error_model(device: Device, channel: Channel) -> AcousticLink | FixedBerLink:
    """The loss model (``Modem.error``) of an acoustic device transmitting on ``channel``.

    Raises ValueError if the device or the channel is not acoustic."""
    from ..phy.acoustic import AcousticLink, FixedBerLink  # noqa: PLC0415 - see above

    dev, ch = device.acoustic, channel.acoustic
    if dev is None:
        raise ValueError(f"device {device.dccomms_id!r} is not an AcousticCommsDevice")
    if ch is None:
        raise ValueError(f"device {device.dccomms_id!r}: an AcousticCommsDevice needs an AcousticCommsChannel,"
                         f" channel {channel.id} is a CustomCommsChannel")
    link = AcousticLink(channel_params(ch, dev.spreading_k), modem_params(dev, ch, device.bitrate))
    return link if dev.bit_error_rate is None else FixedBerLink(link, dev.bit_error_rate)


def channel_options(channel: Channel) -> dict:
    """Keyword options of the simulator's `phy.channel.Channel` for a scene channel: its interference rule."""
    spec = channel.acoustic
    if spec is None or spec.interference != "sinr":
        return {}
    return {"sinr": True, "sinr_threshold_db": spec.sinr_threshold_db,
            "lock_first_db": spec.acquire_threshold_db if spec.capture == "first" else None}


def modem_error_model(device: Device, tx_channel: Channel,
                      rx_channel: Channel | None = None) -> AcousticLink | FixedBerLink:
    """The acoustic physics of a device transmitting on ``tx_channel`` (the built-in channel model
    "acoustic").  Raises ValueError with the reason if the device or a channel is not acoustic."""
    link = build_error_model(device, tx_channel)
    if rx_channel is not None and rx_channel.acoustic is None:
        raise ValueError(f"device {device.dccomms_id!r}: an AcousticCommsDevice needs an AcousticCommsChannel,"
                         f" channel {rx_channel.id} is a CustomCommsChannel")
    return link


def build_channel_model(device: Device, tx_spec: Channel, rx_spec: Channel, seed: int,
                        environment: Environment | None = None,
                        positions: Sequence[Sequence[float]] = ()) -> ChannelModel:
    """The channel model a device transmits with: its channel's `<channelModel>`, else the device's default
    (`Device.default_model`), made by the model's `from_context` (phy.models).  ValueError: one line."""
    from ..phy.models import ModelContext
    from ..phy.registry import resolve as resolve_model

    builtins = {"expression": lambda: RateErrorModel(device.error.expr, device.error.unit),
                "acoustic": lambda: modem_error_model(device, tx_spec, rx_spec)}
    ctx = ModelContext(device, tx_spec, seed, builtins, device.default_model, environment, positions)
    spec = tx_spec.model
    name = device.default_model if spec is None else spec.name
    cls = resolve_model(name)
    params = _ReadParams({} if spec is None else spec.params)
    try:
        model = cls.from_context(params, ctx)
    except ValueError as e:
        if spec is None:
            raise
        raise ValueError(f"channel model {name!r}: {e}") from None
    except Exception as e:  # noqa: BLE001 - a plug-in's constructor: one line, not a traceback
        raise ValueError(f"channel model {name!r} could not be built: {type(e).__name__}: {e}") from None
    if not isinstance(model, ChannelModel):
        raise ValueError(f"channel model {name!r}: from_context gave a {type(model).__name__}, not a ChannelModel")
    unknown = set(params) - params.read - set(getattr(cls, "params_known", ()))
    if unknown:
        known = sorted(params.read | set(getattr(cls, "params_known", ()))) or ["none"]
        raise ValueError(f"channelModel {name}: unknown parameter(s) {', '.join(sorted(unknown))}"
                         f" (it reads: {', '.join(known)})")
    if channel_options(tx_spec) and not model.reports_power:
        raise ValueError(f"channel {tx_spec.id} decides collisions by SINR, which needs the received power of"
                         f" every transmitter: channel model {name!r} reports none")
    return model


class BuildError(ValueError):
    """A device the build step cannot make (its MAC, its loss model), with the scene line to blame."""

    def __init__(self, msg: str, line: int = 0) -> None:
        super().__init__(msg)
        self.line = line


class _ReadParams(dict):
    """A MAC's parameters, noting which ones it looks at (to refuse the ones it does not know)."""

    def __init__(self, *a: object) -> None:
        super().__init__(*a)
        self.read: set[str] = set()

    def get(self, key, default=None):  # noqa: ANN001, ANN201
        self.read.add(key)
        return super().get(key, default)

    def __getitem__(self, key):  # noqa: ANN001, ANN204
        self.read.add(key)
        return super().__getitem__(key)

    def __contains__(self, key: object) -> bool:
        self.read.add(key)  # type: ignore[arg-type]
        return super().__contains__(key)


def make_mac(modem: Modem, spec: MacSpec) -> Mac:
    """The MAC a device's `<macProtocol>` names, built with its modem as the MAC's context.

    Parameters the MAC does not look at while it is built are refused (a misspelt `maxBackof` would
    otherwise silently run with the default); a MAC that reads parameters later declares them in a
    class attribute `params_known`.  Any failure of a plug-in's constructor is a one-line error."""
    cls = resolve(spec.name)
    params = _ReadParams(spec.params)
    try:
        mac = cls(modem, params)
    except ValueError:
        raise
    except Exception as e:  # noqa: BLE001 - a plug-in's constructor: one line, not a traceback
        raise ValueError(f"MAC protocol {spec.name!r} could not be built: {type(e).__name__}: {e}") from None
    unknown = set(spec.params) - params.read - set(getattr(cls, "params_known", ()))
    if unknown:
        known = sorted(params.read | set(getattr(cls, "params_known", ()))) or ["none"]
        raise ValueError(f"macProtocol {spec.name}: unknown parameter(s) {', '.join(sorted(unknown))}"
                         f" (it reads: {', '.join(known)})")
    return mac


def build_modem(cfg: Device, vehicle: str, vehicle_index: int, sched: Scheduler, tracer: Tracer,
                tx: PhyChannel, rx: PhyChannel, seeds: Callable[[str, str], int],
                tx_spec: Channel, rx_spec: Channel, environment: Environment | None = None,
                positions: Sequence[Sequence[float]] = ()) -> Modem:
    """One modem with its channel model and its MAC, listening on its rx channel (`positions`: where the scene
    puts its vehicle, for a model that needs it before the run)."""
    try:
        error = build_channel_model(cfg, tx_spec, rx_spec, seeds("channel", cfg.dccomms_id), environment,
                                    positions)
    except ValueError as e:
        line = tx_spec.model.line if tx_spec.model is not None else cfg.error.line or cfg.line
        raise BuildError(f"device {cfg.dccomms_id!r}: {e}", line) from None
    modem = Modem(cfg, vehicle, vehicle_index, sched, tracer, tx, rx, seeds, error)
    try:
        mac = make_mac(modem, cfg.mac)
    except ValueError as e:
        raise BuildError(f"device {cfg.dccomms_id!r}: {e}", cfg.mac.line or cfg.line) from None
    modem.attach_mac(mac)
    return modem
