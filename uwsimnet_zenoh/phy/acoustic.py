"""Sans-IO underwater acoustic link physics: pure numpy functions, no I/O, no zenoh.

Units follow the field's customs and are stated in every docstring:

* frequency ``f_khz`` in kHz (Thorp, Francois-Garrison and the Wenz/Coates noise fits are written in kHz);
  bandwidth in Hz; bit rate in bit/s;
* distance in m (absorption coefficients in dB/km); depth in m; temperature in deg C; salinity in ppt (PSU);
* levels in dB: source level and received level in dB re 1 uPa @ 1 m / dB re 1 uPa, noise power spectral
  density in dB re 1 uPa^2/Hz, noise level in a band in dB re 1 uPa; ratios (SNR, Eb/N0) in dB unless a
  name says ``_linear``.

Every function accepts Python floats or numpy arrays and broadcasts; an array in gives an array of the
broadcast shape out, scalars in give a numpy float64 (a ``float`` subclass) out.

The link model is the one of ns-3 UAN (``UanPropModelThorp`` + ``UanNoiseModelDefault``) and of Stojanovic
(2007): passive sonar equation SNR = SL - TL - NL + DI (Urick), TL = k*10log10(d) + d/1000*alpha(f),
NL = N(f_c) + 10log10(B), Eb/N0 = SNR + 10log10(B/R), an AWGN bit-error formula per modulation and
PER = 1 - (1 - BER)^(8L).  `AcousticLink` precomputes everything that does not depend on distance, so the
per-frame call ``link.per(distances, size_bytes)`` costs a few microseconds.  The modem presets carry a
receiver margin against noise (``margin_db``), calibrated so that each reaches its rated range: it stands
for what the free-field AWGN model leaves out (multipath, fading, Doppler, implementation losses,
conservative ratings) and is not a noise level; see `PRESETS` and docs/acoustic.md.  `AcousticLink` also
gives received powers and PER from SINR for the channel's interference (capture) mode.

References (full list in docs/acoustic.md):
    Thorp (1967) JASA 42:270; Francois & Garrison (1982) JASA 72:896 and 72:1879; Mackenzie (1981) JASA
    70:807; Coates (1989) / Wenz (1962) noise; Stojanovic (2007) ACM MC2R 11(4); Urick, Principles of
    Underwater Sound; Proakis, Digital Communications (BER formulas).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any, TypeAlias

import numpy as np

from .models import DistanceModel

ArrayLike: TypeAlias = float | np.ndarray
Absorption: TypeAlias = str | float | Callable[[np.ndarray], np.ndarray]

__all__ = ["AcousticChannelParams", "AcousticLink", "AcousticModemParams", "MODULATIONS", "PRESETS",
           "ber_bfsk_coherent", "ber_bfsk_noncoherent", "ber_bpsk", "ber_bpsk_rayleigh", "ber_dpsk",
           "calibrate_margin", "db_to_linear", "ebn0_db", "erfc", "francois_garrison_db_per_km", "linear_to_db",
           "noise_level_db", "noise_psd_db", "per_from_ber", "required_ebn0_db", "snr_db",
           "sound_speed_francois_garrison", "sound_speed_mackenzie", "source_level_db", "thorp_db_per_km",
           "transmission_loss_db"]


def _out(x: np.ndarray) -> ArrayLike:
    """0-d arrays become numpy float64 scalars; anything else stays an array."""
    return x[()] if isinstance(x, np.ndarray) and x.ndim == 0 else x


def _f(x: ArrayLike) -> np.ndarray:
    return np.asarray(x, dtype=float)


def db_to_linear(db: ArrayLike) -> ArrayLike:
    """Power ratio from dB: 10^(dB/10)."""
    return _out(np.power(10.0, _f(db) * 0.1))


def linear_to_db(x: ArrayLike) -> ArrayLike:
    """dB from a power ratio: 10 log10(x) (x <= 0 gives -inf)."""
    with np.errstate(divide="ignore"):
        return _out(10.0 * np.log10(_f(x)))


# ---------------------------------------------------------------------------------------------------
# Sound speed
# ---------------------------------------------------------------------------------------------------
def sound_speed_mackenzie(temperature_c: ArrayLike, salinity_ppt: ArrayLike, depth_m: ArrayLike) -> ArrayLike:
    """Speed of sound in sea water, m/s, by Mackenzie's nine-term equation.

    K. V. Mackenzie, "Nine-term equation for sound speed in the oceans", JASA 70(3):807-812, 1981:
        c = 1448.96 + 4.591 T - 5.304e-2 T^2 + 2.374e-4 T^3 + 1.340 (S - 35) + 1.630e-2 D + 1.675e-7 D^2
            - 1.025e-2 T (S - 35) - 7.139e-13 T D^3
    T temperature in deg C, S salinity in ppt, D depth in m.  Valid for T in [-2, 30] deg C, S in
    [25, 40] ppt, D in [0, 8000] m (standard error 0.07 m/s).  Check value (MBARI's implementation of the
    same paper): c = 1718.774 m/s at S = 40 ppt, T = 40 deg C, D = 10 000 m (outside the validity domain, a
    pure arithmetic check).
    """
    t, s, d = _f(temperature_c), _f(salinity_ppt), _f(depth_m)
    ds = s - 35.0
    c = (1448.96 + t * (4.591 + t * (-5.304e-2 + t * 2.374e-4)) + 1.340 * ds + d * (1.630e-2 + 1.675e-7 * d)
         - 1.025e-2 * t * ds - 7.139e-13 * t * d ** 3)
    return _out(c)


def sound_speed_francois_garrison(temperature_c: ArrayLike, salinity_ppt: ArrayLike,
                                  depth_m: ArrayLike) -> ArrayLike:
    """The simple sound speed used inside the Francois-Garrison absorption equation, m/s.

    c = 1412 + 3.21 T + 1.19 S + 0.0167 D  (T deg C, S ppt, D m; Francois & Garrison 1982, Part I).
    """
    return _out(1412.0 + 3.21 * _f(temperature_c) + 1.19 * _f(salinity_ppt) + 0.0167 * _f(depth_m))


# ---------------------------------------------------------------------------------------------------
# Absorption and transmission loss
# ---------------------------------------------------------------------------------------------------
def thorp_db_per_km(f_khz: ArrayLike) -> ArrayLike:
    """Thorp's absorption coefficient, dB/km, for frequency ``f_khz`` in kHz.

    W. H. Thorp, "Analytic description of the low-frequency attenuation coefficient", JASA 42:270, 1967,
    in the form used by ns-3 ``UanPropModelThorp::GetAttenDbKm``:
        f >= 0.4 kHz: alpha = 0.11 f^2/(1+f^2) + 44 f^2/(4100+f^2) + 2.75e-4 f^2 + 0.003
        f <  0.4 kHz: alpha = 0.002 + 0.11 f^2/(1+f^2) + 0.011 f^2
    The low-frequency branch is the one of current ns-3-dev (src/uan/model/uan-prop-model-thorp.cc, which
    uses f^2); ns-3.40 and earlier used f (linear) there: 0.002 + 0.11 f/(1+f) + 0.011 f.  The two agree to
    within 0.001 dB/km at 0.4 kHz and only matter below it.  Values: 1.19 / 6.10 / 12.9 dB/km at
    10 / 25 / 40 kHz.
    """
    f = _f(f_khz)
    fsq = f * f
    hi = 0.11 * fsq / (1.0 + fsq) + 44.0 * fsq / (4100.0 + fsq) + 2.75e-4 * fsq + 0.003
    lo = 0.002 + 0.11 * fsq / (1.0 + fsq) + 0.011 * fsq
    return _out(np.where(f >= 0.4, hi, lo))


def francois_garrison_db_per_km(f_khz: ArrayLike, temperature_c: ArrayLike, salinity_ppt: ArrayLike,
                                depth_m: ArrayLike, ph: ArrayLike = 8.0) -> ArrayLike:
    """Francois-Garrison absorption coefficient of sea water, dB/km.

    R. E. Francois and G. R. Garrison, "Sound absorption based on ocean measurements", Part I (pure water
    and MgSO4), JASA 72(3):896-907 and Part II (boric acid, total), JASA 72(6):1879-1890, 1982.
    Sum of three contributions, f in kHz, T in deg C, S in ppt, D in m, c from
    `sound_speed_francois_garrison`:
        boric acid   A1 = 8.86/c 10^(0.78 pH - 5),  P1 = 1,  f1 = 2.8 sqrt(S/35) 10^(4 - 1245/(273+T))
        MgSO4        A2 = 21.44 S/c (1 + 0.025 T),  P2 = 1 - 1.37e-4 D + 6.2e-9 D^2,
                     f2 = 8.17 10^(8 - 1990/(273+T)) / (1 + 0.0018 (S - 35))
        pure water   P3 = 1 - 3.83e-5 D + 4.9e-10 D^2,
                     A3 = 4.937e-4 - 2.59e-5 T + 9.11e-7 T^2 - 1.50e-8 T^3   (T <= 20 deg C)
                     A3 = 3.964e-4 - 1.146e-5 T + 1.45e-7 T^2 - 6.5e-10 T^3  (T >  20 deg C)
        alpha = A1 P1 f1 f^2/(f^2+f1^2) + A2 P2 f2 f^2/(f^2+f2^2) + A3 P3 f^2
    Valid 0.2 kHz - 1 MHz, all oceanic conditions.  Temperatures are taken as given (the equation was fitted
    on IPTS-68; the ITS-90 difference, a factor 1.00024, is negligible here).
    """
    f, t, s, d, p = _f(f_khz), _f(temperature_c), _f(salinity_ppt), _f(depth_m), _f(ph)
    c = 1412.0 + 3.21 * t + 1.19 * s + 0.0167 * d
    tk = t + 273.0
    fsq = f * f
    a1 = 8.86 / c * np.power(10.0, 0.78 * p - 5.0)
    f1 = 2.8 * np.sqrt(s / 35.0) * np.power(10.0, 4.0 - 1245.0 / tk)
    a2 = 21.44 * s / c * (1.0 + 0.025 * t)
    p2 = 1.0 - 1.37e-4 * d + 6.2e-9 * d * d
    f2 = 8.17 * np.power(10.0, 8.0 - 1990.0 / tk) / (1.0 + 0.0018 * (s - 35.0))
    p3 = 1.0 - 3.83e-5 * d + 4.9e-10 * d * d
    a3 = np.where(t <= 20.0,
                  4.937e-4 - 2.59e-5 * t + 9.11e-7 * t * t - 1.50e-8 * t ** 3,
                  3.964e-4 - 1.146e-5 * t + 1.45e-7 * t * t - 6.5e-10 * t ** 3)
    alpha = a1 * f1 * fsq / (fsq + f1 * f1) + a2 * p2 * f2 * fsq / (fsq + f2 * f2) + a3 * p3 * fsq
    return _out(alpha)


def _absorption_db_per_km(f_khz: ArrayLike, absorption: Absorption) -> ArrayLike:
    if isinstance(absorption, str):
        if absorption.lower() == "thorp":
            return thorp_db_per_km(f_khz)
        raise ValueError(f"unknown absorption model {absorption!r}: use 'thorp', a number in dB/km, or a "
                         "callable f_khz -> dB/km (e.g. functools.partial(francois_garrison_db_per_km, ...))")
    if callable(absorption):
        return absorption(f_khz)
    return float(absorption)


def transmission_loss_db(distance_m: ArrayLike, f_khz: ArrayLike, spreading_k: float = 1.5,
                         absorption: Absorption = "thorp") -> ArrayLike:
    """Transmission loss, dB: TL = k 10 log10(d) + (d/1000) alpha(f).

    ``distance_m`` in m, clamped to >= 1 m (the source level is referenced to 1 m); ``f_khz`` in kHz;
    ``spreading_k`` 1 cylindrical, 2 spherical, 1.5 "practical" (Stojanovic 2007, ns-3 default);
    ``absorption``: "thorp" (default), a constant in dB/km, or a callable ``f_khz -> dB/km``.
    About 51 dB at 1 km, 25 kHz, k = 1.5.
    """
    d = np.maximum(_f(distance_m), 1.0)
    alpha = _f(_absorption_db_per_km(f_khz, absorption))
    return _out(spreading_k * 10.0 * np.log10(d) + d * 1e-3 * alpha)


# ---------------------------------------------------------------------------------------------------
# Ambient noise
# ---------------------------------------------------------------------------------------------------
def noise_psd_db(f_khz: ArrayLike, shipping: ArrayLike = 0.5, wind_mps: ArrayLike = 0.0) -> ArrayLike:
    """Ambient noise power spectral density, dB re 1 uPa^2/Hz (Wenz 1962 curves as fitted by Coates 1989).

    Same model as ns-3 ``UanNoiseModelDefault`` and Stojanovic (2007); f in kHz, shipping activity s in
    [0, 1], wind speed w in m/s; the four sources are summed in linear power units:
        turbulence  Nt  = 17 - 30 log f
        shipping    Ns  = 40 + 20 (s - 0.5) + 26 log f - 60 log(f + 0.03)
        wind        Nw  = 50 + 7.5 sqrt(w) + 20 log f - 40 log(f + 0.4)
        thermal     Nth = -15 + 20 log f
    At 25 kHz: 22.3 dB (s = 0.5, w = 0) and 45.5 dB (w = 10 m/s).
    """
    f, s, w = _f(f_khz), _f(shipping), _f(wind_mps)
    lf = np.log10(f)
    nt = 17.0 - 30.0 * lf
    ns = 40.0 + 20.0 * (s - 0.5) + 26.0 * lf - 60.0 * np.log10(f + 0.03)
    nw = 50.0 + 7.5 * np.sqrt(w) + 20.0 * lf - 40.0 * np.log10(f + 0.4)
    nth = -15.0 + 20.0 * lf
    total = (np.power(10.0, 0.1 * nt) + np.power(10.0, 0.1 * ns) + np.power(10.0, 0.1 * nw)
             + np.power(10.0, 0.1 * nth))
    return _out(10.0 * np.log10(total))


def noise_level_db(f_khz: ArrayLike, bandwidth_hz: ArrayLike, shipping: ArrayLike = 0.5,
                   wind_mps: ArrayLike = 0.0) -> ArrayLike:
    """Noise level in a receiver band, dB re 1 uPa: N(f_c) + 10 log10(B).

    The PSD is taken at the centre frequency ``f_khz`` (kHz) and assumed flat over ``bandwidth_hz`` (Hz), as
    ns-3 and Stojanovic (2007) do.
    """
    return _out(_f(noise_psd_db(f_khz, shipping, wind_mps)) + 10.0 * np.log10(_f(bandwidth_hz)))


# ---------------------------------------------------------------------------------------------------
# Link budget
# ---------------------------------------------------------------------------------------------------
SOURCE_LEVEL_AT_1W_DB = 170.8
"""dB re 1 uPa @ 1 m radiated by 1 W of acoustic power from an omnidirectional source in sea water."""


def source_level_db(power_w: ArrayLike) -> ArrayLike:
    """Source level, dB re 1 uPa @ 1 m, of ``power_w`` watts of radiated acoustic power (omnidirectional).

    SL = 170.8 + 10 log10(P) (Urick; I = P/(4 pi r^2) with rho c = 1.5e6 kg/m^2/s).  Electrical power into a
    transducer gives an upper bound only: multiply by its electro-acoustic efficiency first.
    """
    return _out(SOURCE_LEVEL_AT_1W_DB + 10.0 * np.log10(_f(power_w)))


def snr_db(sl_db: ArrayLike, tl_db: ArrayLike, nl_db: ArrayLike, di_db: ArrayLike = 0.0) -> ArrayLike:
    """Passive sonar equation, dB: SNR = SL - TL - NL + DI (Urick).

    ``sl_db`` source level (dB re 1 uPa @ 1 m), ``tl_db`` transmission loss (dB), ``nl_db`` noise level in the
    receiver band (dB re 1 uPa), ``di_db`` receiver directivity index (dB, 0 for an omni hydrophone).
    """
    return _out(_f(sl_db) - _f(tl_db) - _f(nl_db) + _f(di_db))


def ebn0_db(snr_db: ArrayLike, bandwidth_hz: ArrayLike, bitrate: ArrayLike) -> ArrayLike:
    """Energy per bit over noise PSD, dB: Eb/N0 = SNR + 10 log10(B/R); B in Hz, R in bit/s."""
    return _out(_f(snr_db) + 10.0 * np.log10(_f(bandwidth_hz) / _f(bitrate)))


# ---------------------------------------------------------------------------------------------------
# Bit and packet error rates
# ---------------------------------------------------------------------------------------------------
def _erfc_nonneg(z: np.ndarray) -> np.ndarray:
    # Numerical Recipes "erfcc" (Chebyshev fit): fractional error < 1.2e-7 everywhere, so the far tail
    # (BER 1e-30) is as accurate as the bulk.  z >= 0.
    t = 1.0 / (1.0 + 0.5 * z)
    poly = -1.26551223 + t * (1.00002368 + t * (0.37409196 + t * (0.09678418 + t * (
        -0.18628806 + t * (0.27886807 + t * (-1.13520398 + t * (1.48851587 + t * (
            -0.82215223 + t * 0.17087277))))))))
    return t * np.exp(-z * z + poly)


def erfc(x: ArrayLike) -> ArrayLike:
    """Complementary error function, vectorised, relative error < 1.2e-7 (no scipy needed)."""
    x = _f(x)
    r = _erfc_nonneg(np.abs(x))
    return _out(np.where(x >= 0.0, r, 2.0 - r))


def ber_bpsk(ebn0_linear: ArrayLike) -> ArrayLike:
    """Coherent BPSK (and Gray-coded QPSK) in AWGN: Pb = 1/2 erfc(sqrt(Eb/N0)); Eb/N0 linear."""
    g = np.maximum(_f(ebn0_linear), 0.0)
    return _out(0.5 * _erfc_nonneg(np.sqrt(g)))


def ber_bfsk_coherent(ebn0_linear: ArrayLike) -> ArrayLike:
    """Coherent orthogonal BFSK in AWGN: Pb = 1/2 erfc(sqrt(Eb/(2 N0))), 3 dB worse than BPSK."""
    g = np.maximum(_f(ebn0_linear), 0.0)
    return _out(0.5 * _erfc_nonneg(np.sqrt(0.5 * g)))


def ber_bfsk_noncoherent(ebn0_linear: ArrayLike) -> ArrayLike:
    """Non-coherent orthogonal BFSK in AWGN: Pb = 1/2 exp(-Eb/(2 N0))."""
    return _out(0.5 * np.exp(-0.5 * np.maximum(_f(ebn0_linear), 0.0)))


def ber_dpsk(ebn0_linear: ArrayLike) -> ArrayLike:
    """Binary DPSK (differentially coherent) in AWGN: Pb = 1/2 exp(-Eb/N0)."""
    return _out(0.5 * np.exp(-np.maximum(_f(ebn0_linear), 0.0)))


def ber_bpsk_rayleigh(ebn0_linear: ArrayLike) -> ArrayLike:
    """Coherent BPSK in flat Rayleigh fading, mean Eb/N0 = gamma: Pb = 1/2 (1 - sqrt(gamma/(1+gamma)))."""
    g = np.maximum(_f(ebn0_linear), 0.0)
    return _out(0.5 * (1.0 - np.sqrt(g / (1.0 + g))))


def _scalar_bers() -> dict[str, Callable[[float], float]]:
    # The same formulas on Python floats, for the simulator's small per-frame batches (math beats numpy's
    # per-call overhead below a few dozen elements).
    return {
        "bpsk": lambda g: 0.5 * math.erfc(math.sqrt(g)),
        "bfsk_coherent": lambda g: 0.5 * math.erfc(math.sqrt(0.5 * g)),
        "bfsk_noncoherent": lambda g: 0.5 * math.exp(-0.5 * g),
        "dpsk": lambda g: 0.5 * math.exp(-g),
        "bpsk_rayleigh": lambda g: 0.5 * (1.0 - math.sqrt(g / (1.0 + g))),
    }


_BER_SCALAR = _scalar_bers()

MODULATIONS: dict[str, Callable[[ArrayLike], ArrayLike]] = {
    "bpsk": ber_bpsk,
    "bfsk_coherent": ber_bfsk_coherent,
    "bfsk_noncoherent": ber_bfsk_noncoherent,
    "dpsk": ber_dpsk,
    "bpsk_rayleigh": ber_bpsk_rayleigh,
}
"""Modulation name -> BER function of linear Eb/N0."""


def per_from_ber(ber: ArrayLike, size_bytes: ArrayLike) -> ArrayLike:
    """Packet error rate of a ``size_bytes`` frame with independent bit errors: 1 - (1 - Pb)^(8 L).

    Computed as -expm1(8 L log1p(-Pb)) so that Pb = 1e-12 on a 64-byte frame gives 5.1e-10, not 0.
    """
    b = np.clip(_f(ber), 0.0, 1.0)
    with np.errstate(divide="ignore"):
        return _out(-np.expm1(8.0 * _f(size_bytes) * np.log1p(-b)))


def required_ebn0_db(modulation: str, target_per: float, size_bytes: int) -> float:
    """The Eb/N0 (dB) at which ``modulation`` gives PER ``target_per`` on ``size_bytes``-byte frames."""
    if not 0.0 < target_per < 1.0:
        raise ValueError(f"target_per must be in (0, 1), got {target_per}")
    ber_fn = MODULATIONS[modulation]
    target_ber = -math.expm1(math.log1p(-target_per) / (8.0 * size_bytes))
    lo, hi = -30.0, 120.0                         # BER decreases with Eb/N0: bisection in dB
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        if float(ber_fn(10.0 ** (mid / 10.0))) > target_ber:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


# ---------------------------------------------------------------------------------------------------
# Parameters
# ---------------------------------------------------------------------------------------------------
@dataclass(frozen=True, kw_only=True)
class AcousticChannelParams:
    """The water and its noise, shared by every modem on a channel.

    Attributes (units):
        temperature_c: water temperature, deg C (default 25).
        salinity_ppt: salinity, ppt / PSU (default 35).
        depth_m: representative depth for sound speed and Francois-Garrison absorption, m (default 0).
        ph: pH, for Francois-Garrison boric-acid absorption (default 8.0).
        spreading_k: geometric spreading exponent k: 1 cylindrical, 2 spherical, 1.5 practical (default).
        absorption: "thorp" (default), "francois-garrison" (uses temperature, salinity, depth, pH),
            a constant in dB/km, or a callable f_khz -> dB/km.
        shipping: shipping activity in [0, 1] for the Wenz/Coates noise model (default 0.5).
        wind_mps: wind speed at the surface, m/s (default 0).
        noise_psd_db: if set, a fixed noise PSD in dB re 1 uPa^2/Hz replacing the Wenz/Coates model.
        noise_level_db: if set, a fixed in-band noise level in dB re 1 uPa (already integrated over the
            receiver band; overrides noise_psd_db and the Wenz/Coates model).
        sound_speed_mps: if set, a fixed sound speed in m/s instead of Mackenzie (1981).
    """

    temperature_c: float = 25.0
    salinity_ppt: float = 35.0
    depth_m: float = 0.0
    ph: float = 8.0
    spreading_k: float = 1.5
    absorption: Absorption = "thorp"
    shipping: float = 0.5
    wind_mps: float = 0.0
    noise_psd_db: float | None = None
    noise_level_db: float | None = None
    sound_speed_mps: float | None = None

    def __post_init__(self) -> None:
        if not 0.0 <= self.shipping <= 1.0:
            raise ValueError(f"shipping must be in [0, 1], got {self.shipping}")
        if self.wind_mps < 0.0:
            raise ValueError(f"wind_mps must be >= 0, got {self.wind_mps}")
        if self.spreading_k <= 0.0:
            raise ValueError(f"spreading_k must be > 0, got {self.spreading_k}")
        if self.depth_m < 0.0:
            raise ValueError(f"depth_m must be >= 0, got {self.depth_m}")
        if self.sound_speed_mps is not None and self.sound_speed_mps <= 0.0:
            raise ValueError(f"sound_speed_mps must be > 0, got {self.sound_speed_mps}")
        if isinstance(self.absorption, str) and self.absorption.lower() not in ("thorp", "francois-garrison"):
            raise ValueError(f"unknown absorption model {self.absorption!r}")

    def sound_speed(self) -> float:
        """Sound speed, m/s: the fixed value if given, else Mackenzie (1981) at (T, S, depth)."""
        if self.sound_speed_mps is not None:
            return float(self.sound_speed_mps)
        return float(sound_speed_mackenzie(self.temperature_c, self.salinity_ppt, self.depth_m))

    def absorption_db_per_km(self, f_khz: ArrayLike) -> ArrayLike:
        """Absorption coefficient of this water at ``f_khz`` (kHz), dB/km."""
        if isinstance(self.absorption, str) and self.absorption.lower() == "francois-garrison":
            return francois_garrison_db_per_km(f_khz, self.temperature_c, self.salinity_ppt, self.depth_m,
                                               self.ph)
        return _absorption_db_per_km(f_khz, self.absorption)

    def noise_level_in_band_db(self, f_khz: float, bandwidth_hz: float) -> float:
        """Noise level in a receiver band centred on ``f_khz`` (kHz) of ``bandwidth_hz`` (Hz), dB re 1 uPa."""
        if self.noise_level_db is not None:
            return float(self.noise_level_db)
        psd = self.noise_psd_db if self.noise_psd_db is not None else \
            float(noise_psd_db(f_khz, self.shipping, self.wind_mps))
        return float(psd + 10.0 * math.log10(bandwidth_hz))


@dataclass(frozen=True, kw_only=True)
class AcousticModemParams:
    """One modem mode: what it sends and how well it receives.

    Attributes (units):
        carrier_khz: centre frequency, kHz.
        bandwidth_hz: occupied / receiver bandwidth, Hz.
        bitrate_bps: raw bit rate on air, bit/s.
        source_level_db: source level, dB re 1 uPa @ 1 m.  Give this OR power_w.
        power_w: radiated acoustic power, W (SL = 170.8 + 10 log10 P).  Give this OR source_level_db.
        modulation: key of `MODULATIONS` (default "bpsk").
        directivity_index_db: receiver directivity index DI, dB (default 0: omnidirectional).
        implementation_loss_db: receiver implementation loss, dB, subtracted from Eb/N0 (and from the
            SINR-derived Eb/N0): synchronisation, equalisation, coding relative to the ideal formula.
        margin_db: receiver margin against ambient noise, dB: the noise this modem's receiver sees is the
            channel's (Wenz/Coates or fixed) noise raised by margin_db.  A lumped stand-in for everything
            the free-field AWGN model leaves out (multipath, fading, Doppler, implementation losses, platform
            noise, conservative ratings), NOT a physical noise level.  Acting on noise only, it sets the range
            but leaves the signal-to-interference ratio a strong frame needs to capture the receiver to the
            modulation itself; and being relative to the channel noise, wind, shipping or a fixed noise level
            still shift the range.  0 = ideal AWGN link; the presets calibrate it to their rated range (see
            `calibrate_margin` and docs/acoustic.md).
        name: a label.
        band_khz: (low, high) band edges, kHz, for documentation (None if not known).
        rated_range_m: the manufacturer's (or assumed) maximum range, m, for documentation and calibration.
        source: where each figure comes from, and which ones are assumptions.
    """

    carrier_khz: float
    bandwidth_hz: float
    bitrate_bps: float
    source_level_db: float | None = None
    power_w: float | None = None
    modulation: str = "bpsk"
    directivity_index_db: float = 0.0
    implementation_loss_db: float = 0.0
    margin_db: float = 0.0
    name: str = "custom"
    band_khz: tuple[float, float] | None = None
    rated_range_m: float | None = None
    source: str = ""

    def __post_init__(self) -> None:
        if (self.source_level_db is None) == (self.power_w is None):
            raise ValueError("give exactly one of source_level_db (dB re 1 uPa @ 1 m) and power_w (W)")
        if self.power_w is not None and self.power_w <= 0.0:
            raise ValueError(f"power_w must be > 0, got {self.power_w}")
        if self.carrier_khz <= 0.0 or self.bandwidth_hz <= 0.0 or self.bitrate_bps <= 0.0:
            raise ValueError("carrier_khz, bandwidth_hz and bitrate_bps must be > 0")
        if self.modulation not in MODULATIONS:
            raise ValueError(f"unknown modulation {self.modulation!r}; one of {sorted(MODULATIONS)}")

    @property
    def sl_db(self) -> float:
        """Source level, dB re 1 uPa @ 1 m (from power_w if that is what was given)."""
        if self.source_level_db is not None:
            return float(self.source_level_db)
        return float(source_level_db(self.power_w))


# ---------------------------------------------------------------------------------------------------
# The link
# ---------------------------------------------------------------------------------------------------
_SMALL = 48            # per(): up to this many distances, a Python loop over math is faster than numpy
_EBN0_CAP_DB = 3000.0  # 10^(0.1 x) stays finite


class AcousticLink(DistanceModel):
    """A modem mode in a given water: received level, SNR, BER and PER as functions of distance.

    Everything independent of distance is computed once here, so ``per(distance_m, size_bytes)`` (the
    simulator's per-frame call) is: TL = k 10 log10(d) + a d, Eb/N0 = const - TL, BER(Eb/N0), PER(BER).
    ``channel`` defaults to `AcousticChannelParams()`; ``modem`` may be an `AcousticModemParams` or the name
    of a preset.

    Noise at the receiver, dB re 1 uPa: NL = channel noise in the modem band + modem.margin_db.
    SNR = SL - TL - NL + DI;  Eb/N0 = SNR + 10 log10(B/R) - modem.implementation_loss_db.
    """

    __slots__ = ("channel", "modem", "c_mps", "alpha_db_per_km", "sl_db", "nl_db", "di_db", "bw_gain_db",
                 "_k10", "_alpha_per_m", "_ebn0_const", "_ber", "_ber1", "_noise_lin", "_sinr_to_ebn0")
    reports_power = True
    family = "acoustic"         # the channel model "acoustic" (phy.models.DistanceModel.from_context)

    def __init__(self, channel: AcousticChannelParams | None = None,
                 modem: AcousticModemParams | str = "evologics-s2cr-18-34") -> None:
        channel = AcousticChannelParams() if channel is None else channel
        modem = PRESETS[modem] if isinstance(modem, str) else modem
        self.channel = channel
        self.modem = modem
        self.c_mps = channel.sound_speed()
        self.alpha_db_per_km = float(channel.absorption_db_per_km(modem.carrier_khz))
        self.sl_db = modem.sl_db
        self.nl_db = (channel.noise_level_in_band_db(modem.carrier_khz, modem.bandwidth_hz)
                      + modem.margin_db)
        self.di_db = float(modem.directivity_index_db)
        self.bw_gain_db = 10.0 * math.log10(modem.bandwidth_hz / modem.bitrate_bps)
        self._k10 = 10.0 * channel.spreading_k
        self._alpha_per_m = self.alpha_db_per_km * 1e-3
        self._sinr_to_ebn0 = self.bw_gain_db - modem.implementation_loss_db
        # Eb/N0(d) = SL - TL(d) - NL + DI + 10log10(B/R) - implementation loss
        self._ebn0_const = self.sl_db - self.nl_db + self.di_db + self._sinr_to_ebn0
        self._ber = MODULATIONS[modem.modulation]
        self._ber1 = _BER_SCALAR[modem.modulation]
        # noise after the receiver's directivity (DI lowers isotropic noise), linear power re 1 uPa^2
        self._noise_lin = 10.0 ** ((self.nl_db - self.di_db) / 10.0)

    def __repr__(self) -> str:
        return f"AcousticLink({self.modem.name!r}, f={self.modem.carrier_khz} kHz, SL={self.sl_db:.1f} dB)"

    def sound_speed(self) -> float:
        """Sound speed in this water, m/s."""
        return self.c_mps

    def propagation_delay_s(self, distance_m: ArrayLike) -> ArrayLike:
        """Straight-line propagation delay, s: d / c."""
        return _out(_f(distance_m) / self.c_mps)

    def transmission_loss_db(self, distance_m: ArrayLike) -> ArrayLike:
        """TL at ``distance_m`` (m, clamped to >= 1 m), dB."""
        d = np.maximum(_f(distance_m), 1.0)
        return _out(self._k10 * np.log10(d) + self._alpha_per_m * d)

    def received_level_db(self, distance_m: ArrayLike) -> ArrayLike:
        """Received level RL = SL - TL, dB re 1 uPa."""
        return _out(self.sl_db - _f(self.transmission_loss_db(distance_m)))

    def levels(self, distances: Any) -> list[float]:
        """RL = SL - TL (dB re 1 uPa) at each distance (>= 1 m), a list: the model's levels, the trace's `level`."""
        ds = distances if isinstance(distances, list) else np.asarray(distances, dtype=float).ravel().tolist()
        sl, k10, a, log10 = self.sl_db, self._k10, self._alpha_per_m, math.log10
        return [sl - (k10 * log10(x) + a * x) for x in (d if d > 1.0 else 1.0 for d in ds)]

    def received_power(self, distance_m: ArrayLike) -> np.ndarray:
        """Received power, linear, uPa^2 (10^(RL/10)), at each distance (m, clamped to >= 1 m): a new array.

        The channel's SINR mode stores this per listener for every transmission."""
        d = np.maximum(np.asarray(distance_m, dtype=float), 1.0)
        return np.power(10.0, 0.1 * (self.sl_db - self._k10 * np.log10(d) - self._alpha_per_m * d))

    @property
    def noise_power(self) -> float:
        """Noise power at this modem's receiver, linear, uPa^2: 10^((NL - DI)/10), margin included."""
        return self._noise_lin

    def snr_db(self, distance_m: ArrayLike) -> ArrayLike:
        """In-band SNR = SL - TL - NL + DI, dB (NL includes the modem's margin)."""
        return _out(self.sl_db - _f(self.transmission_loss_db(distance_m)) - self.nl_db + self.di_db)

    def ebn0_db(self, distance_m: ArrayLike) -> ArrayLike:
        """Effective Eb/N0 = SNR + 10 log10(B/R) - implementation loss, dB."""
        return _out(self._ebn0_const - _f(self.transmission_loss_db(distance_m)))

    def ber(self, distance_m: ArrayLike) -> ArrayLike:
        """Bit error rate at ``distance_m`` (m)."""
        return self._ber(np.power(10.0, 0.1 * _f(self.ebn0_db(distance_m))))

    def per(self, distance_m: ArrayLike, size_bytes: int) -> ArrayLike:
        """Packet error rate of a ``size_bytes`` frame at ``distance_m`` (m): 1 - (1 - BER)^(8 L).  The
        simulator's per-frame call: ``distance_m`` is the array of listener distances."""
        d = np.asarray(distance_m, dtype=float)
        if d.size <= _SMALL:
            return self._per_small(d, size_bytes)
        d = np.maximum(d, 1.0)
        g = np.power(10.0, 0.1 * np.minimum(
            self._ebn0_const - self._k10 * np.log10(d) - self._alpha_per_m * d, _EBN0_CAP_DB))
        b = np.asarray(self._ber(g))
        with np.errstate(divide="ignore"):
            return _out(-np.expm1((8.0 * size_bytes) * np.log1p(-b)))

    def _per_small(self, d: np.ndarray, size_bytes: int) -> ArrayLike:
        c, k10, a, ber, n8 = self._ebn0_const, self._k10, self._alpha_per_m, self._ber1, 8.0 * size_bytes
        log10, expm1, log1p = math.log10, math.expm1, math.log1p
        out = []
        for x in d.ravel().tolist():
            x = x if x > 1.0 else 1.0
            e = c - k10 * log10(x) - a * x
            b = ber(10.0 ** (0.1 * (e if e < _EBN0_CAP_DB else _EBN0_CAP_DB)))
            out.append(1.0 if b >= 1.0 else -expm1(n8 * log1p(-b)))
        if d.ndim == 0:
            return np.float64(out[0])
        return np.array(out).reshape(d.shape)

    def sinr_db(self, signal_rl_db: ArrayLike, interferer_rl_dbs: ArrayLike = ()) -> ArrayLike:
        """Signal to interference-plus-noise ratio, dB, for capture decisions.

        ``signal_rl_db``: received level of the wanted frame, dB re 1 uPa.  ``interferer_rl_dbs``: received
        levels of the overlapping frames, dB re 1 uPa, summed over the last axis (an empty sequence gives
        the SNR).  Interference is added to the noise in linear power units; the directivity index lowers
        the (isotropic) noise only."""
        s = _f(signal_rl_db)
        i = _f(interferer_rl_dbs)
        interf = np.power(10.0, 0.1 * i).sum(axis=-1) if i.size else 0.0
        return _out(s - 10.0 * np.log10(self._noise_lin + interf))

    def per_from_sinr(self, sinr_db: ArrayLike, size_bytes: int) -> ArrayLike:
        """PER of a ``size_bytes`` frame received at ``sinr_db`` (dB), interference treated as Gaussian noise:
        ``per_from_sinr(sinr_db(received_level_db(d)), L) == per(d, L)``."""
        g = np.power(10.0, 0.1 * (_f(sinr_db) + self._sinr_to_ebn0))
        b = np.asarray(self._ber(g))
        with np.errstate(divide="ignore"):
            return _out(-np.expm1((8.0 * size_bytes) * np.log1p(-b)))

    def distance_for_per(self, target_per: float = 0.5, size_bytes: int = 64, lo_m: float = 1.0,
                         hi_m: float = 1e6) -> float:
        """The distance (m) at which the PER of ``size_bytes`` frames reaches ``target_per`` (bisection).
        PER increases monotonically with distance; returns ``hi_m`` if the target is never reached."""
        if float(self.per(hi_m, size_bytes)) < target_per:
            return hi_m
        lo, hi = math.log(lo_m), math.log(hi_m)
        for _ in range(80):
            mid = 0.5 * (lo + hi)
            if float(self.per(math.exp(mid), size_bytes)) < target_per:
                lo = mid
            else:
                hi = mid
        return math.exp(0.5 * (lo + hi))


def calibrate_margin(modem: AcousticModemParams, channel: AcousticChannelParams | None = None,
                           range_m: float | None = None, target_per: float = 0.1,
                           size_bytes: int = 64) -> float:
    """The margin (dB) that makes ``modem`` reach PER = ``target_per`` on ``size_bytes`` frames at
    ``range_m`` (default: its rated range) in ``channel`` (default: `AcousticChannelParams()`).

    A negative result means the ideal model is pessimistic for that modem.
    """
    range_m = modem.rated_range_m if range_m is None else range_m
    if range_m is None:
        raise ValueError("no range given and the modem has no rated_range_m")
    ideal = AcousticLink(channel, replace(modem, margin_db=0.0))
    return float(ideal.ebn0_db(range_m)) - required_ebn0_db(modem.modulation, target_per, size_bytes)


# ---------------------------------------------------------------------------------------------------
# Presets
# ---------------------------------------------------------------------------------------------------
# Each preset's margin_db is calibrate_margin(preset) (PER 10 % on 64-byte frames at the rated range, default
# channel: Thorp, k = 1.5, shipping 0.5, wind 0), rounded to 0.1 dB; tests/test_acoustic.py checks they stay
# in step with the model.  It is tens of dB because with these source levels the free-field AWGN model
# reaches 8-27 km whatever the rated range: the ratings are set by multipath, fading, Doppler and caution,
# not by ambient noise (docs/acoustic.md, "The presets' margin", has the per-preset breakdown).
_CALIBRATION = ("margin_db calibrated so that PER(64 B) = 10 % at the rated range in the default "
                "channel (Thorp, k = 1.5, shipping 0.5, wind 0 m/s).")

PRESETS: dict[str, AcousticModemParams] = {
    "evologics-s2cr-18-34": AcousticModemParams(
        name="EvoLogics S2CR 18/34", band_khz=(18.0, 34.0), carrier_khz=26.0, bandwidth_hz=16_000.0,
        bitrate_bps=13_900.0, power_w=35.0, modulation="dpsk", rated_range_m=3_500.0,
        margin_db=37.8,
        source=("Band 18-34 kHz, up to 13.9 kbit/s, range 3500 m, transmit power 2.8 W (1000 m) to 35 W "
                "(3500 m): EvoLogics S2CR 18/34 product information sheet (evologics.de/files/DataSheets/"
                "EvoLogics_S2CR_1834_Product_Information.pdf), as quoted in public repositories; not read "
                "first-hand.  Carrier = band centre.  Source level: not published; ASSUMED 170.8 + "
                "10 log10(35 W) = 186.2 dB re 1 uPa @ 1 m, i.e. the 35 W transmit consumption taken as "
                "radiated power (an upper bound; the modem steps its SL down by 6/12/20 dB).  Modulation: "
                "the proprietary sweep-spread-carrier (S2C) waveform is modelled as DPSK. " + _CALIBRATION)),
    "evologics-s2cr-7-17": AcousticModemParams(
        name="EvoLogics S2CR 7/17", band_khz=(7.0, 17.0), carrier_khz=12.0, bandwidth_hz=10_000.0,
        bitrate_bps=6_900.0, source_level_db=186.2, modulation="dpsk", rated_range_m=8_000.0,
        margin_db=39.3,
        source=("Band 7-17 kHz, up to 6.9 kbit/s, range 8000 m: EvoLogics S2CR 7/17 product information, "
                "as quoted in public comparison tables; not read first-hand.  Carrier = band centre.  "
                "Source level: not published; ASSUMED equal to the 18/34 preset (186.2 dB re 1 uPa @ 1 m).  "
                "Modulation: S2C modelled as DPSK. " + _CALIBRATION)),
    "whoi-micromodem": AcousticModemParams(
        name="WHOI Micro-Modem FH-FSK 80 bps", band_khz=(23.0, 27.0), carrier_khz=25.0, bandwidth_hz=4_000.0,
        bitrate_bps=80.0, source_level_db=185.0, modulation="bfsk_noncoherent", rated_range_m=8_000.0,
        margin_db=24.3,
        source=("80 bps FH-FSK in a 4 kHz band (data rates 80-5400 bps; FSK BW = 4 kHz, PSK BW = 5 kHz): "
                "acomms.whoi.edu/micro-modem.  Carrier 25 kHz: the common band of the Micro-Modem, which "
                "can be configured in four bands between 3 and 30 kHz (Freitag et al., 'The WHOI "
                "Micro-Modem: an acoustic communications and navigation system for multiple platforms', "
                "OCEANS 2005).  Source level: depends on the power amplifier and transducer chosen, not on "
                "the public pages; ASSUMED 185 dB re 1 uPa @ 1 m.  Range: WHOI publishes none; ASSUMED "
                "8000 m for the robust FSK mode.  Modulation: non-coherent BFSK. " + _CALIBRATION)),
    "whoi-micromodem-psk5400": AcousticModemParams(
        name="WHOI Micro-Modem PSK 5400 bps", band_khz=(22.5, 27.5), carrier_khz=25.0, bandwidth_hz=5_000.0,
        bitrate_bps=5_400.0, source_level_db=185.0, modulation="bpsk", rated_range_m=2_500.0,
        margin_db=51.2,
        source=("5400 bps PSK (highest Micro-Modem rate), 5 kHz band: acomms.whoi.edu/micro-modem.  "
                "Carrier 25 kHz and SL 185 dB re 1 uPa @ 1 m ASSUMED as for the FSK preset.  Range: ASSUMED "
                "2500 m, after Frye et al., 'An acoustically-linked deep-ocean observatory' (OCEANS 2005), "
                "where 5000 bps Micro-Modems link instruments on the sea floor at 2362 m to a buoy.  "
                "Modulation: coded PSK modelled as uncoded BPSK. " + _CALIBRATION)),
    "seatrac-x150": AcousticModemParams(
        name="Blueprint Subsea SeaTrac X150", band_khz=(24.0, 32.0), carrier_khz=28.0, bandwidth_hz=8_000.0,
        bitrate_bps=100.0, source_level_db=176.0, modulation="dpsk", rated_range_m=1_000.0,
        margin_db=73.1,
        source=("Band 24-32 kHz and 1000 m range: Blueprint Subsea SeaTrac X150 datasheet, as quoted "
                "in public project documentation; not read first-hand.  100 bit/s: SeaTrac Serial "
                "Command Interface Reference (UM-140-D00221), CID_DAT_SEND: 'larger quantities of data "
                "will take longer to send (by 80ms per byte)'.  Carrier = band centre.  Source level: not "
                "in the sources we could read; ASSUMED 176 dB re 1 uPa @ 1 m (cf. 175 dB at ~2 W for the "
                "Diver6 modem's manual and ~168 dB for the Newcastle nanomodem V3, same 24-32 kHz band).  "
                "Modulation: the broadband spread-spectrum waveform is modelled as DPSK. " + _CALIBRATION)),
}
"""Named modem presets; see docs/acoustic.md for the table and the sources."""


class FixedBerLink(DistanceModel):
    """An `AcousticLink` whose noise-limited bit error rate is a constant (legacy ``bitErrorRate``).

    per(d, L) = 1 - (1 - BER)^(8L) at every distance; the received power, the noise and PER from SINR
    (capture) stay the physics of the wrapped link, with PER(SINR) never below the fixed PER."""

    __slots__ = ("link", "ber")
    reports_power = True
    family = "acoustic"

    def __init__(self, link: AcousticLink, ber: float) -> None:
        self.link = link
        self.ber = float(ber)

    def __repr__(self) -> str:
        return f"FixedBerLink({self.link!r}, ber={self.ber:g})"

    def per(self, distance_m: np.ndarray | float, size_bytes: int) -> np.ndarray:
        return np.full(np.shape(distance_m), float(per_from_ber(self.ber, size_bytes)))

    def received_power(self, distance_m: np.ndarray | float) -> np.ndarray:
        return self.link.received_power(distance_m)

    def levels(self, distance_m: Any) -> list[float]:
        return self.link.levels(distance_m)

    @property
    def noise_power(self) -> float:
        return self.link.noise_power

    def per_from_sinr(self, sinr_db: float, size_bytes: int) -> float:
        return max(float(per_from_ber(self.ber, size_bytes)), float(self.link.per_from_sinr(sinr_db, size_bytes)))
