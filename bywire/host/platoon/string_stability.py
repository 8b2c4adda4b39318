"""String-stability estimate of a recorded or simulated platoon (seed 003, Sec. V-D).

Seed 003 Sec. V-D argues that, with enough slack in the lock on the leader, "platoon stability directly
follows from the stability of the follow controller" (Sec. V-C) and gives no number for it. Deviation:
we quantify string stability the usual way (Ploeg et al., IEEE T-ITS 15(2), 2014): the H-infinity norm
of the error propagation transfer function between successive vehicles, here estimated from data as the
peak over the excited band of |H_i(f)|, H_i the transfer function from vehicle i-1's acceleration (or
speed) to vehicle i's. A string is stable when every ratio is <= 1.

Estimator: the H1 transfer estimate |H_i(f)| = |S_(i-1)i(f)| / S_(i-1)(i-1)(f) from Welch cross and
auto spectra (scipy.signal.csd / welch, Hann window, 50 % overlap). Why H1 and not sqrt(S_ii/S_(i-1)(i-1)):
noise that is uncorrelated with the predecessor (GNSS speed noise of the follower, its own driver or
road disturbances) adds to S_ii and inflates the autospectral ratio, i.e. would report instability that
is not propagated; it averages out of the cross spectrum. H1 is biased low by noise on the predecessor's
signal instead, so the coherence at the peak is reported with every pair to judge that.

Excited band rule: on the leader's (first vehicle's) acceleration PSD restricted to 0.01-1 Hz, the band
between the 5 % and 95 % points of the cumulative power, i.e. the central band holding 90 % of the
leader's acceleration power. Outside it the leader hardly excites the string and |H| is noise / noise.
Acceleration is used for the band even when the ratio is computed on speed: both give the same H.

Loader: `host.platoon.platoon_csv.load_platoon_csv` (every published OpenACC and CARMA layout, told apart
by the header; gaps, row order and the acceleration OpenACC lacks are handled there, see its notes).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy import signal as sps

from bywire.host.platoon.platoon_csv import (
    ACCEL_LOWPASS_HZ,
    MAX_GAP_S,
    MIN_DURATION_S,
    FloatArray,
    Platoon,
    PlatoonCsvError,
    Vehicle,
    differentiate_speed,
    load_platoon_csv,
)

SignalName = Literal["accel", "speed"]

# Welch segment length: 0.02 Hz resolution, enough to resolve a |H| peak of a car-following loop
# (bandwidths ~0.1-0.5 Hz) while averaging >= 10 segments on a 5 min record. Shorter records use half
# their length (see _welch_nperseg).
WELCH_SEGMENT_S = 50.0
DEFAULT_SEARCH_BAND_HZ = (0.01, 1.0)
BAND_POWER_FRACTION = 0.9


@dataclass(frozen=True)
class PairResult:
    leader: str
    follower: str
    ratio: float  # peak |H1| over the band
    peak_hz: float
    coherence_at_peak: float
    gain: FloatArray  # |H1(f)| on Result.freq_hz


@dataclass(frozen=True)
class Result:
    string_stability: float  # worst (largest) pair ratio
    band_hz: tuple[float, float]
    signal: SignalName
    freq_hz: FloatArray
    leader_psd: FloatArray  # leader's PSD of `signal`, for plotting
    pairs: tuple[PairResult, ...]


# ---------------------------------------------------------------------------------------------- estimate


def _welch_nperseg(n_samples: int, dt_s: float) -> int:
    # At least three half-overlapping segments: with a single segment H1 degenerates to a ratio of two DFTs
    # and the coherence is identically 1, hiding how little the estimate can be trusted (AstaZero cut, 30 s).
    return int(min(n_samples // 2, round(WELCH_SEGMENT_S / dt_s)))


def excited_band(
    freq_hz: FloatArray,
    leader_accel_psd: FloatArray,
    search_hz: tuple[float, float] = DEFAULT_SEARCH_BAND_HZ,
    fraction: float = BAND_POWER_FRACTION,
) -> tuple[float, float]:
    """Central band holding `fraction` of the leader's acceleration power inside search_hz (see module doc).
    The lower search edge is raised to the first non-zero frequency bin (DC carries the mean, not motion)."""
    sel = (freq_hz >= search_hz[0]) & (freq_hz <= search_hz[1]) & (freq_hz > 0)
    f, p = freq_hz[sel], leader_accel_psd[sel]
    if f.size < 2 or not np.isfinite(p).all() or p.sum() <= 0:
        raise ValueError(f"no leader power to define an excited band in {search_hz} Hz")
    cum = np.cumsum(p) / p.sum()
    tail = 0.5 * (1.0 - fraction)
    lo = int(np.searchsorted(cum, tail))
    hi = min(int(np.searchsorted(cum, 1.0 - tail)), f.size - 1)
    if hi <= lo:
        hi = min(lo + 1, f.size - 1)
        lo = hi - 1
    return float(f[lo]), float(f[hi])


def string_stability(
    platoon: Platoon, signal: SignalName = "accel", band_hz: tuple[float, float] | None = None
) -> Result:
    """Peak H1 gain over the excited band for every successive pair; the worst is `string_stability`."""
    if len(platoon.vehicles) < 2:
        raise ValueError("need at least two vehicles")
    dt_s = platoon.sample_period_s
    fs_hz = 1.0 / dt_s
    n = platoon.time_s.size
    nperseg = _welch_nperseg(n, dt_s)
    # Linear detrend: a ramp in speed (a steady acceleration) would otherwise leak into the lowest bins.
    kw = {"fs": fs_hz, "window": "hann", "nperseg": nperseg, "noverlap": nperseg // 2, "detrend": "linear"}

    def series(v: Vehicle) -> FloatArray:
        return v.accel_mps2 if signal == "accel" else v.speed_mps

    freq_hz, leader_acc_psd = sps.welch(platoon.vehicles[0].accel_mps2, **kw)  # type: ignore[arg-type]
    band = band_hz if band_hz is not None else excited_band(freq_hz, leader_acc_psd)
    if not band[0] < band[1]:
        raise ValueError(f"band {band} Hz: low edge must be below high edge")
    in_band = (freq_hz >= band[0]) & (freq_hz <= band[1])
    if not in_band.any():
        raise ValueError(f"band {band} Hz holds no frequency bin (resolution {freq_hz[1]:.3f} Hz)")

    pairs: list[PairResult] = []
    for prev, cur in zip(platoon.vehicles[:-1], platoon.vehicles[1:], strict=True):
        x, y = series(prev), series(cur)
        _, s_xx = sps.welch(x, **kw)  # type: ignore[arg-type]
        _, s_yy = sps.welch(y, **kw)  # type: ignore[arg-type]
        _, s_xy = sps.csd(x, y, **kw)  # type: ignore[arg-type]
        with np.errstate(divide="ignore", invalid="ignore"):
            gain = np.abs(s_xy) / s_xx
            coh = np.abs(s_xy) ** 2 / (s_xx * s_yy)
        g_band = np.where(in_band, gain, -np.inf)
        k = int(np.argmax(g_band))
        pairs.append(
            PairResult(
                prev.name, cur.name, float(gain[k]), float(freq_hz[k]), float(coh[k]), gain.astype(np.float64)
            )
        )
    speed_psd = sps.welch(platoon.vehicles[0].speed_mps, **kw)[1]  # type: ignore[arg-type]
    plot_psd = leader_acc_psd if signal == "accel" else speed_psd
    return Result(
        string_stability=max(p.ratio for p in pairs),
        band_hz=(float(band[0]), float(band[1])),
        signal=signal,
        freq_hz=np.asarray(freq_hz, dtype=np.float64),
        leader_psd=np.asarray(plot_psd, dtype=np.float64),
        pairs=tuple(pairs),
    )


# ---------------------------------------------------------------------------------------------- synthetic


def cth_follower_tf(
    headway_s: float, kp_per_s2: float, kd_per_s: float, lag_s: float
) -> tuple[FloatArray, FloatArray]:
    """Transfer function a_(i-1) -> a_i (numerator, denominator in s) of a constant-time-headway follower.

    Double integrator with first-order actuator lag, lag_s a' + a = u, and PD spacing control
    u = kp e + kd e', e = x_(i-1) - x_i - r - headway_s v_i. Laplace:
    H(s) = (kd s + kp) / (lag_s s^3 + (1 + kd h) s^2 + (kd + kp h) s + kp).
    """
    num = np.array([kd_per_s, kp_per_s2], dtype=np.float64)
    den = np.array(
        [lag_s, 1.0 + kd_per_s * headway_s, kd_per_s + kp_per_s2 * headway_s, kp_per_s2], dtype=np.float64
    )
    return num, den


def hinf_norm(
    num: FloatArray, den: FloatArray, band_hz: tuple[float, float] = (1e-4, 10.0), n: int = 20000
) -> tuple[float, float]:
    """Peak |H(j 2 pi f)| over band_hz on a dense log grid; returns (gain, frequency in Hz)."""
    f_hz = np.geomspace(band_hz[0], band_hz[1], n)
    _, h = sps.freqs(num, den, worN=2 * np.pi * f_hz)
    k = int(np.argmax(np.abs(h)))
    return float(np.abs(h[k])), float(f_hz[k])


def linear_chain_platoon(
    leader_accel_mps2: FloatArray,
    dt_s: float,
    num: FloatArray,
    den: FloatArray,
    n_followers: int,
    leader_speed0_mps: float = 20.0,
    speed_noise_mps: float = 0.0,
    seed: int = 0,
) -> Platoon:
    """Synthetic platoon: every follower's acceleration is its predecessor's passed through num/den
    (Tustin-discretised); speeds are integrated (and optionally corrupted by white noise, the GNSS case,
    in which case the accelerations are re-differentiated from the noisy speed like OpenACC's)."""
    b, a, _ = sps.cont2discrete((num, den), dt_s, method="bilinear")
    rng = np.random.default_rng(seed)
    accels = [np.asarray(leader_accel_mps2, dtype=np.float64)]
    for _ in range(n_followers):
        accels.append(np.asarray(sps.lfilter(np.ravel(b), a, accels[-1]), dtype=np.float64))
    time_s = dt_s * np.arange(accels[0].size, dtype=np.float64)
    vehicles = []
    for i, acc in enumerate(accels):
        speed = leader_speed0_mps + np.concatenate([[0.0], np.cumsum(0.5 * (acc[1:] + acc[:-1])) * dt_s])
        if speed_noise_mps > 0:
            speed = speed + rng.normal(0.0, speed_noise_mps, speed.size)
            vehicles.append(Vehicle(str(i + 1), speed, differentiate_speed(speed, dt_s), False))
        else:
            vehicles.append(Vehicle(str(i + 1), speed, acc, True))
    return Platoon("synthetic", "synthetic", time_s, tuple(vehicles))


def band_limited_noise(
    duration_s: float, dt_s: float, band_hz: tuple[float, float], rms_mps2: float = 0.5, seed: int = 0
) -> FloatArray:
    """Leader acceleration: white noise band-passed (4th-order Butterworth, zero phase) to band_hz."""
    rng = np.random.default_rng(seed)
    n = round(duration_s / dt_s)
    b, a = sps.butter(4, [band_hz[0] * 2 * dt_s, band_hz[1] * 2 * dt_s], btype="band")
    x = sps.filtfilt(b, a, rng.normal(size=n))
    return np.asarray(rms_mps2 * x / np.std(x), dtype=np.float64)


# The loader moved to platoon_csv; its names stay importable from here for the estimator's callers.
__all__ = [
    "ACCEL_LOWPASS_HZ",
    "MAX_GAP_S",
    "MIN_DURATION_S",
    "FloatArray",
    "PairResult",
    "Platoon",
    "PlatoonCsvError",
    "Result",
    "SignalName",
    "Vehicle",
    "band_limited_noise",
    "cth_follower_tf",
    "differentiate_speed",
    "excited_band",
    "hinf_norm",
    "linear_chain_platoon",
    "load_platoon_csv",
    "string_stability",
]
