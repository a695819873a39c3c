"""The native extensions: `<flow>` (traffic sources), a vehicle's `<ros2Link>`, and their checks against the
scene."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

from .model import (
    BROADCAST,
    Device,
    Flow,
    Simulation,
    Vehicle,
)
from .ros2_link import RULE_KEYS, LinkError, LinkSpec, TopicRule, rule_from_fields
from .xml import SceneError, XmlReader, _El, _Fields, _is_element

MIN_FLOW_INTERVAL = 1e-6
"""s: a flow's (mean) interval below this is refused: the run could not finish (at 1e-12 s simulated
time stops advancing; the trace grows without end)."""
MAX_FLOW_FRAMES = 10_000_000
"""Frames all flows together may offer over the run (duration, or each flow's stop): a bound on what
a run can finish (about 5 events and a few trace lines per frame)."""
MAX_FLOW_RATE = 100_000.0
"""frames per simulated second all flows together may offer (a run with no end, e.g. realtime until
Ctrl-C, is bounded by this alone)."""


class NativeVocabulary(XmlReader):
    """Mixin: flows, ROS 2 links."""

    # --- ROS 2 links (docs/ros2-link.md) -------------------------------------------------------------

    def ros2_link(self, el: _El, devices: Sequence[Device]) -> tuple[LinkSpec, list[_El]]:
        """`<ros2Link>`: `<modem>` (a dccommsId of the vehicle; may be left out when it has one device),
        `<rosDomain>`, `<mtu>`, `<namespace>` and one `<topic .../>` per topic, whose attributes are the
        keys of `--topic` (`name` for `topic`). Also the topic elements, for the scene-wide checks."""
        k = self.kids(el, single=("modem", "rosDomain", "mtu", "namespace"), repeat=("topic",))
        ids = [d.dccomms_id for d in devices]
        if (e := k.get("modem")) is not None:
            modem = self.string(e)
            if modem not in ids:
                self.fail(e, f"ros2Link/modem: {modem!r} is not a device of this vehicle"
                             f" ({', '.join(ids) or 'it has none'})")
        elif len(ids) == 1:
            modem = ids[0]
        else:
            self.fail(el, f"ros2Link: missing <modem> (the vehicle has {len(ids)} devices: name one)")
        domain = self.integer(self.need(k, "rosDomain"))[0]
        mtu_el = k.get("mtu")
        mtu = self.integer(mtu_el)[0] if mtu_el is not None else 64
        dev = devices[ids.index(modem)]
        if mtu_el is not None and mtu > dev.max_frame_bytes:
            self.fail(mtu_el, f"ros2Link/mtu: {mtu} is larger than {modem}'s maxFrameBytes {dev.max_frame_bytes}")
        namespace = self.string(e) if (e := k.get("namespace")) is not None else "/"
        topic_els = k.all("topic")
        rules = [self.link_topic(t) for t in topic_els]
        seen: dict[str, int] = {}
        for r, t in zip(rules, topic_els, strict=True):
            if r.name in seen:
                self.fail(t, f"topic {r.name}: listed twice on the link (first at line {seen[r.name]})")
            seen[r.name] = t.sourceline or 0
        try:
            spec = LinkSpec(modem, domain, tuple(rules), mtu=mtu, namespace=namespace, line=el.sourceline or 0)
        except LinkError as e:
            where = {"ROS domain": k.get("rosDomain"), "mtu": mtu_el, "namespace": k.get("namespace")}
            self.fail(next((w for p, w in where.items() if str(e).startswith(p) and w is not None), el),
                      f"ros2Link: {e}")
        return spec, topic_els

    def link_topic(self, el: _El) -> TopicRule:
        keys = {("name" if k == "topic" else k) for k in RULE_KEYS}
        self._no_attributes(el, keys)
        if any(_is_element(c) for c in el) or (el.text or "").strip():
            self.fail(el, "topic: its settings are attributes (name=, type=, dir=, ...), it holds nothing")
        missing = [a for a in ("name", "type") if a not in el.attrib]
        if missing:
            self.fail(el, f"topic: missing {' and '.join(missing)}= (both are required)")
        fields = {("topic" if k == "name" else k): v for k, v in el.attrib.items()}
        try:
            return rule_from_fields(fields, "topic")
        except LinkError as e:
            self.fail(el, str(e))

    def check_ros2_links(self, vehicles: Sequence[tuple[Vehicle, list[_El]]], addresses: set[int]) -> None:
        """Across the scene: one ROS domain per robot (its graph is its own), the same topics in the same
        order on every link (the topic index on air is the position), destinations that exist."""
        domains: dict[int, tuple[str, int]] = {}
        first: tuple[Vehicle, list[_El]] | None = None
        for v, topic_els in vehicles:
            spec = v.ros2_link
            assert spec is not None
            if spec.domain in domains:
                other, line = domains[spec.domain]
                raise SceneError(self.source, spec.line, f"ros2Link: rosDomain {spec.domain} is also {other}'s"
                                 f" (line {line}): each robot's graph needs its own domain")
            domains[spec.domain] = (v.name, spec.line)
            for r, t in zip(spec.topics, topic_els, strict=True):
                if r.dst != BROADCAST and r.dst not in addresses:
                    self.fail(t, f"topic {r.name}: dst {r.dst}: no device of the scene has that mac"
                                 " (255 = broadcast)")
            if first is None:
                first = (v, topic_els)
                continue
            ref = first[0].ros2_link
            assert ref is not None
            mine, theirs = spec.signature(), ref.signature()
            for i, (a, t) in enumerate(zip(mine, topic_els, strict=True)):
                if i >= len(theirs) or a != theirs[i]:
                    want = f"{theirs[i][0]} ({theirs[i][1]})" if i < len(theirs) else "nothing"
                    self.fail(t, f"topic {a[0]}: position {i + 1} on {first[0].name}'s link (line {ref.line}) is"
                                 f" {want}: every link lists the same topics in the same order (the index on air)")
            if len(mine) < len(theirs):
                raise SceneError(self.source, spec.line, f"ros2Link: {len(mine)} topics, {first[0].name}'s link"
                                 f" (line {ref.line}) has {len(theirs)}: every link lists the same topics")

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

    def check_flow_load(self, flows: Sequence[Flow], els: Sequence[_El], sim: Simulation) -> None:
        """Flows whose event rate a run cannot finish (the bounds above), at the flow's interval/rate."""
        end = sim.duration
        if end is None:       # Scene.end_time without a duration: the last flow stop, else 60 s (+1)
            stops = [f.stop for f in flows if f.stop is not None]
            end = max(stops, default=60.0) + 1.0
        rate = 0.0
        frames = 0.0
        worst: tuple[float, int] = (-1.0, 0)
        for i, f in enumerate(flows):
            if f.interval < MIN_FLOW_INTERVAL or not math.isfinite(end + f.interval) or end + f.interval == end:
                self.fail(els[i], f"flow {f.name!r}: interval {f.interval:g} s is below the bound of"
                                  f" {MIN_FLOW_INTERVAL:g} s: a run could not finish")
            stop = end if f.stop is None else min(f.stop, end)
            n = max(0.0, stop - f.start) / f.interval
            rate += 1.0 / f.interval
            frames += n
            if n > worst[0]:
                worst = (n, i)
            if rate > MAX_FLOW_RATE:
                self.fail(els[i], f"flow {f.name!r}: the flows offer {rate:.6g} frames/s in all, above the"
                                  f" bound of {MAX_FLOW_RATE:g}/s: a run could not keep up")
        if frames > MAX_FLOW_FRAMES:
            f = flows[worst[1]]
            self.fail(els[worst[1]], f"flow {f.name!r}: the flows offer {frames:.6g} frames over the run"
                                     f" ({end:g} s), above the bound of {MAX_FLOW_FRAMES:g}: a run could"
                                     " not finish (shorten the duration or lengthen the intervals)")

    def check_flow(self, flow: Flow, els: dict[str, _El],
                   devices: Mapping[str, tuple[Device, dict[str, _El]]]) -> None:
        if flow.src not in devices:
            if flow.src in self.disabled:
                self.fail(els["src"], f"src: device {flow.src!r} is disabled"
                                      f" (line {self.disabled[flow.src]})")
            self.fail(els["src"], f"src: no device with dccommsId {flow.src!r}")
        dev = devices[flow.src][0]
        framing = None
        if dev.tx_framing:
            from ..phy.framing import builder  # noqa: PLC0415 - scenes with a framing only (start-up time)

            framing = builder(dev.tx_framing)
        if framing is not None and (why := framing.check_payload(flow.size)) is not None:
            self.fail(els["size"], f"size: {why} of device {dev.dccomms_id!r}")
        framed = framing.frame_size(flow.size) if framing is not None else flow.size
        on_air = framed + dev.header_bytes
        if on_air > dev.max_frame_bytes:
            head = f" framed by {framing.name} = {framed}" if framing is not None else ""
            head += f" + headerBytes {dev.header_bytes} = {on_air}" if dev.header_bytes else ""
            self.fail(els["size"], f"size: {flow.size}{head} bytes exceeds maxFrameBytes"
                                   f" {dev.max_frame_bytes} of device {dev.dccomms_id!r}")
        if 0 < dev.tx_fifo_bytes < on_air:
            self.fail(els["size"], f"size: {on_air} bytes on air exceed txFifoSize {dev.tx_fifo_bytes} of device"
                                   f" {dev.dccomms_id!r} (every frame would be refused: it could never wait there)")
        if flow.dst == dev.address:
            self.fail(els["dst"], f"dst: {flow.dst} is the address of the flow's own device {dev.dccomms_id!r}"
                                  " (a frame to itself would be sent and never get an outcome)")
        if flow.dst != BROADCAST:
            cache = getattr(self, "_listening", None)     # (rx channel, address) of every device, built once
            if cache is None or cache[0] is not devices or cache[1] != len(devices):
                cache = self._listening = (devices, len(devices), {(d.rx_channel, d.address)
                                                                   for d, _ in devices.values()})
            if (dev.tx_channel, flow.dst) not in cache[2]:
                self.warn(els["dst"], f"flow {flow.name!r}: no device listening on channel {dev.tx_channel}"
                                      f" has address {flow.dst}")

