"""`uwsimnet run --ros2`: the run's ROS 2 face, a Zenoh client session that speaks rmw_zenoh's wire
(docs/ros2.md). ROS 2 nodes (RMW_IMPLEMENTATION=rmw_zenoh_cpp) see its nodes and topics with no bridge.

It is an application of the run like any other (a client of the run's router, or of the host's rmw_zenohd
when the run joins it): it translates, through ros2/bridge.py,

    ROS pose topics (Odometry, PoseStamped, /tf)  ->  uwsimnet/<world>/pose/<vehicle>
    ROS tx topics (Transmit, dmac2 send, Stonefish data_to_send)  ->  uwsimnet/<world>/modem/<id>/tx
    uwsimnet/<world>/modem/<id>/rx, status  ->  ROS rx/status topics (Frame, Status, dmac2 recv, received_data)
    uwsimnet/<world>/pose/<scene vehicle>  ->  /tf, /tf_static;   clock  ->  /clock;   info  ->  /diagnostics

Zenoh callbacks only enqueue; one worker thread translates and publishes, so a slow ROS consumer never
stalls the session. Its liveliness tokens are undeclared before the session closes (the nodes leave the
ROS graph at once, not after a lease).
"""

from __future__ import annotations

import contextlib
import logging
import queue
import threading
import time
from collections.abc import Sequence
from typing import Any

import zenoh
import zenoh.ext as zext
from uwsimnet_gli import wire
from uwsimnet_gli.wire import Keys

from ..ros2 import wire as rw
from ..ros2.bridge import ModemInfo, Options, PoseUpdate, Ros2Bridge, TxRequest, VehicleInfo
from .clock import sim_time
from .session import make_config, open_raw

log = logging.getLogger("uwsimnet.bus.ros2")

SAMPLE_MISS_HEARTBEAT_S = 0.5
"""Heartbeat of a reliable transient-local publisher (rmw_zenoh's SAMPLE_MISS_DETECTION_HEARTBEAT_PERIOD)."""


class Ros2Adapter:
    """    with Ros2Adapter(["tcp/127.0.0.1:7447"], "lab", opts, modems, vehicles) as ros: ...
    `codec` is a ros2.cdr.Codec (it needs the extra uwsimnet-zenoh[ros2])."""

    def __init__(self, connect: Sequence[str], world: str, opts: Options, modems: Sequence[ModemInfo],
                 vehicles: Sequence[VehicleInfo], codec: Any, *, clock_rate_hz: float = 50.0,
                 diagnostics_period_s: float = 1.0) -> None:
        self.keys = Keys(world)
        self.opts = opts
        self.codec = codec
        self.clock_rate_hz = clock_rate_hz
        self.diagnostics_period_s = diagnostics_period_s
        self._q: queue.SimpleQueue = queue.SimpleQueue()
        self._stop = threading.Event()
        self._clock: dict[str, Any] | None = None
        # rmw_zenoh's sessions have timestamping on; late joiners' history (/tf_static) needs it
        conf = make_config("client", connect=list(connect), connect_timeout_ms=3000,
                           extra={"timestamping/enabled": True})
        self.session = open_raw(conf)
        self._entities: list[Any] = []
        self._tokens: list[Any] = []
        self._pubs: dict[str, Any] = {}
        self._thread: threading.Thread | None = None
        self._diag_thread: threading.Thread | None = None
        try:
            self.bridge = Ros2Bridge(opts, str(self.session.zid()), codec, modems, vehicles)
        except BaseException:
            self.session.close()
            raise

    def __enter__(self) -> Ros2Adapter:
        self.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # -- declarations -----------------------------------------------------------------------------
    def start(self) -> None:
        s, b, k = self.session, self.bridge, self.keys
        try:
            for ep in b.publishers():
                if ep.qos.durability == rw.TRANSIENT_LOCAL:
                    miss = (zext.MissDetectionConfig(sporadic_heartbeat=SAMPLE_MISS_HEARTBEAT_S)
                            if ep.qos.reliability == rw.RELIABLE else None)
                    pub = zext.declare_advanced_publisher(s, ep.key, cache=zext.CacheConfig(max(1, ep.qos.depth)),
                                                          publisher_detection=True, sample_miss_detection=miss)
                else:
                    pub = s.declare_publisher(ep.key, reliability=zenoh.Reliability.RELIABLE
                                              if ep.qos.reliability == rw.RELIABLE else zenoh.Reliability.BEST_EFFORT)
                self._pubs[ep.key] = pub
                self._entities.append(pub)
            for ep in b.subscriptions():
                self._entities.append(s.declare_subscriber(ep.match_key, _direct(self._on_ros)))
            self._entities.append(s.declare_subscriber(k.rx_all, _direct(self._on_sim("rx"))))
            self._entities.append(s.declare_subscriber(k.status_all, _direct(self._on_sim("status"))))
            self._entities.append(s.declare_subscriber(k.pose_all, _direct(self._on_sim("pose")),
                                                       allowed_origin=zenoh.Locality.REMOTE))
            self._entities.append(s.declare_subscriber(k.clock, _direct(self._on_sim("clock"))))
            self._tokens = [s.liveliness().declare_token(t) for t in b.tokens()]
        except BaseException:
            self.close()
            raise
        self._thread = threading.Thread(target=self._work, name="uwsimnet-ros2", daemon=True)
        self._thread.start()
        self._diag_thread = threading.Thread(target=self._poll_info, name="uwsimnet-ros2-info", daemon=True)
        self._diag_thread.start()
        log.info("ROS 2 (%s, domain %d): %d node(s), %d publisher(s), %d subscription(s)", self.opts.distro,
                 self.opts.domain, len(b.graph.nodes), len(b.publishers()), len(b.subscriptions()))

    def close(self) -> None:
        """Tokens first (the nodes leave the ROS graph), then the entities, the worker and the session."""
        self._stop.set()
        self._q.put(None)
        for t in self._tokens:
            with contextlib.suppress(Exception):
                t.undeclare()
        self._tokens = []
        for th in (self._thread, self._diag_thread):
            if th is not None:
                th.join(5.0)
        self._thread = self._diag_thread = None
        for e in self._entities:
            with contextlib.suppress(Exception):
                e.undeclare()
        self._entities = []
        with contextlib.suppress(Exception):
            self.session.close()

    # -- callbacks: enqueue only ------------------------------------------------------------------
    def _on_ros(self, sample: zenoh.Sample) -> None:
        att = sample.attachment
        self._q.put(("ros", str(sample.key_expr), sample.payload.to_bytes(), None if att is None else att.to_bytes()))

    def _on_sim(self, kind: str) -> Any:
        def cb(sample: zenoh.Sample) -> None:
            self._q.put((kind, str(sample.key_expr), sample.payload.to_bytes(), None))
        return cb

    # -- the worker -------------------------------------------------------------------------------
    def _work(self) -> None:
        period = 1.0 / self.clock_rate_hz if self.opts.clock and self.clock_rate_hz > 0 else None
        next_clock = time.monotonic()
        while not self._stop.is_set():
            try:
                item = self._q.get(timeout=max(0.0, next_clock - time.monotonic()) if period else None)
            except queue.Empty:
                item = ()
            if item is None:
                break
            try:
                if item:
                    self._handle(*item)
                if period and time.monotonic() >= next_clock:
                    next_clock = max(next_clock + period, time.monotonic())
                    if self._clock is not None:
                        self._publish(self.bridge.clock(sim_time(self._clock), time.time_ns()))
            except Exception:  # noqa: BLE001 - the worker never dies on one bad record
                log.exception("ROS 2 adapter: error handling %s", item[:2] if item else "the clock")

    def _poll_info(self) -> None:
        """The modems' info records for /diagnostics, on a thread of its own (a query may take a while)."""
        while not self._stop.wait(self.diagnostics_period_s):
            infos = []
            try:
                for r in self.session.get(self.keys.info_all, timeout=max(0.1, self.diagnostics_period_s / 2)):
                    if r.ok is not None:
                        with contextlib.suppress(wire.CodecError):
                            m = wire.unpack(r.ok.payload.to_bytes(), wire.MAX_REPLY_MESSAGE)
                            if isinstance(m, dict):
                                infos.append(m)
            except zenoh.ZError:
                continue
            self._q.put(("diag", "", sorted(infos, key=lambda m: str(m.get("id"))), None))

    def _handle(self, kind: str, key: str, payload: Any, attachment: bytes | None) -> None:
        b = self.bridge
        if kind == "diag":
            t = sim_time(self._clock) if self._clock else 0.0
            self._publish(b.diagnostics(payload, t, time.time_ns()))
            return
        if kind == "ros":
            for action in b.on_ros_sample(key, payload, attachment):
                if isinstance(action, PoseUpdate):
                    self.session.put(self.keys.pose(action.vehicle), wire.encode_pose(action.p, q=action.q,
                                                                                      v=action.v))
                elif isinstance(action, TxRequest):
                    self.session.put(self.keys.tx(action.dev), wire.encode_tx(action.dst, action.data, action.tag),
                                     congestion_control=zenoh.CongestionControl.BLOCK)  # DROP loses it unseen
            return
        try:
            if kind == "rx":
                dev = wire.modem_id(key, "rx")
                if dev is not None:
                    f = wire.decode_rx(payload)
                    self._publish(b.rx(dev, f.src, f.dst, f.data, f.seq, f.t_tx, f.t_rx, f.dist, time.time_ns()))
            elif kind == "status":
                dev = wire.modem_id(key, "status")
                if dev is not None:
                    st = wire.decode_status(payload)
                    self._publish(b.status(dev, st.event, st.reason, st.tag, st.seq, st.t, time.time_ns()))
            elif kind == "pose":
                k = wire.parse(key)
                if k is not None and k.kind == "pose" and k.world == self.keys.world:
                    p = wire.decode_pose(payload)
                    t = p.t if p.t is not None else (sim_time(self._clock) if self._clock else 0.0)
                    self._publish(b.vehicle_pose(k.name, p.p, p.q, t, time.time_ns()))
            elif kind == "clock":
                m = wire.unpack(payload, wire.MAX_SMALL_MESSAGE)
                if isinstance(m, dict) and isinstance(m.get("t"), int | float):
                    self._clock = m
        except wire.CodecError:
            b.stats[f"sim_{kind}_bad"] += 1

    def _publish(self, puts: Sequence[Any]) -> None:
        for p in puts:
            pub = self._pubs.get(p.key)
            if pub is not None:
                pub.put(p.payload, attachment=p.attachment)


def _direct(fn: Any) -> Any:
    """On Zenoh's network thread (the callbacks only enqueue)."""
    return zenoh.handlers.Callback(fn, indirect=False)
