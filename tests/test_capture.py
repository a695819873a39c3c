"""SINR interference (capture) on an acoustic channel: phy.interference and the channel's SINR mode (#5).

The PHY is the capture experiment's (uwsimnet_zenoh.experiments.capture): non-coherent BFSK, 1000 bit/s,
22 kHz, 4 kHz band, SL 190 dB, Thorp, k = 1.5, sound speed 1500 m/s; 40-byte frames (0.32 s on air).
Sensors transmit on channel 0 and listen on channel 1, the sink listens on channel 0.
"""

from __future__ import annotations

import math

import pytest
from conftest import Recorded

from uwsimnet_zenoh.engine.build import build_error_model
from uwsimnet_zenoh.engine.network import Network
from uwsimnet_zenoh.experiments import capture as C
from uwsimnet_zenoh.phy.acoustic import thorp_db_per_km
from uwsimnet_zenoh.phy.interference import classify, max_interference, min_sinr_db
from uwsimnet_zenoh.scene.model import (
    AcousticChannelSpec,
    AcousticDeviceSpec,
    Channel,
    Device,
    Scene,
    Simulation,
    Vehicle,
)

T = C.FRAME_TIME
c = C.SOUND_SPEED


def line(senders: dict[str, float], rule: str = "per", threshold: float | None = None,
         modem: dict | None = None, sink_tx: bool = False) -> Recorded:
    """A sink at x = 0 and transmit-only senders at the given x (m); `rule`: binary | per | threshold."""
    spec = C.channel_spec(rule)
    if threshold is not None:
        spec = spec.model_copy(update={"sinr_threshold_db": threshold})
    acoustic = C.MODEM.model_copy(update=modem or {})
    sink = Device(dccomms_id="sink", address=0, tx_channel=0, rx_channel=0, bitrate=C.BITRATE,
                  header_bytes=C.HEADER, acoustic=C.MODEM)
    vehicles = [Vehicle(name="sink", position=(0.0, 0.0, 0.0), devices=(sink,))]
    for i, (name, x) in enumerate(senders.items()):
        dev = Device(dccomms_id=name, address=i + 1, tx_channel=0, rx_channel=0 if sink_tx else 1,
                     bitrate=C.BITRATE, header_bytes=C.HEADER, acoustic=acoustic)
        vehicles.append(Vehicle(name=f"v-{name}", position=(x, 0.0, 0.0), devices=(dev,)))
    sc = Scene(name="capture-test", simulation=Simulation(duration=30.0, seed=7),
               channels=(Channel(id=0, acoustic=spec), Channel(id=1, acoustic=AcousticChannelSpec())),
               vehicles=tuple(vehicles))
    return Recorded(sc)


def send(rec: Recorded, t: float, dev: str, dst: int = 0) -> None:
    rec.net.sched.at(t, lambda: rec.net.modems[dev].send(dst, C.PAYLOAD))


def outcome(rec: Recorded, src: str) -> str:
    addr = rec.net.modems[src].address
    got = [r for r in rec.records if r["ev"] in ("rx", "drop") and r["src"] == addr and r["dev"] == "sink"]
    assert len(got) == 1, got
    return "rx" if got[0]["ev"] == "rx" else got[0]["reason"]


def near_far(rule: str = "per", threshold: float | None = None) -> Recorded:
    """near at 200 m and far at 1000 m, timed so that their frames overlap at the sink by 0.2 s."""
    rec = line({"near": 200.0, "far": 1000.0}, rule, threshold)
    send(rec, 1.0, "near")                                  # at the sink [1.1333, 1.4533)
    send(rec, 1.0 + 200 / c - 1000 / c + 0.12, "far")       # at the sink [1.2533, 1.5733)
    return rec.run()


# The numbers: RL = 190 - 15 log10(d) - d/1000 alpha(22 kHz); noise far below (SNR > 60 dB at 1 km).
ALPHA = float(thorp_db_per_km(22.0))                        # 4.89 dB/km
SIR_NEAR = 15 * math.log10(1000 / 200) + 0.8 * ALPHA        # 10.49 + 3.91 = 14.40 dB


def test_the_worked_numbers() -> None:
    assert abs(ALPHA - 4.89) < 0.01
    assert abs(SIR_NEAR - 14.40) < 0.01
    near = build_error_model(Device(dccomms_id="n", address=1, tx_channel=0, rx_channel=0, bitrate=1000,
                                    acoustic=C.MODEM), Channel(id=0, acoustic=C.channel_spec("per")))
    snr_1km = 10 * math.log10(float(near.received_power(1000.0)) / near.noise_power)
    assert snr_1km > 60
    sinr = min_sinr_db(float(near.received_power(200.0)), near.noise_power,
                       [(0.0, 1.0, float(near.received_power(1000.0)))], 0.0)
    assert sinr == pytest.approx(SIR_NEAR, abs=0.01)        # interference-limited: SINR = SIR
    # PER from SINR: Eb/N0 = SINR + 10 log10(4000/1000); non-coherent BFSK Pb = exp(-Eb/2N0)/2; 320 bits
    ebn0 = 10 ** ((SIR_NEAR + 10 * math.log10(4)) / 10)
    assert float(near.per_from_sinr(SIR_NEAR, 40)) == pytest.approx(1 - (1 - 0.5 * math.exp(-ebn0 / 2)) ** 320)
    assert float(near.per_from_sinr(SIR_NEAR, 40)) < 1e-20            # the near frame survives
    assert float(near.per_from_sinr(-SIR_NEAR, 40)) == pytest.approx(1.0)  # the far one cannot


@pytest.mark.parametrize("rule", ["per", "threshold"])
def test_near_sender_wins_a_collision(rule: str) -> None:
    rec = near_far(rule)
    assert outcome(rec, "near") == "rx"
    assert outcome(rec, "far") == "col"
    assert rec.net.channels[0].captures == 1


def test_threshold_decides_at_the_worked_sinr() -> None:
    assert outcome(near_far("threshold", SIR_NEAR - 0.05), "near") == "rx"
    assert outcome(near_far("threshold", SIR_NEAR + 0.05), "near") == "col"


def test_binary_rule_loses_both() -> None:
    rec = near_far("binary")
    assert not rec.net.channels[0].sinr
    assert (outcome(rec, "near"), outcome(rec, "far")) == ("col", "col")


def test_binary_rule_is_the_default_of_an_acoustic_channel() -> None:
    spec = AcousticChannelSpec()
    assert spec.interference == "binary" and spec.sinr_threshold_db is None
    net = Network(Scene(channels=(Channel(id=0, acoustic=spec),)))
    assert net.channels[0].sinr is False


@pytest.mark.parametrize("rule", ["per", "threshold"])
def test_equal_powers_lose_both(rule: str) -> None:
    rec = line({"east": 500.0, "west": -500.0}, rule)
    send(rec, 1.0, "east")
    send(rec, 1.1, "west")
    rec.run()
    assert (outcome(rec, "east"), outcome(rec, "west")) == ("col", "col")
    assert rec.net.channels[0].captures == 0


def test_no_overlap_no_interference() -> None:
    rec = line({"near": 200.0, "far": 1000.0}, "per")
    send(rec, 1.0, "near")
    send(rec, 1.0 + 200 / c - 1000 / c + T + 0.001, "far")  # arrives 1 ms after near's last bit
    rec.run()
    assert (outcome(rec, "near"), outcome(rec, "far")) == ("rx", "rx")
    assert rec.net.channels[0].captures == 0


def test_own_transmission_on_a_half_duplex_modem_still_loses_the_frame() -> None:
    rec = line({"near": 200.0}, "per", sink_tx=True)
    send(rec, 1.0, "near")                                  # at the sink [1.1333, 1.4533)
    rec.net.sched.at(1.1, lambda: rec.net.modems["sink"].send(1, 5))   # the sink sends [1.1, 1.164)
    rec.run()
    assert outcome(rec, "near") == "col"


def test_a_lossy_frame_that_overlapped_is_mult_and_alone_is_prop() -> None:
    # the far sender's noise-limited BER is fixed at 0.5 (legacy bitErrorRate): PER(SNR) = 1
    rec = line({"near": 200.0, "far": 1000.0}, "per", modem={"bit_error_rate": 0.5})
    send(rec, 1.0, "near")
    send(rec, 1.0 + 200 / c - 1000 / c + 0.12, "far")
    send(rec, 10.0, "far")
    rec.run()
    drops = [r["reason"] for r in rec.ev("drop", dev="sink")]
    assert sorted(drops) == ["mult", "mult", "prop"]       # near (fixed BER too) and far overlap; then far alone


def test_minimum_sinr_uses_the_worst_instant_not_the_sum() -> None:
    # two interferers of power 1 that do not overlap each other: the worst instant sees 1, not 2
    assert max_interference([(0.0, 1.0, 1.0), (1.0, 2.0, 1.0)], 0.0) == 1.0
    assert max_interference([(0.0, 1.5, 1.0), (1.0, 2.0, 1.0)], 0.0) == 2.0
    # an interferer that started before the reception counts from its start a
    assert max_interference([(-1.0, 0.5, 3.0), (0.4, 1.0, 1.0)], 0.0) == 4.0
    assert min_sinr_db(100.0, 1.0, [(-1.0, 0.5, 3.0), (0.4, 1.0, 1.0)], 0.0) == pytest.approx(10 * math.log10(20))
    assert min_sinr_db(100.0, 1.0, [], 0.0) == pytest.approx(20.0)


def test_three_frames_in_the_air() -> None:
    # near (200 m) overlaps mid (600 m) and far (1000 m), which do not overlap each other: near's minimum
    # SINR is against mid alone (15 log 3 + 0.4 alpha = 9.1 dB) -> survives an 8 dB threshold
    rec = line({"near": 200.0, "mid": 600.0, "far": 1000.0}, "threshold")
    send(rec, 1.0, "near")                                  # [1.1333, 1.4533)
    send(rec, 1.1333 - 600 / c - 0.05, "mid")               # [1.0833, 1.4033)
    send(rec, 1.4033 - 1000 / c + 0.001, "far")             # [1.4043, 1.7243)
    rec.run()
    assert outcome(rec, "near") == "rx"
    assert outcome(rec, "mid") == "col" and outcome(rec, "far") == "col"


@pytest.mark.parametrize(("u", "overlap", "expected"), [
    (0.05, False, "prop"), (0.05, True, "mult"), (0.2, True, "col"), (0.5, True, "col"), (0.7, True, None),
    (0.7, False, None)])
def test_classification_with_one_draw(u: float, overlap: bool, expected: str | None) -> None:
    # PER(SNR) = 0.1, PER(SINR) = 0.6: u < 0.1 noise, 0.1 <= u < 0.6 interference, else received
    assert classify(u, 0.1, 0.6 if overlap else 0.1, overlap) == expected


def test_capture_statistics_match_the_draw() -> None:
    # a frame whose PER(SINR) is strictly between 0 and 1 (600 m against 1000 m: SIR = 15 log(5/3) +
    # 0.4 alpha = 5.28 dB, Eb/N0 = 11.3 dB, PER 0.17): over many trials the received fraction is
    # 1 - PER(SINR) (one draw per frame and receiver)
    spec = C.channel_spec("per")
    dev = Device(dccomms_id="n", address=1, tx_channel=0, rx_channel=0, bitrate=1000, acoustic=C.MODEM)
    link = build_error_model(dev, Channel(id=0, acoustic=spec))
    s, i = float(link.received_power(600.0)), float(link.received_power(1000.0))
    per = float(link.per_from_sinr(10 * math.log10(s / (link.noise_power + i)), 40))
    assert 0.05 < per < 0.95
    rec = line({"near": 600.0, "far": 1000.0}, "per")
    n = 400
    for k in range(n):
        t = 1.0 + k * 1.0
        send(rec, t, "near")
        send(rec, t + 600 / c - 1000 / c + 0.05, "far")
    rec.run(n + 5.0)
    got = sum(1 for r in rec.ev("rx", dev="sink") if r["src"] == 1)
    assert got / n == pytest.approx(1 - per, abs=4 * math.sqrt(per * (1 - per) / n))


def test_a_custom_device_cannot_transmit_on_a_sinr_channel() -> None:
    sc = Scene(channels=(Channel(id=0, acoustic=C.channel_spec("per")),),
               vehicles=(Vehicle(name="v", devices=(Device(dccomms_id="d", address=1, tx_channel=0,
                                                            rx_channel=0),)),))
    with pytest.raises(ValueError, match="SINR"):
        Network(sc)


def test_capture_line_gains_over_binary() -> None:
    # the experiment at G = 1, short: SINR capture beats the binary rule, which matches ALOHA theory
    s = {}
    for rule in C.RULES:
        net = Network(C.scene(8, 1.0, 600.0, rule))
        net.run()
        s[rule] = C.measured_throughput(net.tracer.count("rx"), 600.0)
    assert s["binary"] == pytest.approx(C.theory_binary(8, 1.0), abs=0.03)
    assert s["threshold"] > 1.5 * s["binary"] and s["per"] > 1.5 * s["binary"]


def test_device_power_model_fields() -> None:
    link = build_error_model(Device(dccomms_id="n", address=1, tx_channel=0, rx_channel=0, bitrate=1000,
                                    acoustic=AcousticDeviceSpec(source_level_db=190.0, carrier_khz=22.0,
                                                                bandwidth_hz=4000.0)),
                             Channel(id=0, acoustic=AcousticChannelSpec(spreading_k=1.5)))
    rl = 190 - 15 * math.log10(300) - 0.3 * ALPHA
    assert 10 * math.log10(float(link.received_power(300.0))) == pytest.approx(rl, abs=1e-9)


# ------------------------------------------------------------------ capture "first" (ns-3 UanPhyGen rules)

def test_capture_first_misses_a_stronger_frame_that_arrives_later() -> None:
    # far arrives first and is locked onto (SNR > 60 dB > 10 dB); near arrives 0.12 s later: under "any"
    # near captures the sink, under "first" the sink is busy with far, whose SINR then drops to -14 dB
    def run(rule: str) -> tuple[str, str]:
        rec = line({"near": 200.0, "far": 1000.0}, rule)
        send(rec, 1.0, "far")                                   # at the sink [1.6667, 1.9867)
        send(rec, 1.0 + 1000 / c - 200 / c + 0.12, "near")      # at the sink [1.7867, 2.1067)
        rec.run()
        return outcome(rec, "near"), outcome(rec, "far")

    assert run("threshold") == ("rx", "col")
    assert run("first") == ("col", "col")


def test_capture_first_keeps_a_stronger_frame_that_arrives_first() -> None:
    rec = line({"near": 200.0, "far": 1000.0}, "first")
    send(rec, 1.0, "near")
    send(rec, 1.0 + 200 / c - 1000 / c + 0.12, "far")
    rec.run()
    assert (outcome(rec, "near"), outcome(rec, "far")) == ("rx", "col")
    assert rec.net.channels[0].captures == 1


def test_capture_first_needs_the_acquisition_sinr() -> None:
    rec = line({"near": 200.0}, "first")
    spec = C.channel_spec("first").model_copy(update={"acquire_threshold_db": 200.0})   # above any SNR
    rec2 = Recorded(rec.net.scene.model_copy(update={"channels": (Channel(id=0, acoustic=spec),
                                                                  rec.net.scene.channels[1])}))
    for r in (rec, rec2):
        send(r, 1.0, "near")
        r.run()
    assert outcome(rec, "near") == "rx"
    assert outcome(rec2, "near") == "prop"                      # alone, never locked onto: lost to noise


def test_capture_first_matches_ns3_throughput() -> None:
    # ns-3.44 UAN (bench/ns3_capture.cc), same scenario, N = 16, G = 1, 6400 s: 4600 frames received
    # (S = 0.230); 2000 s here, so the tolerance is the statistical error of the shorter run
    net = Network(C.scene(16, 1.0, 2000.0, "first"))
    net.run()
    s = C.measured_throughput(net.tracer.count("rx"), 2000.0)
    assert s == pytest.approx(0.230, abs=0.015)
