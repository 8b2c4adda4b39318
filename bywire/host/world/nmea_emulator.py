"""GPS/INS receiver emulator for the HIL plant: the NMEA byte stream a receiver would send for a true state.

`ReceiverEmulator.update(t_s, truth)` is called by the plant at its own step (faster than the sentence
rates) with the true state of the car on the local plane; it returns the bytes the receiver has put on
the line by t_s. Epoch k of a sentence with rate f is at k / f (receivers align to the GPS second); every
epoch in (previous call, t_s] is emitted, described by the truth handed in by the call that reaches it (the
plant's step, 10 ms, bounds that error). Sentences leave `latency_s` after their epoch, in epoch order.

Errors, deterministic for a seed (numpy's PCG64):

- position: white noise plus a slowly drifting bias per fix type — a first-order Gauss-Markov process per
  axis, ``b_k+1 = exp(-dt/tau) b_k + sqrt(1 - exp(-2 dt/tau)) sigma_b n_k`` — stepped at every GGA epoch
  for every fix type at once, so that a fix type coming back brings its own, continued bias (as the
  correction stream's geometry does). Defaults (1-sigma per axis): RTK fixed 1 cm white + 1 cm bias,
  RTK float 10 + 20 cm, DGPS 30 + 50 cm, GPS 1 + 1.5 m.
- heading (HDT) white noise 0.1 deg (seed 000 Sec. 2.3); speed over ground 0.05 m/s; course over ground
  from the velocity noise (speed noise / speed).
- `Outage` periods: ``rtk_loss`` (the fix degrades to `Outage.quality`, RTK float by default),
  ``no_fix`` (GGA quality 0 with empty fields, RMC status V, empty HDT), ``frozen`` (the receiver repeats
  its last fix: position, quality, speed and heading frozen, the UTC time still advancing unless
  `Outage.freeze_time`): seed 003 Sec. VI's bridge.
- `byte_error_rate`: each byte sent is replaced by a random one with this probability (line noise).

The configured sentence rates must fit the serial line (`baud`, 10 bits a byte) with 25 % headroom;
otherwise `EmulatorConfig` raises: a real receiver would silently drop sentences.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from bywire.host.geo import LocalFrame

from .nmea import KNOT_MPS, FixQuality, with_checksum

OutageKind = Literal["rtk_loss", "no_fix", "frozen"]
# Typical lengths of our sentences in bytes with CR LF, for the line budget.
_SENTENCE_BYTES = {"GGA": 82, "RMC": 76, "VTG": 44, "HDT": 20, "GST": 62}


@dataclass(frozen=True)
class FixNoise:
    white_std_m: float
    bias_std_m: float
    bias_tau_s: float


def default_fix_noise() -> dict[int, FixNoise]:
    return {
        FixQuality.RTK_FIXED: FixNoise(0.01, 0.01, 60.0),
        FixQuality.RTK_FLOAT: FixNoise(0.10, 0.20, 60.0),
        FixQuality.DGPS: FixNoise(0.30, 0.50, 120.0),
        FixQuality.GPS: FixNoise(1.0, 1.5, 300.0),
    }


@dataclass(frozen=True)
class Outage:
    start_s: float
    end_s: float
    kind: OutageKind
    quality: int = FixQuality.RTK_FLOAT  # for rtk_loss: the degraded fix type
    freeze_time: bool = False  # for frozen: the UTC field stops too

    def active(self, t_s: float) -> bool:
        return self.start_s <= t_s < self.end_s


@dataclass(frozen=True)
class TruthState:
    t_s: float
    x_m: float
    y_m: float
    heading_rad: float  # local plane, CCW from east
    speed_mps: float


@dataclass(frozen=True)
class EmulatorConfig:
    origin_lat_deg: float = 51.4708  # GCDC 2011: the A270 near Helmond, NL
    origin_lon_deg: float = 5.6230
    talker: str = "GN"
    gga_hz: float = 10.0
    rmc_hz: float = 10.0
    hdt_hz: float = 10.0
    vtg_hz: float = 0.0
    gst_hz: float = 1.0
    quality: int = FixQuality.RTK_FIXED
    fix_noise: dict[int, FixNoise] = field(default_factory=default_fix_noise)
    heading_std_deg: float = 0.1
    speed_std_mps: float = 0.05
    latency_s: float = 0.0
    outages: tuple[Outage, ...] = ()
    byte_error_rate: float = 0.0
    utc_start_s: float = 12 * 3600.0  # seconds of the UTC day at t = 0
    date: tuple[int, int, int] = (2011, 5, 14)
    num_sats: int = 14
    hdop: float = 0.8
    alt_m: float = 20.0
    baud: int = 115200

    def __post_init__(self) -> None:
        for name in ("gga_hz", "rmc_hz", "hdt_hz", "vtg_hz", "gst_hz"):
            rate = getattr(self, name)
            if not (0.0 <= rate <= 100.0):
                raise ValueError(f"EmulatorConfig.{name} = {rate!r} Hz: must be within 0..100")
        if self.quality not in self.fix_noise:
            raise ValueError(f"EmulatorConfig.quality {self.quality} has no entry in fix_noise")
        for o in self.outages:
            if o.kind == "rtk_loss" and o.quality not in self.fix_noise:
                raise ValueError(f"Outage at {o.start_s} s degrades to quality {o.quality}, not in fix_noise")
            if not o.end_s > o.start_s:
                raise ValueError(f"Outage {o.kind} ends ({o.end_s} s) before it starts ({o.start_s} s)")
        if not 0.0 <= self.byte_error_rate <= 1.0:
            raise ValueError(
                f"EmulatorConfig.byte_error_rate = {self.byte_error_rate!r}: must be within 0..1"
            )
        need = self.bits_per_second()
        if need > 0.75 * self.baud:
            raise ValueError(
                f"sentence rates need {need:.0f} bit/s, more than 75 % of the {self.baud} baud line: "
                "lower the rates or raise the baud rate"
            )

    def bits_per_second(self) -> float:
        rates = {
            "GGA": self.gga_hz,
            "RMC": self.rmc_hz,
            "VTG": self.vtg_hz,
            "HDT": self.hdt_hz,
            "GST": self.gst_hz,
        }
        return sum(10.0 * _SENTENCE_BYTES[k] * r for k, r in rates.items())


def _lat_field(lat_deg: float) -> str:
    a = abs(lat_deg)
    d = int(a)
    return f"{d:02d}{(a - d) * 60.0:010.7f},{'N' if lat_deg >= 0 else 'S'}"


def _lon_field(lon_deg: float) -> str:
    a = abs(lon_deg)
    d = int(a)
    return f"{d:03d}{(a - d) * 60.0:010.7f},{'E' if lon_deg >= 0 else 'W'}"


def _utc_field(utc_s: float) -> str:
    cs = round(utc_s * 100.0) % (86400 * 100)
    h, rem = divmod(cs, 360000)
    m, rem = divmod(rem, 6000)
    return f"{h:02d}{m:02d}{rem / 100.0:05.2f}"


@dataclass(frozen=True)
class _Epoch:
    """What the receiver believes at one epoch (frozen fixes repeat one of these)."""

    lat_deg: float
    lon_deg: float
    quality: int
    std_m: float
    speed_mps: float
    course_deg: float
    heading_deg: float


class ReceiverEmulator:
    """See the module docstring. Deterministic for a given seed and sequence of calls."""

    def __init__(self, config: EmulatorConfig | None = None, seed: int = 0) -> None:
        self.cfg = config or EmulatorConfig()
        self.frame = LocalFrame(self.cfg.origin_lat_deg, self.cfg.origin_lon_deg)
        self.rng = np.random.default_rng(seed)
        self._t_last = -math.inf
        self._bias = {q: np.zeros(2) for q in self.cfg.fix_noise}
        self._t_bias = math.nan
        self._last_good: _Epoch | None = None
        self._frozen_utc: float | None = None
        self._queue: list[tuple[float, int, bytes]] = []
        self._seq = 0
        self.sentences_sent = 0
        self.bytes_corrupted = 0

    def _outage(self, t_s: float) -> Outage | None:
        for o in self.cfg.outages:
            if o.active(t_s):
                return o
        return None

    def _step_bias(self, t_s: float) -> None:
        dt = 0.0 if math.isnan(self._t_bias) else t_s - self._t_bias
        self._t_bias = t_s
        for q, noise in self.cfg.fix_noise.items():
            if math.isnan(dt) or dt <= 0.0:
                if not np.any(self._bias[q]):
                    self._bias[q] = self.rng.normal(0.0, noise.bias_std_m, 2)
                continue
            phi = math.exp(-dt / noise.bias_tau_s)
            self._bias[q] = phi * self._bias[q] + math.sqrt(1.0 - phi * phi) * self.rng.normal(
                0.0, noise.bias_std_m, 2
            )

    def _measure(self, t_s: float, truth: TruthState, quality: int) -> _Epoch:
        c = self.cfg
        noise = c.fix_noise[quality]
        err = self._bias[quality] + self.rng.normal(0.0, noise.white_std_m, 2)
        lat, lon = self.frame.to_geodetic(truth.x_m + float(err[0]), truth.y_m + float(err[1]))
        speed = max(0.0, truth.speed_mps + float(self.rng.normal(0.0, c.speed_std_mps)))
        course_noise = min(math.pi, c.speed_std_mps / max(truth.speed_mps, 1e-3))
        course = self.frame.true_azimuth_from_heading(
            truth.heading_rad + float(self.rng.normal(0.0, course_noise)), lat, lon
        )
        heading = self.frame.true_azimuth_from_heading(truth.heading_rad, lat, lon)
        heading = (heading + float(self.rng.normal(0.0, c.heading_std_deg))) % 360.0
        return _Epoch(
            lat, lon, quality, math.hypot(noise.white_std_m, noise.bias_std_m), speed, course, heading
        )

    def _epochs(self, rate_hz: float, t0: float, t1: float) -> list[float]:
        if rate_hz <= 0.0:
            return []
        k0 = math.floor(t0 * rate_hz) + 1 if math.isfinite(t0) else math.ceil(t1 * rate_hz - 1e-9)
        k1 = math.floor(t1 * rate_hz + 1e-9)
        return [k / rate_hz for k in range(k0, k1 + 1)]

    def update(self, t_s: float, truth: TruthState) -> bytes:
        """Bytes on the line by t_s; call at the plant's step with the true state at t_s."""
        c = self.cfg
        t0 = self._t_last
        self._t_last = t_s
        due: list[tuple[float, int, str]] = []
        for order, (kind, rate) in enumerate(
            (("GGA", c.gga_hz), ("RMC", c.rmc_hz), ("VTG", c.vtg_hz), ("HDT", c.hdt_hz), ("GST", c.gst_hz))
        ):
            for e in self._epochs(rate, t0, t_s):
                due.append((e, order, kind))
        due.sort()
        epoch_cache: dict[float, _Epoch | None] = {}
        for e, _, kind in due:
            if e not in epoch_cache:
                epoch_cache[e] = self._epoch_state(e, truth)
            body = self._sentence(kind, e, epoch_cache[e])
            if body is not None:
                self._queue.append((e + c.latency_s, self._seq, with_checksum(body)))
                self._seq += 1
        self._queue.sort()
        out = bytearray()
        while self._queue and self._queue[0][0] <= t_s + 1e-9:
            out += self._queue.pop(0)[2]
            self.sentences_sent += 1
        return self._corrupt(bytes(out))

    def _epoch_state(self, e: float, truth: TruthState) -> _Epoch | None:
        """The receiver's state at epoch e (None: no fix)."""
        outage = self._outage(e)
        self._step_bias(e)
        if outage is not None and outage.kind == "no_fix":
            self._frozen_utc = None
            return None
        if outage is not None and outage.kind == "frozen" and self._last_good is not None:
            if outage.freeze_time and self._frozen_utc is None:
                self._frozen_utc = self._utc(e - 1.0 / max(self.cfg.gga_hz, 1.0))
            return self._last_good
        self._frozen_utc = None
        quality = outage.quality if outage is not None and outage.kind == "rtk_loss" else self.cfg.quality
        state = self._measure(e, truth, quality)
        self._last_good = state
        return state

    def _utc(self, e: float) -> float:
        return (self.cfg.utc_start_s + e) % 86400.0

    def _sentence(self, kind: str, e: float, st: _Epoch | None) -> str | None:
        c = self.cfg
        tk = c.talker
        utc = _utc_field(self._frozen_utc if self._frozen_utc is not None else self._utc(e))
        if kind == "GGA":
            if st is None:
                return f"{tk}GGA,{utc},,,,,0,00,99.99,,M,,M,,"
            hdop = c.hdop if st.quality in (FixQuality.RTK_FIXED, FixQuality.RTK_FLOAT) else 1.2 * c.hdop
            age = "1.0" if st.quality in (FixQuality.RTK_FIXED, FixQuality.RTK_FLOAT, FixQuality.DGPS) else ""
            station = "0001" if age else ""
            return (
                f"{tk}GGA,{utc},{_lat_field(st.lat_deg)},{_lon_field(st.lon_deg)},{st.quality},"
                f"{c.num_sats:02d},{hdop:.2f},{c.alt_m:.3f},M,47.000,M,{age},{station}"
            )
        y, mo, d = c.date
        date = f"{d:02d}{mo:02d}{y % 100:02d}"
        if kind == "RMC":
            if st is None:
                return f"{tk}RMC,{utc},V,,,,,,,{date},,,N"
            mode = {FixQuality.RTK_FIXED: "R", FixQuality.RTK_FLOAT: "F", FixQuality.DGPS: "D"}.get(
                st.quality, "A"
            )
            return (
                f"{tk}RMC,{utc},A,{_lat_field(st.lat_deg)},{_lon_field(st.lon_deg)},"
                f"{st.speed_mps / KNOT_MPS:.3f},{st.course_deg:.2f},{date},,,{mode}"
            )
        if kind == "VTG":
            if st is None:
                return f"{tk}VTG,,T,,M,,N,,K,N"
            kn, kmh = st.speed_mps / KNOT_MPS, st.speed_mps * 3.6
            return f"{tk}VTG,{st.course_deg:.2f},T,,M,{kn:.3f},N,{kmh:.3f},K,A"
        if kind == "HDT":
            return f"{tk}HDT,,T" if st is None else f"{tk}HDT,{st.heading_deg:.3f},T"
        if kind == "GST":
            if st is None:
                return None
            s = st.std_m
            return f"{tk}GST,{utc},{s:.3f},{s:.3f},{s:.3f},0.0,{s:.3f},{s:.3f},{2 * s:.3f}"
        raise AssertionError(kind)

    def _corrupt(self, data: bytes) -> bytes:
        p = self.cfg.byte_error_rate
        if p <= 0.0 or not data:
            return data
        arr = np.frombuffer(data, dtype=np.uint8).copy()
        hit = self.rng.random(arr.size) < p
        n = int(hit.sum())
        if n:
            arr[hit] = self.rng.integers(0, 256, n, dtype=np.uint8)
            self.bytes_corrupted += n
        return arr.tobytes()
