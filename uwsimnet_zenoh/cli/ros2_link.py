"""`uwsimnet ros2-link`: one robot's ROS 2 topics across its (simulated or real) modem (docs/ros2-link.md)."""

from __future__ import annotations

import argparse
import json
import os
from typing import Any

from ..app import ros2
from ..errors import UserError
from ..ros2.distros import DEFAULT_DISTRO, DISTROS
from .zenoh_flags import DEFAULT_CONNECT


def add_commands(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("ros2-link", help="carry a robot's ROS 2 topics over its modem to the other robots' graphs")
    p.add_argument("modem", help="the modem id (dccommsId) this robot's link sends and receives through")
    p.add_argument("--scene", metavar="FILE", help="take the link from the <ros2Link> of the vehicle holding MODEM"
                                                   " (its topics, domain, mtu, namespace; the scene's world)")
    p.add_argument("--topic", action="append", default=[], metavar="topic=/NAME,type=PKG/msg/T[,dir=..,...]",
                   help="a topic crossing the water (repeat; same list and order on every robot): dir=out|in|both,"
                        " dst=ADDR (255 broadcast), prio=N (0 first), policy=fifo|keep_last, depth=N, rate=HZ,"
                        " budget=BYTES/S, compress=1|0")
    p.add_argument("--world", help="the simulated world's name (required without --scene)")
    p.add_argument("--connect", action="append", metavar="ENDPOINT", help=f"Zenoh router (default {DEFAULT_CONNECT})")
    p.add_argument("--ros-domain", type=int, help="this robot's ROS_DOMAIN_ID (default: $ROS_DOMAIN_ID, else 0)")
    p.add_argument("--ros-namespace", help="namespace of the link's node (default /)")
    p.add_argument("--ros-distro", choices=DISTROS, default=os.environ.get("ROS_DISTRO") or DEFAULT_DISTRO)
    p.add_argument("--mtu", type=int, help="bytes per frame handed to the modem, header included (default 64)")
    p.add_argument("--duration", type=float, help="stop after S seconds (default: Ctrl-C)")
    p.set_defaults(fn=cmd_ros2_link)


def cmd_ros2_link(args: argparse.Namespace) -> int:
    spec, world = link_spec(args)
    summary = ros2.run_link(args.connect or [DEFAULT_CONNECT], world, spec, distro=args.ros_distro,
                            duration=args.duration)
    print(json.dumps(summary, indent=1))
    return 0


def link_spec(args: argparse.Namespace) -> tuple[Any, str]:
    """The link (a scene.ros2_link.LinkSpec) and the world: from the scene's <ros2Link> (--scene) or from the
    options, the same model."""
    from ..scene import load_scene  # noqa: PLC0415 - this command only (start-up time of the others)
    from ..scene.ros2_link import LinkSpec, parse_rule  # noqa: PLC0415

    if args.scene:
        if args.topic or args.ros_domain is not None or args.mtu is not None or args.ros_namespace is not None:
            raise UserError("ros2-link --scene: the link's topics, domain, mtu and namespace come from the scene")
        scene = load_scene(args.scene)
        for v in scene.vehicles:
            if v.ros2_link is not None and v.ros2_link.modem == args.modem:
                return v.ros2_link, args.world or scene.world
        raise UserError(f"{args.scene}: no <ros2Link> uses modem {args.modem!r}")
    if not args.world:
        raise UserError("ros2-link: give --world (or --scene)")
    if not args.topic:
        raise UserError("ros2-link: give at least one --topic (or --scene)")
    domain = args.ros_domain if args.ros_domain is not None else int(os.environ.get("ROS_DOMAIN_ID") or 0)
    return LinkSpec(args.modem, domain, tuple(parse_rule(t) for t in args.topic),
                    mtu=64 if args.mtu is None else args.mtu, namespace=args.ros_namespace or "/"), args.world
