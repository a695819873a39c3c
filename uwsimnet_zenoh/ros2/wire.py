"""rmw_zenoh's wire, sans-IO: what makes a Zenoh session a ROS 2 node (docs/ros2.md).

No zenoh, no rosbags, no I/O: strings and bytes in, strings and bytes out, so every rule here is tested
against rmw_zenoh's own golden strings in microseconds.

    data key      <domain>/<topic without leading/trailing '/'>/<pkg::msg::dds_::Name_>/<type hash>
    node token    @ros2_lv/<domain>/<zid>/<nid>/<nid>/NN/<enclave>/<namespace>/<node>
    entity token  @ros2_lv/<domain>/<zid>/<nid>/<eid>/<MP|MS|SS|SC>/<enclave>/<namespace>/<node>/<topic>/
                  <type>/<hash>/<qos>
    attachment    <i64 seq LE><i64 source timestamp ns LE><0x10><16-byte gid>    (33 bytes, mandatory)

In tokens every '/' inside a part becomes '%' (an empty namespace or the default enclave is '%').
The type hash is `RIHS01_<sha256 hex>` (REP-2011) from Jazzy on, the literal `TypeHashNotSupported` on
Humble: the two never match, so the distro is a setting (`--ros-distro`).
"""

from __future__ import annotations

import hashlib
import json
import math
import re
import struct
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from ..errors import UwsimnetError
from .distros import DEFAULT_DISTRO as DEFAULT_DISTRO
from .distros import DISTROS

# == distros ==========================================================================================

TYPE_HASH_NOT_SUPPORTED = "TypeHashNotSupported"
"""What Humble's rmw_zenoh puts where later distros put the RIHS01 hash."""


class Ros2WireError(UwsimnetError, ValueError):
    """Input this module cannot accept; `reason` is a short token (counted by the adapter)."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


def check_distro(distro: str) -> str:
    if distro not in DISTROS:
        raise Ros2WireError("distro", f"unknown ROS 2 distro {distro!r} (one of {', '.join(DISTROS)})")
    return distro


def uses_type_hash(distro: str) -> bool:
    """True when keys and tokens carry RIHS01 hashes (every distro but Humble)."""
    return check_distro(distro) != "humble"


def key_type_hash(distro: str, rihs01: str) -> str:
    """The hash chunk of keys and tokens for `distro`."""
    return rihs01 if uses_type_hash(distro) else TYPE_HASH_NOT_SUPPORTED


# == names ============================================================================================

_ROS_TYPE = re.compile(r"^([A-Za-z][A-Za-z0-9_]*)/(msg|srv)/([A-Z][A-Za-z0-9]*)$")
_NAME_TOKEN = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def split_type(ros_type: str) -> tuple[str, str, str]:
    """`'nav_msgs/msg/Odometry'` -> `('nav_msgs', 'msg', 'Odometry')` (`pkg/Name` means `pkg/msg/Name`)."""
    if ros_type.count("/") == 1:
        pkg, name = ros_type.split("/")
        ros_type = f"{pkg}/msg/{name}"
    m = _ROS_TYPE.match(ros_type)
    if not m:
        raise Ros2WireError("type", f"{ros_type!r} is not a ROS 2 interface type like pkg/msg/Name")
    return m.group(1), m.group(2), m.group(3)


def dds_type(ros_type: str) -> str:
    """The type name rmw_zenoh puts in keys: `std_msgs/msg/String` -> `std_msgs::msg::dds_::String_`."""
    pkg, kind, name = split_type(ros_type)
    return f"{pkg}::{kind}::dds_::{name}_"


def ros_type_of(dds: str) -> str:
    """Inverse of `dds_type`."""
    parts = dds.split("::")
    if len(parts) != 4 or parts[2] != "dds_" or not parts[3].endswith("_"):
        raise Ros2WireError("type", f"{dds!r} is not a DDS type name like pkg::msg::dds_::Name_")
    return f"{parts[0]}/{parts[1]}/{parts[3][:-1]}"


def fully_qualified(name: str, namespace: str = "/") -> str:
    """A ROS 2 topic or service name made absolute: `('chatter', '/robot1')` -> `/robot1/chatter`.

    Names are tokens of letters, digits and '_' separated by '/', not starting with a digit (ROS 2
    naming rules); '~' (private names) and substitutions are not supported."""
    ns = normalize_namespace(namespace)
    if not isinstance(name, str) or not name or name == "/":
        raise Ros2WireError("name", f"topic name {name!r} is empty")
    full = name if name.startswith("/") else (ns.rstrip("/") + "/" + name)
    full = full.rstrip("/") if len(full) > 1 else full
    for tok in full.strip("/").split("/"):
        if not _NAME_TOKEN.match(tok):
            raise Ros2WireError("name", f"topic name {name!r}: {tok!r} is not a valid ROS 2 name token")
    return full


def normalize_namespace(namespace: str) -> str:
    if not isinstance(namespace, str):
        raise Ros2WireError("name", f"namespace {namespace!r} is not a string")
    if namespace in ("", "/"):
        return "/"
    ns = "/" + namespace.strip("/")
    for tok in ns.strip("/").split("/"):
        if not _NAME_TOKEN.match(tok):
            raise Ros2WireError("name", f"namespace {namespace!r}: {tok!r} is not a valid ROS 2 name token")
    return ns


def check_node_name(node: str) -> str:
    if not isinstance(node, str) or not _NAME_TOKEN.match(node):
        raise Ros2WireError("name", f"node name {node!r}: letters, digits and '_' only, not starting with a digit")
    return node


def mangle(name: str) -> str:
    """rmw_zenoh's mangling for token parts: every '/' becomes '%'."""
    return name.replace("/", "%")


def demangle(part: str) -> str:
    return part.replace("%", "/")


def strip_slashes(name: str) -> str:
    """One leading and one trailing '/' removed (rmw_zenoh's strip_slashes)."""
    if name.startswith("/"):
        name = name[1:]
    if name.endswith("/"):
        name = name[:-1]
    return name


def data_key(domain: int, topic: str, ros_type: str, type_hash: str) -> str:
    """The Zenoh key of a topic's samples; `topic` fully qualified (see `fully_qualified`)."""
    return f"{check_domain(domain)}/{strip_slashes(topic)}/{dds_type(ros_type)}/{type_hash}"


def check_domain(domain: int) -> int:
    # ROS_DOMAIN_ID: 0..232 is what DDS allows; rmw_zenoh takes any size_t. Keep the ROS range.
    if not isinstance(domain, int) or isinstance(domain, bool) or not 0 <= domain <= 232:
        raise Ros2WireError("domain", f"ROS domain id must be an integer 0..232, got {domain!r}")
    return domain


# == QoS ==============================================================================================

RELIABLE, BEST_EFFORT = 1, 2
TRANSIENT_LOCAL, VOLATILE = 1, 2
KEEP_LAST, KEEP_ALL = 1, 2
_AUTOMATIC = 1


@dataclass(frozen=True, slots=True)
class QoS:
    """The QoS part of a token. Written explicitly (reliability, durability, history, depth): an empty
    field means "the reader's default", and rmw_zenoh's default durability changed (Jazzy 0.2.3)."""

    reliability: int = RELIABLE
    durability: int = VOLATILE
    history: int = KEEP_LAST
    depth: int = 10

    def __post_init__(self) -> None:
        if self.reliability not in (RELIABLE, BEST_EFFORT):
            raise Ros2WireError("qos", f"reliability must be 1 (reliable) or 2 (best effort), got"
                                       f" {self.reliability!r}")
        if self.durability not in (TRANSIENT_LOCAL, VOLATILE):
            raise Ros2WireError("qos", f"durability must be 1 (transient local) or 2 (volatile), got"
                                       f" {self.durability!r}")
        if self.history not in (KEEP_LAST, KEEP_ALL):
            raise Ros2WireError("qos", f"history must be 1 (keep last) or 2 (keep all), got {self.history!r}")
        if not isinstance(self.depth, int) or self.depth < 0:
            raise Ros2WireError("qos", f"depth must be a non-negative integer, got {self.depth!r}")

    def keyexpr(self, explicit: bool = True) -> str:
        """`<rel>:<dur>:<hist>,<depth>:<deadline s>,<ns>:<lifespan s>,<ns>:<liveliness>,<lease s>,<ns>`;
        deadline, lifespan and liveliness left empty (= infinite, automatic). `explicit=False` leaves
        empty, as rmw_zenoh does, every field equal to rmw_zenoh's current default."""
        fields = [str(self.reliability), str(self.durability), str(self.history), str(self.depth)]
        if not explicit:
            fields = ["" if f == str(_QOS_DEFAULTS[k]) else f for f, k in zip(fields, _QOS_DEFAULTS, strict=True)]
        rel, dur, hist, depth = fields
        return f"{rel}:{dur}:{hist},{depth}:,:,:,,"


# rmw_zenoh's defaults for empty fields (qos.cpp) of the rmw_zenoh version the token came from; for
# durability that is VOLATILE since Jazzy 0.2.3 / Humble 0.1.2 (TRANSIENT_LOCAL before).
_QOS_DEFAULTS = {"reliability": RELIABLE, "durability": VOLATILE, "history": KEEP_LAST, "depth": 42}


def parse_qos(text: str) -> QoS:
    """The QoS in a token's last part (empty fields = rmw_zenoh's current defaults)."""
    parts = text.split(":")
    if len(parts) < 6:
        raise Ros2WireError("qos", f"{text!r}: expected 6 ':'-separated fields")
    hist = parts[2].split(",")
    if len(hist) < 2 or len(parts[3].split(",")) < 2 or len(parts[4].split(",")) < 2 or len(parts[5].split(",")) < 3:
        raise Ros2WireError("qos", f"{text!r}: malformed history/deadline/lifespan/liveliness fields")

    def num(s: str, default: int) -> int:
        if s == "":
            return default
        if not s.isdigit():
            raise Ros2WireError("qos", f"{text!r}: {s!r} is not a number")
        return int(s)

    try:
        return QoS(num(parts[0], _QOS_DEFAULTS["reliability"]), num(parts[1], _QOS_DEFAULTS["durability"]),
                   num(hist[0], _QOS_DEFAULTS["history"]), num(hist[1], _QOS_DEFAULTS["depth"]))
    except Ros2WireError as e:
        raise Ros2WireError("qos", f"{text!r}: {e.detail}") from None


# == liveliness tokens ================================================================================

ADMIN_SPACE = "@ros2_lv"
ENTITY_KINDS = ("NN", "MP", "MS", "SS", "SC")


def node_token(domain: int, zid: str, node_id: int, node: str, namespace: str = "/", enclave: str = "/") -> str:
    """The liveliness token that makes `node` appear in `ros2 node list`."""
    return "/".join((ADMIN_SPACE, str(check_domain(domain)), _zid(zid), str(node_id), str(node_id), "NN",
                     mangle(enclave or "/"), mangle(normalize_namespace(namespace)), mangle(check_node_name(node))))


def entity_token(domain: int, zid: str, node_id: int, entity_id: int, kind: str, node: str, topic: str,
                 ros_type: str, type_hash: str, qos: QoS, namespace: str = "/", enclave: str = "/",
                 explicit_qos: bool = True) -> str:
    """The token of a publisher (MP), subscription (MS), service server (SS) or client (SC);
    `topic` fully qualified (`explicit_qos`: see QoS.keyexpr)."""
    if kind not in ENTITY_KINDS[1:]:
        raise Ros2WireError("token", f"entity kind must be one of MP, MS, SS, SC, got {kind!r}")
    return "/".join((ADMIN_SPACE, str(check_domain(domain)), _zid(zid), str(node_id), str(entity_id), kind,
                     mangle(enclave or "/"), mangle(normalize_namespace(namespace)), mangle(check_node_name(node)),
                     mangle(topic), mangle(dds_type(ros_type)), mangle(type_hash), qos.keyexpr(explicit_qos)))


def _zid(zid: str) -> str:
    z = str(zid)
    if not z or not re.fullmatch(r"[0-9a-f]+", z):
        raise Ros2WireError("token", f"session id {zid!r} must be lowercase hex")
    return z


@dataclass(frozen=True, slots=True)
class Token:
    """A parsed graph token (topic fields None for nodes)."""

    domain: int
    zid: str
    node_id: str
    entity_id: str
    kind: str
    enclave: str
    namespace: str
    node: str
    topic: str | None = None
    dds_type: str | None = None
    type_hash: str | None = None
    qos: QoS | None = None


def parse_token(key: str) -> Token | None:
    """A token of the ROS graph, or None for anything else (never raises)."""
    parts = str(key).split("/")
    if len(parts) < 9 or parts[0] != ADMIN_SPACE or any(p == "" for p in parts):
        return None
    if parts[5] not in ENTITY_KINDS or not parts[1].isdigit():
        return None
    base = dict(domain=int(parts[1]), zid=parts[2], node_id=parts[3], entity_id=parts[4], kind=parts[5],
                enclave=demangle(parts[6]), namespace=demangle(parts[7]), node=demangle(parts[8]))
    if parts[5] == "NN":
        return Token(**base)
    if len(parts) < 13:
        return None
    try:
        qos = parse_qos(parts[12])
    except Ros2WireError:
        return None
    return Token(**base, topic=demangle(parts[9]), dds_type=demangle(parts[10]), type_hash=demangle(parts[11]),
                 qos=qos)


# == attachment =======================================================================================

ATTACHMENT_SIZE = 33
GID_SIZE = 16
_ATT = struct.Struct("<qqB16s")


@dataclass(frozen=True, slots=True)
class Attachment:
    seq: int
    timestamp_ns: int
    gid: bytes


def encode_attachment(seq: int, timestamp_ns: int, gid: bytes) -> bytes:
    """zenoh-ext serialization of (int64, int64, 16 x uint8): the form of rmw_zenoh >= Jazzy 0.2.4 /
    Humble 0.1.2 / Kilted (the 77-byte labelled form of older releases is not spoken)."""
    if len(gid) != GID_SIZE:
        raise Ros2WireError("attachment", f"gid must be {GID_SIZE} bytes, got {len(gid)}")
    return _ATT.pack(seq, timestamp_ns, GID_SIZE, bytes(gid))


def decode_attachment(raw: bytes | bytearray | memoryview | None) -> Attachment:
    if raw is None:
        raise Ros2WireError("no-attachment", "sample without attachment")
    b = bytes(raw)
    if len(b) != ATTACHMENT_SIZE:
        raise Ros2WireError("attachment", f"attachment of {len(b)} bytes, expected {ATTACHMENT_SIZE}")
    seq, ts, n, gid = _ATT.unpack(b)
    if n != GID_SIZE:
        raise Ros2WireError("attachment", f"gid length byte {n}, expected {GID_SIZE}")
    return Attachment(seq, ts, gid)


def gid_of(token: str) -> bytes:
    """A 16-byte gid for an entity, derived from its token. rmw_zenoh uses XXH3-128 of the token;
    receivers never check it, so a keyed BLAKE2b keeps this dependency-free."""
    return hashlib.blake2b(token.encode(), digest_size=GID_SIZE).digest()


# == CDR encapsulation ================================================================================

CDR_LE_HEADER = b"\x00\x01\x00\x00"


def check_cdr_header(payload: bytes) -> None:
    if len(payload) < 4 or payload[:4] != CDR_LE_HEADER:
        raise Ros2WireError("cdr", f"payload does not start with the CDR little-endian header 00 01 00 00"
                                   f" ({bytes(payload[:4]).hex() or 'empty'})")


def encode_string_cdr(data: bytes) -> bytes:
    """std_msgs/String with arbitrary bytes (Stonefish puts raw frames in it)."""
    return CDR_LE_HEADER + struct.pack("<I", len(data) + 1) + bytes(data) + b"\x00"


def decode_string_cdr(payload: bytes) -> bytes:
    check_cdr_header(payload)
    if len(payload) < 8:
        raise Ros2WireError("cdr", "std_msgs/String shorter than its length field")
    (n,) = struct.unpack_from("<I", payload, 4)
    if n == 0 or 8 + n > len(payload) or payload[8 + n - 1] != 0:
        raise Ros2WireError("cdr", f"std_msgs/String length {n} does not fit a {len(payload)}-byte payload")
    return bytes(payload[8:8 + n - 1])


# == RIHS01 (REP-2011 type hashes), as rosidl_generator_type_description computes them ===============

# type_description_interfaces/msg/FieldType ids
_BASE_IDS = {
    "int8": 2, "uint8": 3, "int16": 4, "uint16": 5, "int32": 6, "uint32": 7, "int64": 8, "uint64": 9,
    "float32": 10, "float64": 11, "char": 3, "bool": 15, "byte": 16, "string": 17, "wstring": 18,
}
# .msg `char` is an alias of uint8 in ROS 2 (rosidl maps it to uint8, id 3); `byte` is octet (16).
_NESTED_ID = 1
_BOUNDED_STRING, _BOUNDED_WSTRING = 21, 22
_ARRAY, _BOUNDED_SEQ, _UNBOUNDED_SEQ = 48, 96, 144


@dataclass(frozen=True, slots=True)
class Field:
    name: str
    type: str                 # base type name or nested 'pkg/msg/Name'
    container: str = ""       # '' | 'array' | 'bounded' | 'sequence'
    size: int = 0             # array size or sequence bound
    string_bound: int = 0     # for string<=N


@dataclass(frozen=True, slots=True)
class MsgDef:
    ros_type: str
    fields: tuple[Field, ...]
    constants: tuple[tuple[str, str, str], ...] = field(default=())


_FIELD_RE = re.compile(r"^([A-Za-z][A-Za-z0-9_/]*)(<=\d+)?(\[(<=)?(\d*)\])?\s+([a-z][a-z0-9_]*)(\s+.*)?$")
_CONST_RE = re.compile(r"^([A-Za-z][A-Za-z0-9_]*)\s+([A-Z][A-Z0-9_]*)\s*=\s*(.*)$")


def parse_msg(ros_type: str, text: str) -> MsgDef:
    """A .msg definition (fields and constants; comments and defaults dropped)."""
    pkg, _, _ = split_type(ros_type)
    fields: list[Field] = []
    consts: list[tuple[str, str, str]] = []
    for lineno, raw in enumerate(text.splitlines(), 1):
        line = _strip_comment(raw).strip()
        if not line:
            continue
        c = _CONST_RE.match(line)
        if c:
            consts.append((c.group(1), c.group(2), c.group(3).strip()))
            continue
        m = _FIELD_RE.match(line)
        if not m:
            raise Ros2WireError("msg", f"{ros_type}:{lineno}: cannot read {raw.strip()!r}")
        base, sbound, arr, bounded, n, name, _default = m.groups()
        if base in ("string", "wstring") or base in _BASE_IDS:
            typ = base
        elif base == "Header":
            typ = "std_msgs/msg/Header"
        elif "/" in base:
            typ = "/".join(split_type(base))
        else:
            typ = f"{pkg}/msg/{base}"
        if sbound and base not in ("string", "wstring"):
            raise Ros2WireError("msg", f"{ros_type}:{lineno}: only strings take <=N")
        container, size = "", 0
        if arr:
            if bounded:
                container, size = "bounded", int(n)
            elif n:
                container, size = "array", int(n)
            else:
                container = "sequence"
        fields.append(Field(name, typ, container, size, int(sbound[2:]) if sbound else 0))
    return MsgDef("/".join(split_type(ros_type)), tuple(fields), tuple(consts))


def _strip_comment(line: str) -> str:
    # '#' starts a comment except inside a quoted string default/constant value
    out, quote = [], None
    for ch in line:
        if quote:
            if ch == quote:
                quote = None
        elif ch in "'\"":
            quote = ch
        elif ch == "#":
            break
        out.append(ch)
    return "".join(out)


def _field_type(f: Field) -> dict:
    if f.type in _BASE_IDS:
        tid = _BASE_IDS[f.type]
        if f.string_bound:
            tid = _BOUNDED_STRING if f.type == "string" else _BOUNDED_WSTRING
        nested = ""
    else:
        tid, nested = _NESTED_ID, f.type
    tid += {"": 0, "array": _ARRAY, "bounded": _BOUNDED_SEQ, "sequence": _UNBOUNDED_SEQ}[f.container]
    return {"type_id": tid, "capacity": f.size, "string_capacity": f.string_bound, "nested_type_name": nested}


def type_description(ros_type: str, lookup: Callable[[str], MsgDef] | Mapping[str, MsgDef]) -> dict:
    """The TypeDescription (without default values) REP-2011 hashes, with every referenced type."""
    get = lookup.__getitem__ if isinstance(lookup, Mapping) else lookup

    def individual(t: str) -> dict:
        d = get(t)
        fields = d.fields or (Field("structure_needs_at_least_one_member", "uint8"),)
        return {"type_name": t, "fields": [{"name": f.name, "type": _field_type(f)} for f in fields]}

    top = individual("/".join(split_type(ros_type)))
    seen: dict[str, dict] = {}
    todo = [f["type"]["nested_type_name"] for f in top["fields"] if f["type"]["nested_type_name"]]
    while todo:
        t = todo.pop()
        if t in seen:
            continue
        seen[t] = individual(t)
        todo.extend(f["type"]["nested_type_name"] for f in seen[t]["fields"] if f["type"]["nested_type_name"])
    return {"type_description": top, "referenced_type_descriptions": [seen[t] for t in sorted(seen)]}


def rihs01(ros_type: str, lookup: Callable[[str], MsgDef] | Mapping[str, MsgDef]) -> str:
    """`RIHS01_<sha256>` of `ros_type` (the json form rosidl hashes: ', ' and ': ' separators, ASCII)."""
    text = json.dumps(type_description(ros_type, lookup), ensure_ascii=True, separators=(", ", ": "))
    return "RIHS01_" + hashlib.sha256(text.encode()).hexdigest()


# == frames: ENU <-> NED ==============================================================================

_H = math.sqrt(0.5)


def enu_to_ned(p: tuple[float, float, float]) -> tuple[float, float, float]:
    """World position ENU (x east, y north, z up) -> NED (x north, y east, z down)."""
    x, y, z = p
    return (y, x, -z)


ned_to_enu = enu_to_ned   # the same swap is its own inverse


def _qmul(a, b):
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz)


def _canon(q):
    # one sign convention (w >= 0) so equal rotations compare equal
    return tuple(-c for c in q) if q[3] < 0 or (q[3] == 0 and next((c for c in q if c), 0) < 0) else tuple(q)


_ENU_NED = (_H, _H, 0.0, 0.0)      # rotation between the ENU and NED world axes (pi about (1,1,0)/sqrt2)
_FLU_FRD = (1.0, 0.0, 0.0, 0.0)    # body axes forward-left-up <-> forward-right-down (pi about x)


def enu_to_ned_q(q: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
    """Orientation (x, y, z, w) of a FLU body in ENU -> of the same body as FRD in NED (REP-103 / REP-105
    vs the marine convention). Its own inverse."""
    return _canon(_qmul(_qmul(_ENU_NED, q), _FLU_FRD))


ned_to_enu_q = enu_to_ned_q
