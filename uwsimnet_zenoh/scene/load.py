"""XML scene (UWSim-NET vocabulary + native extensions) -> `Scene`, with `file:line: message` errors.

Reading rules (docs/scene-format.md is the user-facing version):

* Values live in element text, whitespace-trimmed; comments and processing instructions are skipped.
* Units are converted here, once: milliseconds -> seconds, ms/m -> s/m.  Past this module everything is SI.
* Elements of a UWSim scene that only matter to the 3D simulator are skipped with one warning each;
  legacy device settings that have no meaning here are skipped with a warning; anything else unknown is
  an error.  Every error is a `SceneError` carrying the line of the offending element.
* The parser is hardened: no DTD loading, no network, no entity expansion (an entity reference is an
  error), so a scene file can never make the loader read other files.
"""

from __future__ import annotations

import difflib
import math
import os
import re
import sys
from collections.abc import Callable, Iterable, Iterator, Mapping
from decimal import Decimal
from pathlib import Path
from typing import Any, NoReturn, TypeVar

from lxml import etree
from pydantic import BaseModel, ValidationError

from ..phy.expr import compile_expr
from .model import (
    BROADCAST,
    AcousticChannelSpec,
    AcousticDeviceSpec,
    Channel,
    Device,
    ErrorModel,
    Flow,
    MacSpec,
    Scene,
    Simulation,
    Tracing,
    Vehicle,
    Waypoint,
)

__all__ = ["SceneError", "load_scene", "load_scene_text"]

Warn = Callable[[str], None]
M = TypeVar("M", bound=BaseModel)
_El = Any  # lxml.etree._Element (the private class has no public alias worth importing)

ROOT = "UWSimScene"

_UWSIM_3D = "ignored (UWSim 3D scene element)"
_TOP_IGNORED: dict[str, str] = {
    **{name: _UWSIM_3D for name in ("oceanState", "simParams", "camera", "object")},
    "rosInterfaces": "ignored (ROS interfaces: applications reach modems through Zenoh keys)",
}
_VEHICLE_IGNORED: dict[str, str] = {
    **{name: _UWSIM_3D for name in (
        "file", "jointValues", "orientation", "scaleFactor", "virtualCamera", "virtualRangeImage",
        "structuredLightProjector", "rangeSensor", "objectPicker", "imu", "pressureSensor", "gpsSensor",
        "dvlSensor", "multibeamSensor", "simulatedDevices", "echo", "ForceSensor", "DredgeTool", "ARMask",
        "LedArray")},
}
_TF = "ignored (ROS TF frame: the modem sits at the vehicle position)"
_DEVICE_IGNORED: dict[str, str] = {
    "relativeTo": _TF,
    "tfId": _TF,
    "relativeTfId": _TF,
    "position": "ignored (the modem sits at the vehicle position)",
    "orientation": "ignored (the modem sits at the vehicle position)",
    "mesh": _UWSIM_3D,
    "txPacketBuilder": "ignored (framing is not simulated: use <headerBytes> for on-air overhead)",
    "rxPacketBuilder": "ignored (framing is not simulated: use <headerBytes> for on-air overhead)",
    "logLevel": "ignored (use the trace instead)",
}
_CHANNEL_IGNORED: dict[str, str] = {"logLevel": "ignored (use the trace instead)"}
_ACOUSTIC_DEVICE_IGNORED: dict[str, str] = {
    **_DEVICE_IGNORED,
    "L": "ignored (Aqua-Sim system loss factor: use <implementationLoss> in dB)",
    "preamble": "ignored (Aqua-Sim preamble: use <headerBytes> for on-air overhead)",
    "energyModel": "ignored (energy consumption is not simulated)",
}
_ACOUSTIC_DEVICE_TAGS = (
    "dccommsId", "mac", "txChannelId", "rxChannelId", "channelId", "symbolsPerSecond", "codingEff", "bitrate",
    "bitErrorRate", "range", "frequency", "K", "preset", "sourceLevel", "power", "bandwidth", "modulation",
    "directivityIndex", "implementationLoss", "margin", "txFifoSize", "intrinsicDelay", "jitter", "maxDistance",
    "minDistance", "macProtocol", "headerBytes", "maxFrameBytes", "disable")
_MODULATIONS = ("bpsk", "bfsk_coherent", "bfsk_noncoherent", "dpsk", "bpsk_rayleigh")

NO_ERROR_MODEL_WARNING = "no rateErrorModel: assuming no propagation loss (the original assumed 0.01*m)"

_NUMBER = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
_INTEGER = re.compile(r"[+-]?[0-9]+")
_KEY_CHUNK_BAD = re.compile(r"[/*$?#\s]")
_XML_DECL_ENCODING = re.compile(r"""^(\s*<\?xml[^>]*?)\s+encoding\s*=\s*(["'])[^"']*\2""")
_LXML_POSITION = re.compile(r",\s*line \d+, column \d+\s*$")


class SceneError(Exception):
    """A problem in a scene file; `str(e)` is one line: `source:line: message`."""

    def __init__(self, source: str, line: int, message: str) -> None:
        self.source = source
        self.line = line
        self.message = " ".join(message.split())
        super().__init__(str(self))

    def __str__(self) -> str:
        return f"{self.source}:{self.line}: {self.message}"


def _stderr(msg: str) -> None:
    print(msg, file=sys.stderr)


def load_scene(path: str | os.PathLike[str], on_warning: Warn | None = None) -> Scene:
    """Read a scene file.  Warnings (`file:line: warning: ...`) go to `on_warning` (default: stderr)."""
    source = os.fspath(path)
    try:
        data = Path(path).read_bytes()
    except OSError as e:
        raise SceneError(source, 0, f"cannot read scene file: {e.strerror or e}") from None
    return _Reader(source, on_warning).read(data, name=Path(source).stem or "scene")


def load_scene_text(text: str | bytes, source: str = "<string>", on_warning: Warn | None = None) -> Scene:
    """Read a scene from a string (errors and warnings name `source`); the scene name defaults to "scene"."""
    if isinstance(text, str):
        # lxml refuses str input that declares an encoding; the text is already decoded, so drop it
        # (on the same line, so line numbers do not move).
        text = _XML_DECL_ENCODING.sub(r"\1", text, count=1)
    return _Reader(source, on_warning).read(text, name="scene")


def _num_str(x: float) -> str:
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e15 else repr(float(x))


def _ms_to_s(raw: str) -> float:
    # Decimal keeps e.g. 0.6667 ms/m -> 0.0006667 s/m exact (the nearest double, no 6.666999e-4).
    return float(Decimal(raw) / 1000)


def _explain(err: Mapping[str, Any], raw: str | None) -> str:
    """One line saying why pydantic rejected a value, without its boilerplate."""
    kind = err.get("type", "")
    ctx = err.get("ctx") or {}
    inp = err.get("input")
    got = raw if raw is not None else (_num_str(inp) if isinstance(inp, int | float) else repr(inp))
    bounds = {"greater_than": ("greater than", "gt"), "greater_than_equal": ("at least", "ge"),
              "less_than": ("less than", "lt"), "less_than_equal": ("at most", "le")}
    if kind in bounds:
        words, key = bounds[kind]
        limit = ctx.get(key)
        limit_s = _num_str(limit) if isinstance(limit, int | float) else str(limit)
        return f"must be {words} {limit_s}, got {got}"
    if kind == "literal_error":
        return f"expected {ctx.get('expected')}, got {got if raw is not None else repr(inp)}"
    if kind == "missing":
        return "is required"
    if kind == "value_error" and "error" in ctx:
        return str(ctx["error"])
    return f"{err.get('msg', 'invalid value')}, got {got}"


def _show(text: str) -> str:
    """A value as quoted in a message: repr() (one line), shortened."""
    return repr(text if len(text) <= 40 else text[:37] + "...")


def _is_element(node: Any) -> bool:
    return isinstance(node.tag, str)


class _Src:
    """Where a model field's value came from: the element label, its line, the text as written."""

    __slots__ = ("label", "line", "raw")

    def __init__(self, label: str, line: int, raw: str | None = None) -> None:
        self.label = label
        self.line = line
        self.raw = raw


class _Fields:
    """Keyword arguments for a model, plus where each came from (to map validation errors to lines)."""

    def __init__(self) -> None:
        self.values: dict[str, Any] = {}
        self.where: dict[str, _Src] = {}

    def set(self, field: str, value: Any, label: str, el: _El, raw: str | None = None) -> None:
        self.values[field] = value
        self.where[field] = _Src(label, el.sourceline or 0, raw)


class _Kids:
    """The element children of a container, by tag name (document order kept per name)."""

    def __init__(self, parent: _El, by: dict[str, list[_El]]) -> None:
        self.parent = parent
        self.by = by

    def get(self, name: str) -> _El | None:
        found = self.by.get(name)
        return found[0] if found else None

    def all(self, name: str) -> list[_El]:
        return self.by.get(name, [])


class _Reader:
    def __init__(self, source: str, on_warning: Warn | None) -> None:
        self.source = source
        self.on_warning = on_warning or _stderr
        self._warnings: list[tuple[int, int, str]] = []
        self.disabled: dict[str, int] = {}

    # --- reporting -----------------------------------------------------------------------------------

    def fail(self, el: _El | None, message: str) -> NoReturn:
        raise SceneError(self.source, (el.sourceline or 0) if el is not None else 0, message)

    def warn(self, el: _El, message: str) -> None:
        """Queue a warning; they are handed out in line order once reading stops."""
        line = el.sourceline or 0
        text = f"{self.source}:{line}: warning: {' '.join(message.split())}"
        self._warnings.append((line, len(self._warnings), text))

    def _flush_warnings(self, up_to: int | None = None) -> None:
        for line, _, text in sorted(self._warnings):
            if up_to is None or line <= up_to:
                self.on_warning(text)
        self._warnings.clear()

    # --- generic element access ----------------------------------------------------------------------

    def _nodes(self, el: _El) -> Iterator[_El]:
        """Element children of `el`; stray text and entity references are errors."""
        self._no_text(el.text, el, el.sourceline or 0)
        for child in el:
            if isinstance(child, etree._Entity):
                self.fail(el, f"entity references are not supported ({child.text})")
            if _is_element(child):
                yield child
            if child.tail and child.tail.strip():
                # lxml knows where an element starts, not where it ends: count the lines it spans.
                end = (child.sourceline or 0) + etree.tostring(child, with_tail=False).count(b"\n")
                self._no_text(child.tail, el, end)

    def _no_text(self, text: str | None, parent: _El, line: int) -> None:
        if text and text.strip():
            line += text[: len(text) - len(text.lstrip())].count("\n")
            raise SceneError(self.source, line, f"unexpected text {_show(text.strip())} in <{parent.tag}>")

    def _no_attributes(self, el: _El, allowed: Iterable[str] = ()) -> None:
        for name in el.attrib:
            if name not in allowed:
                self.fail(el, f"unexpected attribute {name!r} on <{el.tag}>")

    def kids(self, el: _El, single: Iterable[str] = (), repeat: Iterable[str] = (),
             ignore: Mapping[str, str] | None = None, attrs: Iterable[str] = ()) -> _Kids:
        """Sort the children of a container: known ones by name, ignored ones warned about, others fail."""
        single, repeat, ignore = set(single), set(repeat), dict(ignore or {})
        self._no_attributes(el, attrs)
        by: dict[str, list[_El]] = {}
        where = "" if el.tag == ROOT else f" in <{el.tag}>"
        for child in self._nodes(el):
            tag = child.tag
            if tag in ignore:
                self.warn(child, f"<{tag}>{where} {ignore[tag]}")
                continue
            if tag not in single and tag not in repeat:
                self._unknown(child, el, single | repeat | set(ignore))
            if tag in single and tag in by:
                self.fail(child, f"duplicate <{tag}> in <{el.tag}> (first at line {by[tag][0].sourceline})")
            by.setdefault(tag, []).append(child)
        return _Kids(el, by)

    def _unknown(self, child: _El, parent: _El, known: set[str]) -> NoReturn:
        tag = child.tag
        if tag.startswith("{"):
            local = etree.QName(child).localname
            tag = f"{child.prefix}:{local}" if child.prefix else local
        lower = {k.lower(): k for k in known}
        close = difflib.get_close_matches(tag.lower(), list(lower), n=1, cutoff=0.8)
        hint = f" (did you mean <{lower[close[0]]}>?)" if close else ""
        self.fail(child, f"unknown element <{tag}> in <{parent.tag}>{hint}")

    def need(self, kids: _Kids, name: str) -> _El:
        el = kids.get(name)
        if el is None:
            self.fail(kids.parent, f"{kids.parent.tag}: missing <{name}>")
        return el

    def text(self, el: _El) -> str:
        """The value of a leaf element: its text, trimmed, comments skipped."""
        self._no_attributes(el)
        parts = [el.text or ""]
        for child in el:
            if isinstance(child, etree._Entity):
                self.fail(el, f"entity references are not supported ({child.text})")
            if _is_element(child):
                self.fail(child, f"<{el.tag}> holds a value, not elements (found <{child.tag}>)")
            parts.append(child.tail or "")
        return "".join(parts).strip()

    def string(self, el: _El, label: str | None = None) -> str:
        s = self.text(el)
        if not s:
            self.fail(el, f"{label or el.tag}: must not be empty")
        return s

    def number(self, el: _El, label: str | None = None, raw: str | None = None) -> tuple[float, str]:
        s = self.text(el) if raw is None else raw.strip()
        if not _NUMBER.fullmatch(s) or not math.isfinite(float(s)):
            self.fail(el, f"{label or el.tag}: expected a number, got {_show(s)}")
        return float(s), s

    def integer(self, el: _El, label: str | None = None) -> tuple[int, str]:
        s = self.text(el)
        if not _INTEGER.fullmatch(s) or len(s) > 30:   # int() of thousands of digits is slow, then refused
            self.fail(el, f"{label or el.tag}: expected an integer, got {_show(s)}")
        return int(s), s

    def choice(self, el: _El, options: tuple[str, ...], label: str | None = None) -> str:
        s = self.text(el)
        if s not in options:
            listed = ", ".join(options[:-1]) + f" or {options[-1]}"
            self.fail(el, f"{label or el.tag}: expected {listed}, got {_show(s)}")
        return s

    def build(self, cls: type[M], el: _El, fields: _Fields) -> M:
        """Construct a model; a validation error points at the element that supplied the bad field."""
        try:
            return cls(line=el.sourceline or 0, **fields.values)
        except ValidationError as e:
            err = e.errors(include_url=False)[0]
            loc = err.get("loc") or ()
            field = str(loc[0]) if loc else ""
            src = fields.where.get(field)
            if src is None:
                label, line, raw = (field or el.tag), (el.sourceline or 0), None
            else:
                label, line, raw = src.label, src.line, src.raw
            raise SceneError(self.source, line,
                             f"{label}: {_explain(err, raw)}") from None

    # --- the document --------------------------------------------------------------------------------

    def read(self, data: str | bytes, name: str) -> Scene:
        parser = etree.XMLParser(resolve_entities=False, no_network=True, load_dtd=False,
                                 dtd_validation=False, huge_tree=False)
        try:
            root = etree.fromstring(data, parser)
        except etree.XMLSyntaxError as e:
            line, col = (e.position if e.position else (e.lineno or 0, 0))
            msg = _LXML_POSITION.sub("", e.msg or str(e))
            where = f" (column {col})" if col else ""
            raise SceneError(self.source, line or 0, f"XML syntax error: {msg}{where}") from None
        except (etree.Error, ValueError) as e:
            raise SceneError(self.source, 0, f"cannot parse XML: {e}") from None
        if root is None:
            raise SceneError(self.source, 0, "XML syntax error: empty document")
        if root.tag != ROOT:
            self.fail(root, f"root element must be <{ROOT}>, got <{root.tag}>")
        try:
            scene = self.scene(root, name)
        except SceneError as e:
            # As a reader going top to bottom would: the warnings above the error, then the error.
            self._flush_warnings(up_to=e.line)
            raise
        except (ValidationError, ValueError, etree.Error) as e:   # a gap in the checks above; still one line
            self._flush_warnings()
            raise SceneError(self.source, root.sourceline or 0,
                             f"invalid scene: {' '.join(str(e).split())}") from None
        self._flush_warnings()
        return scene

    def scene(self, root: _El, name: str) -> Scene:
        k = self.kids(root, single=("netTracingScript", "simulation"),
                      repeat=("CustomCommsChannel", "AcousticCommsChannel", "vehicle", "flow"), ignore=_TOP_IGNORED)
        tracing_el, simulation_el = k.get("netTracingScript"), k.get("simulation")
        tracing = self.tracing(tracing_el) if tracing_el is not None else Tracing()
        simulation = self.simulation(simulation_el) if simulation_el is not None else Simulation()

        channels: list[Channel] = []
        channel_line: dict[int, int] = {}
        for el in sorted(k.all("CustomCommsChannel") + k.all("AcousticCommsChannel"), key=lambda e: e.sourceline or 0):
            ch, id_el = self.channel(el) if el.tag == "CustomCommsChannel" else self.acoustic_channel(el)
            if ch.id in channel_line:
                self.fail(id_el, f"duplicate channel id {ch.id} (first at line {channel_line[ch.id]})")
            channel_line[ch.id] = id_el.sourceline or 0
            channels.append(ch)

        vehicles: list[Vehicle] = []
        vehicle_line: dict[str, int] = {}
        devices: dict[str, tuple[Device, dict[str, _El]]] = {}
        listeners: dict[tuple[int, int], tuple[str, int]] = {}
        for el in k.all("vehicle"):
            v, name_el, dev_els = self.vehicle(el)
            if v.name in vehicle_line:
                self.fail(name_el, f"duplicate vehicle name {v.name!r}"
                                   f" (first at line {vehicle_line[v.name]})")
            vehicle_line[v.name] = name_el.sourceline or 0
            for d, els in zip(v.devices, dev_els, strict=True):
                if d.dccomms_id in devices:
                    first = devices[d.dccomms_id][1]["dccommsId"].sourceline
                    self.fail(els["dccommsId"],
                              f"duplicate dccommsId {d.dccomms_id!r} (first at line {first})")
                devices[d.dccomms_id] = (d, els)
                key = (d.rx_channel, d.address)
                if key in listeners:
                    other, line = listeners[key]
                    self.fail(els["mac"], f"mac {d.address} is already used on rx channel {d.rx_channel}"
                                          f" by {other!r} (line {line})")
                listeners[key] = (d.dccomms_id, els["mac"].sourceline or 0)
            vehicles.append(v)

        for d, els in devices.values():
            for tag, ch_id in (("txChannelId", d.tx_channel), ("rxChannelId", d.rx_channel)):
                if ch_id not in channel_line:
                    kind = "AcousticCommsChannel" if d.acoustic is not None else "CustomCommsChannel"
                    self.fail(els[tag], f"{els[tag].tag}: no {kind} with id {ch_id}")
        by_id = {c.id: c for c in channels}
        for d, els in devices.values():
            self.check_acoustic(d, els, by_id)

        flows: list[Flow] = []
        flow_line: dict[str, int] = {}
        for i, el in enumerate(k.all("flow"), start=1):
            f, els = self.flow(el, i)
            if f.name in flow_line:
                self.fail(els.get("name", el),
                          f"duplicate flow name {f.name!r} (first at line {flow_line[f.name]})")
            flow_line[f.name] = el.sourceline or 0
            self.check_flow(f, els, devices)
            flows.append(f)

        fields = _Fields()
        fields.values.update(name=simulation.world or name, source=self.source, simulation=simulation,
                             tracing=tracing, channels=tuple(channels), vehicles=tuple(vehicles),
                             flows=tuple(flows))
        return self.build(Scene, root, fields)

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
        k = self.kids(el, single=("id", "propTimeIncPerMeter", "minPropTime"), ignore=_CHANNEL_IGNORED)
        f = _Fields()
        id_el = self.need(k, "id")
        cid, raw = self.integer(id_el)
        f.set("id", cid, "id", id_el, raw)
        for tag, field in (("propTimeIncPerMeter", "prop_s_per_m"), ("minPropTime", "min_prop_s")):
            if (e := k.get(tag)) is not None:
                _, raw = self.number(e)
                f.set(field, _ms_to_s(raw), tag, e, raw)
        return self.build(Channel, el, f), id_el

    # --- vehicles ------------------------------------------------------------------------------------

    def vehicle(self, el: _El) -> tuple[Vehicle, _El, list[dict[str, _El]]]:
        k = self.kids(el, single=("name", "position", "trajectory", "poseSource", "poseRate"),
                      repeat=("CustomCommsDevice", "AcousticCommsDevice"), ignore=_VEHICLE_IGNORED)
        f = _Fields()
        name_el = self.need(k, "name")
        f.set("name", self.string(name_el), "name", name_el)
        if (e := k.get("position")) is not None:
            f.set("position", self.position(e), "position", e)
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
        devices: list[Device] = []
        dev_els: list[dict[str, _El]] = []
        for d_el in sorted(k.all("CustomCommsDevice") + k.all("AcousticCommsDevice"), key=lambda e: e.sourceline or 0):
            got = self.device(d_el) if d_el.tag == "CustomCommsDevice" else self.acoustic_device(d_el)
            if got is not None:
                devices.append(got[0])
                dev_els.append(got[1])
        f.set("devices", tuple(devices), "CustomCommsDevice", el)
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
            "pktErrRatioIncPerMeter", "macProtocol", "headerBytes", "maxFrameBytes", "disable"),
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

        error = self.error_model(el, k)
        if error is not None:
            f.set("error", error, "rateErrorModel", el)
        if (e := k.get("macProtocol")) is not None:
            f.set("mac", self.mac(e), "macProtocol", e)
        if (e := k.get("disable")) is not None:
            self.integer(e)   # 0 here (non-zero returned early above)
        return self.build(Device, el, f), els

    # --- acoustic physics (AcousticCommsChannel / AcousticCommsDevice; docs/acoustic.md) ----------------

    def acoustic_channel(self, el: _El) -> tuple[Channel, _El]:
        """An `AcousticCommsChannel`: a channel whose delay (1 / sound speed) and losses come from physics."""
        k = self.kids(el, single=(
            "id", "minPropTime", "bandwidth", "temperature", "salinity", "noiseLvl", "depth", "ph", "spreading",
            "absorption", "shipping", "wind", "noisePsd", "soundSpeed", "interference", "sinrThreshold",
            "capture", "acquireThreshold"),
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

    def tx_rx_ms(self, el: _El, f: _Fields, tx_field: str, rx_field: str) -> None:
        k = self.kids(el, single=("tx", "rx"))
        for tag, field in (("tx", tx_field), ("rx", rx_field)):
            if (e := k.get(tag)) is not None:
                _, raw = self.number(e, f"{el.tag}/{tag}")
                f.set(field, _ms_to_s(raw), f"{el.tag}/{tag}", e, raw)

    def error_model(self, dev: _El, k: _Kids) -> ErrorModel | None:
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
        self.warn(dev, NO_ERROR_MODEL_WARNING)
        return None

    def check_expr(self, el: _El, expr: str) -> None:
        try:
            compile_expr(expr)
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
            else:
                params[child.tag] = self.text(child)
        if name_el is None:
            self.fail(el, "macProtocol: missing <name>")
        f = _Fields()
        f.set("name", self.string(name_el, "macProtocol/name"), "macProtocol/name", name_el)
        f.values["params"] = params
        return self.build(MacSpec, el, f)

    # --- flows ---------------------------------------------------------------------------------------

    def flow(self, el: _El, index: int) -> tuple[Flow, dict[str, _El]]:
        k = self.kids(el, single=("name", "src", "dst", "size", "interval", "rate", "arrival", "start",
                                  "stop"))
        f = _Fields()
        els: dict[str, _El] = {tag: k.get(tag) for tag in k.by}
        if (e := k.get("name")) is not None:
            f.set("name", self.string(e), "name", e)
        else:
            f.values["name"] = f"flow{index}"
        src = self.need(k, "src")
        f.set("src", self.string(src), "src", src)
        for tag in ("dst", "size"):
            e = self.need(k, tag)
            v, raw = self.integer(e)
            f.set(tag, v, tag, e, raw)
        interval, rate = k.get("interval"), k.get("rate")
        if interval is not None and rate is not None:
            later = max(interval, rate, key=lambda x: x.sourceline or 0)
            self.fail(later, "flow: give either <interval> or <rate>, not both")
        if interval is not None:
            v, raw = self.number(interval)
            f.set("interval", v, "interval", interval, raw)
        elif rate is not None:
            v, raw = self.number(rate)
            if v <= 0:
                self.fail(rate, f"rate: must be greater than 0, got {raw}")
            f.set("interval", 1.0 / v, "rate", rate, raw)
        else:
            self.fail(el, "flow: missing <interval> (s) or <rate> (frames/s)")
        if (e := k.get("arrival")) is not None:
            f.set("arrival", self.choice(e, ("periodic", "poisson")), "arrival", e)
        for tag in ("start", "stop"):
            if (e := k.get(tag)) is not None:
                v, raw = self.number(e)
                f.set(tag, v, tag, e, raw)
        if "stop" in f.values and f.values["stop"] <= f.values.get("start", 0.0):
            start = f.where["start"].raw if "start" in f.where else "0"
            self.fail(k.get("stop"), f"stop: must be after start (stop {f.where['stop'].raw}, start {start})")
        return self.build(Flow, el, f), els

    def check_flow(self, flow: Flow, els: dict[str, _El],
                   devices: Mapping[str, tuple[Device, dict[str, _El]]]) -> None:
        if flow.src not in devices:
            if flow.src in self.disabled:
                self.fail(els["src"], f"src: device {flow.src!r} is disabled"
                                      f" (line {self.disabled[flow.src]})")
            self.fail(els["src"], f"src: no device with dccommsId {flow.src!r}")
        dev = devices[flow.src][0]
        on_air = flow.size + dev.header_bytes
        if on_air > dev.max_frame_bytes:
            head = f" + headerBytes {dev.header_bytes} = {on_air}" if dev.header_bytes else ""
            self.fail(els["size"], f"size: {flow.size}{head} bytes exceeds maxFrameBytes"
                                   f" {dev.max_frame_bytes} of device {dev.dccomms_id!r}")
        if flow.dst != BROADCAST:
            hearing = [d for d, _ in devices.values()
                       if d.rx_channel == dev.tx_channel and d.address == flow.dst]
            if not hearing:
                self.warn(els["dst"], f"flow {flow.name!r}: no device listening on channel {dev.tx_channel}"
                                      f" has address {flow.dst}")
