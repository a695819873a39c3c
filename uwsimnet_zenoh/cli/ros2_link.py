"""`uwsimnet ros2-link`: one robot's ROS 2 topics across its (simulated or real) modem (docs/ros2-link.md)."""

from __future__ import annotations

import argparse
import json
import os

from ..app import ros2
from ..ros2.distros import DEFAULT_DISTRO, DISTROS
from .zenoh_flags import DEFAULT_CONNECT


def add_commands(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("ros2-link", help="carry a robot's ROS 2 topics over its modem to the other robots' graphs")
    p.add_argument("modem", help="the modem id (dccommsId) this robot's link sends and receives through")
    p.add_argument("--topic", action="append", default=[], metavar="topic=/NAME,type=PKG/msg/T[,dir=..,...]",
                   help="a topic crossing the water (repeat; same list and order on every robot): dir=out|in|both,"
                        " dst=ADDR (255 broadcast), prio=N (0 first), policy=fifo|keep_last, depth=N, rate=HZ,"
                        " budget=BYTES/S, compress=1|0")
    p.add_argument("--world", required=True, help="the simulated world's name")
    p.add_argument("--connect", action="append", metavar="ENDPOINT", help=f"Zenoh router (default {DEFAULT_CONNECT})")
    p.add_argument("--ros-domain", type=int, help="this robot's ROS_DOMAIN_ID (default: $ROS_DOMAIN_ID, else 0)")
    p.add_argument("--ros-namespace", default="/", help="namespace of the link's node")
    p.add_argument("--ros-distro", choices=DISTROS, default=os.environ.get("ROS_DISTRO") or DEFAULT_DISTRO)
    p.add_argument("--mtu", type=int, default=64, help="bytes per frame handed to the modem, header included")
    p.add_argument("--duration", type=float, help="stop after S seconds (default: Ctrl-C)")
    p.set_defaults(fn=cmd_ros2_link)


def cmd_ros2_link(args: argparse.Namespace) -> int:
    domain = args.ros_domain if args.ros_domain is not None else int(os.environ.get("ROS_DOMAIN_ID") or 0)
    summary = ros2.run_link(args.connect or [DEFAULT_CONNECT], args.world, args.modem, args.topic, domain=domain,
                            namespace=args.ros_namespace, mtu=args.mtu, distro=args.ros_distro,
                            duration=args.duration)
    print(json.dumps(summary, indent=1))
    return 0
