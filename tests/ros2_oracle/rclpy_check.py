"""Runs INSIDE the ROS 2 oracle venv (tests/ros2_oracle/setup.sh): real rclpy and rosidl judge bytes and
hashes made by the project. Reads one JSON document on stdin:

    {"cases": [{"type": "nav_msgs/msg/Odometry", "fields": {...}, "ours": HEX}, ...],
     "msg_dirs": {"uwsimnet_msgs": DIR, ...}}

and writes {"cases": [{"rclpy": HEX, "same_message": bool, "equal_but_padding": bool, "padding": [...]}],
"hashes": {type: RIHS01 from rosidl}} on stdout. `equal_but_padding`: our bytes equal rclpy's except at
positions rclpy ignores when reading (fastcdr leaves alignment padding uninitialised).
"""

from __future__ import annotations

import contextlib
import importlib
import json
import sys
import tempfile
from pathlib import Path

import rclpy.serialization as rs


def msg_class(ros_type: str):
    pkg, _, name = ros_type.split("/")
    return getattr(importlib.import_module(f"{pkg}.msg"), name)


def build(cls, d):
    m = cls()
    types = cls.get_fields_and_field_types()
    for k, v in d.items():
        t = types[k]
        if isinstance(v, dict):
            setattr(m, k, build(type(getattr(m, k)), v))
        elif isinstance(v, list) and t.startswith("sequence<") and "/" in t:
            inner = t[t.index("<") + 1:t.rindex(">")].split(",")[0]
            setattr(m, k, [build(msg_class(inner.replace("/", "/msg/", 1)), e) for e in v])
        elif t in ("octet", "byte") and isinstance(v, int):
            setattr(m, k, bytes([v]))
        elif t.startswith("sequence<uint8") or t.startswith("uint8["):
            setattr(m, k, bytes(v) if t.startswith("sequence") else list(v))
        else:
            setattr(m, k, v)
    return m


def rosidl_hashes(msg_dirs: dict[str, str]) -> dict[str, str]:
    from rosidl_adapter import convert_to_idl
    from rosidl_generator_type_description import generate_type_hash
    share = Path(sys.prefix) / "share"
    extra = Path(sys.prefix) / "ros2-install" / "share"
    out = {}
    for pkg, d in msg_dirs.items():
        with tempfile.TemporaryDirectory() as tmp:
            tmp = Path(tmp)
            pkg_dir = tmp / pkg
            (pkg_dir / "msg").mkdir(parents=True)
            for f in sorted(Path(d).glob("*.msg")):
                (pkg_dir / "msg" / f.name).write_text(f.read_text())
            idls = []
            for f in sorted((pkg_dir / "msg").glob("*.msg")):
                idl = convert_to_idl(pkg_dir, pkg, f.relative_to(pkg_dir), tmp / "idl")
                idls.append(f"{tmp / 'idl'}:{idl.relative_to(tmp / 'idl')}")
            inc = [f"{p.name}:{p}" for root in (share, extra) if root.is_dir() for p in sorted(root.iterdir())
                   if (p / "msg").is_dir() and p.name != pkg]
            args = tmp / "args.json"
            args.write_text(json.dumps({"package_name": pkg, "output_dir": str(tmp / "out"), "idl_tuples": idls,
                                        "include_paths": inc}))
            for path in generate_type_hash(str(args)):
                j = json.loads(Path(path).read_text())
                name = j["type_description_msg"]["type_description"]["type_name"]
                out[name] = next(h["hash_string"] for h in j["type_hashes"] if h["type_name"] == name)
    return out


def shipped_hash(ros_type: str) -> str | None:
    pkg, _, name = ros_type.split("/")
    for root in (Path(sys.prefix) / "share", Path(sys.prefix) / "ros2-install" / "share"):
        f = root / pkg / "msg" / f"{name}.json"
        if f.exists():
            j = json.loads(f.read_text())
            return next(h["hash_string"] for h in j["type_hashes"] if h["type_name"] == ros_type)
    return None


def main() -> None:
    req = json.load(sys.stdin)
    out_cases = []
    for c in req["cases"]:
        cls = msg_class(c["type"])
        ref = build(cls, c["fields"])
        mine = bytes.fromhex(c["ours"])
        theirs = rs.serialize_message(ref)
        same = rs.deserialize_message(mine, cls) == ref
        padding = []
        if len(mine) == len(theirs):
            for i in (i for i in range(len(mine)) if mine[i] != theirs[i]):
                flipped = bytearray(mine)
                flipped[i] ^= 0xFF
                if rs.deserialize_message(bytes(flipped), cls) == ref:
                    padding.append(i)
        diff = [i for i in range(min(len(mine), len(theirs))) if mine[i] != theirs[i]]
        out_cases.append({"rclpy": theirs.hex(), "same_message": same, "padding": padding,
                          "equal_but_padding": len(mine) == len(theirs) and diff == padding})
    with contextlib.redirect_stdout(sys.stderr):          # rosidl_adapter prints what it reads and writes
        hashes = rosidl_hashes(req.get("msg_dirs", {}))
    for c in req["cases"]:
        if c["type"] not in hashes:
            h = shipped_hash(c["type"])
            if h:
                hashes[c["type"]] = h
    json.dump({"cases": out_cases, "hashes": hashes}, sys.stdout)


if __name__ == "__main__":
    main()
