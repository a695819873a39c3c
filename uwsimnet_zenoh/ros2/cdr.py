"""CDR for the ROS 2 messages the adapter speaks, through rosbags (the optional extra `uwsimnet-zenoh[ros2]`).

rosbags is pure Python (no ROS install): its serializer gives the bytes rclpy gives (tests compare with
golden CDR made by rclpy from the PyPI ros-jazzy wheels). Type hashes are computed by wire.rihs01 from the
definitions (rosbags' own hash_rihs01 differs from rosidl for `.msg` `char`). The packages this project
ships (interfaces/uwsimnet_msgs, interfaces/dmac2_interfaces) are registered from their .msg files.
"""

from __future__ import annotations

from collections.abc import Mapping
from functools import cached_property
from importlib import resources
from typing import Any

import numpy as np

from . import wire as w

try:
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    from rosbags.typesys.base import Nodetype
except ImportError as e:  # pragma: no cover - depends on the environment
    raise ImportError("ROS 2 support needs rosbags: pip install 'uwsimnet-zenoh[ros2]'") from e

SHIPPED = {"uwsimnet_msgs": ("Frame", "Transmit", "Status"), "dmac2_interfaces": ("DMACPayload",)}
"""Message packages defined by this project's .msg files (ros2/interfaces/<package>/msg/<Name>.msg)."""

# rosbags' type store per distro (an older rosbags without a store falls back to Jazzy's definitions: the
# messages used here have the same definitions, hence hashes, from Humble to Lyrical)
_STORES = {d: getattr(Stores, f"ROS2_{s.upper()}", Stores.ROS2_JAZZY)
           for d, s in (("humble", "humble"), ("jazzy", "jazzy"), ("kilted", "kilted"), ("lyrical", "lyrical"),
                        ("rolling", "lyrical"))}

_NP = {"float64": np.float64, "float32": np.float32, "uint8": np.uint8, "int8": np.int8, "int16": np.int16,
       "uint16": np.uint16, "int32": np.int32, "uint32": np.uint32, "int64": np.int64, "uint64": np.uint64,
       "octet": np.uint8, "byte": np.uint8, "char": np.uint8, "bool": np.bool_}


class Codec:
    """Encode/decode CDR and compute type hashes for one distro's type store + the shipped packages."""

    def __init__(self, distro: str = w.DEFAULT_DISTRO, msg_texts: Mapping[str, str] | None = None) -> None:
        self.distro = w.check_distro(distro)
        self.ts = get_typestore(_STORES[distro])
        self.own: dict[str, w.MsgDef] = {}
        for name, text in (shipped_msg_texts() if msg_texts is None else msg_texts).items():
            self.own[name] = w.parse_msg(name, text)
            self.ts.register(get_types_from_msg(text, name))
        self._hash: dict[str, str] = {}

    # -- hashes ----------------------------------------------------------------------------------
    def msgdef(self, ros_type: str) -> w.MsgDef:
        if ros_type in self.own:
            return self.own[ros_type]
        try:
            _consts, fields = self.ts.fielddefs[ros_type]
        except KeyError:
            raise w.Ros2WireError("type", f"unknown message type {ros_type}") from None
        return w.MsgDef(ros_type, tuple(_field(n, d) for n, d in fields))

    def rihs01(self, ros_type: str) -> str:
        h = self._hash.get(ros_type)
        if h is None:
            h = self._hash[ros_type] = w.rihs01(ros_type, self.msgdef)
        return h

    def key_hash(self, ros_type: str) -> str:
        """The hash chunk for keys and tokens on this distro."""
        return w.key_type_hash(self.distro, self.rihs01(ros_type))

    # -- CDR -------------------------------------------------------------------------------------
    def encode(self, ros_type: str, value: Mapping[str, Any] | Any) -> bytes:
        msg = self.build(ros_type, value) if isinstance(value, Mapping) else value
        return bytes(self.ts.serialize_cdr(msg, ros_type))

    def decode(self, ros_type: str, payload: bytes) -> Any:
        w.check_cdr_header(payload)
        try:
            return self.ts.deserialize_cdr(bytes(payload), ros_type)
        except Exception as e:  # noqa: BLE001 - any decoding failure of foreign bytes is one reason
            raise w.Ros2WireError("cdr", f"{ros_type}: {type(e).__name__}: {e}") from None

    def build(self, ros_type: str, d: Mapping[str, Any]) -> Any:
        """A message object from a (partial) dict: missing fields take ROS defaults' zero values."""
        cls = self.ts.types[ros_type]
        _consts, fields = self.ts.fielddefs[ros_type]
        return cls(**{name: self._value(desc, d.get(name)) for name, desc in fields})

    def _value(self, desc: tuple, v: Any) -> Any:
        kind, detail = desc
        if kind == Nodetype.NAME:
            if v is not None and not isinstance(v, Mapping):
                return v
            return self.build(detail, v or {})
        if kind == Nodetype.BASE:
            typ = detail[0]
            if v is None:
                return "" if typ == "string" else (False if typ == "bool" else (0.0 if typ.startswith("float") else 0))
            return v
        sub, n = detail
        skind, sdetail = sub
        if skind == Nodetype.NAME:
            return [self._value(sub, e) for e in (v or [])]
        typ = sdetail[0]
        if typ == "string":
            return list(v or [])
        if v is None:
            v = [0] * (n if kind == Nodetype.ARRAY else 0)
        if isinstance(v, (bytes, bytearray, memoryview)):
            return np.frombuffer(bytes(v), dtype=np.uint8).copy()
        return np.array(v, dtype=_NP[typ])

    @cached_property
    def types(self) -> frozenset[str]:
        return frozenset(self.ts.types)


def _field(name: str, desc: tuple) -> w.Field:
    kind, detail = desc
    if kind == Nodetype.BASE:
        return w.Field(name, _base(detail[0]), string_bound=detail[1] or 0)
    if kind == Nodetype.NAME:
        return w.Field(name, detail)
    sub, n = detail
    skind, sdetail = sub
    container = "array" if kind == Nodetype.ARRAY else ("bounded" if n else "sequence")
    if skind == Nodetype.NAME:
        return w.Field(name, sdetail, container, n or 0)
    return w.Field(name, _base(sdetail[0]), container, n or 0, sdetail[1] or 0)


def _base(t: str) -> str:
    return {"octet": "byte", "boolean": "bool", "float": "float32", "double": "float64"}.get(t, t)


def shipped_msg_texts() -> dict[str, str]:
    """`{'uwsimnet_msgs/msg/Frame': <.msg text>, ...}` for every package this project ships."""
    root = resources.files(__package__) / "interfaces"
    return {f"{pkg}/msg/{n}": (root / pkg / "msg" / f"{n}.msg").read_text(encoding="utf-8")
            for pkg, names in SHIPPED.items() for n in names}
