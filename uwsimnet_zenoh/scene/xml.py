"""The XML toolkit of the scene loader: hardened parsing, element access, `file:line` errors and warnings,
numbers and units.  The vocabularies (legacy.py, native.py, acoustic.py) are mixins on `XmlReader`."""

from __future__ import annotations

import math
import re
import sys
from collections.abc import Callable, Iterable, Iterator, Mapping
from decimal import Decimal
from typing import Any, NoReturn, TypeVar

from lxml import etree
from pydantic import BaseModel, ValidationError

from ..errors import UwsimnetError

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
    "minDistance", "macProtocol", "headerBytes", "maxFrameBytes", "txPacketBuilder", "rxPacketBuilder", "disable")
_MODULATIONS = ("bpsk", "bfsk_coherent", "bfsk_noncoherent", "dpsk", "bpsk_rayleigh")

NO_ERROR_MODEL_WARNING = "no rateErrorModel: assuming no propagation loss (the original assumed 0.01*m)"

_NUMBER = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
_INTEGER = re.compile(r"[+-]?[0-9]+")
_KEY_CHUNK_BAD = re.compile(r"[/*$?#\s]")
_XML_DECL_ENCODING = re.compile(r"""^(\s*<\?xml[^>]*?)\s+encoding\s*=\s*(["'])[^"']*\2""")
_LXML_POSITION = re.compile(r",\s*line \d+, column \d+\s*$")



class SceneError(UwsimnetError):
    """A problem in a scene file; `str(e)` is one line: `source:line: message`."""

    def __init__(self, source: str, line: int, message: str) -> None:
        self.source = source
        self.line = line
        self.message = " ".join(message.split())
        super().__init__(str(self))

    def __str__(self) -> str:
        return f"{self.source}:{self.line}: {self.message}"



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



def _stderr(msg: str) -> None:
    print(msg, file=sys.stderr)


class XmlReader:
    """Reporting, generic element access and model building; the vocabularies add the elements."""

    def __init__(self, source: str, on_warning: Warn | None) -> None:
        self.source = source
        self.on_warning = on_warning or _stderr
        self._warnings: list[tuple[int, int, str]] = []
        self.disabled: dict[str, int] = {}
        self.modelled: set[int] = set()
        self.link_topics: dict[str, list[_El]] = {}
        """A vehicle's `<ros2Link>` topic elements, by vehicle name (for the scene-wide checks)."""
        """Ids of the channels that name a `<channelModel>` (their devices' rateErrorModel is not used)."""

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
        import difflib  # noqa: PLC0415 - an error only (start-up time)

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

