"""Throughput of the ALOHA family and S-FAMA against theory and expected behaviour (docs/mac.md).

Counts of successful frames are treated as Poisson: the tolerance is 4 standard deviations of the
expected count, sqrt(K) (measured over 20 seeds the spread of (K - K_theory)/sqrt(K_theory) is 0.8-0.9,
so sqrt(K) is slightly conservative).
"""

from __future__ import annotations

import math

import pytest

from uwsimnet_zenoh.engine.network import Network
from uwsimnet_zenoh.experiments import aloha
from uwsimnet_zenoh.scene.model import Channel, Device, Flow, MacSpec, Scene, Simulation, Vehicle

T = aloha.FRAME_TIME          # 40 B at 1000 bps = 0.32 s


def sensors_scene(n: int, load: float, duration: float, radius: float, mac: str = "none",
                  params: dict[str, str] | None = None, *, shared: bool = True, fifo: int = 0,
                  seed: int = 1) -> Scene:
    """A sink at the origin, n sensors on a circle, Poisson traffic of `load` frame-times in total.

    shared=True: the sensors listen on the channel they send on (half duplex: they hear each other,
    so carrier sense can work); False: they only transmit (the textbook ALOHA model)."""
    spec = MacSpec(name=mac, params=params or {})
    sink = Device(dccomms_id="sink", address=0, tx_channel=0, rx_channel=0, bitrate=aloha.BITRATE,
                  header_bytes=aloha.HEADER, tx_fifo_bytes=fifo, mac=spec)
    vehicles = [Vehicle(name="sink", position=(0.0, 0.0, 0.0), devices=(sink,))]
    flows = []
    for i in range(n):
        a = 2 * math.pi * i / n
        dev = Device(dccomms_id=f"s{i}", address=i + 1, tx_channel=0, rx_channel=0 if shared else 1,
                     bitrate=aloha.BITRATE, header_bytes=aloha.HEADER, tx_fifo_bytes=fifo, mac=spec)
        vehicles.append(Vehicle(name=f"v{i}", position=(radius * math.cos(a), radius * math.sin(a), 0.0),
                                devices=(dev,)))
        flows.append(Flow(name=f"s{i}", src=f"s{i}", dst=0, size=aloha.PAYLOAD, interval=n * T / load,
                          arrival="poisson"))
    return Scene(name="sensors", simulation=Simulation(duration=duration, seed=seed),
                 channels=(Channel(id=0, prop_s_per_m=1 / 1500), Channel(id=1, prop_s_per_m=1 / 1500)),
                 vehicles=tuple(vehicles), flows=tuple(flows))


class Outcome:
    def __init__(self, sc: Scene) -> None:
        self.net = Network(sc)
        self.records: list[dict] = []
        self.net.tracer.add(self.records.append)
        self.net.run()
        d = sc.simulation.duration
        data = [r for r in self.records if r["kind"] == "data"]
        self.received = sum(1 for r in data if r["ev"] == "rx" and r["dev"] == "sink")
        self.sent = sum(1 for r in data if r["ev"] == "tx")
        self.collisions = sum(1 for r in data if r["ev"] == "drop" and r["reason"] in ("col", "mult"))
        self.S = self.received * T / d           # frames per frame-time


def within(k: int, expected: float, sigmas: float = 4.0) -> bool:
    return abs(k - expected) <= sigmas * math.sqrt(max(expected, 1.0))


# -- pure ALOHA -----------------------------------------------------------------------------------
def test_theory_formula_limits():
    assert aloha.theory(1000, 0.5) == pytest.approx(0.5 * math.exp(-1.0), rel=2e-3)
    assert aloha.theory(1, 1.0) == pytest.approx(0.5)            # alone: busy half the time


@pytest.mark.parametrize("load", [0.1, 0.25, 0.5, 1.0, 2.0])
def test_pure_aloha_matches_the_finite_population_formula(load):
    """No MAC, sensors that only transmit, no queue: S = N g/(1+g) [e^-g/(1+g)]^(N-1), g = G/N."""
    n, duration = 16, 3000.0
    out = Outcome(aloha.scene(n, load, duration, seed=7))
    out.received = out.net.modems["sink"].counters["rx"]
    expected = aloha.theory(n, load) * duration / T
    assert within(out.received, expected), (load, out.received, expected)


def test_aloha_mac_without_carrier_sense_or_ack_is_pure_aloha():
    """`aloha` with carrierSense=0 and ack=0, sensors on the shared channel: the same formula."""
    n, load, duration = 16, 0.5, 3000.0
    out = Outcome(sensors_scene(n, load, duration, 500.0, "aloha", {"carrierSense": "0", "ack": "0"}, seed=3))
    assert out.sent > 0.9 * load * duration / T * math.exp(-load / n)   # only busy-sensor drops
    assert within(out.received, aloha.theory(n, load) * duration / T)


# -- slotted ALOHA --------------------------------------------------------------------------------
def slotted_theory(n: int, rate: float, slot: float) -> float:
    """Successes per slot with the no-queue rule: a sensor sends in a slot the first frame that arrived
    in its collection window, which is the whole previous slot if it was silent in it, and only the
    part after its own frame (slot - T) if it was sending.  Stationary sending probability pi of that
    two-state chain, then S = N pi (1 - pi)^(N-1)."""
    p_idle = 1 - math.exp(-rate * slot)
    p_busy = 1 - math.exp(-rate * (slot - T))
    pi = p_idle / (1 - p_busy + p_idle)
    return n * pi * (1 - pi) ** (n - 1)


@pytest.mark.parametrize("load", [0.25, 0.5, 1.0, 2.0])
def test_slotted_aloha_matches_theory(load):
    n, duration, slot = 16, 3000.0, 0.4
    params = {"slotTime": str(slot), "ack": "0"}
    out = Outcome(sensors_scene(n, load, duration, 500.0, "slotted-aloha", params, seed=5))
    rate = load / (n * T)                      # frames/s per sensor
    expected = slotted_theory(n, rate, slot) * duration / slot
    assert within(out.received, expected), (load, out.received, expected)


def test_slotted_aloha_doubles_the_peak_of_pure_aloha():
    """At their best loads: pure ALOHA about 1/(2e) per frame time, slotted ALOHA about 1/e per slot.
    (The slot is 10 ms longer than the frame: with no guard at all, frames of consecutive slots touch
    at the sink and rounding in the sensor positions makes some of them overlap by 1e-13 s.)"""
    n, duration, slot = 16, 3000.0, T + 0.01
    pure = Outcome(aloha.scene(n, 0.5, duration, seed=2))
    pure_s = pure.net.modems["sink"].counters["rx"] * T / duration
    load = T / slot                            # one frame per slot on average
    slotted = Outcome(sensors_scene(n, load, duration, 500.0, "slotted-aloha", {"slotTime": str(slot), "ack": "0"},
                                    shared=False, seed=2))
    per_slot = slotted.received * slot / duration
    assert within(slotted.received, slotted_theory(n, load / (n * T), slot) * duration / slot)
    assert per_slot == pytest.approx(1 / math.e, abs=0.03)
    assert pure_s == pytest.approx(1 / (2 * math.e), abs=0.02)
    assert 1.7 * pure_s < slotted.S


# -- carrier sense ----------------------------------------------------------------------------------
@pytest.mark.parametrize("load", [0.5, 1.0])
def test_carrier_sense_helps_only_when_propagation_is_short(load):
    """Ten sensors on a circle around the sink, no ACK (to isolate the carrier sense).  Radius 15 m:
    sensors hear each other within 20 ms, a = 0.06 of the 0.32 s frame, and sensing avoids most
    collisions.  Radius 500 m: up to 0.67 s, a = 2: what a sensor hears is stale, sensing no longer helps."""
    n, duration = 10, 1500.0
    plain = Outcome(sensors_scene(n, load, duration, 15.0, "aloha", {"carrierSense": "0", "ack": "0"}))
    near = Outcome(sensors_scene(n, load, duration, 15.0, "aloha", {"ack": "0", "maxDistance": "30"}))
    far = Outcome(sensors_scene(n, load, duration, 500.0, "aloha", {"ack": "0", "maxDistance": "1000"}))
    sigma = math.sqrt(plain.received) * T / duration
    assert pytest.approx(aloha.theory(n, load), abs=4 * sigma) == plain.S
    assert near.S > plain.S + 0.15                       # far beyond the noise (sigma ~ 0.006)
    assert near.collisions < 0.25 * plain.collisions
    assert plain.S + 4 * sigma > far.S                   # no gain any more


# -- S-FAMA -----------------------------------------------------------------------------------------
def test_sfama_keeps_data_frames_collision_free_and_saturates_below_its_slot_bound():
    """Long delay (radius 500 m, maxDistance 1000 m): slot = 5 ms + 56 ms (7-byte CTS) + 667 ms = 0.728 s;
    a 40-byte frame needs D = 2 data slots, so an exchange (RTS, CTS, DATA, ACK) takes >= 5 slots and
    S <= T / (5 slot) = 0.088.  Light load gets through entirely; heavy load saturates below the bound;
    no data frame ever collides, whereas CS-ALOHA loses most of its data frames at the same load."""
    n, r = 10, 500.0
    params = {"maxDistance": "1000"}
    slot = 0.005 + 7 * 8 / aloha.BITRATE + 1000 / 1500
    bound = T / (5 * slot)
    light = Outcome(sensors_scene(n, 0.02, 3000.0, r, "sfama", params, fifo=100_000))
    assert light.collisions == 0
    assert within(light.received, sum(f.sent for f in light.net.flows) - 1)
    heavy = Outcome(sensors_scene(n, 0.5, 1500.0, r, "sfama", params, fifo=100_000))
    assert heavy.collisions == 0 and heavy.sent > 150
    assert 0.3 * bound < heavy.S < bound
    aloha_heavy = Outcome(sensors_scene(n, 0.5, 1500.0, r, "aloha", params, fifo=100_000))
    assert aloha_heavy.collisions > 0.5 * aloha_heavy.sent


def test_sfama_against_cs_aloha_at_short_delay():
    """Short delay (radius 15 m): CS-ALOHA carries more (it needs no handshake), S-FAMA still has no
    data collision; both deliver a light load entirely."""
    n, r, duration = 10, 15.0, 1000.0
    params = {"maxDistance": "30"}
    sf = Outcome(sensors_scene(n, 1.0, duration, r, "sfama", params, fifo=100_000))
    cs = Outcome(sensors_scene(n, 1.0, duration, r, "aloha", params, fifo=100_000))
    assert sf.collisions == 0 and cs.collisions > 100
    assert cs.S > sf.S > 0.2
    light = Outcome(sensors_scene(n, 0.1, duration, r, "sfama", params, fifo=100_000))
    assert light.received >= sum(f.sent for f in light.net.flows) - 2
