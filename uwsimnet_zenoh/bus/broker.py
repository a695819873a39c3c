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
* `control/<op>` queryables (bus/control.py); `driver/real` tokens of real drivers (HIL swap): while one is
  present the broker stops serving that id (its sim token goes, the simulated modem leaves the channel, what
  it held ends `dropped` `swapped`, its tx is ignored); when it goes the device is re-added and served again.

Threading (the turn's rules: kernel/realtime.py): Zenoh callbacks run on Zenoh's network thread and hand
raw bytes on: a tx message to its modem's ingress `Lane` (bounded, taken round-robin: a flood on one modem
does not delay the others), run at once when the engine waits (`clock.run_here`), else `clock.call_soon`.
Pose samples wait in a Zenoh ring channel (bus/poses.py).  The simulation never makes a Zenoh put nor
encodes: it hands the output port's rx, status and trace events to bounded `Outbox`es (bus/outbox.py), one
thread each (one per modem), which encode and put, so a consumer that cannot keep up loses messages at the
edge, counted (`info` "edge", the run summary), and never stalls the engine or another modem.  A bad message
never stops the broker: it is answered on the modem's `status` with `dropped` and a reason, counted, and
logged (rate-limited).
"""

from __future__ import annotations

import contextlib
import logging
import sys
import time
from collections import Counter, deque
from collections.abc import Callable, Iterable
from typing import TYPE_CHECKING, Any

import zenoh
from uwsimnet_gli import wire
from uwsimnet_gli.wire import Keys, check_chunk, parse

from ..trace.events import Batch, Listener
from ..trace.tracer import FRAME_EVENTS
from .control import Control
from .endpoint import BLOCK, ModemEndpoint, put_record
from .hil import RETOKEN, SWAP_IN, SWAP_OUT, HilSwap
from .outbox import INGRESS_WARN_S, LANE_CAPACITY, OUTBOX_CAPACITY, POSE_KEYS, Lane, Latest, Outbox, Throttle
from .poses import KEY_CACHE, POSE_RING, Poses
from .queries import Queries

if TYPE_CHECKING:
    from ..engine.network import Network
    from ..kernel.frame import Frame
    from ..kernel.realtime import RealtimeClock
    from ..phy.modem import Modem

log = logging.getLogger("uwsimnet.bus.broker")
SWITCH_INTERVAL = 0.0005
"""s: the interpreter's thread switch interval while a broker runs (see Broker.start)."""
POSE_POLL_S = 0.002
"""Wall s: the engine takes the pose samples at least this often when it waits (RealtimeClock.poll)."""
_MISS = object()

def _direct(fn: Any) -> Any:
    """`fn` as a Zenoh callback run on Zenoh's network thread (`indirect=False`, unstable in zenoh-python),
    not on a Python thread of its own: one thread hop (~0.1 ms of wake-up on a VM) less per message.  The tx
    callback offers to a bounded lane and, when the engine waits, runs the message and its events right
    there (`RealtimeClock.run_here`): what that costs is said once, in kernel/realtime.py."""
    return zenoh.handlers.Callback(fn, indirect=False)


class Endpoint(ModemEndpoint):
    """What the broker holds for one served modem: its output keys and outbox (bus/endpoint.py, shared
    with the driver host), its ingress lane (its tx messages wait there for the engine), its token."""

    __slots__ = ("modem", "token", "bad", "lane")

    def __init__(self, session: zenoh.Session, keys: Keys, modem: Modem, out: Outbox, lane: Lane) -> None:
        super().__init__(session, keys, modem.id, out)
        self.modem = modem
        self.lane = lane
        self.token: Any = None
        self.bad: Counter[str] = Counter()      # messages refused before reaching the modem, by reason


class _Output(Listener):
    """The broker on the output port: the rx (frames handed up: kind data) and status events of the
    modems it serves go to their endpoints' outboxes at once; the trace goes at idle (`_trace_batch`)."""

    def __init__(self, broker: Broker) -> None:
        self.broker = broker

    def event(self, t: Any, ev: str, ch: int, dev: str, frame: Frame, reason: str | None, fifo: int | None,
              dist: Any, implicit: Any) -> None:
        if ev == "rx":
            if frame.kind == "data":
                self.broker._on_rx(dev, frame, t, dist)
        elif ev not in FRAME_EVENTS:
            self.broker._on_status(dev, frame, ev, reason, t)


class Broker(Poses, Queries):
    def __init__(self, session: zenoh.Session, net: Network, clock: RealtimeClock, *,
                 world: str | None = None, channels: Iterable[int] | None = None,
                 tx_limit: int = wire.MAX_TX_MESSAGE, publish_trace: bool = True,
                 clock_rate_hz: float = 10.0, foreign: Iterable[str] = (),
                 outbox_capacity: int = OUTBOX_CAPACITY, lane_capacity: int = LANE_CAPACITY,
                 ingress_warn_s: float = INGRESS_WARN_S) -> None:
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
        self.hil = HilSwap()
        """Who serves each id, the simulator or a real driver (bus/hil.py); `real`, `swapped` are its sets."""
        self.foreign: set[str] = set(foreign)
        """Modem ids of the scene served by other brokers (their channels are not ours): ignored here."""
        self.counters: Counter[str] = Counter()
        self.warn = Throttle(logger=log)
        self.outbox_capacity = outbox_capacity
        self.lane_capacity = lane_capacity
        self.ingress_warn_s = ingress_warn_s
        self.lanes: dict[str, Lane] = {}
        """Ingress lanes by modem id (kept after a modem leaves: its counts stay in the summary)."""
        self.outboxes: dict[str, Outbox] = {}
        """Outboxes by modem id, plus `*trace` and `*misc` (poses, clock, answers to unknown ids)."""
        self._other_lane = Lane("*", lane_capacity)         # tx for ids we do not serve (refused there)
        self._info_lane = Lane("*info", lane_capacity)      # info and control queries take their turn in
        self._control_lane = Lane("*control", lane_capacity)  # the round-robin like one more modem each
        self._poses_in = Latest(POSE_KEYS)
        """Pose samples waiting, the newest per key: applied when the geometry is read (see _pull_poses)."""
        self._tx_keys: dict[str, str | None] = {}
        """tx key -> modem id (None: not a tx key of this world), parsed once per key."""
        self._pose_keys: dict[str, tuple[str | None, str | None]] = {}
        """pose key -> (vehicle, None) to apply, or (name, counter) to refuse, classified once per key."""
        self._pose_sub: Any = None
        self._pose_taken = 0.0      # simulation time of the last take of the ring (arrival stamps are not before)
        self._to_wake: deque[Outbox] = deque()
        """Outboxes holding non-urgent messages (statuses) whose thread is to be woken (_wake_outboxes)."""
        self._misc = self._outbox("*misc", outbox_capacity)
        self._trace_out: Outbox | None = None
        self._leaving: dict[str, Outbox] = {}
        """Simulated modems handed to a real driver, by id: what they still say goes out here (HIL swap)."""
        self._entities: list[Any] = []
        self._trace_pubs: dict[int, Any] = {}
        self._pose_pubs: dict[str, Any] = {}
        self._clock_pub: Any = None
        self._waiting_pose: set[str] = set()
        self._due_poses: list[list[str]] = []
        self._clock_due = False
        self._started = False
        self._closed = False
        self.control = Control(self)

    @property
    def real(self) -> set[str]:
        """Modem ids for which a real driver holds `driver/real`."""
        return self.hil.real

    @property
    def swapped(self) -> dict[str, tuple[str, Any]]:
        """Modems handed to a real driver: (vehicle, device config) to put them back when it leaves."""
        return self.hil.held

    # -- lifecycle (main thread, before the clock starts) ----------------------------------------
    def start(self) -> None:
        # The engine thread shares the GIL with the outbox threads and Zenoh's callbacks; with Python's
        # default 5 ms switch interval a busy outbox thread (a flood's statuses) could hold the engine
        # several times 5 ms per frame.  0.5 ms bounds that wait (measured in tests/test_edge.py).
        if sys.getswitchinterval() > SWITCH_INTERVAL:
            sys.setswitchinterval(SWITCH_INTERVAL)
        net, k, s = self.net, self.keys, self.session
        for name in net.poses.names:
            check_chunk(name, "vehicle name")
        for dev in net.modems:
            check_chunk(dev, "dccommsId")
        for m in list(net.modems.values()):
            self.attach(m)
        net.tracer.listen(_Output(self), statuses=True)
        ent = self._entities
        cb = _direct
        ent.append(s.declare_subscriber(k.tx_all, cb(self._on_tx_sample)))
        # poses wait in a ring on Zenoh's side, with no Python callback: a swarm publishes its poses in
        # bursts (256 vehicles at once), and 256 callbacks in a row take the interpreter from the engine
        # thread for milliseconds (docs/runtime.md); the engine takes them when it reads the geometry
        self._pose_sub = s.declare_subscriber(k.pose_all, zenoh.handlers.RingChannel(POSE_RING),
                                              allowed_origin=zenoh.Locality.REMOTE)
        ent.append(self._pose_sub)
        self.clock.poll = POSE_POLL_S
        ent.append(s.declare_queryable(k.info_all, cb(self._on_info_query)))
        ent.append(s.declare_queryable(k.control_all, cb(self._on_control_query)))
        ent.append(s.liveliness().declare_subscriber(k.drivers("real"), cb(self._on_driver_sample), history=True))
        if self.publish_trace:
            for ch in net.channels:
                self._trace_pubs[ch] = s.declare_publisher(k.trace(ch))
            self._trace_out = self._outbox("*trace", 16 * self.outbox_capacity)   # every record of the channels
            net.tracer.consume(self._trace_batch)         # records made from the tracer's rows when the
            self.clock.idle_hooks.append(net.tracer.flush)  # engine is idle, not between an event and its rx
        self._clock_pub = s.declare_publisher(k.clock)
        self.clock.idle_hooks.append(self._publish_due)
        self.clock.idle_hooks.append(self._pull_poses_now)
        self.clock.done_hooks.append(self._wake_outboxes)
        net.poses.pull = self._pull_poses
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
        if self._trace_out is not None:     # the records not yet published (later ones are not)
            with contextlib.suppress(Exception):
                self.net.tracer.flush()
        self._closed = True
        self._pose_sub = None
        for e in self._entities:            # no more input
            self._undeclare(e)
        self._entities.clear()
        deadline = time.monotonic() + 2.0   # what is queued goes out (a stuck consumer does not hold us)
        for out in self.outboxes.values():
            out.close(max(0.05, deadline - time.monotonic()))
        for k in ("rx", "status", "trace"):  # the outboxes' counts, with what was left at close: one count
            if n := sum(out.dropped[k] for out in self.outboxes.values()):
                self.counters[f"edge_{k}"] = n      # set, not added: the outboxes' totals are the count
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

    def _outbox(self, name: str, capacity: int, on_wake: Callable[[], None] | None = None) -> Outbox:
        out = self.outboxes.get(name)
        if out is None or out._closing:
            out = self.outboxes[name] = Outbox(name, capacity, defer=self._to_wake.append, cpu=self.clock.cpu,
                                               on_wake=on_wake)
        return out

    def _wake_outboxes(self) -> None:
        """(engine, done hook) Wake the threads of the outboxes that took statuses meanwhile."""
        q = self._to_wake
        while q:
            q.popleft().wake()

    def attach(self, m: Modem) -> Endpoint:
        k, s = self.keys, self.session
        lane = self.lanes.get(m.id)
        if lane is None:
            lane = self.lanes[m.id] = Lane(m.id, self.lane_capacity)
        # a modem's rx frame is the output whose time is modelled: the engine yields to its put
        ep = Endpoint(s, k, m, self._outbox(m.id, self.outbox_capacity, self.clock.yield_to_output), lane)
        self.endpoints[m.id] = ep
        self.foreign.discard(m.id)
        if m.id not in self.real:
            ep.token = s.liveliness().declare_token(k.driver(m.id, "sim"))
        self._leaving.pop(m.id, None)
        return ep

    def detach(self, dev: str) -> None:
        ep = self.endpoints.pop(dev, None)
        if ep is None:
            return
        self._undeclare(ep.token)
        ep.token = None
        ep.undeclare_after_queued()

    def serving(self, dev: str) -> Endpoint | None:
        """The endpoint if this broker serves `dev` right now (not handed to a real driver)."""
        if dev in self.real:
            return None
        return self.endpoints.get(dev)

    # -- Zenoh callbacks: enqueue only -----------------------------------------------------------
    def _tx_dev(self, key: str) -> str | None:
        """The modem id of a tx key of this world, else None (parsed once per key, then a dict hit)."""
        dev = self._tx_keys.get(key, _MISS)
        if dev is _MISS:
            k = parse(key)
            dev = k.name if (k is not None and k.kind == "modem" and k.leaf == "tx"
                             and k.world == self.keys.world) else None
            if len(self._tx_keys) < KEY_CACHE:
                self._tx_keys[key] = dev
        return dev  # type: ignore[return-value]

    def _on_tx_sample(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        pl = sample.payload
        size = len(pl)
        raw = None if size > self.tx_limit else pl.to_bytes()     # do not copy what we will refuse anyway
        dev = self._tx_dev(key)
        lane = self.lanes.get(dev) if dev is not None and dev in self.endpoints else None
        if lane is None:
            lane = self._other_lane
        item = (self.clock.now(), dev, raw, size)
        r = lane.offer(item)
        if r:
            self.clock.run_here(self._drain_lane, lane)     # here if the engine waits, else its inbox
        elif r is None:
            self._lane_full(lane, dev, raw)

    def _lane_full(self, lane: Lane, dev: str | None, raw: bytes | None) -> None:
        """(Zenoh thread) A modem's ingress lane is full: the message is refused like a full FIFO
        (status `dropped`, reason `fifo`), counted, never traced (the modem never saw it)."""
        self.counters["ingress_fifo"] += 1
        ep = self.endpoints.get(dev) if dev is not None else None
        if ep is None:
            return
        tag = None
        if raw is not None:
            with contextlib.suppress(wire.CodecError):
                tag = wire.decode_tx(raw, self.tx_limit).tag
        ep.status(tag, "dropped", "fifo", self.clock.now())
        self.warn(f"ingress:{dev}", "%s: tx dropped (fifo): its ingress lane is full (%d messages waiting for"
                  " the engine)", dev, len(lane))

    def _drain_lane(self, lane: Lane) -> None:
        """(engine) One tx message of one modem, then back in line behind the other modems."""
        got = lane.take()
        if got is None:
            return
        delay, (stamp, dev, raw, size) = got
        sched = self.net.sched
        if stamp > sched.now:           # arrived after this turn was queued: not before its time
            nt = sched.next_time()
            if nt is None or nt >= stamp:
                sched.now = stamp
        if delay > self.ingress_warn_s:
            self.counters["ingress_late"] += 1
            self.warn(f"ingress_late:{lane.name}", "%s: ingress delay %.1f ms (put to engine) is over %.0f ms:"
                      " the engine cannot keep up with what arrives", lane.name, delay * 1e3,
                      self.ingress_warn_s * 1e3)
        try:
            self._handle_tx(dev, raw, size)
        finally:
            if lane.more():
                self.clock.call_soon(self._drain_lane, lane)

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
        if ep is not None:
            ep.status(tag, "dropped", reason, self.net.sched.now)
        else:
            self._misc.put(self._put_status(dev), wire.encode_status(tag, "dropped", reason, self.net.sched.now),
                           "status")

    def _put_status(self, dev: str) -> Any:
        key = self.keys.status(dev)
        return lambda payload: self.session.put(key, payload, congestion_control=BLOCK)

    def _handle_tx(self, dev: str | None, raw: bytes | None, size: int) -> None:
        if dev is None:                                 # not a tx key of this world
            return
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
        self._pull_poses(self.net.sched.now)
        refuse = None if self.net.poses.known[m.vehicle_index] else "nopose"
        if refuse:
            self.counters["nopose"] += 1
            ep.bad["nopose"] += 1
            self.warn(f"nopose:{dev}", "%s: tx dropped (nopose): vehicle %s has no pose yet", dev, m.vehicle)
        m.send(req.dst, len(req.data), data=req.data, flow=req.flow, tag=req.tag, refuse=refuse, msg=req.msg)

    def _on_rx(self, dev: str, frame: Frame, t: float, dist: float) -> None:
        ep = self.serving(dev)
        if ep is None:
            return
        data = frame.data if frame.data is not None else bytes(frame.payload)
        if not ep.rx(frame.src, frame.dst, data, frame.seq, frame.t_tx, t, dist, frame.msg):
            self._edge_drop(dev, "rx")

    def _on_status(self, dev: str, frame: Frame, event: str, reason: str | None, t: float) -> None:
        tag = frame.tag if isinstance(frame.tag, int) and not isinstance(frame.tag, bool) else None
        leaving = self._leaving.get(dev)
        if leaving is not None:
            # a simulated modem handed to a real driver: what it still held ends here, said once
            if event == "dropped" and reason == "removed":
                reason = "swapped"
            leaving.put(self._put_status(dev), wire.encode_status(tag, event, reason, t, frame.seq), "status")
            return
        ep = self.serving(dev)
        if ep is None:
            return
        if not ep.status(tag, event, reason, t, frame.seq):
            self._edge_drop(dev, "status")

    def _edge_drop(self, dev: str, kind: str) -> None:
        self.counters[f"edge_{kind}"] += 1
        self.warn(f"edge:{dev}", "%s: %s message dropped at the edge: its consumer does not keep up (outbox"
                  " of %d full)", dev, kind, self.outbox_capacity)

    def _trace_batch(self, b: Batch) -> None:
        """(engine: an idle hook, or a full batch) Each record of the batch on its channel's `trace` key."""
        out = self._trace_out
        if out is None or self._closed:
            return
        pubs = self._trace_pubs
        for t9, r in zip(b.t9, b.rows, strict=True):
            pub = pubs.get(r[2])
            if pub is not None and not out.put(put_record, (pub, t9, r), "trace"):
                self.counters["edge_trace"] += 1

    def _driver_change(self, key: str, present: bool) -> None:
        k = parse(key)
        if k is None or k.leaf != "driver" or k.driver != "real" or k.world != self.keys.world:
            return
        dev = k.name
        if present:
            ep = self.endpoints.get(dev)
            if self.hil.driver_up(dev, served=ep is not None) == SWAP_OUT:
                self._swap_out(dev, ep)
            return
        action, held = self.hil.driver_down(dev, in_network=dev in self.net.modems)
        if action == SWAP_IN:
            vehicle, cfg = held
            try:
                m = self.net.add_device(vehicle, cfg)
            except ValueError as e:
                log.warning("%s: the real driver left but the simulated modem cannot come back: %s", dev, e)
                return
            self.attach(m)
            self.counters["swap_in"] += 1
            log.info("%s: the real driver left; the simulated modem serves it again", dev)
        elif action == RETOKEN and dev in self.endpoints and self.endpoints[dev].token is None:
            self.endpoints[dev].token = self.session.liveliness().declare_token(self.keys.driver(dev, "sim"))

    def _swap_out(self, dev: str, ep: Endpoint) -> None:
        """A real driver takes `dev` (HIL swap): the simulated modem leaves the channel, so simulated
        frames neither reach it nor come from it; every frame it still held ends with a `dropped`
        status (reason `swapped`) before its keys go quiet."""
        m = ep.modem
        if ep.token is not None:
            self._undeclare(ep.token)
            ep.token = None
        self._leaving[dev] = self._misc           # see _on_status
        while m.fifo:
            m.drop(m.fifo_pop(), "swapped")
        self.hil.swapped_out(dev, m.vehicle, m.cfg)
        with contextlib.suppress(ValueError):
            self.net.remove_device(dev)
        self.detach(dev)
        self.counters["swap_out"] += 1
        log.info("%s: a real driver took over; the simulated modem left the channel", dev)






