"""The Zenoh key space of DESIGN.md, in one place: builders, wildcards and a parser.

    uwsimnet/<world>/pose/<vehicle>              pose samples
    uwsimnet/<world>/modem/<id>/tx               app -> modem
    uwsimnet/<world>/modem/<id>/rx               modem -> app
    uwsimnet/<world>/modem/<id>/status           modem -> app
    uwsimnet/<world>/modem/<id>/info             queryable
    uwsimnet/<world>/modem/<id>/driver/<kind>    liveliness token: sim | real
    uwsimnet/<world>/trace/<channel>             trace events
    uwsimnet/<world>/clock                       simulation time
    uwsimnet/<world>/control/<op>                queryables (docs/runtime.md)

World names, vehicle names and modem ids are each exactly one key chunk: non-empty, without `/`, `*`,
`$`, `?`, `#` or whitespace (the same rule the scene loader applies to `<world>`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

PREFIX = "uwsimnet"
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
    def pose(self, vehicle: str) -> str:
        return f"{self.base}/pose/{check_chunk(vehicle, 'vehicle')}"

    def modem(self, dev: str, leaf: str) -> str:
        return f"{self.base}/modem/{check_chunk(dev, 'modem id')}/{leaf}"

    def tx(self, dev: str) -> str:
        return self.modem(dev, "tx")

    def rx(self, dev: str) -> str:
        return self.modem(dev, "rx")

    def status(self, dev: str) -> str:
        return self.modem(dev, "status")

    def info(self, dev: str) -> str:
        return self.modem(dev, "info")

    def driver(self, dev: str, kind: str) -> str:
        if kind not in DRIVER_KINDS:
            raise KeyNameError(f"driver kind must be one of {DRIVER_KINDS}, got {kind!r}")
        return f"{self.modem(dev, 'driver')}/{kind}"

    def trace(self, channel: int | str) -> str:
        return f"{self.base}/trace/{check_chunk(str(channel), 'channel')}"

    @property
    def clock(self) -> str:
        return f"{self.base}/clock"

    def control(self, op: str) -> str:
        return f"{self.base}/control/{check_chunk(op, 'control operation')}"

    # -- wildcards (what the broker and generic clients subscribe to) ----------------------------
    @property
    def pose_all(self) -> str:
        return f"{self.base}/pose/**"

    @property
    def tx_all(self) -> str:
        return f"{self.base}/modem/*/tx"

    @property
    def rx_all(self) -> str:
        return f"{self.base}/modem/*/rx"

    @property
    def status_all(self) -> str:
        return f"{self.base}/modem/*/status"

    @property
    def info_all(self) -> str:
        return f"{self.base}/modem/*/info"

    def drivers(self, kind: str = "*", dev: str = "*") -> str:
        """Liveliness key expression for drivers: all kinds and modems by default."""
        if dev != "*":
            check_chunk(dev, "modem id")
        if kind != "*" and kind not in DRIVER_KINDS:
            raise KeyNameError(f"driver kind must be one of {DRIVER_KINDS} or '*', got {kind!r}")
        return f"{self.base}/modem/{dev}/driver/{kind}"

    @property
    def trace_all(self) -> str:
        return f"{self.base}/trace/*"

    @property
    def control_all(self) -> str:
        return f"{self.base}/control/**"


@dataclass(frozen=True, slots=True)
class Key:
    """A parsed key: `kind` is pose | modem | trace | clock | control; `name` the vehicle, modem id,
    channel or control operation; `leaf` the modem leaf (tx, rx, status, info, driver); `driver` the
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
    return None


def modem_id(key: object, leaf: str) -> str | None:
    """The modem id of a `.../modem/<id>/<leaf>` key, else None (the broker's hot path)."""
    k = parse(key)
    if k is None or k.kind != "modem" or k.leaf != leaf:
        return None
    return k.name
