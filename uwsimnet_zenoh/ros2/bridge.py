"""The ROS 2 side of a run, sans-IO: its nodes, publishers and subscriptions (numbered as rmw_zenoh numbers
them) and the translation between ROS 2 messages and the simulator's own records (docs/ros2.md).

`Ros2Bridge` is handed ROS samples (key, payload, attachment) and the simulator's rx/status/pose/clock/info
records, and returns pose updates, tx requests and `Put`s (key, CDR, attachment). The Zenoh glue
(bus/ros2.py) declares what `publishers()`, `subscriptions()` and `tokens()` list and forwards samples.
Bad input from ROS is counted by reason and reported once per (reason, topic); it never raises.

Topics (node namespace `/uwsimnet` by default; `<m>` = the modem id as a ROS name):

    native      /uwsimnet/<m>/rx (uwsimnet_msgs/Frame), /uwsimnet/<m>/status (Status), /uwsimnet/<m>/tx (Transmit)
    dmac2       /<m>/recv and /<m>/send (dmac2_interfaces/DMACPayload), as the dmac2 driver node `<m>`
    stonefish   /<m>/received_data and /<m>/data_to_send (std_msgs/String), as Stonefish's acoustic modems
    always      /tf, /tf_static (scene-driven vehicles), /diagnostics; /clock when asked
    poses in    per vehicle: nav_msgs/Odometry, geometry_msgs/PoseStamped, or a child frame of /tf
"""

from __future__ import annotations

import logging
import math
import re
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

from ..kernel.frame import BROADCAST
from . import wire as w

log = logging.getLogger("uwsimnet.ros2")

PROFILES = ("native", "dmac2", "stonefish")
SIM_NODE = "uwsimnet"


class Hasher(Protocol):
    def key_hash(self, ros_type: str) -> str: ...


class Codec(Hasher, Protocol):
    def encode(self, ros_type: str, value: Any) -> bytes: ...
    def decode(self, ros_type: str, payload: bytes) -> Any: ...


# == the graph: what rmw_zenoh would declare for our nodes ============================================

@dataclass
class Endpoint:
    kind: str                     # MP | MS
    node: str
    namespace: str
    topic: str                    # fully qualified
    ros_type: str
    qos: w.QoS
    key: str                      # the data key
    token: str
    gid: bytes
    role: str = ""                # rx status tx dmac_recv dmac_send sf_recv sf_send pose tf tf_in tf_static clock diag
    arg: str = ""                 # the modem id or vehicle name it serves
    seq: int = 0

    def attachment(self, now_ns: int) -> bytes:
        """The next sample's attachment (sequence numbers start at 1, as rmw_zenoh's)."""
        self.seq += 1
        return w.encode_attachment(self.seq, now_ns, self.gid)

    @property
    def topic_key(self) -> str:
        """The data key without its type and hash chunks."""
        return self.key.rsplit("/", 2)[0]

    @property
    def match_key(self) -> str:
        """What a subscription declares: the topic with any type and hash, so that wrong ones are counted
        (a ROS subscriber declares the exact key and never hears them)."""
        return self.topic_key + "/*/*"


class Graph:
    """Nodes and entities of one Zenoh session, numbered as rmw_zenoh numbers them: one counter from 0
    for the session, a node's token repeating its own id."""

    def __init__(self, domain: int, zid: str, hasher: Hasher) -> None:
        self.domain = w.check_domain(domain)
        self.zid = zid
        self.hasher = hasher
        self._next = 0
        self.nodes: list[tuple[str, str, str]] = []      # (name, namespace, token)
        self.endpoints: list[Endpoint] = []
        self._node_ids: dict[tuple[str, str], int] = {}

    def _id(self) -> int:
        self._next += 1
        return self._next - 1

    def node(self, name: str, namespace: str = "/") -> int:
        k = (name, w.normalize_namespace(namespace))
        if k not in self._node_ids:
            nid = self._node_ids[k] = self._id()
            self.nodes.append((name, k[1], w.node_token(self.domain, self.zid, nid, name, k[1])))
        return self._node_ids[k]

    def add(self, kind: str, node: str, namespace: str, topic: str, ros_type: str, qos: w.QoS,
            role: str = "", arg: str = "") -> Endpoint:
        nid = self.node(node, namespace)
        full = w.fully_qualified(topic, namespace)
        h = self.hasher.key_hash(ros_type)
        token = w.entity_token(self.domain, self.zid, nid, self._id(), kind, node, full, ros_type, h, qos,
                               namespace=namespace)
        ep = Endpoint(kind, node, w.normalize_namespace(namespace), full, ros_type, qos,
                      w.data_key(self.domain, full, ros_type, h), token, w.gid_of(token), role, arg)
        self.endpoints.append(ep)
        return ep

    def tokens(self) -> list[str]:
        return [t for _, _, t in self.nodes] + [e.token for e in self.endpoints]


# == options and the scene's view =====================================================================

@dataclass(frozen=True)
class PoseInput:
    """A vehicle positioned from ROS: `source` odom | pose | tf; `topic` (odom, pose) or child frame (tf);
    `frame` the convention of the incoming poses (auto: from the message's frame id)."""

    vehicle: str
    source: str
    topic: str
    frame: str = "auto"


POSE_TYPES = {"odom": "nav_msgs/msg/Odometry", "pose": "geometry_msgs/msg/PoseStamped",
              "tf": "tf2_msgs/msg/TFMessage"}


def parse_pose_input(spec: str) -> PoseInput:
    """`VEHICLE=odom:/auv1/odom`, `VEHICLE=pose:/auv1/pose` or `VEHICLE=tf:auv1/base_link`, each optionally
    followed by `@enu` or `@ned` (default: the convention the message's frame id names)."""
    m = re.fullmatch(r"([^=\s]+)=(odom|pose|tf):([^@\s]+)(?:@(enu|ned))?", spec.strip())
    if not m:
        raise w.Ros2WireError("option", f"--ros-pose {spec!r}: expected VEHICLE=odom:TOPIC, VEHICLE=pose:TOPIC"
                                        " or VEHICLE=tf:CHILD_FRAME, optionally followed by @enu or @ned")
    vehicle, src, topic, frame = m.groups()
    if src != "tf":
        topic = w.fully_qualified(topic)
    return PoseInput(vehicle, src, topic, frame or "auto")


@dataclass(frozen=True)
class Options:
    domain: int = 0
    distro: str = w.DEFAULT_DISTRO
    namespace: str = "/uwsimnet"          # of the native modem nodes
    profiles: tuple[str, ...] = ("native",)
    poses: tuple[PoseInput, ...] = ()
    scene_frame: str = "enu"              # the convention of the scene's coordinates
    world_frame: str = "world"            # parent frame id of /tf and /tf_static
    clock: bool = False

    def __post_init__(self) -> None:
        w.check_domain(self.domain)
        w.check_distro(self.distro)
        w.normalize_namespace(self.namespace)
        for p in self.profiles:
            if p not in PROFILES:
                raise w.Ros2WireError("option", f"--ros-profile {p!r}: one of {', '.join(PROFILES)}")
        if self.scene_frame not in ("enu", "ned"):
            raise w.Ros2WireError("option", f"--ros-frame {self.scene_frame!r}: enu or ned")


@dataclass(frozen=True)
class ModemInfo:
    dev: str
    address: int
    vehicle: str


@dataclass(frozen=True)
class VehicleInfo:
    name: str
    pose_source: str                      # scene | zenoh
    static: bool = False                  # scene-driven and never moving: its pose goes on /tf_static
    ros_pose: str | None = None           # the scene's <rosPose> (odom:TOPIC | pose:TOPIC | tf:FRAME[@enu|@ned])


def ros_name(name: str) -> str:
    """A simulator name as one ROS 2 name token: other characters become '_' (`alpha-m` -> `alpha_m`)."""
    s = re.sub(r"[^A-Za-z0-9_]", "_", name)
    return s if s and not s[0].isdigit() else "_" + s


def check_poses(opts: Options, vehicles: Sequence[VehicleInfo]) -> None:
    """Every --ros-pose names a vehicle of the scene that is positioned from outside, once."""
    known = {v.name: v for v in vehicles}
    seen = set()
    for p in opts.poses:
        if p.vehicle not in known:
            raise w.Ros2WireError("option", f"--ros-pose {p.vehicle}: the scene has no vehicle {p.vehicle!r}"
                                            f" (it has {', '.join(sorted(known)) or 'none'})")
        if known[p.vehicle].pose_source != "zenoh":
            raise w.Ros2WireError("option", f"--ros-pose {p.vehicle}: the scene drives this vehicle; give it"
                                            " <poseSource>zenoh</poseSource> to position it from ROS")
        if p.vehicle in seen:
            raise w.Ros2WireError("option", f"--ros-pose {p.vehicle}: given twice")
        seen.add(p.vehicle)


def default_poses(opts: Options, vehicles: Sequence[VehicleInfo]) -> tuple[PoseInput, ...]:
    """--ros-pose inputs; for every vehicle positioned from outside that none names, the scene's <rosPose>,
    else `nav_msgs/Odometry` on `/<vehicle>/odom` (the topic a robot simulator's odometry plug-in publishes),
    so a `poseSource zenoh` vehicle follows ROS with no option."""
    named = {p.vehicle for p in opts.poses}
    return opts.poses + tuple(
        parse_pose_input(f"{v.name}={v.ros_pose}") if v.ros_pose
        else PoseInput(v.name, "odom", f"/{ros_name(v.name)}/odom")
        for v in vehicles if v.pose_source == "zenoh" and v.name not in named)


# == what the bridge hands back =======================================================================

@dataclass(frozen=True)
class Put:
    """A ROS sample to publish on `endpoint` (its key), CDR payload and attachment."""

    endpoint: Endpoint
    payload: bytes
    attachment: bytes

    @property
    def key(self) -> str:
        return self.endpoint.key


@dataclass(frozen=True)
class PoseUpdate:
    """A pose for the simulator's pose table, in the scene's convention."""

    vehicle: str
    p: tuple[float, float, float]
    q: tuple[float, float, float, float] | None = None
    v: tuple[float, float, float] | None = None


@dataclass(frozen=True)
class TxRequest:
    """A frame for modem `dev` to send (the simulator's tx message)."""

    dev: str
    dst: int
    data: bytes
    tag: int | None = None


@dataclass
class Problems:
    """Bad input from ROS, counted by reason; each (reason, topic) is logged once."""

    counts: Counter = field(default_factory=Counter)
    reported: set = field(default_factory=set)

    def __call__(self, reason: str, topic: str, detail: str) -> None:
        self.counts[reason] += 1
        if (reason, topic) not in self.reported:
            self.reported.add((reason, topic))
            log.warning("ROS 2: %s on %s: %s (ignored; counted, reported once)", reason, topic, detail)


QOS_DATA = w.QoS(w.RELIABLE, w.VOLATILE, w.KEEP_LAST, 10)
QOS_TF = w.QoS(w.RELIABLE, w.VOLATILE, w.KEEP_LAST, 100)
QOS_TF_STATIC = w.QoS(w.RELIABLE, w.TRANSIENT_LOCAL, w.KEEP_LAST, 1)
QOS_CLOCK = w.QoS(w.BEST_EFFORT, w.VOLATILE, w.KEEP_LAST, 1)
QOS_DMAC = w.QoS(w.RELIABLE, w.VOLATILE, w.KEEP_LAST, 100)           # the dmac2 driver's depth
QOS_SF_RECV = w.QoS(w.RELIABLE, w.VOLATILE, w.KEEP_LAST, 10)         # Stonefish's received_data
QOS_SF_SEND = w.QoS(w.RELIABLE, w.VOLATILE, w.KEEP_LAST, 1)          # Stonefish's data_to_send


# == the bridge =======================================================================================

class Ros2Bridge:
    """Everything ROS 2 about one run: the graph it declares and the translation both ways."""

    def __init__(self, opts: Options, zid: str, codec: Codec, modems: Sequence[ModemInfo],
                 vehicles: Sequence[VehicleInfo]) -> None:
        self.opts = opts
        self.codec = codec
        self.graph = g = Graph(opts.domain, zid, codec)
        self.problems = Problems()
        self.stats: Counter = Counter()
        self.modems = {m.dev: m for m in modems}
        self.vehicles = {v.name: v for v in vehicles}
        check_poses(opts, vehicles)
        self._subs: dict[str, Endpoint] = {}
        self._pubs: dict[tuple[str, str], Endpoint] = {}
        self._pose_in: dict[str, PoseInput] = {}                 # topic -> input (odom, pose)
        self._tf_in: dict[str, PoseInput] = {}                   # child frame -> input
        self._static: dict[str, dict] = {}                       # vehicle -> its transform on /tf_static

        self._pub(g.add("MP", SIM_NODE, "/", "/tf", POSE_TYPES["tf"], QOS_TF, "tf"))
        self._pub(g.add("MP", SIM_NODE, "/", "/tf_static", POSE_TYPES["tf"], QOS_TF_STATIC, "tf_static"))
        self._pub(g.add("MP", SIM_NODE, "/", "/diagnostics", "diagnostic_msgs/msg/DiagnosticArray", QOS_DATA,
                        "diag"))
        if opts.clock:
            self._pub(g.add("MP", SIM_NODE, "/", "/clock", "rosgraph_msgs/msg/Clock", QOS_CLOCK, "clock"))
        for p in default_poses(opts, vehicles):
            if p.source == "tf":
                self._tf_in[p.topic.strip("/")] = p
            else:
                self._pose_in[p.topic] = p
                self._sub(g.add("MS", SIM_NODE, "/", p.topic, POSE_TYPES[p.source], QOS_DATA, "pose", p.vehicle))
        if self._tf_in:
            self._sub(g.add("MS", SIM_NODE, "/", "/tf", POSE_TYPES["tf"], QOS_TF, "tf_in"))
        for m in modems:
            node = ros_name(m.dev)
            if "native" in opts.profiles:
                ns = opts.namespace
                self._pub(g.add("MP", node, ns, f"{node}/rx", "uwsimnet_msgs/msg/Frame", QOS_DATA, "rx", m.dev))
                self._pub(g.add("MP", node, ns, f"{node}/status", "uwsimnet_msgs/msg/Status", QOS_DATA,
                                "status", m.dev))
                self._sub(g.add("MS", node, ns, f"{node}/tx", "uwsimnet_msgs/msg/Transmit", QOS_DATA, "tx",
                                m.dev))
            if "dmac2" in opts.profiles:
                dmac = "dmac2_interfaces/msg/DMACPayload"
                self._pub(g.add("MP", node, "/", f"{node}/recv", dmac, QOS_DMAC, "dmac_recv", m.dev))
                self._sub(g.add("MS", node, "/", f"{node}/send", dmac, QOS_DMAC, "dmac_send", m.dev))
            if "stonefish" in opts.profiles:
                self._pub(g.add("MP", node, "/", f"{node}/received_data", "std_msgs/msg/String", QOS_SF_RECV,
                                "sf_recv", m.dev))
                self._sub(g.add("MS", node, "/", f"{node}/data_to_send", "std_msgs/msg/String", QOS_SF_SEND,
                                "sf_send", m.dev))

    def _pub(self, ep: Endpoint) -> None:
        self._pubs[(ep.role, ep.arg)] = ep

    def _sub(self, ep: Endpoint) -> None:
        self._subs[ep.topic_key] = ep

    # -- declarations -----------------------------------------------------------------------------
    def publishers(self) -> list[Endpoint]:
        return [e for e in self.graph.endpoints if e.kind == "MP"]

    def subscriptions(self) -> list[Endpoint]:
        return [e for e in self.graph.endpoints if e.kind == "MS"]

    def tokens(self) -> list[str]:
        return self.graph.tokens()

    def publisher(self, role: str, arg: str = "") -> Endpoint | None:
        return self._pubs.get((role, arg))

    # -- ROS -> simulator -------------------------------------------------------------------------
    def on_ros_sample(self, key: str, payload: bytes, attachment: bytes | None) -> list[PoseUpdate | TxRequest]:
        """A sample heard on one of the subscriptions' match keys: what it asks of the simulator.
        Samples of another type or hash, without a valid attachment, or with bad CDR are counted and
        give nothing."""
        base, _, rest = str(key).rpartition("/")
        base, _, dds = base.rpartition("/")
        ep = self._subs.get(base)
        if ep is None:
            return []
        h = rest
        if dds != w.dds_type(ep.ros_type):
            self.problems("type", ep.topic, f"a {dds} sample on a {ep.ros_type} topic")
            return []
        want = self.codec.key_hash(ep.ros_type)
        if h != want:
            if h == w.TYPE_HASH_NOT_SUPPORTED:
                why = "a Humble publisher (TypeHashNotSupported): run with --ros-distro humble"
            elif want == w.TYPE_HASH_NOT_SUPPORTED:
                why = "a publisher with an RIHS01 hash (Jazzy or later) while --ros-distro is humble"
            else:
                why = f"type hash {h}, expected {want} (another definition of {ep.ros_type})"
            self.problems("type_hash", ep.topic, why)
            return []
        try:
            w.decode_attachment(attachment)
            msg = self.codec.decode(ep.ros_type, payload)
        except w.Ros2WireError as e:
            self.problems(e.reason, ep.topic, e.detail)
            return []
        try:
            out = self._translate_in(ep, msg)
        except (ValueError, TypeError, AttributeError, UnicodeError) as e:
            self.problems("invalid", ep.topic, str(e))
            return []
        self.stats["ros_in"] += 1
        return out

    def _translate_in(self, ep: Endpoint, msg: Any) -> list[PoseUpdate | TxRequest]:
        role = ep.role
        if role == "pose":
            p = self._pose_in[ep.topic]
            if ep.ros_type == POSE_TYPES["odom"]:
                pose, lin = msg.pose.pose, msg.twist.twist.linear
                return [self._pose(p, msg.header.frame_id, _xyz(pose.position), _xyzw(pose.orientation),
                                   (lin.x, lin.y, lin.z))]
            return [self._pose(p, msg.header.frame_id, _xyz(msg.pose.position), _xyzw(msg.pose.orientation))]
        if role == "tf_in":
            out: list[PoseUpdate | TxRequest] = []
            for t in msg.transforms:
                p = self._tf_in.get(t.child_frame_id.strip("/"))
                if p is not None:
                    out.append(self._pose(p, t.header.frame_id, _xyz(t.transform.translation),
                                          _xyzw(t.transform.rotation)))
            return out
        if role == "tx":
            return [TxRequest(ep.arg, _address(msg.dst), bytes(msg.data), int(msg.tag) if msg.has_tag else None)]
        if role == "dmac_send":
            return [TxRequest(ep.arg, _address(msg.destination_address), msg.payload.encode("utf-8"),
                              int(msg.msg_id))]
        if role == "sf_send":
            return [TxRequest(ep.arg, BROADCAST, msg.data.encode("utf-8"))]
        return []

    def _pose(self, p: PoseInput, frame_id: str, xyz: tuple, q: tuple, body_v: tuple | None = None) -> PoseUpdate:
        if not all(math.isfinite(c) for c in (*xyz, *q)):
            raise ValueError("pose with NaN or infinite values")
        n = math.sqrt(sum(c * c for c in q))
        q = tuple(c / n for c in q) if n > 1e-9 else (0.0, 0.0, 0.0, 1.0)
        v = rotate(q, body_v) if body_v is not None and all(math.isfinite(c) for c in body_v) else None
        conv = p.frame if p.frame != "auto" else frame_convention(frame_id)
        if conv != self.opts.scene_frame:
            xyz, q = w.enu_to_ned(xyz), w.enu_to_ned_q(q)
            v = w.enu_to_ned(v) if v is not None else None
        return PoseUpdate(p.vehicle, _floats(xyz), _floats(q), _floats(v) if v is not None else None)

    # -- simulator -> ROS -------------------------------------------------------------------------
    def rx(self, dev: str, src: int, dst: int, data: bytes, seq: int, t_tx: float, t_rx: float,
           dist: float | None, now_ns: int) -> list[Put]:
        """A frame modem `dev` delivered: Frame / DMACPayload / String on that modem's topics."""
        puts = []
        ep = self.publisher("rx", dev)
        if ep:
            puts.append(self._put(ep, {"header": header(t_rx, dev), "src": src, "dst": dst, "seq": seq,
                                       "t_tx": t_tx, "t_rx": t_rx, "distance": math.nan if dist is None else dist,
                                       "data": bytes(data)}, now_ns))
        ep = self.publisher("dmac_recv", dev)
        if ep:
            text = bytes(data).decode("utf-8", "replace")
            puts.append(self._put(ep, {
                "header": header(t_rx, ep.node), "msg_id": seq & 0xFFFFFFFF, "source_address": src & 0xFF,
                "destination_address": dst & 0xFF, "type": 0,
                "propagation_time": min(0xFFFFFFFF, int(round(max(0.0, t_rx - t_tx) * 1e6))),
                "timestamp": int(t_rx * 1e6) & 0xFFFFFFFF, "payload": text,
                "info": [{"key": "simulated", "value": "uwsimnet"}]}, now_ns))
        ep = self.publisher("sf_recv", dev)
        if ep:
            puts.append(Put(ep, w.encode_string_cdr(bytes(data)), ep.attachment(now_ns)))
        self.stats["rx_out"] += len(puts)
        return puts

    def status(self, dev: str, event: str, reason: str | None, tag: int | None, seq: int | None, t: float,
               now_ns: int) -> list[Put]:
        ep = self.publisher("status", dev)
        if not ep:
            return []
        return [self._put(ep, {"header": header(t, dev), "event": event, "reason": reason or "",
                               "tag": 0 if tag is None else tag, "has_tag": tag is not None,
                               "seq": 0 if seq is None else seq & 0xFFFFFFFF, "has_seq": seq is not None}, now_ns)]

    def clock(self, t: float, now_ns: int) -> list[Put]:
        ep = self.publisher("clock")
        return [self._put(ep, {"clock": stamp(t)}, now_ns)] if ep else []

    def vehicle_pose(self, vehicle: str, p: Sequence[float], q: Sequence[float] | None, t: float,
                     now_ns: int) -> list[Put]:
        """A scene-driven vehicle's pose (as the simulator publishes it): on /tf, or once on /tf_static for a
        vehicle that never moves (all static vehicles in one message, as tf2's static broadcaster does)."""
        v = self.vehicles.get(vehicle)
        if v is None or v.pose_source != "scene":
            return []
        tr = self._transform(vehicle, p, q, t)
        if v.static:
            old = self._static.get(vehicle)
            if old is not None and old["transform"] == tr["transform"]:
                return []
            self._static[vehicle] = tr
            return [self._put(self.publisher("tf_static"), {"transforms": list(self._static.values())}, now_ns)]
        return [self._put(self.publisher("tf"), {"transforms": [tr]}, now_ns)]

    def _transform(self, vehicle: str, p: Sequence[float], q: Sequence[float] | None, t: float) -> dict:
        q = tuple(q) if q is not None else (0.0, 0.0, 0.0, 1.0)
        return {"header": header(t, self.opts.world_frame), "child_frame_id": ros_name(vehicle),
                "transform": {"translation": dict(zip("xyz", _floats(p), strict=True)),
                              "rotation": dict(zip("xyzw", _floats(q), strict=True))}}

    def diagnostics(self, infos: Iterable[dict], t: float, now_ns: int) -> list[Put]:
        """/diagnostics: one status per modem (its kind sim|real and counters, from its info record) and one
        for the ROS 2 side (the bad samples it ignored, by reason)."""
        status = []
        for info in infos:
            dev, kind = str(info.get("id", "?")), str(info.get("kind", "sim"))
            values = [{"key": "kind", "value": kind}]
            values += [{"key": str(k), "value": str(n)} for k, n in sorted((info.get("counters") or {}).items())]
            status.append({"level": 0, "name": f"uwsimnet/{dev}", "message": f"{kind} modem",
                           "hardware_id": f"{kind}:{dev}", "values": values})
        bad = self.problems.counts
        status.append({"level": 1 if bad else 0, "name": "uwsimnet/ros2",
                       "message": "ignored bad samples" if bad else "ok", "hardware_id": "uwsimnet",
                       "values": [{"key": k, "value": str(n)} for k, n in sorted(bad.items())]})
        return [self._put(self.publisher("diag"), {"header": header(t, ""), "status": status}, now_ns)]

    def _put(self, ep: Endpoint, fields: dict, now_ns: int) -> Put:
        return Put(ep, self.codec.encode(ep.ros_type, fields), ep.attachment(now_ns))


# == helpers ==========================================================================================

def stamp(t: float) -> dict:
    """builtin_interfaces/Time of `t` seconds (>= 0)."""
    ns = max(0, int(round(float(t) * 1e9)))
    return {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}


def header(t: float, frame_id: str) -> dict:
    return {"stamp": stamp(t), "frame_id": frame_id}


def frame_convention(frame_id: str) -> str:
    """`ned` when the frame id names NED (`world_ned`, `ned`, `map_ned`, `ned/...`), else `enu` (REP-103)."""
    f = frame_id.strip("/").lower()
    return "ned" if f == "ned" or f.endswith("_ned") or f.startswith(("ned_", "ned/")) or "_ned/" in f else "enu"


def rotate(q: Sequence[float], v: Sequence[float]) -> tuple[float, float, float]:
    """`v` rotated by the unit quaternion `q` = (x, y, z, w)."""
    x, y, z, qw = q
    vx, vy, vz = v
    tx, ty, tz = 2 * (y * vz - z * vy), 2 * (z * vx - x * vz), 2 * (x * vy - y * vx)
    return (vx + qw * tx + (y * tz - z * ty), vy + qw * ty + (z * tx - x * tz), vz + qw * tz + (x * ty - y * tx))


def _xyz(o: Any) -> tuple[float, float, float]:
    return (o.x, o.y, o.z)


def _xyzw(o: Any) -> tuple[float, float, float, float]:
    return (o.x, o.y, o.z, o.w)


def _floats(v: Iterable[float]) -> tuple:
    return tuple(float(c) for c in v)


def _address(a: Any) -> int:
    a = int(a)
    if not 0 <= a <= 65535:
        raise ValueError(f"destination address {a} out of range 0..65535")
    return a
