"""`uwsimnet run --ros2`: the options, the topology choice (stand in for rmw_zenohd, or join it) and the
adapter's life inside a realtime run (docs/ros2.md)."""

from __future__ import annotations

import contextlib
import os
import re
from typing import TYPE_CHECKING, Any

from ..errors import UserError, UwsimnetError
from ..ros2.distros import DEFAULT_DISTRO, DISTROS

if TYPE_CHECKING:
    from ..ros2.bridge import ModemInfo, Options, VehicleInfo
# ros2.wire and ros2.bridge are imported by the functions that use them: `uwsimnet run` builds its parser
# with add_arguments, and a virtual run needs nothing more of ROS 2 (start-up time)

ROS_PORT = 7447
ROS_LISTEN = [f"tcp/127.0.0.1:{ROS_PORT}", f"tcp/[::1]:{ROS_PORT}"]
"""Where ROS 2 nodes look for their router: rmw_zenoh sessions dial tcp/localhost:7447, and localhost is
127.0.0.1 or ::1 depending on the resolver, so a router standing in for rmw_zenohd listens on both."""
ROS_CONNECT = [f"tcp/localhost:{ROS_PORT}"]


def add_arguments(r: Any) -> None:
    g = r.add_argument_group("ROS 2 (realtime; needs the extra uwsimnet-zenoh[ros2])")
    g.add_argument("--ros2", action="store_true",
                   help="be a ROS 2 participant on rmw_zenoh's wire: modem nodes and topics, poses from ROS,"
                        " the scene's <ros2Link>s")
    g.add_argument("--ros-domain", type=int, metavar="N", help="ROS_DOMAIN_ID (default: $ROS_DOMAIN_ID, else 0)")
    g.add_argument("--ros-distro", choices=DISTROS,
                   help=f"the ROS 2 distro of the other nodes (default: $ROS_DISTRO, else {DEFAULT_DISTRO})")
    g.add_argument("--ros-profile", action="append", choices=("native", "dmac2", "stonefish"),
                   help="modem topics: native (uwsimnet_msgs, default), dmac2 (send/recv DMACPayload),"
                        " stonefish (data_to_send/received_data); repeatable")
    g.add_argument("--ros-pose", action="append", metavar="VEHICLE=odom:TOPIC|pose:TOPIC|tf:FRAME[@enu|@ned]",
                   help="position a <poseSource>zenoh</poseSource> vehicle from a ROS topic; repeatable")
    g.add_argument("--ros-frame", choices=("enu", "ned"), default="enu",
                   help="the convention of the scene's coordinates (default enu, as ROS)")
    g.add_argument("--ros-namespace", default="/uwsimnet", help="namespace of the modem nodes (native profile)")
    g.add_argument("--ros-clock", action="store_true", help="publish the simulation time on /clock")


def enabled(args: Any) -> bool:
    return bool(getattr(args, "ros2", False))


def options(args: Any) -> Options:
    from ..ros2 import wire as rw  # noqa: PLC0415 - see the imports
    from ..ros2.bridge import Options, parse_pose_input  # noqa: PLC0415

    domain = args.ros_domain
    if domain is None:
        env = os.environ.get("ROS_DOMAIN_ID", "").strip()
        domain = int(env) if env.isdigit() else 0
    distro = args.ros_distro or os.environ.get("ROS_DISTRO", "").strip().lower() or DEFAULT_DISTRO
    if distro not in DISTROS:
        raise UserError(f"ROS_DISTRO={distro}: uwsimnet speaks {', '.join(DISTROS)} (give --ros-distro)")
    try:
        return Options(domain=domain, distro=distro, namespace=args.ros_namespace,
                       profiles=tuple(dict.fromkeys(args.ros_profile or ["native"])),
                       poses=tuple(parse_pose_input(p) for p in args.ros_pose or ()),
                       scene_frame=args.ros_frame, world_frame="world" if args.ros_frame == "enu" else "world_ned",
                       clock=bool(args.ros_clock))
    except rw.Ros2WireError as e:
        raise UserError(e.detail) from None


def scene_view(scene: Any) -> tuple[list[ModemInfo], list[VehicleInfo]]:
    """The modems and vehicles of a scene as the bridge needs them."""
    from ..ros2.bridge import ModemInfo, VehicleInfo  # noqa: PLC0415 - see the imports

    modems, vehicles = [], []
    for v in scene.vehicles:
        static = v.pose_source == "scene" and len({(p.x, p.y, p.z) for p in v.trajectory}) <= 1
        vehicles.append(VehicleInfo(v.name, v.pose_source, static, v.ros_pose))
        modems += [ModemInfo(d.dccomms_id, d.address, v.name) for d in v.devices]
    return modems, vehicles


def check(opts: Options, scene: Any) -> tuple[list[ModemInfo], list[VehicleInfo]]:
    """The scene's view, once the options are known to fit it (UserError otherwise), before any session."""
    from ..ros2 import wire as rw  # noqa: PLC0415 - see the imports
    from ..ros2.bridge import check_poses, default_poses  # noqa: PLC0415

    modems, vehicles = scene_view(scene)
    try:
        check_poses(opts, vehicles)
        default_poses(opts, vehicles)
    except rw.Ros2WireError as e:
        raise UserError(e.detail) from None
    return modems, vehicles


def codec(distro: str) -> Any:
    try:
        from ..ros2.cdr import Codec
    except ImportError:
        raise UserError("--ros2 needs rosbags: pip install 'uwsimnet-zenoh[ros2]'") from None
    return Codec(distro)


def router_running(host: str = "127.0.0.1", port: int = ROS_PORT, timeout: float = 0.3) -> bool:
    """Something (rmw_zenohd, another router) accepts TCP connections on the ROS router port."""
    import socket  # noqa: PLC0415 - a --ros2 run only (start-up time)

    with contextlib.suppress(OSError), socket.create_connection((host, port), timeout=timeout):
        return True
    return False


def topology(listen: list[str], connect: list[str]) -> tuple[list[str], list[str], str | None]:
    """(listen, connect, message) for a --ros2 run given no endpoints: join the host's router if one runs on
    7447 (as a client, the DESIGN's rule), else be it, on 127.0.0.1 and ::1."""
    if listen or connect:
        return listen, connect, None
    if router_running():
        return [], list(ROS_CONNECT), ("a Zenoh router already listens on 7447 (rmw_zenohd?): joining it as a"
                                       " client")
    return list(ROS_LISTEN), [], None


def adapter_endpoint(mode: str, connect: list[str], listen: list[str], locs: list[str]) -> list[str]:
    """Where the adapter's client session connects: the run's router (one of its loopback locators), or the
    router the run itself joined."""
    if mode == "client":
        return list(connect)
    for ep in list(locs) + list(listen):
        m = re.fullmatch(r"(tcp|udp)/(.+):(\d+)", ep.split("#")[0])
        if not m or m.group(3) == "0":
            continue
        host = {"0.0.0.0": "127.0.0.1", "[::]": "[::1]"}.get(m.group(2), m.group(2))
        if host in ("127.0.0.1", "localhost", "[::1]"):
            return [f"tcp/{host}:{m.group(3)}"]
    for ep in list(locs) + list(listen):
        m = re.fullmatch(r"(tcp|udp)/(.+):(\d+)", ep.split("#")[0])
        if m and m.group(3) != "0":
            host = {"0.0.0.0": "127.0.0.1", "[::]": "[::1]"}.get(m.group(2), m.group(2))
            return [f"{m.group(1)}/{host}:{m.group(3)}"]
    raise UserError(f"--ros2: cannot tell where the run's router listens ({', '.join(listen) or 'nowhere'})")


def start_links(scene: Any, connect: list[str], world: str, distro: str) -> list[Any]:
    """The links of the scene's vehicles (`<ros2Link>`), each started in this process as `uwsimnet ros2-link`
    would run it, a client of the run's router; the caller closes them (`close_links`)."""
    from uwsimnet_gli.world import GliError  # noqa: PLC0415 - a --ros2 run with links only

    from ..bus.ros2_link import Ros2Link  # noqa: PLC0415

    links: list[Any] = []
    try:
        for v in scene.vehicles:
            spec = v.ros2_link
            if spec is None or spec.modem not in {d.dccomms_id for d in v.devices}:   # not run here (--channels)
                continue
            try:
                link = Ros2Link(connect, world, spec.modem, spec.topics, codec=codec(distro), domain=spec.domain,
                                namespace=spec.namespace, mtu=spec.mtu)
            except (GliError, UwsimnetError) as e:     # e.g. a type the distro's type store does not know
                raise UserError(f"{scene.source}:{spec.line}: ros2Link of {v.name}: {e}") from None
            links.append(link.__enter__())
            print(f"uwsimnet: ros2Link of {v.name}: {spec.modem} carries {', '.join(r.name for r in spec.topics)}"
                  f" of ROS domain {spec.domain}", flush=True)
    except BaseException:
        close_links(links)
        raise
    return links


def close_links(links: list[Any]) -> dict[str, dict]:
    """Close the links; their summaries by modem (for the run's summary)."""
    out = {}
    for link in links:
        out[link.modem_id] = link.summary()
        link.close()
    return out


def link_lines(summaries: dict[str, dict]) -> list[str]:
    """The run summary's lines for the links: one per topic that moved anything, one for problems."""
    lines = []
    for modem, s in summaries.items():
        for name, d in s["topics"].items():
            if not (d["offered"] or d["received"] or d["dropped"]):
                continue
            lat = (f", latency mean {d['latency_mean_s'] * 1e3:.1f} ms max {d['latency_max_s'] * 1e3:.1f} ms"
                   if d["received"] else "")
            drops = ", ".join(f"{n} {why}" for why, n in d["dropped"].items())
            lines.append(f"ros2 link {modem} {name}: offered {d['offered']}, sent {d['sent']} ({d['frames']} frames,"
                         f" {d['bytes']} B), received {d['received']}{lat}" + (f"; dropped {drops}" if drops else ""))
        if s["problems"]:
            lines.append(f"ros2 link {modem} problems: " + ", ".join(f"{n} {k}" for k, n in s["problems"].items()))
    return lines


def run_link(connect: list[str], world: str, spec: Any, *, distro: str, duration: float | None) -> dict:
    """`uwsimnet ros2-link`: join this robot's graph to the others through `spec.modem` until Ctrl-C or
    `duration` seconds; returns the link's summary (per-topic counters, latency, problems)."""
    import time  # noqa: PLC0415 - start-up time, as the module's other imports

    from ..bus.ros2_link import Ros2Link  # noqa: PLC0415

    try:
        from ..ros2.cdr import Codec  # noqa: PLC0415 - the extra uwsimnet-zenoh[ros2]
    except ImportError:
        raise UserError("ros2-link needs the extra: pip install 'uwsimnet-zenoh[ros2]'") from None
    from uwsimnet_gli.world import GliError  # noqa: PLC0415

    try:
        link = Ros2Link(connect, world, spec.modem, spec.topics, codec=Codec(distro), domain=spec.domain,
                        namespace=spec.namespace, mtu=spec.mtu)
    except GliError as e:
        raise UserError(f"ros2-link: {e}") from None
    with link:
        print(f"ros2-link: {spec.modem} carries {len(spec.topics)} topic(s) of ROS domain {spec.domain}; running",
              flush=True)
        end = None if duration is None else time.monotonic() + duration
        with contextlib.suppress(KeyboardInterrupt):
            while end is None or time.monotonic() < end:
                time.sleep(0.2)
        return link.summary()
