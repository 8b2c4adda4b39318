"""Pose server: our own position, heading, speed and acceleration (seed 003 Sec. II-a/h; seed 000 Sec. 2.3).

AnnieWAY's pose came from an RTK GPS/INS (seed 000 Sec. 2.3: "better than 0.02 m" with corrections, 0.1 deg
heading from a 2-m dual-antenna baseline, odometry from the wheel encoders). We rebuild the dead-reckoning
part ourselves from what the car gives us, so that a receiver without an INS, or one that loses its fix
under a bridge, still yields a usable pose.

`PoseFilter` — an extended Kalman filter on the local plane (`geo.LocalFrame`, x east, y north),
state ``[x, y, heading, k, b]``: position of the reference point [m], heading [rad, CCW from east],
odometer scale ``k`` (true speed = k * wheel speed; tyre wear and pressure move it by ~1 %) and yaw-rate
bias ``b`` [rad/s]. Inputs (the ECU's measurements, as plain numbers at their own rate, held between
samples): wheel speed ``v_w`` and yaw rate ``w_m``. Propagation over dt (midpoint rule)::

    v = k v_w,  w = w_m - b,  psi_mid = psi + w dt / 2
    x += v cos(psi_mid) dt,  y += v sin(psi_mid) dt,  psi += w dt

Process noise: the input noises as white-noise densities (``speed_noise_mps`` and
``yaw_rate_noise_radps`` are per-sample 1-sigma at ``odometry_rate_hz``, density = sigma^2 / rate), a small
position random walk for what the model leaves out (wheel slip, lever arm), and random walks on k and b.
Steps longer than `MAX_STEP_S` are split so the midpoint rule stays accurate through input gaps.

Measurements: GNSS position (per-axis sigma from GST when recent, else a table by GGA fix quality times
HDOP for the non-RTK fixes: RTK fixed 3 cm, RTK float 0.3 m, DGPS 0.7 m, GPS 2 m); true heading (HDT/THS,
0.1 deg after seed 000); course over ground above 3 m/s when no heading sentence came for 1 s (a car
does not crab); speed over ground (updates k). The fix's time is its receive time minus the configured
receiver latency; a fix older than the filter (odometry runs ahead) is compared with the position the
filter had at that time (a 1 s history) and the correction is applied now — the usual measurement
back-dating for a latency-bound receiver. A position innovation beyond the chi-square gate (99.9 %, 2 dof)
is rejected and counted; `reset_after_rejections` rejections in a row mean the filter, not the receiver,
is wrong (e.g. after a long outage with an optimistic covariance): it is reset onto the fix.

Outputs (`Pose`): flags ``rtk`` (the newest accepted fix, within `fix_timeout_s`, was RTK fixed), ``gnss``
(any fix accepted within `fix_timeout_s`), ``dead_reckoning`` (no fix within it: odometry only, the
covariance grows), ``stale`` (no odometry for `odometry_timeout_s`, or the query time is that far ahead of
the inputs: the pose is extrapolation, do not drive on it). ``position_std_m`` is the square root of the
largest eigenvalue of the position covariance (the worst axis, conservative). Acceleration is the ECU's
longitudinal acceleration when given, else the derivative of the corrected speed, both through a first-
order low-pass (``accel_tau_s``).

Deviations: no lever arm (the antenna is taken to be at the reference point, the geometric centre, as in
the GCDC state vector); the fix time comes from the receive time, not the sentence's UTC field (the host
clock is not assumed to be GPS-disciplined); 2-D only (seed 003 Sec. IV: "a flat 2-D world").

`PoseServer` — `nmea.NmeaStream` + `LocalFrame` + `PoseFilter`: feed it the serial bytes with their receive
time and the ECU's odometry; ask it for the pose at any time. Frozen fixes (a receiver under a bridge
repeating its last position while we move faster than 0.5 m/s) and repeated epochs (the same UTC time) are
dropped and counted, and so are that receiver's heading and velocity sentences until a fresh fix comes.
Fix quality 6 (the receiver's own dead reckoning), 7 and 8 are not used: we dead-reckon ourselves.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from bywire.host.geo import LocalFrame, wrap_angle

from .nmea import FixQuality, Gga, Gst, Heading, NmeaRecord, NmeaStream, Rmc, Vtg

FloatArray = npt.NDArray[np.float64]

MAX_STEP_S = 0.05
# chi-square 99.9 % points: a fix this unlikely under the filter's own covariance is an outlier.
CHI2_2DOF_999 = 13.82
CHI2_1DOF_999 = 10.83

IX, IY, IPSI, IK, IB = range(5)


def _default_position_std() -> dict[int, float]:
    # Per-axis 1-sigma [m] by GGA quality (scaled by HDOP for the non-RTK ones). RTK fixed: seed 000's
    # 0.02 m plus margin for multipath; the rest are typical receiver figures.
    return {
        FixQuality.RTK_FIXED: 0.03,
        FixQuality.RTK_FLOAT: 0.3,
        FixQuality.DGPS: 0.7,
        FixQuality.GPS: 2.0,
        FixQuality.PPS: 2.0,
    }


@dataclass(frozen=True)
class PoseFilterConfig:
    odometry_rate_hz: float = 100.0
    speed_noise_mps: float = 0.05  # wheel speed, 1-sigma per sample
    yaw_rate_noise_radps: float = 0.005  # gyro, 1-sigma per sample
    position_walk_m2ps: float = 0.002  # unmodelled motion (slip, lever arm): 0.14 m 1-sigma after 10 s
    scale_walk_per_s: float = 1e-4  # odometer scale random walk, 1/sqrt(s)
    bias_walk_radps_per_s: float = 2e-5  # gyro bias random walk, rad/s/sqrt(s)
    initial_scale_std: float = 0.02
    initial_bias_std_radps: float = 0.005
    position_std_by_quality: dict[int, float] = field(default_factory=_default_position_std)
    min_position_std_m: float = 0.01
    heading_std_rad: float = math.radians(0.1)  # dual-antenna heading, seed 000 Sec. 2.3
    course_std_rad: float = math.radians(1.0)
    course_min_speed_mps: float = 3.0  # below this the course over ground is mostly noise
    heading_sentence_timeout_s: float = 1.0  # prefer HDT/THS; fall back to course after this
    gnss_speed_std_mps: float = 0.1
    speed_update_min_mps: float = 1.0
    gate_chi2: float = CHI2_2DOF_999
    heading_gate_chi2: float = CHI2_1DOF_999
    reset_after_rejections: int = 10
    fix_timeout_s: float = 0.5  # no accepted fix for this long: dead reckoning
    odometry_timeout_s: float = 0.2  # 20 samples at 100 Hz
    history_s: float = 1.0  # oldest fix that is back-dated rather than dropped
    accel_tau_s: float = 0.2
    gst_max_age_s: float = 1.5


@dataclass(frozen=True)
class Pose:
    """Our pose at t_s on the local plane, with where it came from."""

    t_s: float
    x_m: float
    y_m: float
    heading_rad: float
    speed_mps: float
    accel_mps2: float
    yaw_rate_radps: float
    lat_deg: float
    lon_deg: float
    position_std_m: float
    heading_std_rad: float
    rtk: bool
    gnss: bool
    dead_reckoning: bool
    stale: bool
    fix_quality: int  # of the newest accepted fix (0: none yet)


@dataclass(frozen=True)
class FilterState:
    t_s: float
    mean: FloatArray  # [x, y, heading, k, b]
    cov: FloatArray


class PoseFilter:
    """EKF over [x, y, heading, odometer scale, gyro bias]; see the module docstring."""

    def __init__(self, config: PoseFilterConfig | None = None) -> None:
        self.cfg = config or PoseFilterConfig()
        c = self.cfg
        self._q_v = c.speed_noise_mps**2 / c.odometry_rate_hz
        self._q_w = c.yaw_rate_noise_radps**2 / c.odometry_rate_hz
        self.t_s = math.nan
        self.x = np.zeros(5)
        self.P = np.eye(5)
        self.initialized = False
        self.counts: Counter[str] = Counter()
        # Held inputs
        self._v_w = 0.0
        self._w_m = 0.0
        self._accel_in: float | None = None
        self._t_odo = -math.inf
        self._accel = 0.0
        self._prev_speed: float | None = None
        # Newest accepted measurements
        self._t_fix = -math.inf
        self._fix_quality = 0
        self._t_heading = -math.inf
        self._rejections = 0
        self._history: deque[tuple[float, float, float]] = deque()
        # Before the filter is initialised: the newest fix, waiting for a heading
        self._pending_fix: tuple[float, float, float, float, int] | None = None
        self._pending_heading: tuple[float, float] | None = None

    # -------------------------------------------------------------------------------- propagation

    def _propagate(self, x: FloatArray, P: FloatArray, dt: float) -> tuple[FloatArray, FloatArray]:
        c = self.cfg
        x = x.copy()
        k, b = x[IK], x[IB]
        v = k * self._v_w
        w = self._w_m - b
        psi_mid = x[IPSI] + 0.5 * w * dt
        cm, sm = math.cos(psi_mid), math.sin(psi_mid)
        x[IX] += v * cm * dt
        x[IY] += v * sm * dt
        x[IPSI] = wrap_angle(x[IPSI] + w * dt)
        F = np.eye(5)
        F[IX, IPSI] = -v * sm * dt
        F[IY, IPSI] = v * cm * dt
        F[IX, IK] = self._v_w * cm * dt
        F[IY, IK] = self._v_w * sm * dt
        F[IX, IB] = 0.5 * v * sm * dt * dt
        F[IY, IB] = -0.5 * v * cm * dt * dt
        F[IPSI, IB] = -dt
        # Input noise through G (per unit input), densities times dt.
        g_v = np.array([k * cm, k * sm, 0.0, 0.0, 0.0]) * dt
        g_w = np.array([-0.5 * v * sm * dt, 0.5 * v * cm * dt, 1.0, 0.0, 0.0]) * dt
        Q = (np.outer(g_v, g_v) * self._q_v + np.outer(g_w, g_w) * self._q_w) / dt
        Q[IX, IX] += c.position_walk_m2ps * dt
        Q[IY, IY] += c.position_walk_m2ps * dt
        Q[IK, IK] += c.scale_walk_per_s**2 * dt
        Q[IB, IB] += c.bias_walk_radps_per_s**2 * dt
        P = F @ P @ F.T + Q
        return x, P

    def _predict_to(
        self, x: FloatArray, P: FloatArray, t0: float, t1: float
    ) -> tuple[FloatArray, FloatArray]:
        dt_total = t1 - t0
        if dt_total <= 0.0:
            return x, P
        n = max(1, math.ceil(dt_total / MAX_STEP_S))
        dt = dt_total / n
        for _ in range(n):
            x, P = self._propagate(x, P, dt)
        return x, P

    def _advance(self, t_s: float) -> None:
        if t_s > self.t_s:
            self.x, self.P = self._predict_to(self.x, self.P, self.t_s, t_s)
            self.t_s = t_s
            self._history.append((t_s, float(self.x[IX]), float(self.x[IY])))
            while self._history and self._history[0][0] < t_s - self.cfg.history_s:
                self._history.popleft()

    # ------------------------------------------------------------------------------------ inputs

    def update_odometry(
        self, t_s: float, speed_mps: float, yaw_rate_radps: float, accel_mps2: float | None = None
    ) -> None:
        """The ECU's wheel speed [m/s] and yaw rate [rad/s] (and optionally longitudinal accel) at t_s."""
        if not (math.isfinite(t_s) and math.isfinite(speed_mps) and math.isfinite(yaw_rate_radps)):
            self.counts["odometry_nonfinite"] += 1
            return
        if t_s < self._t_odo:
            self.counts["odometry_out_of_order"] += 1
            return
        if self.initialized:
            self._advance(t_s)
        self._v_w = speed_mps
        self._w_m = yaw_rate_radps
        self._accel_in = accel_mps2 if accel_mps2 is not None and math.isfinite(accel_mps2) else None
        dt = t_s - self._t_odo
        speed = float(self.x[IK]) * speed_mps if self.initialized else speed_mps
        if math.isfinite(dt) and dt > 0.0:
            alpha = dt / (self.cfg.accel_tau_s + dt)
            raw = self._accel_in
            if raw is None:
                raw = (speed - self._prev_speed) / dt if self._prev_speed is not None else 0.0
            self._accel += alpha * (raw - self._accel)
        self._prev_speed = speed
        self._t_odo = t_s

    def _position_at(self, t_s: float) -> tuple[float, float] | None:
        """The filter's position at an earlier time t_s, from the history (None: older than kept)."""
        hist = self._history
        if not hist or t_s < hist[0][0]:
            return None
        for i in range(len(hist) - 1, 0, -1):
            t1, x1, y1 = hist[i]
            t0, x0, y0 = hist[i - 1]
            if t0 <= t_s <= t1:
                f = (t_s - t0) / (t1 - t0) if t1 > t0 else 1.0
                return x0 + f * (x1 - x0), y0 + f * (y1 - y0)
        return hist[-1][1], hist[-1][2]

    def update_position(
        self, t_s: float, x_m: float, y_m: float, std_x_m: float, std_y_m: float, quality: int
    ) -> bool:
        """A GNSS fix at t_s. Returns whether it was accepted."""
        if not self.initialized:
            self._pending_fix = (t_s, x_m, y_m, max(std_x_m, std_y_m), quality)
            self._try_initialize()
            return self.initialized
        if t_s >= self.t_s:
            self._advance(t_s)
            px, py = float(self.x[IX]), float(self.x[IY])
        else:
            past = self._position_at(t_s)
            if past is None:
                self.counts["fix_too_old"] += 1
                return False
            px, py = past
        nu = np.array([x_m - px, y_m - py])
        R = np.diag([std_x_m**2, std_y_m**2])
        S = self.P[:2, :2] + R
        d2 = float(nu @ np.linalg.solve(S, nu))
        if d2 > self.cfg.gate_chi2:
            self._rejections += 1
            self.counts["fix_rejected_jump"] += 1
            if self._rejections >= self.cfg.reset_after_rejections:
                self.counts["filter_reset"] += 1
                self.x[IX] += nu[0]
                self.x[IY] += nu[1]
                self.P[:2, :] = 0.0
                self.P[:, :2] = 0.0
                self.P[:2, :2] = R
                self._history.clear()
                self._rejections = 0
                self._accept_fix(t_s, quality)
                return True
            return False
        self._rejections = 0
        H = np.zeros((2, 5))
        H[0, IX] = H[1, IY] = 1.0
        self._kalman(H, nu, R)
        self._accept_fix(t_s, quality)
        return True

    def _accept_fix(self, t_s: float, quality: int) -> None:
        self._t_fix = max(self._t_fix, t_s)
        self._fix_quality = quality
        self.counts["fix_accepted"] += 1

    def update_heading(
        self, t_s: float, heading_rad: float, std_rad: float, from_course: bool = False
    ) -> bool:
        """A true heading (or, `from_course`, course over ground) converted to the local plane."""
        if not from_course:
            self._t_heading = max(self._t_heading, t_s)
        if not self.initialized:
            self._pending_heading = (t_s, heading_rad)
            self._try_initialize()
            return self.initialized
        if from_course and t_s - self._t_heading < self.cfg.heading_sentence_timeout_s:
            return False
        if t_s > self.t_s:
            self._advance(t_s)
        nu = np.array([wrap_angle(heading_rad - float(self.x[IPSI]))])
        R = np.array([[std_rad**2]])
        S = float(self.P[IPSI, IPSI]) + std_rad**2
        if nu[0] ** 2 / S > self.cfg.heading_gate_chi2:
            self.counts["heading_rejected"] += 1
            return False
        H = np.zeros((1, 5))
        H[0, IPSI] = 1.0
        self._kalman(H, nu, R)
        self.x[IPSI] = wrap_angle(float(self.x[IPSI]))
        return True

    def update_speed(self, t_s: float, speed_mps: float, std_mps: float) -> bool:
        """GNSS speed over ground: observes the odometer scale (speed = k * wheel speed)."""
        if not self.initialized or self._v_w < self.cfg.speed_update_min_mps:
            return False
        if t_s > self.t_s:
            self._advance(t_s)
        nu = np.array([speed_mps - float(self.x[IK]) * self._v_w])
        H = np.zeros((1, 5))
        H[0, IK] = self._v_w
        R = np.array([[std_mps**2]])
        S = float((H @ self.P @ H.T)[0, 0]) + std_mps**2
        if nu[0] ** 2 / S > self.cfg.heading_gate_chi2:
            self.counts["speed_rejected"] += 1
            return False
        self._kalman(H, nu, R)
        return True

    def _kalman(self, H: FloatArray, nu: FloatArray, R: FloatArray) -> None:
        P = self.P
        S = H @ P @ H.T + R
        K = np.linalg.solve(S, H @ P).T
        self.x = self.x + K @ nu
        IKH = np.eye(5) - K @ H
        # Joseph form: keeps P symmetric positive definite under rounding.
        self.P = IKH @ P @ IKH.T + K @ R @ K.T

    def _try_initialize(self) -> None:
        fix, hdg = self._pending_fix, self._pending_heading
        if fix is None or hdg is None or abs(fix[0] - hdg[0]) > 1.0:
            return
        c = self.cfg
        t = max(fix[0], hdg[0], self._t_odo if math.isfinite(self._t_odo) else -math.inf)
        self.x = np.array([fix[1], fix[2], hdg[1], 1.0, 0.0])
        # Heading: 2 deg covers a course-over-ground start; an HDT update tightens it at once.
        self.P = np.diag(
            [
                fix[3] ** 2,
                fix[3] ** 2,
                math.radians(2.0) ** 2,
                c.initial_scale_std**2,
                c.initial_bias_std_radps**2,
            ]
        )
        self.t_s = t
        self.initialized = True
        self._history.clear()
        self._history.append((t, fix[1], fix[2]))
        self._accept_fix(fix[0], fix[4])

    # ------------------------------------------------------------------------------------ output

    def state_at(self, t_s: float) -> FilterState | None:
        """The filter's estimate extrapolated to t_s with the held inputs (the filter is not changed)."""
        if not self.initialized:
            return None
        x, P = self._predict_to(self.x, self.P, self.t_s, t_s)
        return FilterState(t_s=max(t_s, self.t_s), mean=x, cov=P)

    def pose(self, t_s: float, frame: LocalFrame | None = None) -> Pose | None:
        st = self.state_at(t_s)
        if st is None:
            return None
        c = self.cfg
        x, P = st.mean, st.cov
        lat = lon = math.nan
        if frame is not None:
            lat, lon = frame.to_geodetic(float(x[IX]), float(x[IY]))
        pos_std = math.sqrt(max(float(np.linalg.eigvalsh(P[:2, :2])[-1]), 0.0))
        gnss = t_s - self._t_fix <= c.fix_timeout_s
        stale = t_s - self._t_odo > c.odometry_timeout_s
        return Pose(
            t_s=t_s,
            x_m=float(x[IX]),
            y_m=float(x[IY]),
            heading_rad=float(x[IPSI]),
            speed_mps=float(x[IK]) * self._v_w,
            accel_mps2=self._accel,
            yaw_rate_radps=self._w_m - float(x[IB]),
            lat_deg=lat,
            lon_deg=lon,
            position_std_m=pos_std,
            heading_std_rad=math.sqrt(max(float(P[IPSI, IPSI]), 0.0)),
            rtk=gnss and self._fix_quality == FixQuality.RTK_FIXED,
            gnss=gnss,
            dead_reckoning=not gnss,
            stale=stale,
            fix_quality=self._fix_quality,
        )

    @property
    def speed_mps(self) -> float:
        return float(self.x[IK]) * self._v_w if self.initialized else self._v_w


@dataclass(frozen=True)
class PoseServerConfig:
    fix_latency_s: float = 0.0  # receiver latency: fix time = receive time - this
    # A moving car whose receiver repeats exactly the same position is under a bridge (seed 003 Sec. VI).
    frozen_min_speed_mps: float = 0.5
    filter: PoseFilterConfig = field(default_factory=PoseFilterConfig)


class PoseServer:
    """NMEA bytes + the ECU's odometry in, `Pose` out. Clock-injected: every call carries its time."""

    def __init__(self, frame: LocalFrame, config: PoseServerConfig | None = None) -> None:
        self.frame = frame
        self.cfg = config or PoseServerConfig()
        self.stream = NmeaStream()
        self.filter = PoseFilter(self.cfg.filter)
        self.counts: Counter[str] = Counter()
        self._last_gga: Gga | None = None
        self._last_gst: tuple[float, Gst] | None = None
        # Set by a frozen or repeated GGA, cleared by a fresh one: a frozen receiver also repeats its
        # heading and velocity, which must not steer the filter either.
        self.receiver_frozen = False

    def feed(self, data: bytes, t_rx_s: float) -> None:
        """Bytes read from the serial line at host time t_rx_s (arbitrary chunks)."""
        for rec in self.stream.feed(data):
            self.handle(rec, t_rx_s - self.cfg.fix_latency_s)

    def odometry(
        self, t_s: float, speed_mps: float, yaw_rate_radps: float, accel_mps2: float | None = None
    ) -> None:
        self.filter.update_odometry(t_s, speed_mps, yaw_rate_radps, accel_mps2)

    def pose(self, t_s: float) -> Pose | None:
        return self.filter.pose(t_s, self.frame)

    def handle(self, rec: NmeaRecord, t_s: float) -> None:
        """One decoded sentence measured at t_s."""
        if isinstance(rec, Gga):
            self._handle_gga(rec, t_s)
        elif isinstance(rec, Gst):
            self._last_gst = (t_s, rec)
        elif self.receiver_frozen:
            self.counts["frozen_receiver_dropped"] += 1
        elif isinstance(rec, Heading):
            if rec.valid and rec.heading_deg is not None:
                lat, lon = self._reference_latlon()
                hdg = self.frame.heading_from_true_azimuth(rec.heading_deg, lat, lon)
                self.filter.update_heading(t_s, hdg, self.cfg.filter.heading_std_rad)
            else:
                self.counts["heading_invalid"] += 1
        elif isinstance(rec, Rmc | Vtg):
            if isinstance(rec, Rmc) and not rec.valid:
                return
            self._handle_velocity(rec.course_deg, rec.speed_mps, t_s)

    def _reference_latlon(self) -> tuple[float, float]:
        g = self._last_gga
        if g is not None and g.lat_deg is not None and g.lon_deg is not None:
            return g.lat_deg, g.lon_deg
        return self.frame.origin_lat_deg, self.frame.origin_lon_deg

    def _handle_velocity(self, course_deg: float | None, speed_mps: float | None, t_s: float) -> None:
        fc = self.cfg.filter
        if speed_mps is None:
            return
        self.filter.update_speed(t_s, speed_mps, fc.gnss_speed_std_mps)
        if course_deg is not None and speed_mps >= fc.course_min_speed_mps:
            lat, lon = self._reference_latlon()
            hdg = self.frame.heading_from_true_azimuth(course_deg, lat, lon)
            # Course noise grows as the speed falls (velocity noise / speed).
            std = math.hypot(fc.course_std_rad, fc.gnss_speed_std_mps / speed_mps)
            self.filter.update_heading(t_s, hdg, std, from_course=True)

    def _handle_gga(self, g: Gga, t_s: float) -> None:
        prev = self._last_gga
        fc = self.cfg.filter
        if g.quality == FixQuality.INVALID or g.lat_deg is None or g.lon_deg is None:
            self.counts["fix_invalid"] += 1
            return
        base = fc.position_std_by_quality.get(g.quality)
        if base is None:
            # 6 estimated (the receiver's own dead reckoning), 7 manual, 8 simulator: we dead-reckon.
            self.counts["fix_unusable_quality"] += 1
            return
        if prev is not None and g.utc_s is not None and g.utc_s == prev.utc_s:
            self.counts["fix_repeated"] += 1
            self.receiver_frozen = True
            return
        self._last_gga = g
        if (
            prev is not None
            and (g.lat_deg, g.lon_deg) == (prev.lat_deg, prev.lon_deg)
            and abs(self.filter.speed_mps) > self.cfg.frozen_min_speed_mps
        ):
            self.counts["fix_frozen"] += 1
            self.receiver_frozen = True
            return
        self.receiver_frozen = False
        std_x = std_y = base
        if g.quality in (FixQuality.GPS, FixQuality.DGPS, FixQuality.PPS) and g.hdop is not None:
            std_x = std_y = base * max(g.hdop, 1.0)
        gst = self._last_gst
        if gst is not None and t_s - gst[0] <= fc.gst_max_age_s:
            rec = gst[1]
            if rec.lat_std_m is not None and rec.lon_std_m is not None:
                std_x, std_y = rec.lon_std_m, rec.lat_std_m
        std_x = max(std_x, fc.min_position_std_m)
        std_y = max(std_y, fc.min_position_std_m)
        x, y = self.frame.to_local(g.lat_deg, g.lon_deg)
        self.filter.update_position(t_s, x, y, std_x, std_y, g.quality)

    def stats(self) -> dict[str, int]:
        """Every counter: NMEA drops by reason (``drop_*``), accepted sentences (``nmea_*``), fix handling."""
        out: dict[str, int] = {}
        for k, v in self.stream.drops.items():
            out[f"drop_{k}"] = v
        for k, v in self.stream.accepted.items():
            out[f"nmea_{k}"] = v
        out.update(self.counts)
        out.update(self.filter.counts)
        return out
