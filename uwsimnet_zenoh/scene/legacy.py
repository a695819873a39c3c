"""The UWSim-NET vocabulary: `CustomCommsChannel`, `vehicle`, `CustomCommsDevice` and what a device holds
(timing, jitter, rateErrorModel, macProtocol), read as the original wrote it (docs/scene-format.md)."""

from __future__ import annotations

import re

from ..mac import resolve
from .model import (
    Channel,
    Device,
    ErrorModel,
    MacSpec,
    ModelSpec,
    Simulation,
    Tracing,
    Vehicle,
    Waypoint,
)
from .xml import (
    _CHANNEL_IGNORED,
    _DEVICE_IGNORED,
    _KEY_CHUNK_BAD,
    _NUMBER,
    _VEHICLE_IGNORED,
    NO_ERROR_MODEL_WARNING,
    XmlReader,
    _El,
    _Fields,
    _is_element,
    _Kids,
    _ms_to_s,
    _num_str,
)


class LegacyVocabulary(XmlReader):
    """Mixin: the original's elements."""

    # --- top-level sections --------------------------------------------------------------------------

    def tracing(self, el: _El) -> Tracing:
        k = self.kids(el, single=("className", "libPath", "logToFile", "logToConsole", "asyncLog"))
        f = _Fields()
        cls_el = k.get("className")
        if cls_el is not None:
            cls = self.text(cls_el)
            if ":" in cls:
                f.set("class_name", cls, "className", cls_el, cls)
            elif cls:
                self.warn(cls_el, f"netTracingScript: C++ tracing class {cls!r} is not supported, ignored"
                                  " (name a Python class as module:Class)")
        for tag in ("libPath", "logToConsole", "asyncLog"):   # read (so they must be plain values), unused
            if k.get(tag) is not None:
                self.text(k.get(tag))
        log_el = k.get("logToFile")
        if log_el is not None and self.text(log_el):
            f.set("log_to_file", self.text(log_el), "logToFile", log_el)
        return self.build(Tracing, el, f)

    def simulation(self, el: _El) -> Simulation:
        k = self.kids(el, single=("duration", "seed", "clock", "world"))
        f = _Fields()
        if (e := k.get("duration")) is not None:
            v, raw = self.number(e)
            f.set("duration", v, "duration", e, raw)
        if (e := k.get("seed")) is not None:
            v, raw = self.integer(e)
            f.set("seed", v, "seed", e, raw)
        if (e := k.get("clock")) is not None:
            f.set("clock", self.choice(e, ("virtual", "realtime")), "clock", e)
        if (e := k.get("world")) is not None:
            world = self.string(e)
            if _KEY_CHUNK_BAD.search(world):
                self.fail(e, f"world: must be one Zenoh key chunk (no '/', '*', '$', '?', '#' or spaces),"
                             f" got {world!r}")
            f.set("world", world, "world", e)
        return self.build(Simulation, el, f)

    def channel(self, el: _El) -> tuple[Channel, _El]:
        k = self.kids(el, single=("id", "propTimeIncPerMeter", "minPropTime", "channelModel"),
                      ignore=_CHANNEL_IGNORED)
        f = _Fields()
        id_el = self.need(k, "id")
        cid, raw = self.integer(id_el)
        f.set("id", cid, "id", id_el, raw)
        for tag, field in (("propTimeIncPerMeter", "prop_s_per_m"), ("minPropTime", "min_prop_s")):
            if (e := k.get(tag)) is not None:
                _, raw = self.number(e)
                f.set(field, _ms_to_s(raw), tag, e, raw)
        if (e := k.get("channelModel")) is not None:
            f.set("model", self.channel_model(e), "channelModel", e)
            self.modelled.add(cid)
        return self.build(Channel, el, f), id_el

    # --- vehicles ------------------------------------------------------------------------------------

    def vehicle(self, el: _El) -> tuple[Vehicle, _El, list[dict[str, _El]]]:
        k = self.kids(el, single=("name", "position", "geoPosition", "trajectory", "poseSource", "poseRate",
                                  "rosPose", "ros2Link"),
                      repeat=("CustomCommsDevice", "AcousticCommsDevice"), ignore=_VEHICLE_IGNORED)
        f = _Fields()
        name_el = self.need(k, "name")
        f.set("name", self.string(name_el), "name", name_el)
        if (e := k.get("position")) is not None:
            f.set("position", self.position(e), "position", e)
        if (e := k.get("geoPosition")) is not None:
            if "position" in f.values:
                self.fail(e, "geoPosition: give either <position> or <geoPosition>")
            f.set("position", self.geo_position(e), "geoPosition", e)  # type: ignore[attr-defined]
        if (e := k.get("trajectory")) is not None:
            wps = self.trajectory(e)
            f.set("trajectory", wps, "trajectory", e)
            if "position" not in f.values:
                f.set("position", (wps[0].x, wps[0].y, wps[0].z), "trajectory", e)
        if (e := k.get("poseSource")) is not None:
            f.set("pose_source", self.choice(e, ("scene", "zenoh")), "poseSource", e)
        if (e := k.get("poseRate")) is not None:
            v, raw = self.number(e)
            f.set("pose_rate_hz", v, "poseRate", e, raw)
        if (e := k.get("rosPose")) is not None:
            text = self.text(e)
            if not re.fullmatch(r"(odom|pose|tf):\S+", text):
                self.fail(e, f"rosPose: expected odom:TOPIC, pose:TOPIC or tf:CHILD_FRAME[@enu|@ned], got {text!r}")
            f.set("ros_pose", text, "rosPose", e)
        devices: list[Device] = []
        dev_els: list[dict[str, _El]] = []
        for d_el in sorted(k.all("CustomCommsDevice") + k.all("AcousticCommsDevice"), key=lambda e: e.sourceline or 0):
            got = self.device(d_el) if d_el.tag == "CustomCommsDevice" else self.acoustic_device(d_el)
            if got is not None:
                devices.append(got[0])
                dev_els.append(got[1])
        f.set("devices", tuple(devices), "CustomCommsDevice", el)
        if (e := k.get("ros2Link")) is not None:
            spec, self.link_topics[f.values["name"]] = self.ros2_link(e, devices)  # type: ignore[attr-defined]
            f.set("ros2_link", spec, "ros2Link", e)
        return self.build(Vehicle, el, f), name_el, dev_els

    def position(self, el: _El) -> tuple[float, float, float]:
        self._no_attributes(el)
        if any(_is_element(c) for c in el):
            k = self.kids(el, single=("x", "y", "z"))
            return tuple(self.number(self.need(k, c), f"position/{c}")[0] for c in "xyz")  # type: ignore[return-value]
        s = self.text(el)
        parts = [p for p in re.split(r"[\s,]+", s) if p]
        if len(parts) != 3 or not all(_NUMBER.fullmatch(p) for p in parts):
            self.fail(el, f"position: expected 'x y z' or <x>, <y>, <z> children, got {s!r}")
        return tuple(self.number(el, "position", p)[0] for p in parts)  # type: ignore[return-value]

    def trajectory(self, el: _El) -> tuple[Waypoint, ...]:
        k = self.kids(el, repeat=("waypoint",))
        wps: list[Waypoint] = []
        for w_el in k.all("waypoint"):
            wp = self.waypoint(w_el)
            if wps and wp.t <= wps[-1].t:
                self.fail(w_el, f"waypoint: times must increase (t={_num_str(wp.t)} after"
                                f" t={_num_str(wps[-1].t)})")
            wps.append(wp)
        if not wps:
            self.fail(el, "trajectory: needs at least one <waypoint>")
        return tuple(wps)

    def waypoint(self, el: _El) -> Waypoint:
        k = self.kids(el, single=("t", "x", "y", "z"), attrs=("t", "x", "y", "z"))
        f = _Fields()
        for c in "txyz":
            child, attr = k.get(c), el.get(c)
            if child is not None and attr is not None:
                self.fail(child, f"waypoint: {c} given both as attribute and as element")
            if child is not None:
                v, raw = self.number(child, f"waypoint/{c}")
                f.set(c, v, f"waypoint/{c}", child, raw)
            elif attr is not None:
                v, raw = self.number(el, f"waypoint/{c}", raw=attr)
                f.set(c, v, f"waypoint/{c}", el, raw)
            else:
                self.fail(el, f"waypoint: missing {c} (attribute or element)")
        return self.build(Waypoint, el, f)

    # --- devices -------------------------------------------------------------------------------------

    def device(self, el: _El) -> tuple[Device, dict[str, _El]] | None:
        """A `CustomCommsDevice`, or None if it is disabled; also the elements cross-checks point at."""
        disable = [c for c in el if _is_element(c) and c.tag == "disable"]
        if len(disable) > 1:
            self.fail(disable[1], f"duplicate <disable> in <CustomCommsDevice> (first at line"
                                  f" {disable[0].sourceline})")
        if disable and self.integer(disable[0])[0] != 0:
            ids = [self.text(c) for c in el if _is_element(c) and c.tag == "dccommsId"]
            who = f" {ids[0]!r}" if ids and ids[0] else ""
            self.warn(el, f"<CustomCommsDevice>{who} is disabled (<disable>), skipped")
            if ids and ids[0]:
                self.disabled.setdefault(ids[0], el.sourceline or 0)
            return None

        k = self.kids(el, single=(
            "dccommsId", "mac", "txChannelId", "rxChannelId", "bitrate", "txFifoSize", "intrinsicDelay",
            "jitter", "maxDistance", "minDistance", "rateErrorModel", "minPktErrRatio",
            "pktErrRatioIncPerMeter", "macProtocol", "headerBytes", "maxFrameBytes", "txPacketBuilder",
            "rxPacketBuilder", "disable"),
            ignore=_DEVICE_IGNORED)
        f = _Fields()
        els: dict[str, _El] = {}
        for tag in ("dccommsId", "mac", "txChannelId", "rxChannelId"):
            els[tag] = self.need(k, tag)
        f.set("dccomms_id", self.string(els["dccommsId"]), "dccommsId", els["dccommsId"])
        for tag, field in (("mac", "address"), ("txChannelId", "tx_channel"), ("rxChannelId", "rx_channel")):
            v, raw = self.integer(els[tag])
            f.set(field, v, tag, els[tag], raw)

        for tag, field in (("bitrate", "bitrate"), ("maxDistance", "max_distance"),
                           ("minDistance", "min_distance")):
            if (e := k.get(tag)) is not None:
                v, raw = self.number(e)
                f.set(field, v, tag, e, raw)
        self.modem_fields(k, f)

        if "min_distance" in f.values and "max_distance" in f.values \
                and f.values["min_distance"] > f.values["max_distance"]:
            self.fail(k.get("minDistance"), f"minDistance {f.where['min_distance'].raw} is larger than"
                                            f" maxDistance {f.where['max_distance'].raw}")

        error = self.error_model(el, k, f.values["tx_channel"] in self.modelled)
        if error is not None:
            f.set("error", error, "rateErrorModel", el)
        if (e := k.get("macProtocol")) is not None:
            f.set("mac", self.mac(e), "macProtocol", e)
        if (e := k.get("disable")) is not None:
            self.integer(e)   # 0 here (non-zero returned early above)
        if f.values.get("tx_framing") == "DcMacPacketBuilder" and f.values.get("mac", MacSpec()).name in ("none", ""):
            # the original ran DcMac in its apps above a simulator with no MAC (dccomms_examples example4 --dcmac,
            # testing/mac_twinbot.sh): here the modem runs it (docs/mac.md, DcMac)
            f.values["mac"] = MacSpec(name="dcmac")
        return self.build(Device, el, f), els

    def modem_fields(self, k: _Kids, f: _Fields) -> None:
        """What every device has: FIFO, header and frame sizes (bytes), intrinsic delay and jitter (ms)."""
        for tag, field in (("txFifoSize", "tx_fifo_bytes"), ("headerBytes", "header_bytes"),
                           ("maxFrameBytes", "max_frame_bytes")):
            if (e := k.get(tag)) is not None:
                v, raw = self.integer(e)
                f.set(field, v, tag, e, raw)
        if (e := k.get("intrinsicDelay")) is not None:
            if any(_is_element(c) for c in e):
                self.tx_rx_ms(e, f, "intrinsic_tx_s", "intrinsic_rx_s")
            else:
                _, raw = self.number(e)
                f.set("intrinsic_tx_s", _ms_to_s(raw), "intrinsicDelay", e, raw)
        if (e := k.get("jitter")) is not None:
            self.tx_rx_ms(e, f, "jitter_tx_s", "jitter_rx_s")
        for tag, field in (("txPacketBuilder", "tx_framing"), ("rxPacketBuilder", "rx_framing")):
            if (e := k.get(tag)) is not None:
                name, name_el = self.packet_builder(e)
                f.set(field, name, f"{tag}/className", name_el)
        if "tx_framing" in f.values and "max_frame_bytes" not in f.values:
            from ..phy.framing import builder  # noqa: PLC0415 - scenes with a framing only (start-up time)

            # the largest frame is the framing's own (a VariableLength2BPacket of 2048 bytes is 2053 on air)
            f.values["max_frame_bytes"] = builder(f.values["tx_framing"]).max_frame + f.values.get("header_bytes", 0)

    def packet_builder(self, el: _El) -> tuple[str, _El]:
        """`<txPacketBuilder>`/`<rxPacketBuilder>`: a dccomms packet-builder class (phy.framing.builder);
        `libPath` (the shared library the original loaded it from) is not needed here."""
        k = self.kids(el, single=("className", "libPath"))
        name_el = self.need(k, "className")
        name = self.text(name_el)
        from ..phy.framing import builder  # noqa: PLC0415 - scenes with a framing only (start-up time)

        try:
            framing = builder(name)
        except ValueError as e:
            self.fail(name_el, f"{el.tag}: {e}")
        if (lib := k.get("libPath")) is not None and self.text(lib):
            self.warn(lib, f"<libPath> in <{el.tag}> ignored (the dccomms framings are built in)")
        return framing.name, name_el

    def tx_rx_ms(self, el: _El, f: _Fields, tx_field: str, rx_field: str) -> None:
        k = self.kids(el, single=("tx", "rx"))
        for tag, field in (("tx", tx_field), ("rx", rx_field)):
            if (e := k.get(tag)) is not None:
                _, raw = self.number(e, f"{el.tag}/{tag}")
                f.set(field, _ms_to_s(raw), f"{el.tag}/{tag}", e, raw)

    def error_model(self, dev: _El, k: _Kids, modelled: bool = False) -> ErrorModel | None:
        """The device's rateErrorModel (or its legacy form); none given: no loss, said in a warning unless
        its channel names a `<channelModel>` (`modelled`), which the device's rate would not reach."""
        rem = k.get("rateErrorModel")
        legacy = [e for e in (k.get("minPktErrRatio"), k.get("pktErrRatioIncPerMeter")) if e is not None]
        if rem is not None and legacy:
            self.fail(legacy[0], f"{legacy[0].tag}: give either <rateErrorModel> or the legacy"
                                 " <minPktErrRatio>/<pktErrRatioIncPerMeter>, not both")
        if rem is not None:
            ek = self.kids(rem, single=("errorUnit", "errorRateExpr"))
            f = _Fields()
            if (e := ek.get("errorUnit")) is not None:
                f.set("unit", self.choice(e, ("bit", "byte", "packet")), "errorUnit", e)
            expr_el = self.need(ek, "errorRateExpr")
            expr = self.text(expr_el)
            self.check_expr(expr_el, expr)
            f.set("expr", expr, "errorRateExpr", expr_el)
            return self.build(ErrorModel, rem, f)
        if legacy:
            vals = {}
            for tag in ("minPktErrRatio", "pktErrRatioIncPerMeter"):
                e = k.get(tag)
                vals[tag] = self.number(e)[0] if e is not None else 0.0
            expr = f"{_num_str(vals['minPktErrRatio'])}+{_num_str(vals['pktErrRatioIncPerMeter'])}*m"
            self.check_expr(legacy[0], expr)
            self.warn(legacy[0], "legacy <minPktErrRatio>/<pktErrRatioIncPerMeter> read as"
                                 f" rateErrorModel errorUnit=packet errorRateExpr={expr}")
            f = _Fields()
            f.values.update(unit="packet", expr=expr)
            return self.build(ErrorModel, legacy[0], f)
        if not modelled:
            self.warn(dev, NO_ERROR_MODEL_WARNING)
        return None

    def check_expr(self, el: _El, expr: str) -> None:
        from ..phy.error import RateErrorModel  # a plain number is checked without phy.expr (and numpy)

        try:
            RateErrorModel(expr, "packet")
        except Exception as e:   # ExprError (a ValueError) by contract; anything else: still the user's text
            self.fail(el, f"errorRateExpr: {e}")

    def mac(self, el: _El) -> MacSpec:
        self._no_attributes(el)
        name_el: _El | None = None
        params: dict[str, str] = {}
        seen: dict[str, _El] = {}
        for child in self._nodes(el):
            if child.tag in seen:
                self.fail(child, f"duplicate <{child.tag}> in <macProtocol> (first at line"
                                 f" {seen[child.tag].sourceline})")
            seen[child.tag] = child
            if child.tag == "name":
                name_el = child
            elif value := self.text(child):
                params[child.tag] = value       # an empty parameter (a template's <maxBackoffSlots/>): its default
        if name_el is None:
            self.fail(el, "macProtocol: missing <name>")
        name = self.text(name_el) or "none"     # the original's <name></name>: no MAC
        try:
            resolve(name)
        except ValueError as e:
            self.fail(name_el, f"macProtocol/name: {e}")
        f = _Fields()
        f.set("name", name, "macProtocol/name", name_el)
        f.values["params"] = params
        return self.build(MacSpec, el, f)

    def channel_model(self, el: _El) -> ModelSpec:
        """`<channelModel>`: `<name>` and the model's parameters, one element each (docs/channel-models.md).
        The name must resolve here; the parameters are the model's to check when it is built."""
        from ..phy.registry import resolve as resolve_model

        self._no_attributes(el)
        name_el: _El | None = None
        params: dict[str, str] = {}
        seen: dict[str, _El] = {}
        for child in self._nodes(el):
            if child.tag in seen:
                self.fail(child, f"duplicate <{child.tag}> in <channelModel> (first at line"
                                 f" {seen[child.tag].sourceline})")
            seen[child.tag] = child
            if child.tag == "name":
                name_el = child
            else:
                params[child.tag] = self.text(child)
        if name_el is None or not self.text(name_el):
            self.fail(el, "channelModel: missing <name>")
        name = self.text(name_el)
        try:
            resolve_model(name)
        except ValueError as e:
            self.fail(name_el, f"channelModel/name: {e}")
        f = _Fields()
        f.set("name", name, "channelModel/name", name_el)
        f.values["params"] = params
        return self.build(ModelSpec, el, f)
