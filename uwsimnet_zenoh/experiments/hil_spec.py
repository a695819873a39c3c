"""The HIL formation experiment's specification, shared by its virtual-time model (hil_formation.py) and
its real-time processes (hil_apps.py, hil_realtime.py): the vehicles, the formation, the periods, the
waypoints, the scenes (`scene_xml`) and Fig. 9's error definition."""

from __future__ import annotations

import math
from pathlib import Path

SCENES = Path(__file__).resolve().parents[2] / "scenes" / "paper"
PROTOCOLS = {"aloha": "CS-ALOHA", "sfama": "S-FAMA"}
TRAFFIC = {                 # --traffic: what the modems carry
    "paper": "the formation control frames plus the Sec. 3.2 image flows (the paper: 'the same as Section 3.2')",
    "control": "the formation control frames only (waypoints, leader positions, telemetry)",
}
DEFAULT_TRAFFIC = "paper"
IMAGE_SIZE = 400            # bytes: the explorers' image frames of Sec. 3.2
IMAGE_BYTES_PER_S = {"aloha": 30.0, "sfama": 27.5}   # Table 1, E0-E3: the rate the paper gives per MAC
BITRATE = 6900.0            # bit/s: EvoLogics S2CR 7/17 (phy/acoustic.py PRESETS["evologics-s2cr-7-17"])
INTRINSIC_MS = 50           # ms: modem latency (assumption)
SIDE = 1.5                  # m: the formation square
DEPTH = -5.0
DURATION = 240.0
MAX_SPEED = 0.3             # m/s (BlueROV, cautious)
MAX_ACCEL = 0.1             # m/s^2
TICK = 0.1                  # s: kinematics and pose updates
LEADER_PERIOD = 2.0         # s: the leader broadcasts its position
TELEMETRY_PERIOD = 5.0      # s: followers report to the operator
OPERATOR_PERIOD = 4.0       # s: the operator repeats the current waypoint
PAYLOAD = 24                # bytes of every application frame
VEHICLES = {                # name: (address, formation offset from the leader)
    "leader": (1, (0.0, 0.0, 0.0)),
    "follower1": (2, (-SIDE, 0.0, 0.0)),
    "follower2": (3, (0.0, -SIDE, 0.0)),
    "follower3": (4, (-SIDE, -SIDE, 0.0)),
}
OPERATOR = ("operator", 5, (-10.0, -10.0, 0.0))
WAYPOINTS = [(0, (0.0, 0.0)), (20, (6.0, 0.0)), (80, (6.0, 6.0)), (140, (0.0, 6.0)), (200, (0.0, 0.0))]
"""(time s, (x, y)) at which the operator switches to that leader waypoint (depth DEPTH)."""
Vec = tuple[float, float, float]


def image_interval(mac: str) -> float:
    """Seconds between one vehicle's image frames: IMAGE_SIZE bytes at Table 1's rate for `mac`."""
    return IMAGE_SIZE / IMAGE_BYTES_PER_S[mac]


def world_name(mac: str, traffic: str = DEFAULT_TRAFFIC) -> str:
    """The world (and scene file stem): the control-only scenes keep their first names, hil-formation-<mac>."""
    return f"hil-formation-{mac}" + ("" if traffic == "control" else f"-{traffic}")


def scene_path(mac: str, traffic: str = DEFAULT_TRAFFIC) -> Path:
    return SCENES / f"{world_name(mac, traffic)}.xml"


def _image_flows(mac: str) -> str:
    """The Sec. 3.2 image flows: each BlueROV (an explorer there) sends IMAGE_SIZE-byte frames to the
    operator (the buoy there) at Table 1's rate for `mac`, periodic from t = 0 like the TWINBOT scenes."""
    out = []
    for name in VEHICLES:
        out.append(f"""  <flow>
    <name>image-{name}</name>
    <src>{name}-modem</src>
    <dst>{OPERATOR[1]}</dst>
    <size>{IMAGE_SIZE}</size>
    <interval>{image_interval(mac):.6g}</interval>   <!-- {IMAGE_BYTES_PER_S[mac]:g} B/s, Table 1 -->
    <start>0</start>
  </flow>""")
    return "\n".join(out) + "\n"


def scene_xml(mac: str, traffic: str = DEFAULT_TRAFFIC) -> str:
    if traffic not in TRAFFIC:
        raise ValueError(f"traffic: one of {', '.join(TRAFFIC)}, got {traffic!r}")

    def device(name: str, addr: int) -> str:
        return f"""
    <CustomCommsDevice>
      <dccommsId>{name}-modem</dccommsId>
      <mac>{addr}</mac>
      <txChannelId>0</txChannelId>
      <rxChannelId>0</rxChannelId>
      <bitrate>{BITRATE:g}</bitrate>
      <txFifoSize>2000</txFifoSize>
      <intrinsicDelay>{INTRINSIC_MS}</intrinsicDelay>
      <maxDistance>50</maxDistance>
      <rateErrorModel><errorUnit>bit</errorUnit><errorRateExpr>0</errorRateExpr></rateErrorModel>
      <macProtocol><name>{mac}</name></macProtocol>
    </CustomCommsDevice>"""

    vehicles = []
    for name, (addr, off) in VEHICLES.items():
        vehicles.append(f"""  <vehicle>
    <name>{name}</name>
    <position>{off[0]:g} {off[1]:g} {DEPTH:g}</position>
    <poseSource>zenoh</poseSource>{device(name, addr)}
  </vehicle>""")
    name, addr, p = OPERATOR
    vehicles.append(f"""  <vehicle>
    <name>{name}</name>
    <position>{p[0]:g} {p[1]:g} {p[2]:g}</position>{device(name, addr)}
  </vehicle>""")
    body = "\n".join(vehicles)
    flows = _image_flows(mac) if traffic == "paper" else ""
    what = ("\n  Traffic: the control frames of hil_apps.py plus the Sec. 3.2 image flows"
            f" ({IMAGE_SIZE} B to the operator at {IMAGE_BYTES_PER_S[mac]:g} B/s per vehicle, Table 1)."
            if traffic == "paper" else "")
    return f"""<?xml version="1.0"?>
<!--
  UWSim-NET paper, HIL experiment (Fig. 9): four BlueROVs in a {SIDE:g} m square formation, an operator at the
  surface sending waypoints to the leader, followers keeping formation from the leader's broadcast
  positions.  MAC: {PROTOCOLS[mac]}.  Generated by uwsimnet_zenoh/experiments/hil_spec.py (scene_xml).
  Modems: EvoLogics S2CR 7/17 bit rate ({BITRATE:g} bit/s), {INTRINSIC_MS} ms latency, no propagation loss.{what}
  The BlueROVs have poseSource zenoh: in a realtime run `uwsimnet vehicles` (or the real leader) publishes
  their poses; `uwsimnet experiment hil-formation` runs it (and its virtual-time model).
-->
<UWSimScene>
  <simulation>
    <duration>{DURATION:g}</duration>
    <seed>1</seed>
    <world>{world_name(mac, traffic)}</world>
  </simulation>
  <CustomCommsChannel>
    <id>0</id>
    <propTimeIncPerMeter>0.6667</propTimeIncPerMeter>
    <minPropTime>0</minPropTime>
  </CustomCommsChannel>
{body}
{flows}</UWSimScene>
"""


def write_scenes() -> list[Path]:
    out = []
    for traffic in TRAFFIC:
        for mac in PROTOCOLS:
            p = scene_path(mac, traffic)
            p.write_text(scene_xml(mac, traffic))
            out.append(p)
    return out


def waypoint_at(t: float) -> tuple[float, float, float]:
    """The operator's current waypoint for the leader at simulation time `t`."""
    cur = WAYPOINTS[0][1]
    for t0, wp in WAYPOINTS:
        if t >= t0:
            cur = wp
    return (cur[0], cur[1], DEPTH)


def formation_errors(t: float, poses: dict[str, Vec]) -> dict[str, float]:
    """Fig. 9's waypoint distance error of each vehicle whose pose is known: the leader's distance to the
    commanded waypoint; a follower's distance to where it should be given the leader's *actual*
    position (the leader's position plus its formation offset), as the paper defines it."""
    out = {}
    lp = poses.get("leader")
    if lp is not None:
        out["leader"] = math.dist(lp, waypoint_at(t))
    for n, (_, off) in VEHICLES.items():
        p = poses.get(n)
        if n != "leader" and p is not None and lp is not None:
            out[n] = math.dist(p, (lp[0] + off[0], lp[1] + off[1], lp[2] + off[2]))
    return out


if __name__ == "__main__":
    import sys

    if "--write-scenes" in sys.argv:
        for p in write_scenes():
            print(p)
