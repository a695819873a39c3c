"""The sans-IO acoustic physics against published reference values (uwsimnet_zenoh.phy.acoustic).

Sources of the reference values are given next to each test; docs/acoustic.md has the full list.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from uwsimnet_zenoh.phy import acoustic as A
from uwsimnet_zenoh.phy.acoustic import (
    MODULATIONS,
    PRESETS,
    AcousticChannelParams,
    AcousticLink,
    AcousticModemParams,
)


# --------------------------------------------------------------------------------------------------
# Absorption, spreading, noise
# --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("f_khz", "alpha"), [(10.0, 1.19), (25.0, 6.10), (40.0, 12.9)])
def test_thorp_reference_values(f_khz: float, alpha: float) -> None:
    # Thorp (1967) as tabulated in Stojanovic (2007) and the ns-3 UAN documentation
    assert A.thorp_db_per_km(f_khz) == pytest.approx(alpha, abs=0.02)


def test_thorp_low_frequency_branch_is_ns3_dev() -> None:
    # ns-3-dev uan-prop-model-thorp.cc, f < 0.4 kHz: 0.002 + 0.11 f^2/(1+f^2) + 0.011 f^2
    f = 0.2
    expected = 0.002 + 0.11 * f * f / (1 + f * f) + 0.011 * f * f
    assert A.thorp_db_per_km(f) == pytest.approx(expected, rel=1e-12)
    # the two branches nearly meet at 0.4 kHz
    assert A.thorp_db_per_km(0.4) - A.thorp_db_per_km(0.39999) == pytest.approx(0.0, abs=0.0015)


def test_transmission_loss_1km_25khz() -> None:
    # Stojanovic (2007): TL = k 10 log d + d alpha; 1 km, 25 kHz, k = 1.5 -> 45 + 6.1 = 51 dB
    assert A.transmission_loss_db(1000.0, 25.0, 1.5) == pytest.approx(51.0, abs=0.5)


def test_transmission_loss_options() -> None:
    assert A.transmission_loss_db(0.2, 25.0) == A.transmission_loss_db(1.0, 25.0)     # clamped to 1 m
    assert A.transmission_loss_db(1.0, 25.0, absorption=0.0) == 0.0
    assert A.transmission_loss_db(100.0, 25.0, 2.0, absorption=0.0) == pytest.approx(40.0)
    assert A.transmission_loss_db(2000.0, 10.0, 1.0, absorption=3.0) == pytest.approx(
        10 * math.log10(2000) + 6)
    deep = lambda f: A.francois_garrison_db_per_km(f, 4, 35, 1000)  # noqa: E731
    fg = A.transmission_loss_db(1000.0, 25.0, absorption=deep)
    assert fg == pytest.approx(45.0 + deep(25.0))
    with pytest.raises(ValueError):
        A.transmission_loss_db(1000.0, 25.0, absorption="bogus")


def test_noise_psd_reference_values() -> None:
    # Coates (1989) / Wenz, as in ns-3 UanNoiseModelDefault and Stojanovic (2007)
    assert A.noise_psd_db(25.0, shipping=0.5, wind_mps=0.0) == pytest.approx(22.3, abs=0.3)
    assert A.noise_psd_db(25.0, shipping=0.5, wind_mps=10.0) == pytest.approx(45.5, abs=0.3)


def test_noise_level_adds_bandwidth() -> None:
    assert A.noise_level_db(25.0, 4000.0) == pytest.approx(A.noise_psd_db(25.0) + 10 * math.log10(4000.0))


# --------------------------------------------------------------------------------------------------
# Sound speed
# --------------------------------------------------------------------------------------------------
def test_mackenzie_by_hand() -> None:
    # the nine-term equation term by term at T = 25 deg C, S = 35 ppt, D = 0 m
    by_hand = 1448.96 + 4.591 * 25 - 5.304e-2 * 25**2 + 2.374e-4 * 25**3
    assert by_hand == pytest.approx(1534.294375, abs=1e-9)
    assert A.sound_speed_mackenzie(25.0, 35.0, 0.0) == pytest.approx(by_hand, abs=1e-9)
    assert A.sound_speed_mackenzie(25.0, 35.0, 0.0) == pytest.approx(1534.4, abs=0.15)


def test_mackenzie_check_values() -> None:
    assert A.sound_speed_mackenzie(10.0, 35.0, 1000.0) == pytest.approx(1506.4, abs=0.5)
    # check value of MBARI's implementation of Mackenzie (1981) (mbari.org Sndspd.txt):
    # 1718.774 m/s at S = 40, T = 40 deg C, Z = 10000 m
    assert A.sound_speed_mackenzie(40.0, 40.0, 10000.0) == pytest.approx(1718.774, abs=1e-3)


def test_francois_garrison_sound_speed() -> None:
    assert A.sound_speed_francois_garrison(10.0, 35.0, 1000.0) == pytest.approx(1412 + 32.1 + 41.65 + 16.7)


# --------------------------------------------------------------------------------------------------
# Francois-Garrison
# --------------------------------------------------------------------------------------------------
# Check values listed with G. Jimenez Arranz's implementation "seawaterAbsorption_FrancoisGarrison1982"
# (2017), z = 0 m, pH = 8: (T deg C, S ppt, f kHz) -> dB/km, given to 3 significant figures.
FG_CHECK = [
    (0, 30, 1, 6.10e-2), (0, 35, 1, 6.40e-2), (10, 35, 1, 6.00e-2),
    (0, 30, 10, 1.12), (0, 35, 10, 1.29), (10, 35, 10, 9.63e-1),
    (0, 30, 100, 21.0), (0, 35, 100, 23.4), (10, 35, 100, 33.6),
]


@pytest.mark.parametrize(("t", "s", "f", "alpha"), FG_CHECK)
def test_francois_garrison_check_values(t: float, s: float, f: float, alpha: float) -> None:
    assert A.francois_garrison_db_per_km(f, t, s, 0.0, 8.0) == pytest.approx(alpha, rel=0.01)


def test_francois_garrison_close_to_thorp_at_thorps_conditions() -> None:
    # Thorp's fit is for ~4 deg C at ~1 km depth; FG there is 75-85 % of Thorp from 5 to 50 kHz.
    # A sanity bound, not a reference value: agreement within 30 %.
    f = np.array([5.0, 10.0, 25.0, 50.0])
    ratio = A.francois_garrison_db_per_km(f, 4.0, 35.0, 1000.0) / A.thorp_db_per_km(f)
    assert np.all((ratio > 0.7) & (ratio < 1.3))


def test_francois_garrison_trends() -> None:
    f = np.array([1.0, 10.0, 100.0])
    fg = A.francois_garrison_db_per_km
    assert np.all(fg(f, 10, 35, 3000) < fg(f, 10, 35, 0))              # pressure lowers MgSO4 and water terms
    assert fg(1.0, 10, 35, 0, ph=8.2) > fg(1.0, 10, 35, 0)              # boric acid grows with pH
    # the pure-water term switches formula at 20 deg C without a jump
    assert A.francois_garrison_db_per_km(500.0, 20.0, 35, 0) == pytest.approx(
        A.francois_garrison_db_per_km(500.0, 20.0001, 35, 0), rel=0.01)


# --------------------------------------------------------------------------------------------------
# Link budget, BER, PER
# --------------------------------------------------------------------------------------------------
def test_link_budget_arithmetic() -> None:
    assert A.source_level_db(1.0) == pytest.approx(170.8)
    assert A.source_level_db(10.0) == pytest.approx(180.8)
    assert A.snr_db(180.0, 60.0, 70.0) == pytest.approx(50.0)
    assert A.snr_db(180.0, 60.0, 70.0, di_db=3.0) == pytest.approx(53.0)
    assert A.ebn0_db(10.0, 4000.0, 1000.0) == pytest.approx(10.0 + 10 * math.log10(4.0))
    assert A.db_to_linear(A.linear_to_db(123.0)) == pytest.approx(123.0)


def test_erfc_matches_math() -> None:
    x = np.linspace(-5.0, 26.0, 4001)
    ref = np.array([math.erfc(v) for v in x])
    assert np.max(np.abs(A.erfc(x) / ref - 1.0)) < 2e-7


def test_ber_bpsk_at_9_6_db() -> None:
    assert A.ber_bpsk(10 ** 0.96) == pytest.approx(1e-5, rel=0.05)
    assert A.ber_bpsk(10 ** 0.96) == pytest.approx(0.5 * math.erfc(math.sqrt(10 ** 0.96)), rel=2e-7)


def test_coherent_bfsk_needs_3_db_more() -> None:
    g = np.array([1.0, 5.0, 10 ** 0.96, 30.0])
    assert np.allclose(A.ber_bfsk_coherent(2 * g), A.ber_bpsk(g), rtol=1e-12)
    assert A.ber_bfsk_coherent(10 ** 1.26) == pytest.approx(1e-5, rel=0.05)


def test_ber_noncoherent_bfsk_dpsk_rayleigh() -> None:
    assert A.ber_bfsk_noncoherent(10.0) == pytest.approx(0.5 * math.exp(-5.0), rel=1e-12)
    assert A.ber_dpsk(10.0) == pytest.approx(0.5 * math.exp(-10.0), rel=1e-12)
    assert A.ber_bpsk_rayleigh(100.0) == pytest.approx(2.5e-3, rel=0.01)
    assert A.ber_bpsk_rayleigh(100.0) == pytest.approx(0.5 * (1 - math.sqrt(100 / 101)), rel=1e-12)


@pytest.mark.parametrize("name", sorted(MODULATIONS))
def test_ber_limits_and_monotone(name: str) -> None:
    fn = MODULATIONS[name]
    g = np.logspace(-3, 3, 200)
    b = fn(g)
    assert fn(0.0) == pytest.approx(0.5)
    assert np.all(np.diff(b) <= 0) and np.all(b >= 0) and np.all(b <= 0.5)
    assert np.all(np.diff(b[b > 1e-250]) < 0)                           # strictly until it underflows


def test_per_from_ber() -> None:
    assert A.per_from_ber(0.0, 64) == 0.0
    assert A.per_from_ber(1.0, 64) == 1.0
    assert A.per_from_ber(1e-12, 64) == pytest.approx(512e-12, rel=1e-6)      # expm1/log1p keep this
    assert A.per_from_ber(1e-3, 64) == pytest.approx(1 - (1 - 1e-3) ** 512, rel=1e-12)
    assert A.per_from_ber(1e-3, 128) > A.per_from_ber(1e-3, 64)


def test_required_ebn0_inverts_per() -> None:
    for name in MODULATIONS:
        e = A.required_ebn0_db(name, 0.1, 64)
        assert A.per_from_ber(MODULATIONS[name](10 ** (e / 10)), 64) == pytest.approx(0.1, rel=1e-6)
    with pytest.raises(ValueError):
        A.required_ebn0_db("bpsk", 1.0, 64)


# --------------------------------------------------------------------------------------------------
# Vectorisation
# --------------------------------------------------------------------------------------------------
def test_vectorised_shapes() -> None:
    f = np.array([[5.0, 10.0, 25.0], [30.0, 40.0, 60.0]])
    d = np.array([[10.0, 100.0, 1000.0], [2000.0, 5000.0, 9000.0]])
    for out in (A.thorp_db_per_km(f), A.noise_psd_db(f), A.noise_level_db(f, 4000.0),
                A.francois_garrison_db_per_km(f, 10.0, 35.0, 100.0), A.transmission_loss_db(d, f),
                A.sound_speed_mackenzie(f, 35.0, d), A.erfc(f / 10), A.per_from_ber(f * 1e-5, 64),
                *(fn(f) for fn in MODULATIONS.values())):
        assert isinstance(out, np.ndarray) and out.shape == f.shape
    link = AcousticLink(None, "whoi-micromodem")
    for method in (link.transmission_loss_db, link.received_level_db, link.snr_db, link.ebn0_db, link.ber,
                   link.propagation_delay_s):
        assert method(d).shape == d.shape
    for dd in (d, np.linspace(1, 9000, 500).reshape(20, 25)):        # both the small and the numpy path
        p = link.per(dd, 64)
        assert isinstance(p, np.ndarray) and p.shape == dd.shape


def test_scalars_give_floats() -> None:
    assert isinstance(A.thorp_db_per_km(25.0), float)
    assert isinstance(A.noise_psd_db(25.0), float)
    link = AcousticLink()
    assert isinstance(link.per(500.0, 64), float)
    assert isinstance(link.snr_db(500.0), float)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(min_value=0.0, max_value=50_000.0), min_size=1, max_size=40),
       st.sampled_from(sorted(PRESETS)), st.integers(min_value=1, max_value=4096))
def test_small_and_vector_paths_agree(ds: list[float], name: str, size: int) -> None:
    link = AcousticLink(None, name)
    small = link.per(np.array(ds), size)                              # <= 48 elements: math loop
    big = link.per(np.array(ds * 10), size)[: len(ds)]                # numpy path
    assert np.all((small >= 0) & (small <= 1))
    assert np.allclose(small, big, rtol=1e-5, atol=1e-12)


# --------------------------------------------------------------------------------------------------
# The link and its parameters
# --------------------------------------------------------------------------------------------------
def test_link_matches_the_functions() -> None:
    ch = AcousticChannelParams(wind_mps=3.0, shipping=0.2)
    modem = AcousticModemParams(carrier_khz=20.0, bandwidth_hz=5000.0, bitrate_bps=1000.0, power_w=10.0,
                                modulation="bfsk_noncoherent", directivity_index_db=2.0)
    link = AcousticLink(ch, modem)
    d = np.array([300.0, 3000.0, 6000.0])
    tl = A.transmission_loss_db(d, 20.0)
    nl = A.noise_level_db(20.0, 5000.0, 0.2, 3.0)
    snr = A.snr_db(180.8, tl, nl, 2.0)
    assert np.allclose(link.snr_db(d), snr)
    assert np.allclose(link.ebn0_db(d), A.ebn0_db(snr, 5000.0, 1000.0))
    ber = A.ber_bfsk_noncoherent(10 ** (A.ebn0_db(snr, 5000.0, 1000.0) / 10))
    assert np.allclose(link.ber(d), ber)
    assert np.allclose(link.per(d, 32), A.per_from_ber(ber, 32))
    assert link.sound_speed() == pytest.approx(A.sound_speed_mackenzie(25.0, 35.0, 0.0))
    assert link.propagation_delay_s(1500.0) == pytest.approx(1500.0 / link.sound_speed())


def test_sinr_and_capture() -> None:
    link = AcousticLink(None, "evologics-s2cr-18-34")
    d = np.array([200.0, 1500.0, 3400.0])
    rl = link.received_level_db(d)
    assert np.allclose(link.sinr_db(rl, []), link.snr_db(d))
    assert np.allclose(link.per_from_sinr(link.sinr_db(rl), 64), link.per(d, 64))
    # an equal-power interferer: SINR = 0 dB when the noise is negligible (SNR ~ 49 dB at 200 m)
    s = float(rl[0])
    assert link.snr_db(200.0) > 40
    assert link.sinr_db(s, [s]) == pytest.approx(0.0, abs=0.01)
    # a much weaker interferer changes nothing, a stronger one kills the frame
    assert link.sinr_db(s, [s - 90]) == pytest.approx(link.snr_db(200.0), abs=0.01)
    assert link.per_from_sinr(link.sinr_db(s, [s + 3]), 64) > 0.99
    # several interferers, summed in power; a batch over the last axis
    assert link.sinr_db(s, [s - 3, s - 3]) == pytest.approx(-10 * math.log10(2 * 10 ** -0.3), abs=1e-3)
    batch = link.sinr_db(np.array([s, s]), np.array([[s - 10, s - 10], [s, s]]))
    assert batch.shape == (2,) and batch[0] > batch[1]


def test_channel_options() -> None:
    modem = PRESETS["whoi-micromodem"]
    deep = AcousticChannelParams(absorption="francois-garrison", temperature_c=4.0, depth_m=1000.0)
    fg = AcousticLink(deep, modem)
    assert fg.alpha_db_per_km == pytest.approx(A.francois_garrison_db_per_km(25.0, 4.0, 35.0, 1000.0))
    assert AcousticLink(AcousticChannelParams(absorption=2.5), modem).alpha_db_per_km == 2.5
    fixed_psd = AcousticLink(AcousticChannelParams(noise_psd_db=50.0), modem)
    assert fixed_psd.nl_db == pytest.approx(50.0 + 10 * math.log10(4000.0) + modem.margin_db)
    fixed_nl = AcousticLink(AcousticChannelParams(noise_level_db=90.0, noise_psd_db=50.0), modem)
    assert fixed_nl.nl_db == pytest.approx(90.0 + modem.margin_db)
    assert AcousticLink(AcousticChannelParams(sound_speed_mps=1500.0), modem).sound_speed() == 1500.0
    # more wind, more noise, shorter range
    windy = AcousticLink(AcousticChannelParams(wind_mps=10.0), modem)
    assert windy.distance_for_per(0.5) < AcousticLink(None, modem).distance_for_per(0.5)


def test_parameter_validation() -> None:
    with pytest.raises(ValueError):
        AcousticModemParams(carrier_khz=25, bandwidth_hz=4000, bitrate_bps=100)            # no SL, no power
    with pytest.raises(ValueError):
        AcousticModemParams(carrier_khz=25, bandwidth_hz=4000, bitrate_bps=100, source_level_db=180,
                            power_w=1)
    with pytest.raises(ValueError):
        AcousticModemParams(carrier_khz=25, bandwidth_hz=4000, bitrate_bps=100, power_w=1, modulation="ook")
    with pytest.raises(ValueError):
        AcousticChannelParams(shipping=1.5)
    with pytest.raises(ValueError):
        AcousticChannelParams(wind_mps=-1)
    with pytest.raises(ValueError):
        AcousticChannelParams(absorption="bogus")
    m = AcousticModemParams(carrier_khz=25, bandwidth_hz=4000, bitrate_bps=100, power_w=10)
    assert m.sl_db == pytest.approx(180.8)
    with pytest.raises(AttributeError):
        m.carrier_khz = 30                                                                  # frozen


def test_implementation_loss_and_margin() -> None:
    base = AcousticModemParams(carrier_khz=25, bandwidth_hz=4000, bitrate_bps=1000, source_level_db=180)
    d = 2000.0
    ref = AcousticLink(None, base)
    assert AcousticLink(None, replace(base, implementation_loss_db=5)).ebn0_db(d) == pytest.approx(
        ref.ebn0_db(d) - 5)
    noisy = AcousticLink(None, replace(base, margin_db=5))
    assert noisy.snr_db(d) == pytest.approx(ref.snr_db(d) - 5)
    # the margin acts on noise only: an equal-power interferer gives the same SINR with or without it
    s = float(ref.received_level_db(d))
    assert noisy.sinr_db(s, [s]) == pytest.approx(ref.sinr_db(s, [s]), abs=0.01)


# --------------------------------------------------------------------------------------------------
# Presets
# --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", sorted(PRESETS))
def test_preset_is_documented(name: str) -> None:
    p = PRESETS[name]
    assert p.source and p.rated_range_m and p.band_khz
    assert p.band_khz[0] <= p.carrier_khz <= p.band_khz[1]
    assert p.bandwidth_hz == pytest.approx((p.band_khz[1] - p.band_khz[0]) * 1000.0)
    assert 150.0 < p.sl_db < 200.0


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_preset_per_monotone_in_distance(name: str) -> None:
    link = AcousticLink(None, name)
    d = np.logspace(0, 5, 2000)
    for size in (8, 64, 1024):
        per = link.per(d, size)
        assert np.all(np.diff(per) >= 0.0)
        assert per[0] < 1e-9 and per[-1] == pytest.approx(1.0)


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_preset_rated_range(name: str) -> None:
    # < 1 % of 64-byte frames lost at half the rated range, > 50 % at three times it
    p = PRESETS[name]
    link = AcousticLink(None, p)
    assert link.per(0.5 * p.rated_range_m, 64) < 0.01
    assert link.per(3.0 * p.rated_range_m, 64) > 0.5


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_preset_calibration_is_current(name: str) -> None:
    # margin_db is calibrate_margin() rounded to 0.1 dB: PER(64 B) = 10 % at the rated range
    p = PRESETS[name]
    assert p.margin_db == pytest.approx(A.calibrate_margin(p), abs=0.051)
    r10 = AcousticLink(None, p).distance_for_per(0.1, 64)
    assert r10 == pytest.approx(p.rated_range_m, rel=0.02)


def test_presets_by_name() -> None:
    assert AcousticLink(None, "seatrac-x150").modem is PRESETS["seatrac-x150"]
    assert {"evologics-s2cr-7-17", "evologics-s2cr-18-34", "whoi-micromodem", "seatrac-x150"} <= set(PRESETS)
