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

Threading: Zenoh callbacks run on Zenoh's threads and hand raw bytes on: a tx message to its
modem's ingress `Lane` (bounded; the engine takes the lanes round-robin, so a flood on one modem does
not delay the others), run at once on the callback's thread when the engine waits (`clock.run_here`:
one thread wake-up less, the same work under the engine's lock), anything else to `clock.call_soon`.
Pose samples have no callback: they wait in a Zenoh ring channel that the engine takes from when it
reads the geometry or idles (every 2 ms at least), each stamped with the time the router received it.
Decoding and simulation never make a Zenoh put: rx, status, trace, pose and clock messages leave through
bounded `Outbox`es (bus/outbox.py), one publisher thread each (one per modem), so a consumer that
cannot keep up loses messages at the edge, counted per modem (`info` "edge", the run summary), and
never stalls the engine or another modem.  A bad message never stops the broker: it is answered on
the modem's `status` with `dropped` and a reason, counted, and logged (rate-limited).
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
from uwsimnet_gli.wire import Keys, check_chunk, is_chunk, parse

from ..trace.events import Batch, Listener, row_record
from ..trace.tracer import FRAME_EVENTS
from .control import Control
from .endpoint import BLOCK, ModemEndpoint
from .hil import RETOKEN, SWAP_IN, SWAP_OUT, HilSwap
from .outbox import INGRESS_WARN_S, LANE_CAPACITY, OUTBOX_CAPACITY, POSE_KEYS, Lane, Latest, Outbox

if TYPE_CHECKING:
    from ..engine.network import Network
    from ..kernel.frame import Frame
    from ..kernel.realtime import RealtimeClock
    from ..phy.modem import Modem

log = logging.getLogger("uwsimnet.bus.broker")
SWITCH_INTERVAL = 0.0005
"""s: the interpreter's thread switch interval while a broker runs (see Broker.start)."""
KEY_CACHE = 4096
"""Key expressions whose parse is remembered (tx keys -> modem id, pose keys -> vehicle and verdict)."""
POSE_RING = 16384
"""Pose samples Zenoh holds for the engine between two takes (a ring: when full, the oldest goes)."""
POSE_POLL_S = 0.002
"""Wall s: the engine takes the pose samples at least this often when it waits (RealtimeClock.poll)."""
_MISS = object()

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


class Broker:
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
        self.warn = Throttle()
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

    def _take_poses(self) -> None:
        """(engine) Move the pose samples Zenoh holds into `_poses_in`, each stamped with its arrival."""
        sub = self._pose_sub
        if sub is None:
            return
        clock = self.clock
        now = clock.now()
        epoch = clock.wall_epoch()
        n = 0
        while True:
            smp = sub.try_recv()
            if smp is None:
                break
            n += 1
            self._pose_sample(smp, now, epoch)
        self._pose_taken = now              # what comes next arrived after now
        if n >= POSE_RING:
            self.counters["pose_ring_full"] += 1
            self.warn("pose_ring_full", "%d pose samples waited for the engine: older ones may have been"
                      " lost", n)

    def _pose_sample(self, sample: Any, now: float, epoch: float) -> None:
        """One pose sample, kept as the newest of its key, stamped with its arrival in simulation time: the
        Zenoh timestamp a router gave it on arrival (bounded by the previous take and `now`: another
        machine's clock may be off), else `now`.  `epoch`: the clock's wall_epoch()."""
        raw = sample.payload.to_bytes()       # (a pose is a few dozen bytes; Zenoh's ring bounds the rest)
        if len(raw) > wire.MAX_SMALL_MESSAGE:
            raw = None
        ts = sample.timestamp
        stamp = now
        if ts is not None:
            at = (ts.get_time_as_ntp64().as_secs_f64() - epoch) * self.clock.speed
            stamp = min(now, max(self._pose_taken, at))
        self._poses_in.offer(str(sample.key_expr), stamp, raw)

    def _on_info_query(self, query: zenoh.Query) -> None:
        self._queue_query(self._info_lane, query, self._answer_info, query)

    def _on_control_query(self, query: zenoh.Query) -> None:
        pl = query.payload
        raw = pl.to_bytes() if pl is not None and len(pl) <= wire.MAX_SMALL_MESSAGE else pl
        self._queue_query(self._control_lane, query, self._answer_control, query, raw)

    def _queue_query(self, lane: Lane, query: zenoh.Query, fn: Any, *args: Any) -> None:
        """(Zenoh thread) A query waits in its lane, which takes its turn among the modems' tx lanes: a
        flood of queries costs the other modems' frames one query per round, not the whole flood."""
        r = lane.offer((fn, args))
        if r:
            self.clock.call_soon(self._drain_queries, lane)
        elif r is None:
            with contextlib.suppress(Exception), query:
                query.reply_err(wire.pack({"ok": False, "error": f"busy: {lane.capacity} queries are waiting"}))
            self.warn(f"ingress:{lane.name}", "%s query refused: %d queries waiting for the engine", lane.name[1:],
                      len(lane))

    def _drain_queries(self, lane: Lane) -> None:
        """(engine) One query of `lane`, then back in line behind the modems."""
        got = lane.take()
        if got is None:
            return
        _, (fn, args) = got
        try:
            fn(*args)
        finally:
            if lane.more():
                self.clock.call_soon(self._drain_queries, lane)

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
            if pub is not None and not out.put(pub.put, wire.pack(row_record(t9, r)), "trace"):
                self.counters["edge_trace"] += 1

    def _pull_poses_now(self) -> None:
        """(engine, idle hook) Apply the pose samples that have arrived by now."""
        self._pull_poses(self.clock.now())

    def _pull_poses(self, t: float) -> None:
        """(engine; PoseTable.pull) Apply the newest pose sample of each vehicle that arrived by
        simulation time t, as of its arrival time.  A sample superseded by a newer one of the same vehicle
        before the geometry was needed is counted (`poses_superseded`), not decoded: the newer one
        replaces it entirely (position, velocity, time)."""
        self._take_poses()
        got = self._poses_in.take(t)
        if got:
            for key, n, stamp, raw in got:
                self._apply_pose(key, n, stamp, raw)
            if self._poses_in.refused:
                self.counters["pose_refused"] = self._poses_in.refused

    def _pose_verdict(self, key: str) -> tuple[str | None, str | None]:
        """(vehicle, None) if samples on `key` position a vehicle, else (name, the counter of refusals)."""
        got = self._pose_keys.get(key)
        if got is not None:
            return got
        k = parse(key)
        if k is None or k.kind != "pose" or k.world != self.keys.world:
            got = (None, "pose_bad_key")
        else:
            v = self.net.vehicles.get(k.name)
            if v is None:
                got = (k.name, "pose_unknown")
            elif v.pose_source != "zenoh":       # another broker of this world publishes it too: expected
                got = (k.name, "pose_peer" if self.channels is not None else "pose_ignored")
            else:
                got = (k.name, None)
        if len(self._pose_keys) < KEY_CACHE:
            self._pose_keys[key] = got
        return got

    def _apply_pose(self, key: str, n: int, stamp: float, raw: bytes | None) -> None:
        name, refused = self._pose_verdict(key)
        if refused is not None:
            self.counters[refused] += n
            if refused == "pose_unknown":
                self.warn("pose_unknown", "pose for unknown vehicle %r ignored", name)
            elif refused == "pose_ignored":
                self.warn(f"pose_ignored:{name}", "pose for %s ignored: the scene drives it (poseSource scene)",
                          name)
            return                               # pose_peer: counted, no warning (two would flood)
        if n > 1:
            self.counters["poses_superseded"] += n - 1
        try:
            if raw is None:
                raise wire.CodecError("toolarge", f"pose sample over {wire.MAX_SMALL_MESSAGE} bytes")
            pose = wire.decode_pose(raw)
        except wire.CodecError as e:
            self.counters["pose_" + e.reason] += 1
            self.warn(f"pose_bad:{name}", "pose for %s ignored (%s): %s", name, e.reason, e.detail)
            return
        self.counters["poses"] += 1
        self.net.move(name, pose.p, pose.v, t=stamp)
        if name in self._waiting_pose:
            self._waiting_pose.discard(name)
            log.info("vehicle %s: first pose %s", name, list(pose.p))

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

    def edge_summary(self) -> dict[str, Any]:
        """Per modem: messages lost at the edge (outbox full, by kind; ingress lane full) and the ingress
        delay (count, mean, max wall s); plus the trace and misc outboxes.  For the run summary."""
        out: dict[str, Any] = {}
        for dev, lane in self.lanes.items():
            ob = self.outboxes.get(dev)
            out[dev] = {"lost": dict(ob.dropped) if ob is not None else {}, "refused": lane.refused,
                        "stalled": dict(ob.stalled) if ob is not None else {},
                        "stalled_max": ob.stalled_max if ob is not None else 0.0,
                        "ingress_n": lane.n, "ingress_mean": lane.delay_sum / lane.n if lane.n else 0.0,
                        "ingress_max": lane.delay_max}
        for name in ("*trace", "*misc"):
            ob = self.outboxes.get(name)
            if ob is not None and (ob.dropped or ob.stalled):
                out[name] = {"lost": dict(ob.dropped), "stalled": dict(ob.stalled), "stalled_max": ob.stalled_max}
        return out

    # -- queries ---------------------------------------------------------------------------------
    def info(self, dev: str) -> dict[str, Any]:
        """The `info` reply of a served modem: configuration, kind and live state."""
        m = self.endpoints[dev].modem
        net = self.net
        cfg = m.cfg
        self._pull_poses(net.sched.now)
        known = bool(net.poses.known[m.vehicle_index])
        pos = net.poses.points(net.sched.now)[m.vehicle_index] if known else None
        ep = self.endpoints[dev]
        counters = dict(m.counters)
        counters.update(ep.bad)
        return ep.info({
            "address": m.address, "vehicle": m.vehicle,
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
            "epoch": self.clock.wall_epoch(), "speed": self.clock.speed,
            # + the edge (docs/runtime.md): messages lost because their consumer did not keep up, and the
            # ingress delay (wall s from the tx put reaching the broker to the engine taking it)
        }, kind="sim", world=self.keys.world, t=net.sched.now, ingress=ep.lane.stats())

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
            pos = net.poses.points(net.sched.now)      # (not `positions`: no array, no numpy import)
            idx = net.poses.index
            now = net.sched.now
            batches, self._due_poses = self._due_poses, []
            for names in batches:
                for name in names:
                    pub = self._pose_pubs.get(name)
                    if pub is not None:
                        self._misc.put(pub.put, wire.encode_pose(pos[idx[name]], t=now), "pose")
        if self._clock_due:
            self._clock_due = False
            self.publish_clock()

    def clock_sample(self) -> dict[str, Any]:
        c = self.clock
        return {"t": self.net.sched.now if c.paused else c.now(), "epoch": c.wall_epoch(), "speed": c.speed,
                "paused": c.paused}

    def publish_clock(self) -> None:
        if self._clock_pub is not None:
            self._misc.put(self._clock_pub.put, wire.pack(self.clock_sample()), "clock")

    def _clock_tick(self) -> None:
        if self._clock_due:
            self.publish_clock()
        self._clock_due = True
        self.net.sched.after(1.0 / self.clock_rate_hz, self._clock_tick)
