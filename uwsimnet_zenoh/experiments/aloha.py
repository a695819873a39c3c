"""The reference pure-ALOHA scenario shared with ns-3 UAN (../shared/notes/ns3-reference.md).

A sink at the origin, N sensors on a 500 m circle, 1000 bps, 40-byte frames (37 B payload + 3 B header,
0.32 s on air), Poisson traffic of G frame-times in total, no MAC, no queue (a frame offered while its
sensor transmits is dropped).  Sensors only transmit (they listen on another channel), as in the
textbook model, so none defers to another.  Theory for that drop rule, with g = G/N:
    S = N·g/(1+g) · [exp(-g)/(1+g)]^(N-1)   ->  G·exp(-2G) for large N.
"""

from __future__ import annotations

import math

from ..scene.model import Channel, Device, Flow, Scene, Simulation, Vehicle

BITRATE = 1000.0
PAYLOAD = 37
HEADER = 3
FRAME_TIME = (PAYLOAD + HEADER) * 8 / BITRATE
RADIUS = 500.0


def theory(n: int, load: float) -> float:
    """Normalised throughput S (frames per frame-time) for N sensors and offered load G."""
    g = load / n
    return n * g / (1 + g) * (math.exp(-g) / (1 + g)) ** (n - 1)


def scene(n: int, load: float, duration: float, seed: int = 1) -> Scene:
    sink = Device(dccomms_id="sink", address=0, tx_channel=0, rx_channel=0, bitrate=BITRATE,
                  header_bytes=HEADER, tx_fifo_bytes=0)
    vehicles = [Vehicle(name="sink", position=(0.0, 0.0, 0.0), devices=(sink,))]
    flows = []
    interval = n * FRAME_TIME / load
    for i in range(n):
        a = 2 * math.pi * i / n
        dev = Device(dccomms_id=f"s{i}", address=i + 1 + (i >= 254), tx_channel=0, rx_channel=1, bitrate=BITRATE,
                     header_bytes=HEADER, tx_fifo_bytes=0)
        vehicles.append(Vehicle(name=f"sensor{i}", position=(RADIUS * math.cos(a), RADIUS * math.sin(a), 0.0),
                                devices=(dev,)))
        flows.append(Flow(name=f"s{i}", src=f"s{i}", dst=0, size=PAYLOAD, interval=interval,
                          arrival="poisson"))
    return Scene(name=f"aloha-{n}", simulation=Simulation(duration=duration, seed=seed),
                 channels=(Channel(id=0, prop_s_per_m=1 / 1500), Channel(id=1, prop_s_per_m=1 / 1500)),
                 vehicles=tuple(vehicles), flows=tuple(flows))


def measured_throughput(received: int, duration: float) -> float:
    return received * FRAME_TIME / duration
