"""`uwsimnet ros2-link`: one robot's ROS 2 graph joined to the others only through its modem
(docs/ros2-link.md). The on-air work is ros2/link.py (sans-IO); this is its glue:

    robot's graph (rmw_zenoh keys of its domain)  --subscribe-->  Sender queues  --one frame at a time-->
    uwsimnet_gli.Modem.send  ~~water~~  Modem rx  -->  Reassembler  --publish, sender's stamp-->  other graph

The modem side is the application wire alone (uwsimnet_gli.Modem), so a real modem after a HIL swap is the
same to the link. One frame is in the modem at a time (the next leaves on its final status), which is what
lets a control message overtake an image at frame granularity. Zenoh callbacks only enqueue.
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
from uwsimnet_gli.modem import Modem
from uwsimnet_gli.world import World, load_config

from ..ros2 import link as L
from ..ros2 import wire as rw
from ..ros2.bridge import Codec, Endpoint, Graph, header

log = logging.getLogger("uwsimnet.bus.ros2_link")
NODE = "uwsimnet_link"
DIAG_TYPE = "diagnostic_msgs/msg/DiagnosticArray"
STATUS_TIMEOUT_S = 30.0
"""A frame whose final status never comes (the modem went away) stops holding the queue after this."""


class Ros2Link:
    """    with Ros2Link(["tcp/127.0.0.1:7447"], "lab", "alpha-modem", rules, domain=1, hasher=codec) as link:
    Both ends list the same rules in the same order (the topic index on air is the position). The summary
    goes on the robot's /diagnostics every `diagnostics_period_s`."""

    def __init__(self, connect: Sequence[str], world: str, modem: str, rules: Sequence[L.TopicRule], *,
                 codec: Codec, domain: int = 0, namespace: str = "/", mtu: int = 64,
                 diagnostics_period_s: float = 1.0) -> None:
        self.rules = L.check_rules(list(rules))
        self.codec = codec
        self.modem_id = modem
        self.diagnostics_period_s = diagnostics_period_s
        self._next_diag = 0.0
        self.sender = L.Sender(self.rules, mtu)
        self.reasm = L.Reassembler()
        self.problems: dict[str, int] = {}
        self._reported: set[str] = set()
        self._q: queue.SimpleQueue = queue.SimpleQueue()
        self._cond = threading.Condition()
        self._in_flight: tuple[int, float] | None = None
        self._stop = threading.Event()
        self._entities: list[Any] = []
        self._tokens: list[Any] = []
        conf = load_config(None, list(connect))
        # as rmw_zenoh's sessions: a TRANSIENT_LOCAL republisher (AdvancedPublisher's cache) needs timestamps
        conf.insert_json5("timestamping/enabled", "true")
        self.world = World(world, config=conf)
        try:
            s = self.world.session
            self.graph = Graph(domain, str(s.zid()), codec)
            self.subs: dict[str, int] = {}
            self.pubs: dict[int, tuple[Endpoint, Any]] = {}
            self._pub_tokens: dict[int, Any] = {}
            self._namespace = namespace
            for i, r in enumerate(self.rules):
                if r.direction in ("out", "both"):
                    # best effort, volatile: by ROS's QoS rules a subscription any publisher's QoS is compatible with
                    ep = self.graph.add("MS", NODE, namespace, r.name, r.type,
                                        rw.QoS(reliability=rw.BEST_EFFORT, depth=r.depth))
                    self.subs[ep.topic_key] = i
                    # REMOTE: never hear our own republications (on a 'both' topic they would echo back over the water)
                    self._entities.append(s.declare_subscriber(ep.match_key, self._on_ros,
                                                               allowed_origin=zenoh.Locality.REMOTE))
            self._diag = self.graph.add("MP", NODE, namespace, "/diagnostics", DIAG_TYPE, rw.QoS(depth=10))
            self._diag_pub = s.declare_publisher(self._diag.key, reliability=zenoh.Reliability.RELIABLE)
            self._entities.append(self._diag_pub)
            self._tokens = [s.liveliness().declare_token(t) for t in self.graph.tokens()]
            for i, r in enumerate(self.rules):
                if r.direction in ("in", "both"):   # the sender's QoS replaces this one once announced
                    self._declare_pub(i, rw.QoS(depth=r.depth))
            # the robot's publishers (their tokens carry their QoS): the QoS the far side republishes with
            self._entities.append(s.liveliness().declare_subscriber(f"{rw.ADMIN_SPACE}/{domain}/**", self._on_token,
                                                                    history=True))
            self.modem = Modem(self.world, modem, on_receive=self._on_frame, on_status=self._on_status)
        except BaseException:
            self.close()
            raise
        self._thread = threading.Thread(target=self._work, name="uwsimnet-ros2-link", daemon=True)

    def __enter__(self) -> Ros2Link:
        self._thread.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def close(self) -> None:
        self._stop.set()
        self._q.put(None)
        with self._cond:
            self._cond.notify_all()
        th = getattr(self, "_thread", None)
        if th is not None and th.is_alive():
            th.join(5.0)
        for e in (*self._tokens, *self._pub_tokens.values(), *self._entities):
            with contextlib.suppress(Exception):
                e.undeclare()
        self._tokens, self._entities = [], []
        self._pub_tokens = {}
        if hasattr(self, "modem"):
            self.modem.close()
        self.world.close()

    def _declare_pub(self, i: int, qos: rw.QoS) -> None:
        """(Re)declare topic i's publisher and its token with `qos` (a new entity: rmw_zenoh's token names
        its QoS, so a QoS change is a new publisher in the graph). TRANSIENT_LOCAL: a cache of `depth`
        samples for late joiners, as rmw_zenoh's AdvancedPublisher."""
        s, r = self.world.session, self.rules[i]
        ep = self.graph.add("MP", NODE, self._namespace, r.name, r.type, qos)
        try:
            if qos.durability == rw.TRANSIENT_LOCAL:
                pub = zext.declare_advanced_publisher(s, ep.key, cache=zext.CacheConfig(max(1, qos.depth)),
                                                      publisher_detection=True)
            else:
                pub = s.declare_publisher(ep.key, reliability=zenoh.Reliability.RELIABLE
                                          if qos.reliability == rw.RELIABLE else zenoh.Reliability.BEST_EFFORT)
        except zenoh.ZError:
            self.graph.endpoints.remove(ep)     # the old publisher stays (the caller counts the problem)
            raise
        old = self.pubs.pop(i, None)
        if old is not None:                     # the new one is in place: the old one leaves the graph
            ep.seq = old[0].seq
            with contextlib.suppress(Exception):
                self._pub_tokens.pop(i).undeclare()
            with contextlib.suppress(Exception):
                old[1].undeclare()
            self.graph.endpoints.remove(old[0])
        self.pubs[i] = (ep, pub)
        self._pub_tokens[i] = s.liveliness().declare_token(ep.token)

    # -- callbacks: enqueue only ------------------------------------------------------------------
    def _on_ros(self, sample: zenoh.Sample) -> None:
        att = sample.attachment
        self._q.put(("ros", str(sample.key_expr), sample.payload.to_bytes(), None if att is None else att.to_bytes(),
                     time.time_ns()))

    def _on_token(self, sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            self._q.put(("tok", str(sample.key_expr), b"", None, 0))

    def _on_frame(self, frame: Any) -> None:
        self._q.put(("rx", frame.src, bytes(frame.data), None, time.time_ns()))

    def _on_status(self, st: Any) -> None:
        if st.event in ("sent", "dropped", "acked", "failed"):
            with self._cond:
                if self._in_flight is not None and self._in_flight[0] == st.tag:
                    self._in_flight = None
                    self._cond.notify_all()

    # -- the worker ---------------------------------------------------------------------------------
    def problem(self, reason: str, detail: str) -> None:
        """Counted always, logged once per reason (a malformed flood never floods the log)."""
        self.problems[reason] = self.problems.get(reason, 0) + 1
        if reason not in self._reported:
            self._reported.add(reason)
            log.warning("ros2-link: %s: %s (counted from now on, not logged again)", reason, detail)

    def _work(self) -> None:
        while not self._stop.is_set():
            if time.monotonic() >= self._next_diag:
                self._next_diag = time.monotonic() + self.diagnostics_period_s
                try:
                    self.publish_diagnostics()
                except Exception as e:  # noqa: BLE001 - diagnostics never stop the link
                    self.problem("diagnostics", repr(e))
            with self._cond:
                if self._in_flight is not None and time.monotonic() - self._in_flight[1] > STATUS_TIMEOUT_S:
                    self._in_flight = None
                if self._in_flight is None:
                    nxt = self.sender.next_frame()
                    if nxt is not None:
                        tag = self.modem.send(nxt[0], nxt[1])
                        self._in_flight = (tag, time.monotonic())
            try:
                item = self._q.get(timeout=0.002 if self._in_flight is None and self.sender.pending() else 0.05)
            except queue.Empty:
                continue
            if item is None:
                return
            try:
                self._handle(item)
            except Exception as e:  # noqa: BLE001 - the link never stops on one bad sample
                self.problem("internal", repr(e))

    def _handle(self, item: tuple) -> None:
        kind, a, payload, att, now_ns = item
        now = now_ns / 1e9
        if kind == "tok":
            return self._learn_qos(a)
        if kind == "ros":
            topic_key = a.rsplit("/", 2)[0]
            i = self.subs.get(topic_key)
            if i is None:
                return self.problem("unknown_topic", a)
            ep = self.graph.endpoints[[e.topic_key for e in self.graph.endpoints].index(topic_key)]
            if a != ep.key:
                return self.problem("type", f"{a} (the link carries {ep.key})")
            try:
                stamp = rw.decode_attachment(att).timestamp_ns
                rw.check_cdr_header(payload)
            except rw.Ros2WireError as e:
                return self.problem(e.reason, f"{a}: {e.detail}")
            with self._cond:
                why = self.sender.offer(self.rules[i].name, payload, stamp, now)
            if why is not None:
                self.problem(why, self.rules[i].name)
            return
        if L.is_control(payload):
            return self._announced(a, payload)
        try:
            done = self.reasm.push(a, payload, now)
        except L.LinkError as e:
            return self.problem("malformed_frame", f"from {a}: {e}")
        if done is None:
            return
        i, cdr, stamp_us = done
        if i not in self.pubs:
            return self.problem("unknown_topic", f"topic index {i} from {a}")
        ep, pub = self.pubs[i]
        src_ns = L.unwrap_stamp(stamp_us or 0, now_ns)
        st = self.sender.stats[i]
        st.received += 1
        lat = max(0.0, (now_ns - src_ns) / 1e9)
        st.latency_sum += lat
        st.latency_max = max(st.latency_max, lat)
        pub.put(cdr, attachment=ep.attachment(src_ns))

    def _learn_qos(self, key: str) -> None:
        """A publisher of a carried topic on this robot's graph (not the link's own): its QoS goes across."""
        tok = rw.parse_token(key)
        if tok is None or tok.kind != "MP" or tok.zid == self.graph.zid or tok.qos is None:
            return
        i = self.sender.index.get(tok.topic or "")
        if i is None or self.rules[i].direction == "in":
            return
        if tok.dds_type != rw.dds_type(self.rules[i].type):
            return self.problem("type", f"publisher of {tok.topic} has type {tok.dds_type}")
        with self._cond:
            if self.sender.set_qos(self.rules[i].name, tok.qos):
                log.info("ros2-link: %s: the publisher's QoS %s goes across", tok.topic, tok.qos.keyexpr())

    def _announced(self, src: int, frame: bytes) -> None:
        try:
            i, qos = L.decode_qos(frame)
        except L.LinkError as e:
            return self.problem("malformed_frame", f"from {src}: {e}")
        if i not in self.pubs:
            return self.problem("unknown_topic", f"QoS of topic index {i} from {src}")
        if self.pubs[i][0].qos != qos:
            try:
                self._declare_pub(i, qos)
            except zenoh.ZError as e:
                self.problem("qos", f"{self.rules[i].name}: cannot republish with {qos.keyexpr()}: {e}")

    def publish_diagnostics(self) -> None:
        now_ns = time.time_ns()
        fields = {"header": header(now_ns / 1e9, ""), "status": L.diagnostic_status(self.summary(), self.modem_id)}
        self._diag_pub.put(self.codec.encode(DIAG_TYPE, fields), attachment=self._diag.attachment(now_ns))

    def summary(self) -> dict:
        """Per-topic counters (sending and receiving side), reassembly drops and problems."""
        topics = {}
        for i, r in enumerate(self.rules):
            d = self.sender.stats[i].as_dict()
            for (t, reason), n in self.reasm.drops.items():
                if t == i:
                    d["dropped"][f"rx_{reason}"] = n
            learned = self.sender.qos[i]
            if learned is not None:                 # the publisher's on this graph (sent across)
                d["qos_out"] = learned.keyexpr()
            if i in self.pubs:                      # what the link republishes with on this graph
                d["qos_in"] = self.pubs[i][0].qos.keyexpr()
            topics[r.name] = d
        return {"topics": topics, "qos_announcements": self.sender.control_frames,
                "problems": dict(sorted(self.problems.items()))}
