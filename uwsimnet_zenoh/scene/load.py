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

import os
import sys
from pathlib import Path

from lxml import etree
from pydantic import ValidationError

from .acoustic import AcousticVocabulary
from .environment import EnvironmentVocabulary
from .legacy import LegacyVocabulary
from .model import (
    Channel,
    Device,
    Flow,
    Scene,
    Simulation,
    Tracing,
    Vehicle,
)
from .native import NativeVocabulary
from .xml import _LXML_POSITION, _TOP_IGNORED, _XML_DECL_ENCODING, ROOT, SceneError, Warn, _El, _Fields

__all__ = ["SceneError", "load_scene", "load_scene_text"]


def _stderr(msg: str) -> None:
    print(msg, file=sys.stderr)


MAX_SCENE_BYTES = 8 * 1024 * 1024
"""A scene file larger than this is refused before parsing (a 49 MB scene took 19 s and 1.2 GB)."""


def _size_error(source: str, n: int) -> SceneError:
    return SceneError(source, 0, f"scene file of {n} bytes is larger than the limit of {MAX_SCENE_BYTES}"
                                 f" bytes ({MAX_SCENE_BYTES // (1024 * 1024)} MiB)")


def load_scene(path: str | os.PathLike[str], on_warning: Warn | None = None) -> Scene:
    """Read a scene file.  Warnings (`file:line: warning: ...`) go to `on_warning` (default: stderr)."""
    source = os.fspath(path)
    try:
        with open(path, "rb") as fh:
            data = fh.read(MAX_SCENE_BYTES + 1)
            if len(data) > MAX_SCENE_BYTES:
                raise _size_error(source, os.fstat(fh.fileno()).st_size)
    except OSError as e:
        raise SceneError(source, 0, f"cannot read scene file: {e.strerror or e}") from None
    return _Reader(source, on_warning).read(data, name=Path(source).stem or "scene")


def load_scene_text(text: str | bytes, source: str = "<string>", on_warning: Warn | None = None) -> Scene:
    """Read a scene from a string (errors and warnings name `source`); the scene name defaults to "scene"."""
    if len(text) > MAX_SCENE_BYTES:
        raise _size_error(source, len(text))
    if isinstance(text, str):
        # lxml refuses str input that declares an encoding; the text is already decoded, so drop it
        # (on the same line, so line numbers do not move).
        text = _XML_DECL_ENCODING.sub(r"\1", text, count=1)
    return _Reader(source, on_warning).read(text, name="scene")



class _Reader(LegacyVocabulary, AcousticVocabulary, NativeVocabulary, EnvironmentVocabulary):
    """The whole document: the root, its sections in order, cross-checks."""

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
        k = self.kids(root, single=("netTracingScript", "simulation", "environment"),
                      repeat=("CustomCommsChannel", "AcousticCommsChannel", "vehicle", "flow"), ignore=_TOP_IGNORED)
        tracing_el, simulation_el = k.get("netTracingScript"), k.get("simulation")
        tracing = self.tracing(tracing_el) if tracing_el is not None else Tracing()
        simulation = self.simulation(simulation_el) if simulation_el is not None else Simulation()
        env_el = k.get("environment")
        environment = self.environment(env_el) if env_el is not None else None

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

        links = [(v, self.link_topics[v.name]) for v in vehicles if v.ros2_link is not None]
        if links:
            self.check_ros2_links(links, {d.address for d, _ in devices.values()})
        for d, els in devices.values():
            for tag, ch_id in (("txChannelId", d.tx_channel), ("rxChannelId", d.rx_channel)):
                if ch_id not in channel_line:
                    kind = "AcousticCommsChannel" if d.acoustic is not None else "CustomCommsChannel"
                    self.fail(els[tag], f"{els[tag].tag}: no {kind} with id {ch_id}")
        by_id = {c.id: c for c in channels}
        for d, els in devices.values():
            self.check_acoustic(d, els, by_id)

        flows: list[Flow] = []
        flow_els: list[_El] = []
        flow_line: dict[str, int] = {}
        for i, el in enumerate(k.all("flow"), start=1):
            f, els = self.flow(el, i)
            if f.name in flow_line:
                self.fail(els.get("name", el),
                          f"duplicate flow name {f.name!r} (first at line {flow_line[f.name]})")
            flow_line[f.name] = el.sourceline or 0
            self.check_flow(f, els, devices)
            flows.append(f)
            where = els.get("interval")
            flow_els.append(where if where is not None else els.get("rate", el))
        self.check_flow_load(flows, flow_els, simulation)

        fields = _Fields()
        fields.values.update(name=simulation.world or name, source=self.source, simulation=simulation,
                             tracing=tracing, channels=tuple(channels), vehicles=tuple(vehicles),
                             flows=tuple(flows), environment=environment)
        return self.build(Scene, root, fields)

