"""The acoustic vocabulary: `AcousticCommsChannel` and `AcousticCommsDevice` (docs/acoustic.md)."""

from __future__ import annotations

import math
from collections.abc import Mapping

from .model import (
    AcousticChannelSpec,
    AcousticDeviceSpec,
    Channel,
    Device,
)
from .xml import (
    _ACOUSTIC_DEVICE_IGNORED,
    _ACOUSTIC_DEVICE_TAGS,
    _CHANNEL_IGNORED,
    _MODULATIONS,
    _NUMBER,
    XmlReader,
    _El,
    _Fields,
    _is_element,
    _ms_to_s,
    _show,
)


class AcousticVocabulary(XmlReader):
    """Mixin: acoustic channels and devices."""

    # --- acoustic physics (AcousticCommsChannel / AcousticCommsDevice; docs/acoustic.md) ----------------

    def acoustic_channel(self, el: _El) -> tuple[Channel, _El]:
        """An `AcousticCommsChannel`: a channel whose delay (1 / sound speed) and losses come from physics."""
        k = self.kids(el, single=(
            "id", "minPropTime", "bandwidth", "temperature", "salinity", "noiseLvl", "depth", "ph", "spreading",
            "absorption", "shipping", "wind", "noisePsd", "soundSpeed", "interference", "sinrThreshold",
            "capture", "acquireThreshold", "channelModel"),
            ignore=_CHANNEL_IGNORED)
        f = _Fields()
        id_el = self.need(k, "id")
        cid, raw = self.integer(id_el)
        f.set("id", cid, "id", id_el, raw)
        if (e := k.get("minPropTime")) is not None:
            _, raw = self.number(e)
            f.set("min_prop_s", _ms_to_s(raw), "minPropTime", e, raw)
        a = _Fields()
        for tag, field in (("bandwidth", "bandwidth_hz"), ("temperature", "temperature_c"),
                           ("salinity", "salinity_ppt"), ("depth", "depth_m"), ("ph", "ph"),
                           ("spreading", "spreading_k"), ("shipping", "shipping"), ("wind", "wind_mps"),
                           ("noisePsd", "noise_psd_db"), ("soundSpeed", "sound_speed_mps"),
                           ("sinrThreshold", "sinr_threshold_db"), ("acquireThreshold", "acquire_threshold_db")):
            if (e := k.get(tag)) is not None:
                v, raw = self.number(e)
                a.set(field, v, tag, e, raw)
        if (e := k.get("noiseLvl")) is not None:
            v, raw = self.number(e)
            if v != 0.0:   # the original's default 0 means "not set": the Wenz/Coates model applies
                a.set("noise_level_db", v, "noiseLvl", e, raw)
        if (e := k.get("absorption")) is not None:
            s = self.text(e)
            if s in ("thorp", "francois-garrison"):
                a.set("absorption", s, "absorption", e)
            elif _NUMBER.fullmatch(s) and math.isfinite(float(s)):
                a.set("absorption", float(s), "absorption", e, s)
            else:
                self.fail(e, f"absorption: expected thorp, francois-garrison or a number (dB/km), got {_show(s)}")
        if (e := k.get("interference")) is not None:
            a.set("interference", self.choice(e, ("binary", "sinr")), "interference", e)
        if (e := k.get("capture")) is not None:
            a.set("capture", self.choice(e, ("any", "first")), "capture", e)
        for tag in ("sinrThreshold", "capture", "acquireThreshold"):
            if (e := k.get(tag)) is not None and a.values.get("interference") != "sinr":
                self.fail(e, f"{tag}: needs <interference>sinr</interference>")
        if (e := k.get("acquireThreshold")) is not None and a.values.get("capture") != "first":
            self.fail(e, "acquireThreshold: needs <capture>first</capture>")
        f.set("acoustic", self.build(AcousticChannelSpec, el, a), "AcousticCommsChannel", el)
        if (e := k.get("channelModel")) is not None:
            f.set("model", self.channel_model(e), "channelModel", e)
            self.modelled.add(cid)
        return self.build(Channel, el, f), id_el

    def acoustic_device(self, el: _El) -> tuple[Device, dict[str, _El]] | None:
        """An `AcousticCommsDevice`, or None if it is disabled; also the elements cross-checks point at."""
        disable = [c for c in el if _is_element(c) and c.tag == "disable"]
        if len(disable) > 1:
            self.fail(disable[1], f"duplicate <disable> in <{el.tag}> (first at line {disable[0].sourceline})")
        if disable and self.integer(disable[0])[0] != 0:
            ids = [self.text(c) for c in el if _is_element(c) and c.tag == "dccommsId"]
            who = f" {ids[0]!r}" if ids and ids[0] else ""
            self.warn(el, f"<{el.tag}>{who} is disabled (<disable>), skipped")
            if ids and ids[0]:
                self.disabled.setdefault(ids[0], el.sourceline or 0)
            return None

        k = self.kids(el, single=_ACOUSTIC_DEVICE_TAGS, ignore=_ACOUSTIC_DEVICE_IGNORED)
        f, a = _Fields(), _Fields()
        els: dict[str, _El] = {"dccommsId": self.need(k, "dccommsId"), "mac": self.need(k, "mac")}
        if (e := k.get("channelId")) is not None:       # older UWSim-NET: one channel, half duplex
            given = [x for x in (k.get("txChannelId"), k.get("rxChannelId")) if x is not None]
            if given:
                self.fail(given[0], f"{given[0].tag}: give either <channelId> or <txChannelId>/<rxChannelId>,"
                                    " not both")
            els["txChannelId"] = els["rxChannelId"] = e
        else:
            els["txChannelId"], els["rxChannelId"] = self.need(k, "txChannelId"), self.need(k, "rxChannelId")
        f.set("dccomms_id", self.string(els["dccommsId"]), "dccommsId", els["dccommsId"])
        for tag, field in (("mac", "address"), ("txChannelId", "tx_channel"), ("rxChannelId", "rx_channel")):
            v, raw = self.integer(els[tag])
            f.set(field, v, els[tag].tag, els[tag], raw)

        sps, eff, rate = k.get("symbolsPerSecond"), k.get("codingEff"), k.get("bitrate")
        if rate is not None and (sps is not None or eff is not None):
            self.fail(rate, "bitrate: give either <bitrate> or <symbolsPerSecond>/<codingEff>, not both")
        if rate is not None:
            v, raw = self.number(rate)
            f.set("bitrate", v, "bitrate", rate, raw)
        elif sps is not None:
            v, raw = self.number(sps)
            ce = 1.0
            if eff is not None:
                ce, ce_raw = self.number(eff)
                if ce <= 0:
                    self.fail(eff, f"codingEff: must be greater than 0, got {ce_raw}")
            f.set("bitrate", v / ce, "symbolsPerSecond", sps, raw)   # as the original: bit/s = sps / codingEff
        elif eff is not None:
            self.fail(eff, "codingEff: needs <symbolsPerSecond> (bit rate = symbolsPerSecond / codingEff)")

        rng, top = k.get("range"), k.get("maxDistance")
        if rng is not None and top is not None:
            later = max(rng, top, key=lambda x: x.sourceline or 0)
            self.fail(later, f"{later.tag}: give either <range> or <maxDistance>, not both")
        for tag, field in (("range", "max_distance"), ("maxDistance", "max_distance"),
                           ("minDistance", "min_distance")):
            if (e := k.get(tag)) is not None:
                v, raw = self.number(e)
                f.set(field, v, tag, e, raw)
        if "min_distance" in f.values and "max_distance" in f.values \
                and f.values["min_distance"] > f.values["max_distance"]:
            self.fail(k.get("minDistance"), f"minDistance {f.where['min_distance'].raw} is larger than"
                                            f" {f.where['max_distance'].label} {f.where['max_distance'].raw}")
        self.modem_fields(k, f)
        if (e := k.get("macProtocol")) is not None:
            f.set("mac", self.mac(e), "macProtocol", e)
        if (e := k.get("disable")) is not None:
            self.integer(e)

        if (e := k.get("preset")) is not None:
            a.set("preset", self.string(e), "preset", e)
        sl, pw = k.get("sourceLevel"), k.get("power")
        if sl is not None and pw is not None:
            later = max(sl, pw, key=lambda x: x.sourceline or 0)
            self.fail(later, f"{later.tag}: give either <sourceLevel> (dB re 1 uPa @ 1 m) or <power> (W), not both")
        for tag, field in (("frequency", "carrier_khz"), ("bandwidth", "bandwidth_hz"),
                           ("sourceLevel", "source_level_db"), ("power", "power_w"),
                           ("bitErrorRate", "bit_error_rate"), ("K", "spreading_k"),
                           ("directivityIndex", "directivity_index_db"),
                           ("implementationLoss", "implementation_loss_db"), ("margin", "margin_db")):
            if (e := k.get(tag)) is not None:
                v, raw = self.number(e)
                a.set(field, v, tag, e, raw)
        if (e := k.get("modulation")) is not None:
            a.set("modulation", self.choice(e, _MODULATIONS), "modulation", e)
        f.set("acoustic", self.build(AcousticDeviceSpec, el, a), el.tag, el)
        return self.build(Device, el, f), els

    def check_acoustic(self, d: Device, els: dict[str, _El], channels: Mapping[int, Channel]) -> None:
        """An acoustic device needs acoustic channels; a SINR channel needs acoustic transmitters."""
        if d.acoustic is not None:
            for tag, cid in (("txChannelId", d.tx_channel), ("rxChannelId", d.rx_channel)):
                if channels[cid].acoustic is None:
                    self.fail(els[tag], f"{els[tag].tag}: channel {cid} is a CustomCommsChannel; an"
                                        " AcousticCommsDevice needs an AcousticCommsChannel")
            return
        spec = channels[d.tx_channel].acoustic
        if spec is not None and spec.interference == "sinr":
            self.fail(els["txChannelId"], f"txChannelId: channel {d.tx_channel} decides collisions by SINR, which"
                                          " needs the received power of every transmitter: only an"
                                          " AcousticCommsDevice can transmit on it")

