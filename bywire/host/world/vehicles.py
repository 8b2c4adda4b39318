"""Vehicle manager: other cars' states, filtered and predicted to any time (seed 003 Sec. II-f, IV-B, IV-C).

Seed 003 II-f: the vehicle manager "abstract[s] from the latency of the received data: through
extrapolation and filtering, it can provide an estimate of the platoon state at any given point in time".
Every message carries the sender's state ``(l, w, phi, lambda, psi, v, psi_dot, a)`` (IV-B) stamped with
its generation (GPS) time; we keep positions on the local plane (`geo.LocalFrame`; `VehicleMessage.
from_geodetic` converts).

Prediction (IV-C): the constant-yaw-rate-and-acceleration model, "movement on a circle", with the speed
"cropped" at the velocity limits. `cyra_predict` integrates it in closed form and piecewise::

    v(t) = clip(v0 + a t, 0, v_max),   psi(t) = psi0 + w t   (while moving)
    x(t) = x0 + int_0^t v(s) cos(psi(s)) ds,   y likewise with sin

Phase 1 runs until the speed reaches 0 or v_max (``t1 = (v_lim - v0) / a``), phase 2 continues at that
speed. At a standstill the heading stops turning too (a parked car does not spin; the paper is silent on
this). The integrals are exact: ``int (v0 + a s) cos(psi0 + w s) ds = [(v0 + a s) sin(.)/w + a cos(.)/w^2]``;
when ``|w t| < 1e-3`` those terms cancel catastrophically, and a second-order series in ``w s`` is used
instead (truncation error < 2e-10 relative), which is the straight-line limit for ``w -> 0``.

Filtering (our choice; the paper does not say how it filtered): one extended Kalman filter per station on
``[x, y, psi, v, w, a]`` with the same CYRA motion model (white jerk and white yaw acceleration as process
noise), updated with the full received state. Its mean is propagated with `cyra_predict`; its covariance
with the exact transition matrix of the model linearised at the current state (``A`` is nilpotent,
``A^3 = 0``, so ``Phi(dt) = I + A dt + A^2 dt^2 / 2``) and ``Q = int_0^dt Phi G Qc G' Phi' ds`` by 3-point
Gauss-Legendre quadrature (exact for this degree-4 integrand). The filter runs in generation time, so a
message's age is absorbed by predicting to the query time. Optional fields (yaw rate, acceleration: CAM's
low-frequency container may lack them) simply drop out of the update. A position innovation beyond the
chi-square gate (99.9 %) is not applied (counted); three in a row re-initialise the track (the sender jumped
for real, e.g. its own filter reset).

Health (seed 003 Sec. VI: "some teams sent outdated data or did not send anything at all ... below
bridges"):

- silent: no message received for `silent_after_s`; removed after `drop_after_s`.
- frozen: the reported position has stayed within `frozen_eps_m` of where it stopped moving while the
  reported or filtered speed says the car should have covered `frozen_min_travel_m` since. Position
  measurements are then ignored: the track continues from its last good state by dead reckoning on the
  sender's own speed (and heading, yaw rate, acceleration, still applied: they come from its odometry
  and gyro), and is marked low-confidence until the position moves again.
"""

from __future__ import annotations

import functools
import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from bywire.host.geo import TWO_PI, LocalFrame, wrap_angle, wrap_angles

FloatArray = npt.NDArray[np.float64]

KMH_TO_MPS = 1.0 / 3.6
SERIES_LIMIT = 1e-3  # |w t| below which the small-angle series replaces the closed form
CHI2_2DOF_999 = 13.82
_GL_NODES = np.array([-math.sqrt(0.6), 0.0, math.sqrt(0.6)])
_GL_WEIGHTS = np.array([5.0, 8.0, 5.0]) / 9.0
IX, IY, IPSI, IV, IW, IA = range(6)


def _arc_integrals(
    v0: FloatArray | float, a: FloatArray | float, psi0: FloatArray | float, w: float, T: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """int_0^T (v0 + a s) (cos, sin)(psi0 + w s) ds, elementwise over T (and v0, a, psi0 if arrays)."""
    T = np.asarray(T, dtype=np.float64)
    c0, s0 = np.cos(psi0), np.sin(psi0)
    small = np.abs(w * T) < SERIES_LIMIT
    any_small = bool(np.any(small))
    if not any_small:
        return _arc_closed_form(v0, a, psi0, w, T, c0, s0)
    # Series to second order in w s.
    m0 = v0 * T + 0.5 * a * T**2
    m1 = 0.5 * v0 * T**2 + a * T**3 / 3.0
    m2 = v0 * T**3 / 3.0 + 0.25 * a * T**4
    ic_ser = c0 * m0 - s0 * w * m1 - 0.5 * c0 * w * w * m2
    is_ser = s0 * m0 + c0 * w * m1 - 0.5 * s0 * w * w * m2
    if bool(np.all(small)):
        return ic_ser, is_ser
    ic, is_ = _arc_closed_form(v0, a, psi0, w if w != 0.0 else 1.0, T, c0, s0)
    return np.where(small, ic_ser, ic), np.where(small, is_ser, is_)


def _arc_closed_form(
    v0: FloatArray | float,
    a: FloatArray | float,
    psi0: FloatArray | float,
    w: float,
    T: FloatArray,
    c0: FloatArray | float,
    s0: FloatArray | float,
) -> tuple[FloatArray, FloatArray]:
    ve = v0 + a * T
    ce, se = np.cos(psi0 + w * T), np.sin(psi0 + w * T)
    ic = (ve * se - v0 * s0) / w + a * (ce - c0) / (w * w)
    is_ = (-ve * ce + v0 * c0) / w + a * (se - s0) / (w * w)
    return ic, is_


@dataclass(frozen=True)
class CyraPrediction:
    """States at the query times (arrays of the query's shape)."""

    t_s: FloatArray
    x_m: FloatArray
    y_m: FloatArray
    heading_rad: FloatArray
    speed_mps: FloatArray
    accel_mps2: FloatArray


def _speed_limit(v0_mps: float, accel_mps2: float, speed_max_mps: float) -> tuple[float, float]:
    """When (s from now) and at what speed a constant acceleration from v0 meets [0, v_max]: inf if never."""
    if accel_mps2 > 0.0:
        return (speed_max_mps - v0_mps) / accel_mps2, speed_max_mps
    if accel_mps2 < 0.0:
        return -v0_mps / accel_mps2, 0.0
    return math.inf, v0_mps


def cyra_predict(
    x_m: float,
    y_m: float,
    heading_rad: float,
    speed_mps: float,
    yaw_rate_radps: float,
    accel_mps2: float,
    dt_s: FloatArray | float,
    speed_max_mps: float = 130.0 * KMH_TO_MPS,
) -> CyraPrediction:
    """Constant yaw rate and acceleration from the state at 0 to times dt_s (>= 0), speed in [0, v_max]."""
    t = np.maximum(np.asarray(dt_s, dtype=np.float64), 0.0)
    v0 = min(max(speed_mps, 0.0), speed_max_mps)
    a, w = accel_mps2, yaw_rate_radps
    t_lim, v_lim = _speed_limit(v0, a, speed_max_mps)
    T1 = np.minimum(t, t_lim)
    ic1, is1 = _arc_integrals(v0, a, heading_rad, w, T1)
    T2 = t - T1
    psi1 = heading_rad + w * T1
    ic2: FloatArray | float
    is2: FloatArray | float
    psi: FloatArray
    if not bool(np.any(T2 > 0.0)):
        ic2 = is2 = 0.0  # the limit is not reached within the queried times
        psi = psi1
    elif v_lim > 0.0:
        ic2, is2 = _arc_integrals(v_lim, 0.0, psi1, w, T2)
        psi = psi1 + w * T2
    else:
        # Standing still: no further travel, and no turning on the spot.
        ic2 = is2 = np.zeros_like(T2)
        psi = psi1
    if v0 == 0.0 and a <= 0.0:
        psi = np.full_like(t, heading_rad)
    in_phase1 = t < t_lim
    return CyraPrediction(
        t_s=t,
        x_m=x_m + ic1 + ic2,
        y_m=y_m + is1 + is2,
        heading_rad=wrap_angles(np.asarray(psi, dtype=np.float64)),
        speed_mps=np.where(in_phase1, v0 + a * T1, v_lim),
        accel_mps2=np.where(in_phase1, a, 0.0),
    )


def _arc_integrals_scalar(v0: float, a: float, psi0: float, w: float, T: float) -> tuple[float, float]:
    """`_arc_integrals` for one time, as Python floats: the same operations in the same order (IEEE
    arithmetic is the same on Python floats as on numpy's), and numpy's own cos, sin and powers, called
    on the same 0-d operands as the array form (numpy's pow differs from the C library's)."""
    c0, s0 = float(np.cos(psi0)), float(np.sin(psi0))
    if not abs(w * T) < SERIES_LIMIT:
        ve = v0 + a * T
        ce, se = float(np.cos(psi0 + w * T)), float(np.sin(psi0 + w * T))
        return (
            (ve * se - v0 * s0) / w + a * (ce - c0) / (w * w),
            (-ve * ce + v0 * c0) / w + a * (se - s0) / (w * w),
        )
    t = np.asarray(T, dtype=np.float64)
    t2, t3, t4 = float(t**2), float(t**3), float(t**4)
    m0 = v0 * T + 0.5 * a * t2
    m1 = 0.5 * v0 * t2 + a * t3 / 3.0
    m2 = v0 * t3 / 3.0 + 0.25 * a * t4
    return (
        c0 * m0 - s0 * w * m1 - 0.5 * c0 * w * w * m2,
        s0 * m0 + c0 * w * m1 - 0.5 * s0 * w * w * m2,
    )


def cyra_predict_scalar(
    x_m: float,
    y_m: float,
    heading_rad: float,
    speed_mps: float,
    yaw_rate_radps: float,
    accel_mps2: float,
    dt_s: float,
    speed_max_mps: float = 130.0 * KMH_TO_MPS,
) -> tuple[float, float, float, float, float]:
    """`cyra_predict` at one time: (x, y, heading, speed, acceleration), bit for bit the same (tests hold
    it to that). The filter asks this of every track at every message and every cycle; on 0-d arrays
    each of its few dozen numpy operations cost a microsecond. A non-finite input takes the array form."""
    values = (x_m, y_m, heading_rad, speed_mps, yaw_rate_radps, accel_mps2, dt_s, speed_max_mps)
    if not all(math.isfinite(v) for v in values):
        p = cyra_predict(*values)
        return float(p.x_m), float(p.y_m), float(p.heading_rad), float(p.speed_mps), float(p.accel_mps2)
    t = dt_s if dt_s > 0.0 else 0.0  # np.maximum(dt, 0.0); dt is never -0.0 (a difference of times)
    v0 = min(max(speed_mps, 0.0), speed_max_mps)
    a, w = accel_mps2, yaw_rate_radps
    t_lim, v_lim = _speed_limit(v0, a, speed_max_mps)
    T1 = t if t <= t_lim else t_lim
    ic1, is1 = _arc_integrals_scalar(v0, a, heading_rad, w, T1)
    T2 = t - T1
    psi1 = heading_rad + w * T1
    if not T2 > 0.0:
        ic2 = is2 = 0.0
        psi = psi1
    elif v_lim > 0.0:
        ic2, is2 = _arc_integrals_scalar(v_lim, 0.0, psi1, w, T2)
        psi = psi1 + w * T2
    else:
        ic2 = is2 = 0.0
        psi = psi1
    if v0 == 0.0 and a <= 0.0:
        psi = heading_rad
    in_phase1 = t < t_lim
    return (
        x_m + ic1 + ic2,
        y_m + is1 + is2,
        (psi + math.pi) % TWO_PI - math.pi,
        v0 + a * T1 if in_phase1 else v_lim,
        a if in_phase1 else 0.0,
    )


@dataclass(frozen=True)
class VehicleMessage:
    """One received state (seed 003 IV-B's vector) on the local plane, stamped with its generation time."""

    station_id: int
    t_gen_s: float
    x_m: float
    y_m: float
    heading_rad: float  # local plane, CCW from east
    speed_mps: float
    yaw_rate_radps: float | None = None
    accel_mps2: float | None = None
    length_m: float = 4.5
    width_m: float = 1.8

    @staticmethod
    def from_geodetic(
        frame: LocalFrame,
        station_id: int,
        t_gen_s: float,
        lat_deg: float,
        lon_deg: float,
        heading_true_deg: float,
        speed_mps: float,
        yaw_rate_radps: float | None = None,
        accel_mps2: float | None = None,
        length_m: float = 4.5,
        width_m: float = 1.8,
    ) -> VehicleMessage:
        """From the broadcast form: WGS84 position, true heading (deg clockwise from north); a yaw rate
        positive to the left (counter-clockwise) as in CAM."""
        x, y = frame.to_local(lat_deg, lon_deg)
        heading = frame.heading_from_true_azimuth(heading_true_deg, lat_deg, lon_deg)
        return VehicleMessage(
            station_id, t_gen_s, x, y, heading, speed_mps, yaw_rate_radps, accel_mps2, length_m, width_m
        )


@dataclass(frozen=True)
class VehicleState:
    station_id: int
    t_s: float
    x_m: float
    y_m: float
    heading_rad: float
    speed_mps: float
    yaw_rate_radps: float
    accel_mps2: float
    length_m: float
    width_m: float
    silent: bool
    frozen: bool
    # The position's 1-sigma, computed when first asked for: only the radar association's gate asks, for
    # the few stations on our lane ahead, and its covariance prediction is most of a state's cost.
    position_std: Callable[[], float] = field(repr=False, compare=False)

    @functools.cached_property
    def position_std_m(self) -> float:
        return self.position_std()

    @property
    def low_confidence(self) -> bool:
        return self.silent or self.frozen


@dataclass(frozen=True)
class Trajectory:
    """A vehicle's predicted states on a grid of absolute times (for the platoon MPC)."""

    station_id: int
    t_s: FloatArray
    x_m: FloatArray
    y_m: FloatArray
    heading_rad: FloatArray
    speed_mps: FloatArray
    accel_mps2: FloatArray
    length_m: float
    low_confidence: bool


@dataclass(frozen=True)
class VehicleManagerConfig:
    speed_max_mps: float = 130.0 * KMH_TO_MPS
    jerk_std_mps3: float = 2.0  # white jerk density^(1/2): GCDC braking manoeuvres
    yaw_accel_std_radps2: float = 0.1
    # Measurement 1-sigmas of a received state (the GCDC rules asked for ~0.5 m; some teams were worse).
    position_std_m: float = 0.5
    heading_std_rad: float = math.radians(2.0)
    speed_std_mps: float = 0.2
    yaw_rate_std_radps: float = 0.02
    accel_std_mps2: float = 0.3
    gate_chi2: float = CHI2_2DOF_999
    reinit_after_jumps: int = 3
    silent_after_s: float = 0.5  # 5 missed messages at the GCDC's 10 Hz
    drop_after_s: float = 5.0
    frozen_eps_m: float = 0.05
    frozen_min_travel_m: float = 1.0
    future_tolerance_s: float = 0.1  # clock skew allowed between sender and us
    max_age_s: float = 2.0  # older messages are useless to a 10-Hz controller


def _transition_matrices(x: FloatArray, dt: float) -> FloatArray:
    """`_transition` as the matrix products define it: the reference `_transition` is held to."""
    A = np.zeros((6, 6))
    c, s = math.cos(x[IPSI]), math.sin(x[IPSI])
    v = x[IV]
    A[IX, IPSI], A[IX, IV] = -v * s, c
    A[IY, IPSI], A[IY, IV] = v * c, s
    A[IPSI, IW] = 1.0
    A[IV, IA] = 1.0
    return np.eye(6) + A * dt + (A @ A) * (0.5 * dt * dt)


def _transition(x: FloatArray, dt: float) -> FloatArray:
    """Phi = I + A dt + A^2 dt^2 / 2 of the CYRA model linearised at x (A^3 = 0).

    Written out entry by entry: a filter step builds four of these, and the matrix form spent most of
    its time allocating. Each entry is the same IEEE operations on the same operands as
    `_transition_matrices`: every entry of A @ A is a sum in which at most one product is non-zero, which
    any summation order and fused multiply-add round alike, and an exact zero added to the identity's 0
    or 1 changes nothing. Non-finite operands (0 * inf in the products) take the matrix form."""
    v = float(x[IV])
    psi = float(x[IPSI])
    if not (math.isfinite(v) and math.isfinite(psi) and math.isfinite(dt)):
        return _transition_matrices(x, dt)
    c, s = math.cos(psi), math.sin(psi)
    half_dt2 = 0.5 * dt * dt
    a_x_psi, a_y_psi = -v * s, v * c
    phi = np.eye(6)
    # (0.0 + a dt) + 0.0: the identity's zero, then A @ A's (zero) entry, as the matrix sum adds them.
    phi[IX, IPSI] = (0.0 + a_x_psi * dt) + 0.0
    phi[IX, IV] = (0.0 + c * dt) + 0.0
    phi[IY, IPSI] = (0.0 + a_y_psi * dt) + 0.0
    phi[IY, IV] = (0.0 + s * dt) + 0.0
    phi[IPSI, IW] = (0.0 + 1.0 * dt) + 0.0
    phi[IV, IA] = (0.0 + 1.0 * dt) + 0.0
    # A @ A: (x, w) = A[x, psi] A[psi, w], (x, a) = A[x, v] A[v, a], likewise for y.
    phi[IX, IW] = 0.0 + (a_x_psi * 1.0) * half_dt2
    phi[IX, IA] = 0.0 + (c * 1.0) * half_dt2
    phi[IY, IW] = 0.0 + (a_y_psi * 1.0) * half_dt2
    phi[IY, IA] = 0.0 + (s * 1.0) * half_dt2
    return phi


@functools.lru_cache(maxsize=64)
def _measurement_matrices(rows: tuple[int, ...], r: tuple[float, ...]) -> tuple[FloatArray, FloatArray]:
    """H (which state components a message measured) and R (their variances): a handful of
    combinations per configuration, built once each (read-only: every update shares them)."""
    H = np.zeros((len(rows), 6))
    H[np.arange(len(rows)), list(rows)] = 1.0
    R = np.diag(r)
    H.setflags(write=False)
    R.setflags(write=False)
    return H, R


class VehicleTrack:
    """One station's filter, health and prediction."""

    def __init__(self, msg: VehicleMessage, t_rx_s: float, cfg: VehicleManagerConfig) -> None:
        self.cfg = cfg
        self.station_id = msg.station_id
        self.counts: Counter[str] = Counter()
        self.frozen = False
        self._init(msg, t_rx_s)
        gq = np.zeros((6, 2))
        gq[IA, 0] = cfg.jerk_std_mps3
        gq[IW, 1] = cfg.yaw_accel_std_radps2
        self._GQG = gq @ gq.T

    def _init(self, msg: VehicleMessage, t_rx_s: float) -> None:
        c = self.cfg
        self.t_s = msg.t_gen_s
        self.x = np.array(
            [
                msg.x_m,
                msg.y_m,
                wrap_angle(msg.heading_rad),
                msg.speed_mps,
                msg.yaw_rate_radps or 0.0,
                msg.accel_mps2 or 0.0,
            ]
        )
        self.P = np.diag(
            [
                c.position_std_m**2,
                c.position_std_m**2,
                c.heading_std_rad**2,
                c.speed_std_mps**2,
                (c.yaw_rate_std_radps if msg.yaw_rate_radps is not None else 0.2) ** 2,
                (c.accel_std_mps2 if msg.accel_mps2 is not None else 2.0) ** 2,
            ]
        )
        self.length_m, self.width_m = msg.length_m, msg.width_m
        self.last_rx_s = t_rx_s
        self._jumps = 0
        self._still_ref = (msg.x_m, msg.y_m, msg.t_gen_s)
        self.frozen = False

    # ------------------------------------------------------------------------------------ filter

    def _mean_at(self, x: FloatArray, dt: float) -> FloatArray:
        """Mean after dt: CYRA for position, heading and speed; yaw rate and acceleration held (the next
        message corrects them; cropping them here would lose the sender's intent)."""
        px, py, ph, pv, _ = cyra_predict_scalar(
            float(x[IX]), float(x[IY]), float(x[IPSI]), float(x[IV]), float(x[IW]), float(x[IA]),
            float(dt), self.cfg.speed_max_mps,
        )  # fmt: skip
        return np.array([px, py, ph, pv, x[IW], x[IA]])

    def _predict(self, dt: float) -> tuple[FloatArray, FloatArray]:
        if dt <= 0.0:
            return self.x.copy(), self.P.copy()
        return self._mean_at(self.x, dt), self._covariance_at(self.x, self.P, dt)

    def _covariance_at(self, x: FloatArray, P: FloatArray, dt: float) -> FloatArray:
        """P propagated by dt > 0 from the state x (the linearisation point) and covariance P."""
        Phi = _transition(x, dt)
        Q = np.zeros((6, 6))
        for node, weight in zip(_GL_NODES, _GL_WEIGHTS, strict=True):
            s = 0.5 * dt * (node + 1.0)
            Ps = _transition(x, dt - s)
            Q += weight * (Ps @ self._GQG @ Ps.T)
        Q *= 0.5 * dt
        return Phi @ P @ Phi.T + Q

    def update(self, msg: VehicleMessage, t_rx_s: float) -> str:
        """Apply one message (already checked for order and age). Returns "ok", "frozen" or "reinit"."""
        c = self.cfg
        x, P = self._predict(msg.t_gen_s - self.t_s)
        self.t_s = msg.t_gen_s
        self.last_rx_s = t_rx_s
        self.length_m, self.width_m = msg.length_m, msg.width_m
        was_frozen = self.frozen
        self.frozen = self._frozen_check(msg, float(x[IV]))
        if was_frozen != self.frozen:
            self.counts["frozen" if self.frozen else "unfrozen"] += 1
        rows: list[int] = []
        z: list[float] = []
        r: list[float] = []
        use_position = not self.frozen
        if use_position:
            nu = np.array([msg.x_m - x[IX], msg.y_m - x[IY]])
            S = P[:2, :2] + np.eye(2) * c.position_std_m**2
            if float(nu @ np.linalg.solve(S, nu)) > c.gate_chi2:
                self._jumps += 1
                self.counts["position_jump"] += 1
                use_position = False
                if self._jumps >= c.reinit_after_jumps:
                    self.counts["reinit"] += 1
                    self._init(msg, t_rx_s)
                    return "reinit"
            else:
                self._jumps = 0
        if use_position:
            rows += [IX, IY]
            z += [msg.x_m, msg.y_m]
            r += [c.position_std_m**2] * 2
        rows.append(IPSI)
        z.append(x[IPSI] + wrap_angle(msg.heading_rad - x[IPSI]))
        r.append(c.heading_std_rad**2)
        rows.append(IV)
        z.append(msg.speed_mps)
        r.append(c.speed_std_mps**2)
        if msg.yaw_rate_radps is not None:
            rows.append(IW)
            z.append(msg.yaw_rate_radps)
            r.append(c.yaw_rate_std_radps**2)
        if msg.accel_mps2 is not None:
            rows.append(IA)
            z.append(msg.accel_mps2)
            r.append(c.accel_std_mps2**2)
        H, R = _measurement_matrices(tuple(rows), tuple(r))
        nu_all = np.asarray(z) - x[rows]
        S_all = H @ P @ H.T + R
        K = np.linalg.solve(S_all, H @ P).T
        x = x + K @ nu_all
        IKH = np.eye(6) - K @ H
        self.P = IKH @ P @ IKH.T + K @ R @ K.T
        x[IPSI] = wrap_angle(float(x[IPSI]))
        x[IV] = max(float(x[IV]), 0.0)
        self.x = x
        return "frozen" if self.frozen else "ok"

    def _frozen_check(self, msg: VehicleMessage, v_pred: float) -> bool:
        c = self.cfg
        x0, y0, t0 = self._still_ref
        if math.hypot(msg.x_m - x0, msg.y_m - y0) > c.frozen_eps_m:
            self._still_ref = (msg.x_m, msg.y_m, msg.t_gen_s)
            return False
        expected_travel = max(msg.speed_mps, v_pred, 0.0) * (msg.t_gen_s - t0)
        return self.frozen or expected_travel > c.frozen_min_travel_m

    # -------------------------------------------------------------------------------- prediction

    def silent(self, t_now_s: float) -> bool:
        return t_now_s - self.last_rx_s > self.cfg.silent_after_s

    def state_at(self, t_s: float, t_now_s: float | None = None) -> VehicleState:
        """The state predicted to t_s (CYRA, speed cropped); health judged at t_now_s (default t_s)."""
        now = t_s if t_now_s is None else t_now_s
        dt = t_s - self.t_s
        sx = self.x
        px, py, ph, pv, pa = cyra_predict_scalar(
            float(sx[IX]), float(sx[IY]), float(sx[IPSI]), float(sx[IV]), float(sx[IW]), float(sx[IA]),
            float(dt), self.cfg.speed_max_mps,
        )  # fmt: skip
        x, P0 = self.x, self.P  # an update replaces both arrays, never changes them in place

        def position_std_m() -> float:
            P = P0.copy() if dt <= 0.0 else self._covariance_at(x, P0, dt)
            return math.sqrt(max(float(np.linalg.eigvalsh(P[:2, :2])[-1]), 0.0))

        return VehicleState(
            station_id=self.station_id,
            t_s=t_s,
            x_m=px,
            y_m=py,
            heading_rad=ph,
            speed_mps=pv,
            yaw_rate_radps=float(self.x[IW]) if pv > 0.0 else 0.0,
            accel_mps2=pa,
            length_m=self.length_m,
            width_m=self.width_m,
            silent=self.silent(now),
            frozen=self.frozen,
            position_std=position_std_m,
        )

    def _cyra(self, dt_s: FloatArray) -> CyraPrediction:
        x = self.x
        return cyra_predict(
            float(x[IX]), float(x[IY]), float(x[IPSI]), float(x[IV]), float(x[IW]), float(x[IA]),
            dt_s, self.cfg.speed_max_mps,
        )  # fmt: skip

    def predict_trajectory(self, t_query_s: FloatArray, t_now_s: float | None = None) -> Trajectory:
        """CYRA from the filtered state to each absolute time in t_query_s (one closed-form evaluation)."""
        t = np.asarray(t_query_s, dtype=np.float64)
        now = t_now_s if t_now_s is not None else (float(t.flat[0]) if t.size else self.t_s)
        p = self._cyra(t - self.t_s)
        return Trajectory(
            station_id=self.station_id,
            t_s=t,
            x_m=p.x_m,
            y_m=p.y_m,
            heading_rad=p.heading_rad,
            speed_mps=p.speed_mps,
            accel_mps2=p.accel_mps2,
            length_m=self.length_m,
            low_confidence=self.frozen or self.silent(now),
        )


@dataclass
class VehicleManager:
    """All other vehicles by station id. Clock-injected: every call carries the time."""

    config: VehicleManagerConfig = field(default_factory=VehicleManagerConfig)
    tracks: dict[int, VehicleTrack] = field(default_factory=dict)
    counts: Counter[str] = field(default_factory=Counter)

    def receive(self, msg: VehicleMessage, t_rx_s: float) -> bool:
        """One received message at host time t_rx_s. Returns whether it was used; drops are counted."""
        c = self.config
        values = (msg.t_gen_s, msg.x_m, msg.y_m, msg.heading_rad, msg.speed_mps, msg.length_m, msg.width_m)
        optional = (msg.yaw_rate_radps, msg.accel_mps2)
        if not all(math.isfinite(v) for v in values) or not all(
            v is None or math.isfinite(v) for v in optional
        ):
            self.counts["nonfinite"] += 1
            return False
        if msg.speed_mps < 0.0 or msg.speed_mps > 1.5 * c.speed_max_mps:
            self.counts["implausible_speed"] += 1
            return False
        if msg.t_gen_s > t_rx_s + c.future_tolerance_s:
            self.counts["from_future"] += 1
            return False
        if msg.t_gen_s < t_rx_s - c.max_age_s:
            self.counts["too_old"] += 1
            return False
        track = self.tracks.get(msg.station_id)
        if track is None:
            self.tracks[msg.station_id] = VehicleTrack(msg, t_rx_s, c)
            self.counts["new"] += 1
            return True
        if msg.t_gen_s <= track.t_s:
            self.counts["out_of_order"] += 1
            return False
        result = track.update(msg, t_rx_s)
        self.counts[f"update_{result}"] += 1
        return True

    def prune(self, t_now_s: float) -> list[int]:
        """Forget stations silent for longer than drop_after_s; returns their ids."""
        gone = [sid for sid, tr in self.tracks.items() if t_now_s - tr.last_rx_s > self.config.drop_after_s]
        for sid in gone:
            del self.tracks[sid]
        self.counts["aged_out"] += len(gone)
        return gone

    def state(self, station_id: int, t_s: float, t_now_s: float | None = None) -> VehicleState | None:
        track = self.tracks.get(station_id)
        return None if track is None else track.state_at(t_s, t_now_s)

    def states(self, t_s: float, t_now_s: float | None = None) -> list[VehicleState]:
        return [tr.state_at(t_s, t_now_s) for tr in self.tracks.values()]

    def predict_trajectory(
        self, station_id: int, t_query_s: FloatArray, t_now_s: float | None = None
    ) -> Trajectory | None:
        track = self.tracks.get(station_id)
        return None if track is None else track.predict_trajectory(t_query_s, t_now_s)

    def predict_all(self, t_query_s: FloatArray, t_now_s: float | None = None) -> dict[int, Trajectory]:
        return {sid: tr.predict_trajectory(t_query_s, t_now_s) for sid, tr in self.tracks.items()}
