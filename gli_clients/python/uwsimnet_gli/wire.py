"""The one wire of uwsimnet: Zenoh keys, key-chunk rule, constants and msgpack codecs (docs/gli-protocol.md).

Shared by the simulator (broker, drivers, bridges, deploy's access-control rules) and by applications
(`uwsimnet_gli`): it imports msgpack and nothing else, so any process can use it.

    uwsimnet/<world>/pose/<vehicle>              pose samples
    uwsimnet/<world>/modem/<id>/tx               app -> modem
    uwsimnet/<world>/modem/<id>/rx               modem -> app
    uwsimnet/<world>/modem/<id>/status           modem -> app
    uwsimnet/<world>/modem/<id>/info             queryable
    uwsimnet/<world>/modem/<id>/driver/<kind>    liveliness token: sim | real
    uwsimnet/<world>/trace/<channel>             trace events
    uwsimnet/<world>/clock                       simulation time
    uwsimnet/<world>/control/<op>                queryables (docs/runtime.md)
    uwsimnet/<world>/vehicle/<name>/cmd          commands to kinematic vehicles

World names, vehicle names and modem ids are each exactly one key chunk: non-empty, without `/`, `*`,
`$`, `?`, `#` or whitespace (the same rule the scene loader applies to `<world>`).

Every decoder takes the raw bytes of a sample and returns a small record or raises `CodecError`, whose
`reason` is the token the broker puts in the `dropped` status it answers with:

    toolarge   the message is longer than the limit (checked before decoding anything)
    malformed  not one msgpack value (random bytes, truncated, trailing bytes, bad UTF-8)
    invalid    msgpack, but not the map the protocol asks for (missing field, wrong type, out of range)

Nothing here raises anything else, whatever the input: the decoders are fuzzed in tests/test_bus_codec.py.
Unknown map keys are ignored (a newer client may send more); encoders write exactly the documented keys.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any

import msgpack

PREFIX = "uwsimnet"
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
"""Where `uwsimnet run` serves Zenoh by default, and where clients connect when told nothing."""
BROADCAST = 255
"""The destination address every modem on a channel accepts (as in dccomms)."""
DRIVER_KINDS = ("sim", "real")
MODEM_LEAVES = ("tx", "rx", "status", "info", "driver")
CONTROL_OPS = ("add_device", "remove_device", "move", "pause", "resume", "state")

_BAD_CHUNK = re.compile(r"[/*$?#\s]")


class KeyNameError(ValueError):
    """A name that cannot be one key chunk."""


def check_chunk(name: object, what: str = "name") -> str:
    """`name` if it can be one key chunk, else KeyNameError saying why."""
    if not isinstance(name, str):
        raise KeyNameError(f"{what} must be a string, got {type(name).__name__}")
    if not name:
        raise KeyNameError(f"{what} must not be empty")
    m = _BAD_CHUNK.search(name)
    if m:
        raise KeyNameError(f"{what} {name!r}: {m.group()!r} is not allowed in a Zenoh key chunk"
                        " (no '/', '*', '$', '?', '#' or whitespace)")
    return name


def is_chunk(name: object) -> bool:
    return isinstance(name, str) and bool(name) and not _BAD_CHUNK.search(name)


class Keys:
    """Key builders for one world: `Keys("lab").tx("alpha-modem") == "uwsimnet/lab/modem/alpha-modem/tx"`."""

    __slots__ = ("world", "base")

    def __init__(self, world: str) -> None:
        self.world = check_chunk(world, "world")
        self.base = f"{PREFIX}/{world}"

    def __repr__(self) -> str:
        return f"Keys({self.world!r})"

    # -- concrete keys ---------------------------------------------------------------------------
    def key(self, template: str, modem: str | None = None, vehicle: str | None = None) -> str:
        """The key of a template of `USES` (`TX`, `POSE`, ...); `modem="*"` for every modem."""
        if modem is not None:
            template = template.replace("{m}", modem if modem == "*" else check_chunk(modem, "modem id"))
        if vehicle is not None:
            template = template.replace("{v}", check_chunk(vehicle, "vehicle"))
        return f"{self.base}/{template}"

    def pose(self, vehicle: str) -> str:
        return self.key(POSE, vehicle=vehicle)

    def modem(self, dev: str, leaf: str) -> str:
        """`dev`: a modem id, or `*` for every modem (a selector for subscriptions and queries)."""
        return self.key(f"modem/{{m}}/{leaf}", dev)

    def tx(self, dev: str) -> str:
        return self.key(TX, dev)

    def rx(self, dev: str) -> str:
        return self.key(RX, dev)

    def status(self, dev: str) -> str:
        return self.key(STATUS, dev)

    def info(self, dev: str) -> str:
        return self.key(INFO, dev)

    def driver(self, dev: str, kind: str) -> str:
        if kind not in DRIVER_KINDS:
            raise KeyNameError(f"driver kind must be one of {DRIVER_KINDS}, got {kind!r}")
        return f"{self.modem(dev, 'driver')}/{kind}"

    def trace(self, channel: int | str) -> str:
        return f"{self.base}/trace/{check_chunk(str(channel), 'channel')}"

    @property
    def clock(self) -> str:
        return self.key(CLOCK)

    def control(self, op: str) -> str:
        return f"{self.base}/control/{check_chunk(op, 'control operation')}"

    def vehicle_cmd(self, vehicle: str) -> str:
        return self.key(VEHICLE_CMD, vehicle=vehicle)

    # -- wildcards (what the broker and generic clients subscribe to) ----------------------------
    @property
    def pose_all(self) -> str:
        return self.key(POSE_ALL)

    @property
    def tx_all(self) -> str:
        return self.key(TX, "*")

    @property
    def rx_all(self) -> str:
        return self.key(RX, "*")

    @property
    def status_all(self) -> str:
        return self.key(STATUS, "*")

    @property
    def info_all(self) -> str:
        return self.key(INFO, "*")

    def drivers(self, kind: str = "*", dev: str = "*") -> str:
        """Liveliness key expression for drivers: all kinds and modems by default."""
        if dev != "*":
            check_chunk(dev, "modem id")
        if kind != "*" and kind not in DRIVER_KINDS:
            raise KeyNameError(f"driver kind must be one of {DRIVER_KINDS} or '*', got {kind!r}")
        return f"{self.base}/modem/{dev}/driver/{kind}"

    @property
    def trace_all(self) -> str:
        return self.key(TRACE)

    @property
    def control_all(self) -> str:
        return self.key(CONTROL_ALL)

    @property
    def vehicle_cmd_all(self) -> str:
        return self.key(VEHICLE_CMD.replace("{v}", "*"))


@dataclass(frozen=True, slots=True)
class Key:
    """A parsed key: `kind` is pose | modem | trace | clock | control | vehicle; `name` the vehicle, modem id,
    channel or control operation; `leaf` the modem leaf (tx, rx, status, info, driver) or `cmd`; `driver` the
    driver kind for driver tokens."""

    world: str
    kind: str
    name: str | None = None
    leaf: str | None = None
    driver: str | None = None


def parse(key: object) -> Key | None:
    """The parts of a concrete key of our key space, or None if it is not one (never raises)."""
    if not isinstance(key, str):
        key = str(key)
    parts = key.split("/")
    if len(parts) < 3 or parts[0] != PREFIX or not all(is_chunk(p) for p in parts[1:]):
        return None
    world, kind, rest = parts[1], parts[2], parts[3:]
    if kind == "clock":
        return Key(world, "clock") if not rest else None
    if kind in ("pose", "trace", "control"):
        if len(rest) != 1:
            return None
        return Key(world, kind, rest[0])
    if kind == "modem":
        if len(rest) == 2 and rest[1] in MODEM_LEAVES and rest[1] != "driver":
            return Key(world, "modem", rest[0], rest[1])
        if len(rest) == 3 and rest[1] == "driver" and rest[2] in DRIVER_KINDS:
            return Key(world, "modem", rest[0], "driver", rest[2])
    if kind == "vehicle" and len(rest) == 2 and rest[1] == "cmd":
        return Key(world, "vehicle", rest[0], "cmd")
    return None


# == who declares what: the access each program needs ==================================================
# Key expressions relative to `uwsimnet/<world>/`.  `{m}` stands for the modem ids a program is run for
# (`--id`, `gli send <modem>`, ...), `{v}` for its vehicle names; a `*` in a template is a wildcard the
# program itself declares (the broker subscribes `modem/*/tx` for every modem).  `Keys` builds every key
# from these templates, and deploy/render.py turns `USES` into the access-control rules of each role, so
# a rendered rule allows exactly what the programs declare (tests/test_deploy.py checks the declarations
# of the real programs against it).

POSE, POSE_ALL = "pose/{v}", "pose/**"
TX, RX, STATUS, INFO = "modem/{m}/tx", "modem/{m}/rx", "modem/{m}/status", "modem/{m}/info"
DRIVER = "modem/{m}/driver/{kind}"
TRACE = "trace/*"
CLOCK = "clock"
CONTROL, CONTROL_ALL = "control/*", "control/**"
VEHICLE_CMD = "vehicle/{v}/cmd"
CAPABILITIES = ("publish", "subscribe", "query", "serve", "token", "watch")
Names = list[str] | tuple[str, ...]
"""Modem ids or vehicle names (the wire imports msgpack and the stdlib's basics only)."""


@dataclass(frozen=True, slots=True)
class Uses:
    """What one program declares, relative to `uwsimnet/<world>/`: publish (publishers, puts), subscribe
    (subscribers), query (get), serve (queryables and their replies), token (liveliness tokens), watch
    (liveliness subscribers and queries)."""

    publish: tuple[str, ...] = ()
    subscribe: tuple[str, ...] = ()
    query: tuple[str, ...] = ()
    serve: tuple[str, ...] = ()
    token: tuple[str, ...] = ()
    watch: tuple[str, ...] = ()
    doc: str = ""

    def keys(self, cap: str) -> tuple[str, ...]:
        return getattr(self, cap)


def _all(t: str) -> str:
    return t.replace("{m}", "*").replace("{v}", "*")


USES: dict[str, Uses] = {
    "broker": Uses(
        publish=(_all(RX), _all(STATUS), TRACE, CLOCK, _all(POSE)),
        subscribe=(_all(TX), POSE_ALL),
        serve=(_all(INFO), CONTROL_ALL),
        token=(_all(DRIVER).replace("{kind}", "sim"),),
        watch=(_all(DRIVER).replace("{kind}", "real"),),
        doc="`uwsimnet run --clock realtime` (bus/broker.py): every simulated modem of the scene"),
    "driver": Uses(
        publish=(RX, STATUS), subscribe=(TX, CLOCK), query=(INFO,), serve=(INFO,),
        token=(DRIVER.replace("{kind}", "real"),), watch=(DRIVER.replace("{kind}", "sim"),),
        doc="`uwsimnet driver evologics|serial --id {m}` (drivers/zenoh_host.py): a real modem serves {m}"),
    "backend": Uses(
        publish=(TX,), subscribe=(RX, STATUS, TRACE, CLOCK), query=(INFO,),
        doc="`uwsimnet emulate ...|bridge ... --id {m}` (drivers/zenoh_backend.py): a simulated modem"
            " made to look like a device"),
    "vehicles": Uses(
        publish=(POSE,), subscribe=(VEHICLE_CMD, CLOCK),
        doc="`uwsimnet vehicles --vehicle {v}=...` (bus/kinematic.py): kinematic vehicles"),
    "modem": Uses(
        publish=(TX,), subscribe=(RX, STATUS), watch=(DRIVER.replace("{kind}", "*"),),
        doc="`gli send|flow {m}`, `Modem(world, {m})`: send frames, statuses, who serves it"),
    "listen": Uses(subscribe=(RX, STATUS), doc="`gli listen [--status] {m}`"),
    "info": Uses(query=(INFO,), doc="`gli info {m}`, `Modem.info()`"),
    "pose": Uses(publish=(POSE,), doc="`gli pose {v} ...`, `World.publish_pose({v}, ...)`"),
    "poses": Uses(subscribe=(_all(POSE),), doc="pose subscribers (`hil_apps` follows the leader's pose)"),
    "command": Uses(publish=(VEHICLE_CMD,), doc="`gli vehicle {v} KEY=VALUE...`: vehicle commands"),
    "clock": Uses(subscribe=(CLOCK,), doc="`World.clock()`, `gli flow`: simulation time"),
    "control": Uses(query=(CONTROL,), doc="`gli control OP ...`, `World.control(OP)`"),
    "trace": Uses(subscribe=(TRACE,), doc="`gli trace`: trace events of every channel"),
}
"""Per program, what it declares on the key space (the rules of deploy/render.py are built from it)."""


def expand(template: str, modems: Names = (), vehicles: Names = (),
           kind: str = "*") -> list[str]:
    """The key expressions of a template for given modem ids and vehicle names (none: `*`)."""
    out = [template.replace("{kind}", kind)]
    for ph, names in (("{m}", modems), ("{v}", vehicles)):
        out = [k.replace(ph, n) for k in out for n in (names or ("*",))] if any(ph in k for k in out) else out
    return list(dict.fromkeys(out))


def intersects(a: str, b: str) -> bool:
    """Whether key expressions `a` and `b` (chunks, `*` = one chunk, `**` = any number) share a key,
    as `zenoh.KeyExpr.intersects` (checked against it in tests/test_bus_keys.py)."""
    return _ix(tuple(a.split("/")), tuple(b.split("/")))


def _ix(a: tuple[str, ...], b: tuple[str, ...]) -> bool:
    if not a or not b:
        return all(c == "**" for c in a + b)
    if a[0] == "**":
        return _ix(a[1:], b) or _ix(a, b[1:])
    if b[0] == "**":
        return _ix(a, b[1:]) or _ix(a[1:], b)
    return (a[0] == b[0] or a[0] == "*" or b[0] == "*") and _ix(a[1:], b[1:])


def includes(a: str, b: str) -> bool:
    """Whether every key of `b` is a key of `a` (how an ACL rule's key expression matches a message)."""
    return _inc(tuple(a.split("/")), tuple(b.split("/")))


def _inc(a: tuple[str, ...], b: tuple[str, ...]) -> bool:
    if not a:
        return not b
    if a[0] == "**":
        return _inc(a[1:], b) or (bool(b) and _inc(a, b[1:]))
    if not b or b[0] == "**":
        return False
    return (a[0] == "*" or (a[0] == b[0] and b[0] != "*")) and _inc(a[1:], b[1:])


ACCESS_KEY = "uwsimnet"
"""Under `metadata` of a client configuration rendered by `uwsimnet deploy render`: the identity, its
role, its world and what the routers' access control allows it, as {"identity", "role", "world",
"allow": {capability: [relative key expressions]}}.  Commands check what they are about to declare
against it, so that an action the routers would drop silently is refused at once, in one line."""


def access_refusals(access: Any, program: str, world: str, modems: Names = (),
                    vehicles: Names = ()) -> list[str]:
    """What `program` (a key of USES) run in `world` for these modems/vehicles would declare that `access`
    does not allow, as `"<capability> <key>"` items; [] when `access` is None (no access control known)."""
    if not isinstance(access, dict):
        return []
    allow = access.get("allow") if isinstance(access.get("allow"), dict) else {}
    aw = access.get("world", "*")
    out = []
    for cap in CAPABILITIES:
        for t in USES[program].keys(cap):
            for k in expand(t, modems, vehicles):
                granted = allow.get(cap) or ()
                if not (aw in ("*", world) and any(isinstance(a, str) and includes(a, k) for a in granted)):
                    out.append(f"{cap} {PREFIX}/{world}/{k}")
    return out


def refusal_message(access: Any, refused: Names) -> str:
    """One line: who may not do what (the first refusal, and how many more)."""
    a = access if isinstance(access, dict) else {}
    who = f"{a.get('identity', '?')} (role {a.get('role', '?')})"
    more = f" and {len(refused) - 1} more" if len(refused) > 1 else ""
    return (f"{who} may not {refused[0]}{more}: the deployment's access control refuses it"
            " (docs/deployment.md, roles)")


def modem_id(key: object, leaf: str) -> str | None:
    """The modem id of a `.../modem/<id>/<leaf>` key, else None (the broker's hot path)."""
    k = parse(key)
    if k is None or k.kind != "modem" or k.leaf != leaf:
        return None
    return k.name


# == payloads ==========================================================================================

MAX_TX_MESSAGE = 65536
"""Default limit for a `tx` message on the wire, in bytes (frames themselves are limited by the modem)."""
MAX_SMALL_MESSAGE = 4096
"""Limit for pose samples and control requests."""
MAX_REPLY_MESSAGE = 1 << 20
"""Limit for replies an application reads (info, control answers): generous, but bounded."""
MAX_ADDRESS = 65535
STATUS_EVENTS = ("queued", "sent", "dropped", "acked", "failed", "transmitted")
FINAL_EVENTS = ("sent", "dropped", "acked", "failed")
"""Every frame offered on tx ends in exactly one of these (docs/gli-protocol.md, status); `queued` and
`transmitted` (an attempt on air whose acknowledgement is awaited) are not final."""
_INT64_MIN, _UINT64_MAX = -(2**63), 2**64 - 1


class CodecError(ValueError):
    """A message that cannot be accepted: `reason` is a status token, `detail` says what exactly.

    `tag` is the message's tag when it could be read (so the dropped status can carry it)."""

    def __init__(self, reason: str, detail: str, tag: int | None = None) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail
        self.tag = tag


def pack(obj: Any) -> bytes:
    """msgpack with bin for bytes and str for text (what every decoder here expects)."""
    return msgpack.packb(obj, use_bin_type=True)


def unpack(raw: bytes | bytearray | memoryview, limit: int) -> Any:
    """One msgpack value, or CodecError (toolarge / malformed)."""
    n = len(raw)
    if n > limit:
        raise CodecError("toolarge", f"message of {n} bytes, the limit is {limit}")
    if n == 0:
        raise CodecError("malformed", "empty message")
    try:
        return msgpack.unpackb(raw, raw=False, strict_map_key=False, use_list=True)
    except msgpack.ExtraData:
        raise CodecError("malformed", "trailing bytes after the msgpack value") from None
    except Exception as e:  # noqa: BLE001 - msgpack raises a zoo of types on bad input
        raise CodecError("malformed", f"not msgpack ({type(e).__name__})") from None


def _is_int(x: Any) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def _is_num(x: Any) -> bool:
    return (isinstance(x, int | float) and not isinstance(x, bool)) and math.isfinite(x)


def _map(obj: Any, what: str) -> dict:
    if not isinstance(obj, dict):
        raise CodecError("invalid", f"{what} must be a msgpack map, got {type(obj).__name__}")
    return obj


def _tag(m: dict) -> int | None:
    tag = m.get("tag")
    return tag if _is_int(tag) and _INT64_MIN <= tag <= _UINT64_MAX else None


def _vec(m: dict, key: str, n: int, required: bool) -> tuple[float, ...] | None:
    v = m.get(key)
    if type(v) is list and len(v) == n:       # the common case, all floats (a swarm: hundreds at once)
        for x in v:
            if type(x) is not float:
                break
        else:
            if math.isfinite(sum(v)):         # not if a nan or inf is in it (nor on an overflow: below)
                return tuple(v)
    if v is None:
        if required:
            raise CodecError("invalid", f"missing {key!r}")
        return None
    if not isinstance(v, list) or len(v) != n or not all(_is_num(x) for x in v):
        raise CodecError("invalid", f"{key!r} must be an array of {n} finite numbers")
    return tuple(float(x) for x in v)


# -- the kind of message (tx and rx) ----------------------------------------------------------
MSG_KINDS = ("burst", "im", "ims", "pbm")
"""`kind` of a message, as an acoustic modem with several services (EvoLogics S2C) tells them apart:
burst data, instant message, synchronous instant message, piggy-back message."""
IM_FLAGS = ("ack", "noack", "force")
MSG_KEYS = ("kind", "flag", "ts", "pid", "aseq")
"""`aseq`: the sending application's own sequence number (dccomms' SetVirtualSeq, 0..2^32-1), with or without
a `kind`; receivers get it unchanged (the original simulator passed it through), beside the modem's `seq`."""


def check_msg(msg: Any) -> dict[str, Any] | None:
    """The message fields of a tx/rx map (`kind`, `flag`, `ts`, `pid`, `aseq`), checked; None if none is
    there.  ValueError says what is wrong: `flag` only with kind im, `ts` (µs, 0..2^32-1) only with ims,
    `pid` 0..7, `aseq` 0..2^32-1; `flag`, `ts`, `pid` need a `kind`."""
    if not msg:
        return None
    aseq = msg.get("aseq")
    if aseq is not None and (not _is_int(aseq) or not 0 <= aseq < 1 << 32):
        raise ValueError("'aseq' must be an integer 0..2^32-1")
    if msg.get("kind") is None:
        if any(msg.get(k) is not None for k in MSG_KEYS[1:4]):
            raise ValueError("'flag', 'ts' and 'pid' need a 'kind'")
        return None if aseq is None else {"aseq": aseq}
    kind, flag, ts, pid = (msg.get(k) for k in MSG_KEYS[:4])
    if kind not in MSG_KINDS:
        raise ValueError(f"'kind' must be one of {MSG_KINDS}")
    if flag is not None and (kind != "im" or flag not in IM_FLAGS):
        raise ValueError(f"'flag' is for kind im only, one of {IM_FLAGS}")
    if ts is not None and (kind != "ims" or not _is_int(ts) or not 0 <= ts < 1 << 32):
        raise ValueError("'ts' is for kind ims only, an integer 0..2^32-1 (µs)")
    if pid is not None and (not _is_int(pid) or not 0 <= pid <= 7):
        raise ValueError("'pid' must be an integer 0..7")
    return {k: v for k, v in zip(MSG_KEYS, (kind, flag, ts, pid, aseq), strict=True) if v is not None}


def _msg_fields(m: dict, what: str, tag: int | None = None) -> dict[str, Any] | None:
    try:
        return check_msg(m)
    except ValueError as e:
        raise CodecError("invalid", f"{what}: {e}", tag) from None


# -- tx: app -> modem ---------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class TxRequest:
    dst: int
    data: bytes
    tag: int | None = None
    flow: str | None = None
    msg: dict[str, Any] | None = None
    """The kind of message the sender chose (`kind`, and `flag` / `ts` / `pid` when set); None: not said."""


def encode_tx(dst: int, data: bytes, tag: int | None = None, flow: str | None = None,
              msg: dict[str, Any] | None = None) -> bytes:
    """`msg`: {"kind": burst|im|ims|pbm, "flag": ack|noack|force (im), "ts": µs (ims), "pid": 0..7}."""
    if not _is_int(dst) or not 0 <= dst <= MAX_ADDRESS:
        raise ValueError(f"dst must be an address 0..{MAX_ADDRESS}, got {dst!r}")
    m: dict[str, Any] = {"dst": dst, "data": bytes(data)}
    if tag is not None:
        m["tag"] = tag
    if flow is not None:
        m["flow"] = flow
    m.update(check_msg(msg) or {})
    return pack(m)


def decode_tx(raw: bytes, limit: int = MAX_TX_MESSAGE) -> TxRequest:
    m = _map(unpack(raw, limit), "a tx message")
    tag = m.get("tag")
    if tag is not None:
        tag = _tag(m)
        if tag is None:
            raise CodecError("invalid", "'tag' must be an integer or nil")
    dst = m.get("dst")
    if not _is_int(dst) or not 0 <= dst <= MAX_ADDRESS:
        raise CodecError("invalid", f"'dst' must be an integer address 0..{MAX_ADDRESS}", tag)
    data = m.get("data")
    if not isinstance(data, bytes):
        raise CodecError("invalid", "'data' must be msgpack bin (bytes)", tag)
    flow = m.get("flow")
    if flow is not None and not isinstance(flow, str):
        raise CodecError("invalid", "'flow' must be a string or nil", tag)
    # the common message says nothing of its kind: no check_msg call (the simulator's per-frame path)
    msg = None if m.keys().isdisjoint(MSG_KEYS) else _msg_fields(m, "a tx message", tag)
    return TxRequest(dst, data, tag, flow, msg)


def tag_of(raw: bytes | None, limit: int = MAX_TX_MESSAGE) -> int | None:
    """The `tag` of a tx message when it can be read (even if the message is otherwise refused), else
    None: what a refusal's status carries."""
    if raw is None:
        return None
    try:
        return _tag(_map(unpack(raw, limit), "a tx message"))
    except CodecError:
        return None


# -- rx: modem -> app ---------------------------------------------------------------------------
def encode_rx(src: int, dst: int, data: bytes, seq: int, t_tx: float, t_rx: float,
              dist: float | None = None, msg: dict[str, Any] | None = None) -> bytes:
    """`msg`: the kind of message as the sender's tx gave it (see encode_tx), passed on unchanged."""
    m: dict[str, Any] = {"src": src, "dst": dst, "data": data, "seq": seq, "t_tx": float(t_tx),
                         "t_rx": float(t_rx)}
    if dist is not None:
        m["dist"] = float(dist)
    m.update(check_msg(msg) or {})
    return pack(m)


@dataclass(frozen=True, slots=True)
class RxFrame:
    src: int
    dst: int
    data: bytes
    seq: int
    t_tx: float
    t_rx: float
    dist: float | None = None
    """m between transmitter and receiver at transmission start (the trace's rx `dist`); None: not sent."""
    msg: dict[str, Any] | None = None
    """The kind of message the sender chose (its tx `kind`, `flag`, `ts`, `pid`); None: it did not say."""


def decode_rx(raw: bytes, limit: int = MAX_TX_MESSAGE) -> RxFrame:
    m = _map(unpack(raw, limit), "an rx message")
    for k in ("src", "dst", "seq"):
        if not _is_int(m.get(k)):
            raise CodecError("invalid", f"{k!r} must be an integer")
    for k in ("t_tx", "t_rx"):
        if not _is_num(m.get(k)):
            raise CodecError("invalid", f"{k!r} must be a number")
    if not isinstance(m.get("data"), bytes):
        raise CodecError("invalid", "'data' must be bin")
    dist = m.get("dist")
    if dist is not None and not (_is_num(dist) and dist >= 0):
        raise CodecError("invalid", "'dist' must be a number >= 0 or absent")
    return RxFrame(m["src"], m["dst"], m["data"], m["seq"], float(m["t_tx"]), float(m["t_rx"]),
                   None if dist is None else float(dist), _msg_fields(m, "an rx message"))


# -- status: modem -> app -----------------------------------------------------------------------
def encode_status(tag: int | None, event: str, reason: str | None, t: float, seq: int | None = None) -> bytes:
    m: dict[str, Any] = {"tag": tag, "event": event, "reason": reason, "t": float(t)}
    if seq is not None:
        m["seq"] = int(seq)
    return pack(m)


@dataclass(frozen=True, slots=True)
class Status:
    tag: int | None
    event: str
    reason: str | None
    t: float
    seq: int | None = None


def decode_status(raw: bytes) -> Status:
    m = _map(unpack(raw, MAX_SMALL_MESSAGE), "a status message")
    ev = m.get("event")
    if ev not in STATUS_EVENTS:
        raise CodecError("invalid", f"'event' must be one of {STATUS_EVENTS}")
    reason = m.get("reason")
    if reason is not None and not isinstance(reason, str):
        raise CodecError("invalid", "'reason' must be a string or nil")
    if not _is_num(m.get("t")):
        raise CodecError("invalid", "'t' must be a number")
    seq = m.get("seq")
    return Status(_tag(m), ev, reason, float(m["t"]), seq if _is_int(seq) else None)


# -- pose samples -------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class Pose:
    p: tuple[float, float, float]
    t: float | None = None
    q: tuple[float, float, float, float] | None = None
    v: tuple[float, float, float] | None = None


def encode_pose(p, *, t: float | None = None, q=None, v=None) -> bytes:
    m: dict[str, Any] = {}
    if t is not None:
        m["t"] = float(t)
    for key, vec, n in (("p", p, 3), ("q", q, 4), ("v", v, 3)):
        if vec is not None:
            m[key] = [float(x) for x in vec]
            if len(m[key]) != n:
                raise ValueError(f"{key} must have {n} components")
    return pack(m)


def decode_pose(raw: bytes) -> Pose:
    m = _map(unpack(raw, MAX_SMALL_MESSAGE), "a pose sample")
    t = m.get("t")
    if t is not None and not _is_num(t):
        raise CodecError("invalid", "'t' must be a finite number or nil")
    p = _vec(m, "p", 3, True)
    return Pose(p, None if t is None else float(t), _vec(m, "q", 4, False), _vec(m, "v", 3, False))  # type: ignore[arg-type]


# -- control requests ---------------------------------------------------------------------------
def decode_request(raw: bytes | None) -> dict:
    """A control request: a msgpack map, or nothing at all (= empty map)."""
    if raw is None or len(raw) == 0:
        return {}
    m = _map(unpack(raw, MAX_SMALL_MESSAGE), "a control request")
    if not all(isinstance(k, str) for k in m):
        raise CodecError("invalid", "control request keys must be strings")
    return m
