"""The ROS 2 link's settings (docs/ros2-link.md): which topics of a robot's graph cross the water, and how.

One model for both forms: the scene's `<ros2Link>` (scene/native.py reads it) and `uwsimnet ros2-link
--topic topic=/cmd_vel,type=...` (`parse_rule`) both build `TopicRule`s through `rule_from_fields`, so the
same keys mean the same thing and are checked by the same code. Here, below ros2/ and bus/, so that the scene
reader can check a link at load time (file:line) without importing the link itself.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field

from ..errors import UwsimnetError

BROADCAST = 255
MAX_TOPICS = 63
"""Topic indices 0..62 carry samples; 63 is the link's own (the QoS announcements, docs/ros2-link.md)."""
DIRECTIONS = ("out", "in", "both")
POLICIES = ("fifo", "keep_last")
_NAME = re.compile(r"(/[A-Za-z_][A-Za-z0-9_]*)+")
"""A fully qualified ROS 2 name: tokens of letters, digits and '_', none starting with a digit (ros2/wire.py)."""
_TYPE = re.compile(r"[A-Za-z][A-Za-z0-9_]*/msg/[A-Z][A-Za-z0-9]*")   # as ros2/wire.py


class LinkError(UwsimnetError, ValueError):
    """A link setting this module cannot accept (one line, for the CLI and the scene reader)."""


@dataclass(frozen=True)
class TopicRule:
    """One topic allowed across the water. `priority`: 0 is served first. `rate`: at most that many
    messages per second are accepted (0 = no limit). `budget`: on-air bytes per second (token bucket,
    burst of one second; 0 = no limit). `depth`: keep-last N for state, FIFO length for commands."""

    name: str
    type: str
    direction: str = "both"
    dst: int = BROADCAST
    priority: int = 5
    policy: str = "fifo"
    depth: int = 10
    rate: float = 0.0
    budget: int = 0
    compress: bool = True

    def __post_init__(self) -> None:
        if not self.name.startswith("/"):
            raise LinkError(f"topic {self.name!r}: a fully qualified name starts with '/'")
        if not _NAME.fullmatch(self.name):
            raise LinkError(f"topic {self.name!r}: not a ROS 2 name (letters, digits and '_' between '/', no"
                            " token starting with a digit)")
        if not _TYPE.fullmatch(self.type):
            raise LinkError(f"topic {self.name}: type {self.type!r} is not pkg/msg/Name")
        if self.direction not in DIRECTIONS:
            raise LinkError(f"topic {self.name}: direction {self.direction!r} (one of {', '.join(DIRECTIONS)})")
        if self.policy not in POLICIES:
            raise LinkError(f"topic {self.name}: policy {self.policy!r} (one of {', '.join(POLICIES)})")
        if not 0 <= self.dst <= 255:
            raise LinkError(f"topic {self.name}: dst {self.dst} is not an address 0..255")
        if self.depth < 1 or self.rate < 0 or self.budget < 0 or self.priority < 0:
            raise LinkError(f"topic {self.name}: depth >= 1, rate, budget and priority >= 0")


RULE_KEYS = {"topic": "name", "type": "type", "dir": "direction", "dst": "dst", "prio": "priority",
             "policy": "policy", "depth": "depth", "rate": "rate", "budget": "budget", "compress": "compress"}
"""The keys of a topic, as `--topic` writes them (the scene's `<topic>` attributes: the same, `name` for `topic`)."""
_INTS = {"dst", "priority", "depth", "budget"}
_BOOLS = {"1": True, "true": True, "yes": True, "0": False, "false": False, "no": False}


def rule_from_fields(fields: Mapping[str, str], what: str) -> TopicRule:
    """A rule from `key -> text` (keys of RULE_KEYS); `what` names the source in errors."""
    kw: dict[str, object] = {}
    for key, value in fields.items():
        if key not in RULE_KEYS:
            raise LinkError(f"{what}: {key!r} is not one of {', '.join(RULE_KEYS)}")
        name = RULE_KEYS[key]
        try:
            if name in _INTS:
                kw[name] = int(value)
            elif name == "rate":
                kw[name] = float(value)
            elif name == "compress":
                kw[name] = _BOOLS[value.strip().lower()]
            else:
                kw[name] = value.strip()
        except (ValueError, KeyError):
            kind = "1 or 0" if name == "compress" else "a number"
            raise LinkError(f"{what}: {key}={value!r} is not {kind}") from None
    if "name" not in kw or "type" not in kw:
        raise LinkError(f"{what}: topic and type are required")
    return TopicRule(**kw)  # type: ignore[arg-type]   (its errors name the topic)


def parse_rule(text: str) -> TopicRule:
    """The CLI form `topic=/cmd_vel,type=geometry_msgs/msg/Twist,dir=out,dst=2,prio=0,policy=fifo,...`."""
    fields: dict[str, str] = {}
    for part in filter(None, (p.strip() for p in text.split(","))):
        key, eq, value = part.partition("=")
        if not eq or key not in RULE_KEYS:
            raise LinkError(f"link topic {text!r}: {part!r} is not one of {', '.join(f'{k}=' for k in RULE_KEYS)}")
        if key in fields:
            raise LinkError(f"link topic {text!r}: {key}= given twice")
        fields[key] = value
    return rule_from_fields(fields, f"link topic {text!r}")


def check_rules(rules: list[TopicRule]) -> list[TopicRule]:
    """The topic index on air is the position in this list: both ends must list the same topics in order."""
    if len(rules) > MAX_TOPICS:
        raise LinkError(f"a link carries at most {MAX_TOPICS} topics ({len(rules)} given)")
    names = [r.name for r in rules]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise LinkError(f"topic listed twice on the link: {', '.join(sorted(dup))}")
    return rules


@dataclass(frozen=True)
class LinkSpec:
    """A vehicle's `<ros2Link>`: the link of `modem` (a dccommsId of the vehicle) for the robot's graph on
    ROS domain `domain`, frames of at most `mtu` bytes, the node in `namespace`. What `uwsimnet ros2-link
    MODEM --ros-domain D --mtu M --topic ...` runs."""

    modem: str
    domain: int
    topics: tuple[TopicRule, ...]
    mtu: int = 64
    namespace: str = "/"
    line: int = field(default=0, compare=False)
    """Source line of the scene's <ros2Link> (0 from the CLI): not part of what the link is."""

    def __post_init__(self) -> None:
        if not self.topics:
            raise LinkError("a link needs at least one topic")
        check_rules(list(self.topics))
        if not 0 <= self.domain <= 232:
            raise LinkError(f"ROS domain {self.domain}: expected 0..232")
        if self.mtu < 10:
            raise LinkError(f"mtu {self.mtu}: at least 10 bytes (a first fragment's header is 8)")
        if self.namespace != "/" and not _NAME.fullmatch("/" + self.namespace.strip("/")):
            raise LinkError(f"namespace {self.namespace!r}: not a ROS 2 namespace")

    def signature(self) -> tuple[tuple[str, str], ...]:
        """What the far ends must agree on: the topics' names and types, in order (the index on air)."""
        return tuple((r.name, r.type) for r in self.topics)
