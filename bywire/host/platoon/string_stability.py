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

Loader: OpenACC ZalaZone (5 metadata lines, then Time, Speed<k>, E<k>, ... IVS<k>), the OpenACC AstaZero
cut (Time, Speed_1..Speed_N) and the CARMA FHWA 2018 table (<vehicle>_avg_speed_driven_wheels,
<vehicle>_acceleration) are told apart by their header. OpenACC has no acceleration; it is
differentiated from the GNSS speed after a zero-phase 2nd-order Butterworth low-pass at 2 Hz (the band of
interest ends at 1 Hz; the same linear filter on both vehicles cancels in H anyway, it only removes noise
from the band edges). Gaps of missing samples up to MAX_GAP_S are interpolated linearly; a longer gap cuts
the record, keeping the longest stretch where every vehicle has data (the cut is reported in
Platoon.notes). A vehicle without any data is dropped (noted); in OpenACC the platoon order is the
vehicle index, so a pair may then span a missing car, which the pair names show.
"""

from __future__ import annotations

import csv
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import numpy.typing as npt
from scipy import signal as sps

FloatArray = npt.NDArray[np.float64]
SignalName = Literal["accel", "speed"]

# Longest run of missing samples bridged by linear interpolation: 1 s is ~ one period of the fastest
# motion in the band (1 Hz); longer holes would invent the dynamics we are trying to measure.
MAX_GAP_S = 1.0
# Shortest record worth a spectral estimate: four 50 s segments would be ideal, but the AstaZero cut is
# 30 s long; below 20 s the lowest resolvable frequency (1/T) climbs above most of the excited band.
MIN_DURATION_S = 20.0
# Welch segment length: 0.02 Hz resolution, enough to resolve a |H| peak of a car-following loop
# (bandwidths ~0.1-0.5 Hz) while averaging >= 10 segments on a 5 min record. Shorter records use half
# their length (see _welch_nperseg).
WELCH_SEGMENT_S = 50.0
DEFAULT_SEARCH_BAND_HZ = (0.01, 1.0)
BAND_POWER_FRACTION = 0.9
ACCEL_LOWPASS_HZ = 2.0

OPENACC_METADATA_LINES = 5
_CARMA_VEHICLES = ("leader", "follower1", "follower2", "follower3", "follower4")


class PlatoonCsvError(ValueError):
    """A platoon CSV that cannot be read; the message names file, line and column."""


@dataclass(frozen=True)
class Vehicle:
    name: str
    speed_mps: FloatArray
    accel_mps2: FloatArray
    accel_from_file: bool


@dataclass(frozen=True)
class Platoon:
    """Vehicles leader first, all sampled on the common uniform grid time_s."""

    source: str
    layout: str
    time_s: FloatArray
    vehicles: tuple[Vehicle, ...]
    notes: tuple[str, ...] = ()

    @property
    def sample_period_s(self) -> float:
        return float(self.time_s[1] - self.time_s[0])


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


# ---------------------------------------------------------------------------------------------- loading


def _parse_float(text: str, path: Path, line: int, column: str) -> float:
    text = text.strip()
    if text == "":
        return math.nan
    try:
        return float(text)
    except ValueError:
        raise PlatoonCsvError(f"{path}:{line}: column {column!r}: not a number: {text!r}") from None


def _read_table(
    path: Path,
    rows: list[list[str]],
    header: list[str],
    first_line: int,
    wanted: dict[str, str],
    notes: list[str],
) -> tuple[FloatArray, dict[str, FloatArray]]:
    """Parse the columns named in `wanted` (column -> key); return time and key -> values (NaN = missing).
    Appends what it repaired to `notes`."""
    index = {name.strip(): j for j, name in enumerate(header)}
    for col in ["Time", *wanted]:
        if col not in index:
            raise PlatoonCsvError(f"{path}:{first_line - 1}: header lacks column {col!r}")
    n_cols = len(header)
    times: list[float] = []
    lines: list[int] = []
    values: dict[str, list[float]] = {key: [] for key in wanted.values()}
    for k, row in enumerate(rows):
        line = first_line + k
        if not row or all(not f.strip() for f in row):
            continue  # blank line (e.g. at the end of the file)
        if len(row) < n_cols:
            raise PlatoonCsvError(
                f"{path}:{line}: {len(row)} fields, header has {n_cols} (truncated row; "
                f"first missing column {header[len(row)].strip()!r})"
            )
        t = _parse_float(row[index["Time"]], path, line, "Time")
        if math.isnan(t):
            raise PlatoonCsvError(f"{path}:{line}: column 'Time': empty")
        times.append(t)
        lines.append(line)
        for col, key in wanted.items():
            values[key].append(_parse_float(row[index[col]], path, line, col))
    if len(times) < 2:
        raise PlatoonCsvError(f"{path}: fewer than two data rows")
    t_s = np.asarray(times)
    # The CARMA table holds a few rows stored out of time order (e.g. the row for 45.0 s between 42.5 and
    # 42.6 s) whose values fit their time stamp: sort them back into place and say so. Two rows with the
    # same time stamp cannot be ordered and are an error.
    order = np.argsort(t_s, kind="stable")
    n_moved = int((np.diff(t_s) < 0).sum())
    if n_moved:
        first_bad = lines[int(np.argmax(np.diff(t_s) <= 0)) + 1]
        notes.append(f"{n_moved} breaks in time order, rows sorted back (first at line {first_bad})")
    t_sorted = t_s[order]
    dup = np.flatnonzero(np.diff(t_sorted) <= 0)
    if dup.size:
        k = int(order[dup[0] + 1])
        raise PlatoonCsvError(f"{path}:{lines[k]}: column 'Time': {t_s[k]} repeats an earlier time stamp")
    return t_sorted, {key: np.asarray(v)[order] for key, v in values.items()}


def _resample(
    t_raw_s: FloatArray, x_raw: FloatArray, grid_s: FloatArray, max_gap_s: float
) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
    """Linear interpolation onto grid_s; a grid point is invalid where the bracketing valid raw samples are
    further apart than max_gap_s (a long hole) or outside the valid span."""
    ok = np.isfinite(x_raw)
    t_ok, x_ok = t_raw_s[ok], x_raw[ok]
    if t_ok.size < 2:
        return np.full(grid_s.shape, math.nan), np.zeros(grid_s.shape, dtype=bool)
    x = np.interp(grid_s, t_ok, x_ok)
    j = np.clip(np.searchsorted(t_ok, grid_s), 1, t_ok.size - 1)
    # A tolerance of a thousandth of a step keeps regular samples (gap == one step) valid despite rounding.
    valid = (
        (t_ok[j] - t_ok[j - 1] <= max_gap_s + 1e-9) & (grid_s >= t_ok[0] - 1e-9) & (grid_s <= t_ok[-1] + 1e-9)
    )
    return x, valid


def _longest_true_run(mask: npt.NDArray[np.bool_]) -> tuple[int, int]:
    """[start, stop) of the longest run of True."""
    best = (0, 0)
    start = -1
    for k, m in enumerate([*mask.tolist(), False]):
        if m and start < 0:
            start = k
        elif not m and start >= 0:
            if k - start > best[1] - best[0]:
                best = (start, k)
            start = -1
    return best


def differentiate_speed(speed_mps: FloatArray, dt_s: float) -> FloatArray:
    """Acceleration from a speed record: zero-phase low-pass (ACCEL_LOWPASS_HZ) then central differences."""
    nyquist_hz = 0.5 / dt_s
    if nyquist_hz > ACCEL_LOWPASS_HZ and speed_mps.size > 15:
        b, a = sps.butter(2, ACCEL_LOWPASS_HZ / nyquist_hz)
        speed_mps = sps.filtfilt(b, a, speed_mps)
    return np.asarray(np.gradient(speed_mps, dt_s), dtype=np.float64)


def _build_platoon(
    path: Path,
    layout: str,
    t_raw_s: FloatArray,
    names: list[str],
    speeds: list[FloatArray],
    accels: list[FloatArray | None],
    notes: list[str],
) -> Platoon:
    dt_s = float(np.median(np.diff(t_raw_s)))
    grid_s = t_raw_s[0] + dt_s * np.arange(math.floor((t_raw_s[-1] - t_raw_s[0]) / dt_s + 1e-6) + 1)
    kept: list[tuple[str, FloatArray, FloatArray | None]] = []
    valid_all = np.ones(grid_s.shape, dtype=bool)
    for name, v_raw, a_raw in zip(names, speeds, accels, strict=True):
        if not np.isfinite(v_raw).any():
            notes.append(f"vehicle {name}: no speed samples, dropped")
            continue
        v, ok = _resample(t_raw_s, v_raw, grid_s, MAX_GAP_S)
        a: FloatArray | None = None
        if a_raw is not None:
            a, ok_a = _resample(t_raw_s, a_raw, grid_s, MAX_GAP_S)
            ok &= ok_a
        if not ok.all():
            notes.append(f"vehicle {name}: {int((~ok).sum())} samples in gaps > {MAX_GAP_S} s")
        valid_all &= ok
        kept.append((name, v, a))
    if len(kept) < 2:
        raise PlatoonCsvError(f"{path}: fewer than two vehicles with data")
    start, stop = _longest_true_run(valid_all)
    if stop - start < grid_s.size:
        notes.append(
            f"record cut to {grid_s[start] - grid_s[0]:.1f}-{grid_s[stop - 1] - grid_s[0]:.1f} s "
            f"(longest stretch without a gap > {MAX_GAP_S} s in any vehicle)"
        )
    if (stop - start - 1) * dt_s < MIN_DURATION_S:
        raise PlatoonCsvError(
            f"{path}: only {(stop - start - 1) * dt_s:.1f} s without gaps > {MAX_GAP_S} s, "
            f"need {MIN_DURATION_S} s"
        )
    vehicles = []
    for name, v, a in kept:
        v = v[start:stop]
        from_file = a is not None
        acc = a[start:stop] if a is not None else differentiate_speed(v, dt_s)
        vehicles.append(Vehicle(name, v, acc, from_file))
    # Re-derive the time axis from the index: subtracting large absolute stamps (12643 s) leaves float dust.
    time_s = dt_s * np.arange(stop - start, dtype=np.float64)
    return Platoon(str(path), layout, time_s, tuple(vehicles), tuple(notes))


def load_platoon_csv(path: str | Path) -> Platoon:
    """Load an OpenACC (ZalaZone or AstaZero cut) or CARMA platoon CSV; layout detected from the header."""
    path = Path(path)
    with path.open(newline="", encoding="utf-8-sig") as fh:
        rows = list(csv.reader(fh))
    notes: list[str] = []
    if not rows:
        raise PlatoonCsvError(f"{path}:1: empty file")
    first = [f.strip() for f in rows[0]]

    # CARMA also starts with a 'Date' column, so it is recognised first, by its per-vehicle columns.
    if first and first[0] == "Date" and "Time" not in first and len(rows) > OPENACC_METADATA_LINES:
        # OpenACC ZalaZone: Date / Vehicle_order / Number_of_vehicles / ACC / Distance_setting, then header.
        order = (
            [f.strip() for f in rows[1][1:] if f.strip()] if rows[1] and rows[1][0] == "Vehicle_order" else []
        )
        header = [f.strip() for f in rows[OPENACC_METADATA_LINES]]
        if not header or header[0] != "Time":
            raise PlatoonCsvError(
                f"{path}:{OPENACC_METADATA_LINES + 1}: expected the OpenACC header 'Time,Speed1,...', "
                f"got {','.join(header[:3])!r}"
            )
        indices = sorted(int(m.group(1)) for c in header if (m := re.fullmatch(r"Speed(\d+)", c)))
        t, cols = _read_table(
            path,
            rows[OPENACC_METADATA_LINES + 1 :],
            header,
            OPENACC_METADATA_LINES + 2,
            {f"Speed{k}": str(k) for k in indices},
            notes,
        )
        names = [f"{k}:{order[k - 1]}" if k <= len(order) else str(k) for k in indices]
        return _build_platoon(
            path, "openacc_zalazone", t, names, [cols[str(k)] for k in indices], [None] * len(indices), notes
        )

    if first and first[0] == "Time" and any(re.fullmatch(r"Speed_\d+", c) for c in first):
        indices = sorted(int(m.group(1)) for c in first if (m := re.fullmatch(r"Speed_(\d+)", c)))
        t, cols = _read_table(path, rows[1:], first, 2, {f"Speed_{k}": str(k) for k in indices}, notes)
        return _build_platoon(
            path,
            "openacc_astazero",
            t,
            [str(k) for k in indices],
            [cols[str(k)] for k in indices],
            [None] * len(indices),
            notes,
        )

    if "Time" in first and "leader_acceleration" in first:
        present = [v for v in _CARMA_VEHICLES if f"{v}_avg_speed_driven_wheels" in first]
        wanted: dict[str, str] = {}
        for v in present:
            wanted[f"{v}_avg_speed_driven_wheels"] = f"{v}_v"
            wanted[f"{v}_acceleration"] = f"{v}_a"
        t, cols = _read_table(path, rows[1:], first, 2, wanted, notes)
        return _build_platoon(
            path,
            "carma",
            t,
            present,
            [cols[f"{v}_v"] for v in present],
            [cols[f"{v}_a"] for v in present],
            notes,
        )

    raise PlatoonCsvError(
        f"{path}:1: unknown platoon CSV layout (expected OpenACC ZalaZone 'Date,...' metadata, "
        f"OpenACC AstaZero 'Time,Speed_1,...' or CARMA '...,leader_acceleration,...'); "
        f"got {','.join(first[:4])!r}"
    )


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
