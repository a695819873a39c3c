"""The channel broker: the simulated modems of a scene's channels, served on Zenoh keys.

One broker hosts a `Network` (usually built from the channels it was given) and puts every modem of it
on the key space of docs/gli-protocol.md:

* `modem/<id>/tx` is read by ONE wildcard subscriber (`modem/*/tx`: one OS thread, not one per modem);
  `rx` and `status` are published per modem; `info` is one wildcard queryable; each modem holds a
  `driver/sim` liveliness token while the broker serves it.
* `pose/**`: vehicles with poseSource zenoh are positioned only by the samples that arrive (last sample,
  extrapolated with its velocity if it has one); the broker publishes the poses of the scene-driven
  vehicles it carries at their `poseRate` (default 10 Hz).
* `trace/<channel>` repeats every trace record; `clock` carries simulation time (and the wall epoch).
* `control/<op>` queryables (bus/control.py); `driver/real` tokens of real modem drivers (HIL swap):
  while one is present the broker stops serving that id (its sim token goes away, the simulated modem
  leaves the channel and what it held ends `dropped` reason `swapped`, its tx is ignored); when the
  token goes the device is re-added from the scene and served again.

Threading: Zenoh callbacks run on Zenoh's threads and only hand raw bytes to `clock.call_soon`; all
decoding, simulation and publishing happens on the engine thread.  A bad message never stops the
broker: it is answered on the modem's `status` with `dropped` and a reason, counted, and logged
(rate-limited).
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections import Counter
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

import zenoh
from uwsimnet_gli import wire
from uwsimnet_gli.wire import Keys, check_chunk, is_chunk, parse

from ..kernel.realtime import Deferred
from .control import Control

if TYPE_CHECKING:
    from ..engine.network import Network
    from ..kernel.frame import Frame
    from ..kernel.realtime import RealtimeClock
    from ..phy.modem import Modem

log = logging.getLogger("uwsimnet.bus.broker")

BLOCK = zenoh.CongestionControl.BLOCK
"""rx frames and status events wait for room rather than being dropped: both come at modem rates (small,
rare), and with *drop* Zenoh gives up after `wait_before_drop` (1 ms) without a free batch, which a loaded
machine hits: the app then missed frames the trace says it received (seen in the HIL formation run).
*Block* waits at most `wait_before_close` (5 s) and then closes the transport to the stuck peer."""


def _direct(fn: Any) -> Any:
    """Run `fn` on Zenoh's network thread instead of a Python thread of its own: one thread hop (and
    ~0.1 ms of wake-up on a VM) less per message.  Only for callbacks that merely enqueue."""
    return zenoh.handlers.Callback(fn, indirect=False)


class Throttle:
    """At most `burst` log lines per key, then one per `every` seconds with the count suppressed."""

    def __init__(self, burst: int = 5, every: float = 5.0) -> None:
        self.burst = burst
        self.every = every
        self._n: Counter[str] = Counter()
        self._last: dict[str, float] = {}
        self._hidden: Counter[str] = Counter()

    def __call__(self, key: str, msg: str, *args: Any) -> None:
        self._n[key] += 1
        now = time.monotonic()
        if self._n[key] <= self.burst or now - self._last.get(key, 0.0) >= self.every:
            hidden = self._hidden.pop(key, 0)
            suffix = f" ({hidden} similar messages suppressed)" if hidden else ""
            log.warning(msg + suffix, *args)
            self._last[key] = now
        else:
            self._hidden[key] += 1


class Endpoint:
    """What the broker holds for one served modem."""

    __slots__ = ("modem", "rx_pub", "status_pub", "token", "bad")

    def __init__(self, modem: Modem, rx_pub: Any, status_pub: Any) -> None:
        self.modem = modem
        self.rx_pub = rx_pub
        self.status_pub = status_pub
        self.token: Any = None
        self.bad: Counter[str] = Counter()      # messages refused before reaching the modem, by reason


class Broker:
    def __init__(self, session: zenoh.Session, net: Network, clock: RealtimeClock, *,
                 world: str | None = None, channels: Iterable[int] | None = None,
                 tx_limit: int = wire.MAX_TX_MESSAGE, publish_trace: bool = True,
                 clock_rate_hz: float = 10.0, foreign: Iterable[str] = ()) -> None:
        self.session = session
        self.net = net
        self.clock = clock
        self.keys = Keys(world or net.scene.world)
        self.channels = None if channels is None else frozenset(channels)
        """Channel ids this broker serves (None: the whole scene)."""
        self.tx_limit = tx_limit
        self.publish_trace = publish_trace
        self.clock_rate_hz = clock_rate_hz
        self.endpoints: dict[str, Endpoint] = {}
        self.real: set[str] = set()
        """Modem ids for which a real driver holds `driver/real`."""
        self.swapped: dict[str, tuple[str, Any]] = {}
        """Modems handed to a real driver: (vehicle, device config) to put them back when it leaves."""
        self.foreign: set[str] = set(foreign)
        """Modem ids of the scene served by other brokers (their channels are not ours): ignored here."""
        self.counters: Counter[str] = Counter()
        self.warn = Throttle()
        self._entities: list[Any] = []
        self._trace_pubs: dict[int, Any] = {}
        self._trace_buf: Deferred | None = None
        self._pose_pubs: dict[str, Any] = {}
        self._clock_pub: Any = None
        self._waiting_pose: set[str] = set()
        self._due_poses: list[list[str]] = []
        self._clock_due = False
        self._started = False
        self._closed = False
        self.control = Control(self)

    # -- lifecycle (main thread, before the clock starts) ----------------------------------------
    def start(self) -> None:
        net, k, s = self.net, self.keys, self.session
        for name in net.poses.names:
            check_chunk(name, "vehicle name")
        for dev in net.modems:
            check_chunk(dev, "dccommsId")
        for m in list(net.modems.values()):
            self.attach(m)
        ent = self._entities
        cb = _direct
        ent.append(s.declare_subscriber(k.tx_all, cb(self._on_tx_sample)))
        ent.append(s.declare_subscriber(k.pose_all, cb(self._on_pose_sample), allowed_origin=zenoh.Locality.REMOTE))
        ent.append(s.declare_queryable(k.info_all, cb(self._on_info_query)))
        ent.append(s.declare_queryable(k.control_all, cb(self._on_control_query)))
        ent.append(s.liveliness().declare_subscriber(k.drivers("real"), cb(self._on_driver_sample), history=True))
        if self.publish_trace:
            for ch in net.channels:
                self._trace_pubs[ch] = s.declare_publisher(k.trace(ch))
            self._trace_buf = Deferred(self._trace_sink)
            net.tracer.add(self._trace_buf)
            self.clock.idle_hooks.append(self._trace_buf.flush)
        self._clock_pub = s.declare_publisher(k.clock)
        self.clock.idle_hooks.append(self._publish_due)
        self._schedule_poses()
        if self.clock_rate_hz > 0:
            net.sched.at(net.sched.now, self._clock_tick)
        for v in net.vehicles.values():
            if v.pose_source == "zenoh" and not net.poses.known[net.poses.index[v.name]]:
                self._waiting_pose.add(v.name)
                mods = [m.id for m in net.modems.values() if m.vehicle == v.name]
                if mods:
                    log.info("vehicle %s has no pose yet: %s neither send nor receive until a sample"
                             " arrives on %s", v.name, ", ".join(mods), k.pose(v.name))
        self._started = True

    def close(self) -> None:
        """Undeclare everything (call after the clock has stopped; the session stays open)."""
        if self._closed:
            return
        self._closed = True
        if self._trace_buf is not None:
            with contextlib.suppress(Exception):
                self._trace_buf.flush()
        for e in self._entities:
            self._undeclare(e)
        for ep in self.endpoints.values():
            for e in (ep.token, ep.rx_pub, ep.status_pub):
                self._undeclare(e)
        for e in (*self._trace_pubs.values(), *self._pose_pubs.values(), self._clock_pub):
            self._undeclare(e)
        self._entities.clear()

    @staticmethod
    def _undeclare(e: Any) -> None:
        if e is None:
            return
        with contextlib.suppress(Exception):      # closing anyway
            e.undeclare()

    # -- serving modems (engine thread once started) ---------------------------------------------
    def serves(self, channel: int) -> bool:
        return self.channels is None or channel in self.channels

    def attach(self, m: Modem) -> Endpoint:
        k, s = self.keys, self.session
        ep = Endpoint(m, s.declare_publisher(k.rx(m.id), congestion_control=BLOCK, express=True),
                      s.declare_publisher(k.status(m.id), congestion_control=BLOCK, express=True))
        self.endpoints[m.id] = ep
        self.foreign.discard(m.id)
        if m.id not in self.real:
            ep.token = s.liveliness().declare_token(k.driver(m.id, "sim"))
        m.on_receive.append(self._on_rx)
        m.on_status.append(self._on_status)
        return ep

    def detach(self, dev: str) -> None:
        ep = self.endpoints.pop(dev, None)
        if ep is None:
            return
        for e in (ep.token, ep.rx_pub, ep.status_pub):
            self._undeclare(e)

    def serving(self, dev: str) -> Endpoint | None:
        """The endpoint if this broker serves `dev` right now (not handed to a real driver)."""
        if dev in self.real:
            return None
        return self.endpoints.get(dev)

    # -- Zenoh callbacks: enqueue only -----------------------------------------------------------
    def _on_tx_sample(self, sample: zenoh.Sample) -> None:
        pl = sample.payload
        if len(pl) > self.tx_limit:                      # do not copy what we will refuse anyway
            self.clock.call_soon(self._handle_tx, str(sample.key_expr), None, len(pl))
        else:
            self.clock.call_soon(self._handle_tx, str(sample.key_expr), pl.to_bytes(), 0)

    def _on_pose_sample(self, sample: zenoh.Sample) -> None:
        pl = sample.payload
        raw = pl.to_bytes() if len(pl) <= wire.MAX_SMALL_MESSAGE else None
        self.clock.call_soon(self._handle_pose, str(sample.key_expr), raw)

    def _on_info_query(self, query: zenoh.Query) -> None:
        self.clock.call_soon(self._answer_info, query)

    def _on_control_query(self, query: zenoh.Query) -> None:
        pl = query.payload
        raw = pl.to_bytes() if pl is not None and len(pl) <= wire.MAX_SMALL_MESSAGE else pl
        self.clock.call_soon(self._answer_control, query, raw)

    def _on_driver_sample(self, sample: zenoh.Sample) -> None:
        self.clock.call_soon(self._driver_change, str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT)

    # -- the engine side -------------------------------------------------------------------------
    def _refuse(self, dev: str, reason: str, detail: str, tag: int | None = None,
                ep: Endpoint | None = None) -> None:
        self.counters[reason] += 1
        if ep is not None:
            ep.bad[reason] += 1
        key = reason if ep is None else f"{reason}:{dev}"        # bounded: unknown ids share one key
        self.warn(key, "%s: tx dropped (%s): %s", dev, reason, detail)
        pub = ep.status_pub if ep is not None else None
        payload = wire.encode_status(tag, "dropped", reason, self.net.sched.now)
        try:
            if pub is not None:
                pub.put(payload)
            else:
                self.session.put(self.keys.status(dev), payload, congestion_control=BLOCK)
        except Exception as e:  # noqa: BLE001 - answering is best effort
            log.debug("status for %s not sent: %s", dev, e)

    def _handle_tx(self, key: str, raw: bytes | None, size: int) -> None:
        k = parse(key)
        if k is None or k.kind != "modem" or k.leaf != "tx" or k.world != self.keys.world:
            return
        dev = k.name
        self.counters["tx_messages"] += 1
        if dev in self.real or dev in self.foreign:
            return                                      # served by a real driver / another broker
        ep = self.endpoints.get(dev)
        if ep is None:
            if self.channels is None:                   # we serve the whole scene: nobody else will answer
                self._refuse(dev, "unknown", "no such modem in this world", wire.tag_of(raw, self.tx_limit))
            else:
                self.counters["unknown"] += 1
            return
        if raw is None:
            self._refuse(dev, "toolarge", f"message of {size} bytes, the limit is {self.tx_limit}", ep=ep)
            return
        try:
            req = wire.decode_tx(raw, self.tx_limit)
        except wire.CodecError as e:
            self._refuse(dev, e.reason, e.detail, e.tag, ep)
            return
        m = ep.modem
        refuse = None if self.net.poses.known[m.vehicle_index] else "nopose"
        if refuse:
            self.counters["nopose"] += 1
            ep.bad["nopose"] += 1
            self.warn(f"nopose:{dev}", "%s: tx dropped (nopose): vehicle %s has no pose yet", dev, m.vehicle)
        m.send(req.dst, len(req.data), data=req.data, flow=req.flow, tag=req.tag, refuse=refuse, msg=req.msg)

    def _on_rx(self, m: Modem, frame: Frame, t: float) -> None:
        ep = self.serving(m.id)
        if ep is None:
            return
        data = frame.data if frame.data is not None else bytes(frame.payload)
        ep.rx_pub.put(wire.encode_rx(frame.src, frame.dst, data, frame.seq, frame.t_tx, t, m.rx_dist, frame.msg))

    def _on_status(self, m: Modem, frame: Frame, event: str, reason: str | None, t: float) -> None:
        tag = frame.tag if isinstance(frame.tag, int) and not isinstance(frame.tag, bool) else None
        if getattr(m, "hil_swapped", False):
            # a simulated modem handed to a real driver: what it still held ends here, said once
            if event == "dropped" and reason == "removed":
                reason = "swapped"
            with contextlib.suppress(Exception):
                self.session.put(self.keys.status(m.id), wire.encode_status(tag, event, reason, t, frame.seq),
                                 congestion_control=BLOCK)
            return
        ep = self.serving(m.id)
        if ep is None or ep.modem is not m:
            return
        ep.status_pub.put(wire.encode_status(tag, event, reason, t, frame.seq))

    def _trace_sink(self, rec: dict) -> None:
        pub = self._trace_pubs.get(rec["ch"])
        if pub is not None:
            pub.put(wire.pack(rec))

    def _handle_pose(self, key: str, raw: bytes | None) -> None:
        k = parse(key)
        if k is None or k.kind != "pose" or k.world != self.keys.world:
            self.counters["pose_bad_key"] += 1
            return
        name = k.name
        v = self.net.vehicles.get(name)
        if v is None:
            self.counters["pose_unknown"] += 1
            self.warn("pose_unknown", "pose for unknown vehicle %r ignored", name)
            return
        if v.pose_source != "zenoh":
            if self.channels is not None:           # another broker of this world publishes it too:
                self.counters["pose_peer"] += 1     # expected, counted, no warning (two would flood)
                return
            self.counters["pose_ignored"] += 1
            self.warn(f"pose_ignored:{name}", "pose for %s ignored: the scene drives it (poseSource scene)",
                      name)
            return
        try:
            if raw is None:
                raise wire.CodecError("toolarge", f"pose sample over {wire.MAX_SMALL_MESSAGE} bytes")
            pose = wire.decode_pose(raw)
        except wire.CodecError as e:
            self.counters["pose_" + e.reason] += 1
            self.warn(f"pose_bad:{name}", "pose for %s ignored (%s): %s", name, e.reason, e.detail)
            return
        self.counters["poses"] += 1
        self.net.move(name, pose.p, pose.v)
        if name in self._waiting_pose:
            self._waiting_pose.discard(name)
            log.info("vehicle %s: first pose %s", name, list(pose.p))

    def _driver_change(self, key: str, present: bool) -> None:
        k = parse(key)
        if k is None or k.leaf != "driver" or k.driver != "real" or k.world != self.keys.world:
            return
        dev = k.name
        if present:
            if dev in self.real:
                return
            ep = self.endpoints.get(dev)
            if ep is not None:
                self._swap_out(dev, ep)
            self.real.add(dev)
        else:
            if dev not in self.real:
                return
            self.real.discard(dev)
            held = self.swapped.pop(dev, None)
            if held is not None and dev not in self.net.modems:
                vehicle, cfg = held
                try:
                    m = self.net.add_device(vehicle, cfg)
                except ValueError as e:
                    log.warning("%s: the real driver left but the simulated modem cannot come back: %s", dev, e)
                    return
                self.attach(m)
                self.counters["swap_in"] += 1
                log.info("%s: the real driver left; the simulated modem serves it again", dev)
            elif dev in self.endpoints and self.endpoints[dev].token is None:
                self.endpoints[dev].token = self.session.liveliness().declare_token(self.keys.driver(dev, "sim"))

    def _swap_out(self, dev: str, ep: Endpoint) -> None:
        """A real driver takes `dev` (HIL swap): the simulated modem leaves the channel, so simulated
        frames neither reach it nor come from it; every frame it still held ends with a `dropped`
        status (reason `swapped`) before its keys go quiet."""
        m = ep.modem
        if ep.token is not None:
            self._undeclare(ep.token)
            ep.token = None
        m.hil_swapped = True                      # type: ignore[attr-defined]  (see _on_status)
        while m.fifo:
            m.drop(m.fifo_pop(), "swapped")
        self.swapped[dev] = (m.vehicle, m.cfg)
        with contextlib.suppress(ValueError):
            self.net.remove_device(dev)
        self.detach(dev)
        self.counters["swap_out"] += 1
        log.info("%s: a real driver took over; the simulated modem left the channel", dev)

    # -- queries ---------------------------------------------------------------------------------
    def info(self, dev: str) -> dict[str, Any]:
        """The `info` reply of a served modem: configuration, kind and live state."""
        m = self.endpoints[dev].modem
        net = self.net
        cfg = m.cfg
        known = bool(net.poses.known[m.vehicle_index])
        pos = net.poses.positions(net.sched.now)[m.vehicle_index] if known else None
        counters = dict(m.counters)
        counters.update(self.endpoints[dev].bad)
        return {
            "id": m.id, "kind": "sim", "world": self.keys.world, "address": m.address, "vehicle": m.vehicle,
            "tx_channel": m.tx_channel.id, "rx_channel": m.rx_channel.id, "bitrate": m.bitrate,
            # the tx channel's delay law, the parameters phy.channel.Channel computes delays with
            "prop": {"min": m.tx_channel.min_prop_s, "per_m": m.tx_channel.prop_s_per_m},
            "rx_prop": {"min": m.rx_channel.min_prop_s, "per_m": m.rx_channel.prop_s_per_m},
            "header_bytes": m.header_bytes, "max_frame_bytes": cfg.max_frame_bytes,
            "tx_framing": cfg.tx_framing, "rx_framing": cfg.rx_framing or cfg.tx_framing,
            "fifo_capacity": m.fifo_cap, "fifo_bytes": m.fifo_bytes, "fifo_frames": len(m.fifo),
            "phy_busy": m.phy_busy, "mac": cfg.mac.name, "pose_known": known,
            "position": None if pos is None else [float(x) for x in pos],
            "counters": counters, "config": cfg.model_dump(mode="json", exclude={"line"}),
            "t": net.sched.now, "epoch": self.clock.wall_epoch(), "speed": self.clock.speed,
        }

    def _answer_info(self, query: zenoh.Query) -> None:
        with query:
            ke = query.key_expr
            for dev in list(self.endpoints):
                if dev in self.real:
                    continue
                key = self.keys.info(dev)
                if ke.intersects(key):
                    query.reply(key, wire.pack(self.info(dev)))

    def _answer_control(self, query: zenoh.Query, raw: Any) -> None:
        with query:
            ke = query.key_expr
            op = str(ke).rsplit("/", 1)[-1]
            if not is_chunk(op) or not ke.intersects(self.keys.control(op)):
                op, reply = "?", {"ok": False, "error": "name one operation: control/<op>"}
            else:
                if raw is not None and not isinstance(raw, bytes):
                    reply = {"ok": False, "error": f"request larger than {wire.MAX_SMALL_MESSAGE} bytes"}
                else:
                    try:
                        reply = self.control.handle(op, wire.decode_request(raw))
                    except wire.CodecError as e:
                        reply = {"ok": False, "error": f"{e.reason}: {e.detail}"}
            if not reply.get("ok"):
                self.warn(f"control:{op}", "control/%s refused: %s", op, reply.get("error"))
            if op == "?":
                query.reply_err(wire.pack(reply))
            else:
                query.reply(self.keys.control(op), wire.pack(reply))

    # -- periodic publications (engine events) ---------------------------------------------------
    def _schedule_poses(self) -> None:
        net = self.net
        served_vehicles = {m.vehicle for m in net.modems.values()}
        by_rate: dict[float, list[str]] = {}
        for v in net.vehicles.values():
            if v.pose_source != "scene":
                continue
            if self.channels is not None and v.name not in served_vehicles:
                continue
            by_rate.setdefault(v.pose_rate_hz, []).append(v.name)
            self._pose_pubs[v.name] = self.session.declare_publisher(self.keys.pose(v.name))
        t0 = net.sched.now
        for rate, names in by_rate.items():
            net.sched.at(t0, self._pose_tick, names, 1.0 / rate, t0, 0)

    def _pose_tick(self, names: list[str], period: float, t0: float, n: int) -> None:
        """Marks the poses of `names` due; the idle hook publishes them (inline if the last batch is
        still waiting: an engine that is never idle still publishes)."""
        if self._due_poses:
            self._publish_due()
        self._due_poses.append(names)
        now = self.net.sched.now
        nxt = t0 + (n + 1) * period
        while nxt <= now:       # fell behind (paused, slow machine): skip, do not burst
            n += 1
            nxt = t0 + (n + 1) * period
        self.net.sched.at(nxt, self._pose_tick, names, period, t0, n + 1)

    def _publish_due(self) -> None:
        """Idle hook: the periodic publications that are due (poses, clock)."""
        if self._due_poses:
            net = self.net
            pos = net.poses.positions(net.sched.now)
            idx = net.poses.index
            now = net.sched.now
            batches, self._due_poses = self._due_poses, []
            for names in batches:
                for name in names:
                    pub = self._pose_pubs.get(name)
                    if pub is not None:
                        pub.put(wire.encode_pose(pos[idx[name]], t=now))
        if self._clock_due:
            self._clock_due = False
            self.publish_clock()

    def clock_sample(self) -> dict[str, Any]:
        c = self.clock
        return {"t": self.net.sched.now if c.paused else c.now(), "epoch": c.wall_epoch(), "speed": c.speed,
                "paused": c.paused}

    def publish_clock(self) -> None:
        if self._clock_pub is not None:
            self._clock_pub.put(wire.pack(self.clock_sample()))

    def _clock_tick(self) -> None:
        if self._clock_due:
            self.publish_clock()
        self._clock_due = True
        self.net.sched.after(1.0 / self.clock_rate_hz, self._clock_tick)
