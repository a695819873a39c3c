"""Capture on a line: pure ALOHA to a sink under the binary collision rule and under SINR capture (#5).

The scenario of docs/acoustic.md ("Capture experiment"), the ns-3 UAN reference ALOHA of
../shared/notes/ns3-reference.md moved onto a line with real propagation loss:

* sink at x = 0; N sensors at x = 200, 400, ..., 200 N m (z = 0), stationary;
* ns-3-like PHY (UanPhyGen with one FSK mode): non-coherent BFSK, 1000 bit/s, carrier 22 kHz, 4 kHz band,
  source level 190 dB re 1 uPa @ 1 m; frames of 37 B payload + 3 B header = 40 B (0.32 s on air);
* channel: Thorp absorption, spreading k = 1.5 (ns-3 UanPropModelThorp), Wenz/Coates noise with ns-3
  UanNoiseModelDefault's defaults (shipping 0, wind 1 m/s), sound speed 1500 m/s (ns-3's);
  at 3.2 km the SNR is still ~60 dB, so noise never loses a frame: only interference does;
* MAC: none; no queue (a frame offered while its sensor transmits is dropped); sensors transmit only
  (they listen on another channel), so none defers to another; Poisson traffic, G frame-times in total.

Rules compared: ``binary`` (any overlap at the sink loses every frame involved), ``threshold`` (SINR mode,
a frame survives iff its minimum SINR >= 8 dB: ns-3 UanPhyPerGenDefault), ``per`` (SINR mode, PER from
the minimum SINR with the BFSK bit error rate) and ``first`` (``threshold`` with capture "first": the sink
locks onto the first frame whose SINR at arrival exceeds 10 dB, as ns-3 UanPhyGen does).  Under the
binary rule the throughput follows the finite-population ALOHA formula `experiments.aloha.theory` whatever
the geometry; `capture first` reproduces ns-3 UAN's throughput (bench/ns3_capture.py, docs/acoustic.md).
"""

from __future__ import annotations

from ..scene.model import (
    AcousticChannelSpec,
    AcousticDeviceSpec,
    Channel,
    Device,
    Flow,
    Scene,
    Simulation,
    Vehicle,
)
from ..trace.tracer import Callback
from . import aloha

SPACING_M = 200.0
BITRATE = 1000.0
PAYLOAD = 37
HEADER = 3
FRAME_TIME = (PAYLOAD + HEADER) * 8 / BITRATE          # 0.32 s
SOUND_SPEED = 1500.0
THRESHOLD_DB = 8.0                                      # ns-3 UanPhyPerGenDefault "Threshold"
ACQUIRE_DB = 10.0                                       # ns-3 UanPhyGen "RxThreshold"
RULES = ("binary", "threshold", "per", "first")

MODEM = AcousticDeviceSpec(carrier_khz=22.0, bandwidth_hz=4000.0, source_level_db=190.0,
                           modulation="bfsk_noncoherent")
"""The ns-3-like modem: UanPhyGen's FSK mode at 1000 bit/s, 22 kHz, 4 kHz band, TxPower 190 dB."""


def channel_spec(rule: str) -> AcousticChannelSpec:
    """The water of the experiment with the interference rule `rule` (one of RULES)."""
    if rule not in RULES:
        raise ValueError(f"unknown rule {rule!r}: one of {RULES}")
    return AcousticChannelSpec(spreading_k=1.5, absorption="thorp", shipping=0.0, wind_mps=1.0,
                               sound_speed_mps=SOUND_SPEED, bandwidth_hz=4000.0,
                               interference="binary" if rule == "binary" else "sinr",
                               sinr_threshold_db=THRESHOLD_DB if rule in ("threshold", "first") else None,
                               capture="first" if rule == "first" else "any", acquire_threshold_db=ACQUIRE_DB)


def scene(n: int, load: float, duration: float, rule: str = "sinr", seed: int = 1,
          spacing: float = SPACING_M) -> Scene:
    """N sensors on a line at `spacing` m, the sink at the origin; offered load G = `load` frame-times."""
    rule = "per" if rule == "sinr" else rule
    sink = Device(dccomms_id="sink", address=0, tx_channel=0, rx_channel=0, bitrate=BITRATE,
                  header_bytes=HEADER, tx_fifo_bytes=0, acoustic=MODEM)
    vehicles = [Vehicle(name="sink", position=(0.0, 0.0, 0.0), devices=(sink,))]
    flows = []
    interval = n * FRAME_TIME / load
    for i in range(n):
        dev = Device(dccomms_id=f"s{i}", address=i + 1 + (i >= 254), tx_channel=0, rx_channel=1,
                     bitrate=BITRATE, header_bytes=HEADER, tx_fifo_bytes=0, acoustic=MODEM)
        vehicles.append(Vehicle(name=f"sensor{i}", position=((i + 1) * spacing, 0.0, 0.0), devices=(dev,)))
        flows.append(Flow(name=f"s{i}", src=f"s{i}", dst=0, size=PAYLOAD, interval=interval, arrival="poisson"))
    spec = channel_spec(rule)
    quiet = AcousticChannelSpec(sound_speed_mps=SOUND_SPEED)       # the sensors' (unused) receive channel
    return Scene(name=f"capture-{rule}-{n}", simulation=Simulation(duration=duration, seed=seed),
                 channels=(Channel(id=0, acoustic=spec), Channel(id=1, acoustic=quiet)),
                 vehicles=tuple(vehicles), flows=tuple(flows))


def theory_binary(n: int, load: float) -> float:
    """Throughput under the binary rule: the finite-population pure-ALOHA formula (no capture)."""
    return aloha.theory(n, load)


def measured_throughput(received: int, duration: float) -> float:
    """Normalised throughput S: frames received at the sink per frame-time."""
    return received * FRAME_TIME / duration


def run(n: int, load: float, duration: float, rule: str, seed: int = 1) -> dict:
    """One simulation: throughput S, captures, and per sensor (nearest first) frames sent and received."""
    from ..engine.network import Network

    net = Network(scene(n, load, duration, rule, seed))
    got = [0] * (n + 2)

    def count(_t, ev, _ch, dev, frame, *_rest) -> None:
        if ev == "rx" and dev == "sink" and frame.kind == "data":
            got[frame.src] += 1

    net.tracer.listen(Callback(count))
    net.run()
    sensors = [net.modems[f"s{i}"] for i in range(n)]
    return {"n": n, "load": load, "rule": rule, "duration": duration, "seed": seed,
            "S": measured_throughput(net.tracer.count("rx"), duration), "captures": net.channels[0].captures,
            "sent": [m.counters["tx"] for m in sensors], "received": [got[m.address] for m in sensors]}
