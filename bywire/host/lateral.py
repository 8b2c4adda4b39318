"""Orbital tracking lateral controller (seed 000 Sec. 11.1, eqs. 18-23), forward and backward.

Model (eq. 18, Fig. 20): the kinematic single-track model with its reference point at the rear axle,
wheelbase l, steering angle delta, signed speed v (negative: backward). In path coordinates s_c
(arc length of the projection), d (lateral offset) and dpsi (heading error):

    ds_c/dt = v cos(dpsi) / (1 - d kappa),   dd/dt = v sin(dpsi),
    d dpsi/dt = v tan(delta) / l - kappa v cos(dpsi) / (1 - d kappa)

Sign conventions, fixed by eq. 18 and used throughout: d > 0 when the rear axle is to the *left* of
the path (left of the path's heading), dpsi = vehicle heading - path heading (wrapped to (-pi, pi]),
kappa > 0 and delta > 0 turn *left* (counter-clockwise). Check: with dpsi > 0 the car points left of
the path and eq. 18 gives dd/dt = v sin(dpsi) > 0 for v > 0, it drifts left; a left steer raises the
heading. Eq. 20 (the linearisation per arc length, ()' = d/ds_c) then reads d' = dpsi, dpsi' =
tan(delta) / l - kappa, and the linearising law (eq. 21)

    delta = arctan(-l k0 d - l k1 dpsi + l kappa)

gives d'' = -k0 d - k1 d', the characteristic polynomial lambda² + k1 lambda + k0 = 0 *per metre of
arc length* (eq. 23): the transient is the same curve over the ground at any speed, hence "orbital".
Eq. 22's k*_1 = l k0 and k*_2 = l k1 are the gains actually applied to d and dpsi.

Gains. The extracted text gives "k0 = 0.25 l and k1 = 1.25 l", which cannot be right dimensionally
(k0 is 1/m², k1 is 1/m, l is in m) nor numerically (k0 = 0.68 1/m², k1 = 3.4 1/m would put 43 deg of
steer on a 0.1 rad heading error, saturating on every small disturbance). Our reading is a lost
division: k0 = 0.25 / l, k1 = 1.25 / l, i.e. the applied gains of eq. 22 are the round numbers
k*_1 = l k0 = 0.25 1/m and k*_2 = l k1 = 1.25 (per rad). Per arc length: k0 = 0.0919 1/m²,
k1 = 0.4596 1/m, natural "frequency" sqrt(k0) = 0.303 1/m, damping k1 / (2 sqrt(k0)) = 0.76; the
roots -0.230 +- 0.198j 1/m decay an error by e every 4.35 m, settling within 2 % in ~17 m with 2.6 %
overshoot: "reduce the error over a certain travelled distance ... and avoid unpredictable
overshoots" (Sec. 11). A 1 m offset asks for 14 deg of steer, inside delta_max = 30 deg.

Backward driving. The path samples carry the heading the *body* should have (the nose direction, also
when reversing, as a zone planner's poses do) and s increasing in the order the samples are driven.
Reversing, the rear axle moves against the heading, so arc length along the path *decreases* in the
body's forward sense, sigma = -s. Eqs. 18-20 hold in sigma for either sign of v, so per distance
travelled (s) the law must flip the sign of the term in d' = dpsi: d''(s) = d''(sigma) and d'(s) =
-d'(sigma), so d''(s) + k1 d'(s) + k0 d = 0 needs tan(delta) = l (-k0 d + k1 dpsi + kappa). In
general, with direction = +1 forward and -1 backward:

    delta = sat_[-delta_max, delta_max] arctan(-l k0 d - direction l k1 dpsi + l kappa)

"the signs of k0 and k1 have to be adjusted to the applied sign convention and yield exactly the same
error dynamics as for forward driving" (Sec. 11.1): with ours only k1's sign changes. kappa is the
steering curvature tan(delta)/l that drives the path (dpsi/dsigma along the body's forward direction;
for a forward path dheading/ds, for a reversing path -dheading/ds); `PathSamples.from_polyline` derives
it correctly for either direction.

Deviation: the paper samples the path as curve points 2 m apart; we project the rear axle onto the
polyline and interpolate heading and curvature linearly between samples (any spacing works; the
controller follows the polyline, so dense samples follow a curve more closely).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import numpy.typing as npt

__all__ = [
    "Direction",
    "LateralOutput",
    "LateralParams",
    "PathProjection",
    "PathSamples",
    "TrackingTrace",
    "VehiclePose",
    "kinematic_step",
    "lateral_step",
    "orbital_steering",
    "project",
    "simulate_tracking",
]

FloatArray = npt.NDArray[np.float64]
Direction = Literal[1, -1]

PASSAT_WHEELBASE_M = 2.72  # l, seed 000 Sec. 11.1


def _wrap(angle_rad: float) -> float:
    return math.atan2(math.sin(angle_rad), math.cos(angle_rad))


@dataclass(frozen=True)
class LateralParams:
    """Eq. 21's parameters: paper values (gains as read in the module docstring)."""

    wheelbase_m: float = PASSAT_WHEELBASE_M  # l
    k0_per_m2: float = 0.25 / PASSAT_WHEELBASE_M  # k0: l k0 = 0.25 1/m
    k1_per_m: float = 1.25 / PASSAT_WHEELBASE_M  # k1: l k1 = 1.25
    steer_max_rad: float = math.radians(30.0)  # delta_max

    def __post_init__(self) -> None:
        for name in ("wheelbase_m", "k0_per_m2", "k1_per_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"LateralParams.{name} = {value}: must be finite and > 0 (eq. 23 stable)")
        if not (math.isfinite(self.steer_max_rad) and 0.0 < self.steer_max_rad < math.pi / 2.0):
            raise ValueError(f"LateralParams.steer_max_rad = {self.steer_max_rad}: must be in (0, pi/2)")

    @classmethod
    def from_poles(cls, decay_per_m: float, damping: float, **overrides: float) -> LateralParams:
        """Gains from the natural decay rate omega (1/m) and damping zeta of lambda² + k1 lambda + k0."""
        return cls(k0_per_m2=decay_per_m**2, k1_per_m=2.0 * damping * decay_per_m, **overrides)

    @property
    def characteristic_roots_per_m(self) -> tuple[complex, complex]:
        """The roots of lambda² + k1 lambda + k0 = 0 (eq. 23), per metre of arc length."""
        disc = complex(self.k1_per_m**2 - 4.0 * self.k0_per_m2)
        root = disc**0.5
        return ((-self.k1_per_m + root) / 2.0, (-self.k1_per_m - root) / 2.0)


@dataclass(frozen=True)
class PathSamples:
    """A path as arrays (all the same length >= 2), independent of any other module.

    heading_rad: the body heading the vehicle should have there (nose direction, also when reversing).
    curvature_1pm: steering curvature tan(delta)/l that drives it (positive = steer left).
    s_m: arc length, strictly increasing in the order the samples are driven.
    """

    x_m: FloatArray
    y_m: FloatArray
    heading_rad: FloatArray
    curvature_1pm: FloatArray
    s_m: FloatArray
    _seg_dx: FloatArray = field(init=False, repr=False, compare=False)
    _seg_dy: FloatArray = field(init=False, repr=False, compare=False)
    _seg_len2: FloatArray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        names = ("x_m", "y_m", "heading_rad", "curvature_1pm", "s_m")
        arrays = {}
        for name in names:
            arr = np.asarray(getattr(self, name), dtype=np.float64)
            if arr.ndim != 1:
                raise ValueError(f"PathSamples.{name}: must be one-dimensional, got shape {arr.shape}")
            bad = np.flatnonzero(~np.isfinite(arr))
            if bad.size:
                raise ValueError(f"PathSamples.{name}[{int(bad[0])}] = {arr[bad[0]]}: must be finite")
            object.__setattr__(self, name, arr)
            arrays[name] = arr
        n = arrays["x_m"].size
        if n < 2:
            raise ValueError(f"PathSamples: needs at least 2 samples, got {n}")
        for name in names[1:]:
            if arrays[name].size != n:
                raise ValueError(f"PathSamples.{name}: {arrays[name].size} samples, x_m has {n}")
        ds = np.diff(arrays["s_m"])
        bad = np.flatnonzero(ds <= 0.0)
        if bad.size:
            i = int(bad[0])
            raise ValueError(
                f"PathSamples.s_m[{i + 1}] = {arrays['s_m'][i + 1]}: not above s_m[{i}] (must increase)"
            )
        dx, dy = np.diff(arrays["x_m"]), np.diff(arrays["y_m"])
        object.__setattr__(self, "_seg_dx", dx)  # cached for `project`
        object.__setattr__(self, "_seg_dy", dy)
        object.__setattr__(self, "_seg_len2", dx * dx + dy * dy)
        seg = np.hypot(dx, dy)
        bad = np.flatnonzero(seg <= 1e-9)
        if bad.size:
            i = int(bad[0])
            raise ValueError(
                f"PathSamples: samples {i} and {i + 1} are at the same point; segments need a length"
            )

    @property
    def length_m(self) -> float:
        return float(self.s_m[-1] - self.s_m[0])

    @classmethod
    def from_polyline(cls, x_m: npt.ArrayLike, y_m: npt.ArrayLike, direction: Direction = 1) -> PathSamples:
        """Heading, curvature and arc length of a polyline driven in its order, forward or backward.

        Heading from central differences of the points (turned by pi when reversing: the nose points
        against the travel), curvature as the derivative of the travel heading over arc length (sign
        flipped when reversing, see the module docstring). Good enough for smooth, densely sampled
        curves; a planner that knows its exact curvature should pass it directly.
        """
        if direction not in (1, -1):
            raise ValueError(f"PathSamples.from_polyline: direction = {direction!r} must be 1 or -1")
        x = np.asarray(x_m, dtype=np.float64)
        y = np.asarray(y_m, dtype=np.float64)
        if x.ndim != 1 or x.shape != y.shape or x.size < 3:
            raise ValueError(
                f"PathSamples.from_polyline: x and y need the same 1-D shape and >= 3 points, "
                f"got {x.shape} and {y.shape}"
            )
        s = np.concatenate(([0.0], np.cumsum(np.hypot(np.diff(x), np.diff(y)))))
        travel = np.unwrap(np.arctan2(np.gradient(y, s), np.gradient(x, s)))
        curvature = np.gradient(travel, s) * direction
        heading = travel if direction == 1 else travel + math.pi
        heading = np.arctan2(np.sin(heading), np.cos(heading))
        return cls(x_m=x, y_m=y, heading_rad=heading, curvature_1pm=curvature, s_m=s)


@dataclass(frozen=True)
class PathProjection:
    """The rear axle's projection onto the path, with the interpolated path state there."""

    s_m: float
    x_m: float
    y_m: float
    heading_rad: float
    curvature_1pm: float
    lateral_m: float  # d: > 0 left of the path heading
    segment: int  # index of the polyline segment [segment, segment + 1]
    beyond: Literal["start", "end"] | None  # extrapolated past the first / last sample


def project(
    path: PathSamples,
    x_m: float,
    y_m: float,
    s_hint_m: float | None = None,
    window_m: float | None = None,
) -> PathProjection:
    """Nearest point of the polyline to (x, y); past either end the end segment is extended.

    With `s_hint_m` and `window_m` only segments overlapping [hint - window, hint + window] are searched
    (a path that comes back near itself, a K-turn, cannot then snap to the wrong part).
    """
    if not (math.isfinite(x_m) and math.isfinite(y_m)):
        raise ValueError(f"project: position ({x_m}, {y_m}) must be finite")
    n_seg = path.s_m.size - 1
    first, stop = 0, n_seg  # the segments searched: [first, stop)
    if s_hint_m is not None and window_m is not None:
        # Segment j spans [s_j, s_j+1]; keep those overlapping [hint - window, hint + window].
        first = max(int(np.searchsorted(path.s_m, s_hint_m - window_m, side="left")) - 1, 0)
        stop = min(int(np.searchsorted(path.s_m, s_hint_m + window_m, side="right")), n_seg)
        if stop <= first:  # the window misses the path: search all of it
            first, stop = 0, n_seg
    x0, y0 = path.x_m[first:stop], path.y_m[first:stop]
    dx, dy = path._seg_dx[first:stop], path._seg_dy[first:stop]
    # Absurd (finite) positions overflow here; that is reported below instead of warned about.
    with np.errstate(over="ignore", invalid="ignore"):
        t_raw = ((x_m - x0) * dx + (y_m - y0) * dy) / path._seg_len2[first:stop]
        t = np.clip(t_raw, 0.0, 1.0)
        if first == 0 and t_raw[0] < 0.0:
            t[0] = t_raw[0]  # extrapolate before the first sample ...
        if stop == n_seg and t_raw[-1] > 1.0:
            t[-1] = t_raw[-1]  # ... and after the last
        px = x0 + t * dx
        py = y0 + t * dy
        dist2 = (x_m - px) ** 2 + (y_m - py) ** 2
    j = int(np.argmin(dist2))
    if not math.isfinite(float(dist2[j])):
        raise ValueError(f"project: position ({x_m}, {y_m}) is too far from the path to project (overflow)")
    i = first + j
    ti = float(t[j])
    s = float(path.s_m[i] + ti * (path.s_m[i + 1] - path.s_m[i]))
    h0 = float(path.heading_rad[i])
    heading = _wrap(h0 + ti * _wrap(float(path.heading_rad[i + 1]) - h0))
    if ti < 0.0 or ti > 1.0:
        k = float(path.curvature_1pm[0] if ti < 0.0 else path.curvature_1pm[-1])
    else:
        k = float(path.curvature_1pm[i] + ti * (path.curvature_1pm[i + 1] - path.curvature_1pm[i]))
    qx, qy = float(px[j]), float(py[j])
    lateral = (x_m - qx) * -math.sin(heading) + (y_m - qy) * math.cos(heading)
    beyond: Literal["start", "end"] | None = "start" if ti < 0.0 else ("end" if ti > 1.0 else None)
    return PathProjection(s, qx, qy, heading, k, lateral, i, beyond)


@dataclass(frozen=True)
class VehiclePose:
    """Rear-axle position (m) and body heading (rad, ENU, counter-clockwise from east)."""

    x_m: float
    y_m: float
    heading_rad: float


@dataclass(frozen=True)
class LateralOutput:
    """One cycle's steering command and the tracking errors it came from (for logging)."""

    steer_rad: float  # delta, saturated; > 0 left
    lateral_error_m: float  # d, > 0 left of the path
    heading_error_rad: float  # dpsi = vehicle heading - path heading
    curvature_1pm: float  # kappa at the projection
    s_m: float  # arc length of the projection
    saturated: bool
    beyond: Literal["start", "end"] | None  # projected past the path's first / last sample


def orbital_steering(
    lateral_m: float,
    heading_error_rad: float,
    curvature_1pm: float,
    direction: Direction,
    params: LateralParams,
) -> tuple[float, bool]:
    """Eq. 21 with the backward sign: (saturated delta in rad, whether it saturated)."""
    l = params.wheelbase_m  # noqa: E741 - the paper's symbol
    u = (
        -l * params.k0_per_m2 * lateral_m
        - direction * l * params.k1_per_m * heading_error_rad
        + l * curvature_1pm
    )
    delta = math.atan(u)
    if abs(delta) > params.steer_max_rad:
        return math.copysign(params.steer_max_rad, delta), True
    return delta, False


def lateral_step(
    path: PathSamples,
    pose: VehiclePose,
    direction: Direction,
    params: LateralParams,
    s_hint_m: float | None = None,
    window_m: float | None = None,
) -> LateralOutput:
    """One control cycle: project the rear axle, compute (d, dpsi), apply eq. 21. Speed-independent.

    `direction` is +1 driving forward, -1 backward (the gear, known also at standstill). Pure; raises
    ValueError naming the field for a non-finite pose or a bad direction.
    """
    if direction not in (1, -1):
        raise ValueError(f"lateral_step: direction = {direction!r} must be 1 (forward) or -1 (backward)")
    if not math.isfinite(pose.heading_rad):
        raise ValueError(f"lateral_step: VehiclePose.heading_rad = {pose.heading_rad} must be finite")
    proj = project(path, pose.x_m, pose.y_m, s_hint_m, window_m)
    dpsi = _wrap(pose.heading_rad - proj.heading_rad)
    steer, saturated = orbital_steering(proj.lateral_m, dpsi, proj.curvature_1pm, direction, params)
    return LateralOutput(steer, proj.lateral_m, dpsi, proj.curvature_1pm, proj.s_m, saturated, proj.beyond)


def kinematic_step(
    pose: VehiclePose,
    speed_mps: float,
    steer_rad: float,
    dt_s: float,
    wheelbase_m: float = PASSAT_WHEELBASE_M,
) -> VehiclePose:
    """Exact motion of the rear-axle single-track model over dt with constant signed speed and steer.

    psi' = v tan(delta) / l; the rear axle moves along its heading (v < 0: backward), i.e. on a
    circular arc of curvature tan(delta) / l (a straight line for delta = 0).
    """
    dist = speed_mps * dt_s
    k = math.tan(steer_rad) / wheelbase_m
    dpsi = k * dist
    psi0 = pose.heading_rad
    if abs(dpsi) < 1e-9:
        # Second-order expansion of the arc keeps the sub-nanoradian case smooth.
        mid = psi0 + 0.5 * dpsi
        return VehiclePose(pose.x_m + dist * math.cos(mid), pose.y_m + dist * math.sin(mid), psi0 + dpsi)
    psi1 = psi0 + dpsi
    return VehiclePose(
        pose.x_m + (math.sin(psi1) - math.sin(psi0)) / k,
        pose.y_m - (math.cos(psi1) - math.cos(psi0)) / k,
        _wrap(psi1),
    )


@dataclass(frozen=True)
class TrackingTrace:
    """A closed-loop run: one row per control cycle (values before that cycle's motion)."""

    t_s: FloatArray
    x_m: FloatArray
    y_m: FloatArray
    heading_rad: FloatArray
    steer_rad: FloatArray
    lateral_error_m: FloatArray
    heading_error_rad: FloatArray
    s_m: FloatArray
    travelled_m: FloatArray  # distance driven so far (either direction)


def simulate_tracking(
    path: PathSamples,
    start: VehiclePose,
    speed_mps: float,
    direction: Direction,
    params: LateralParams,
    dt_s: float,
    max_distance_m: float | None = None,
    stop_before_end_m: float = 0.0,
) -> TrackingTrace:
    """Closed loop of `lateral_step` and `kinematic_step` at constant speed (a test and tuning helper).

    The controller runs every dt_s with zero-order hold (the steering holds between cycles); the plant
    is integrated exactly. Stops after `max_distance_m` of travel or when the projection is within
    `stop_before_end_m` of the path's end (so an end-extrapolation does not dominate a statistic).
    """
    if not (math.isfinite(speed_mps) and speed_mps > 0.0):
        raise ValueError(f"simulate_tracking: speed_mps = {speed_mps} must be > 0 (direction gives the sign)")
    if not (math.isfinite(dt_s) and dt_s > 0.0):
        raise ValueError(f"simulate_tracking: dt_s = {dt_s} must be > 0")
    limit_m = max_distance_m if max_distance_m is not None else 3.0 * path.length_m + 10.0
    end_s = float(path.s_m[-1]) - stop_before_end_m
    rows: list[tuple[float, ...]] = []
    pose = start
    travelled = 0.0
    t = 0.0
    s_hint: float | None = None
    step_m = speed_mps * dt_s
    while travelled <= limit_m:
        out = lateral_step(
            path, pose, direction, params, s_hint, None if s_hint is None else 5.0 + 3.0 * step_m
        )
        if out.s_m >= end_s:
            break
        rows.append(
            (
                t,
                pose.x_m,
                pose.y_m,
                pose.heading_rad,
                out.steer_rad,
                out.lateral_error_m,
                out.heading_error_rad,
                out.s_m,
                travelled,
            )
        )
        s_hint = out.s_m
        pose = kinematic_step(pose, direction * speed_mps, out.steer_rad, dt_s, params.wheelbase_m)
        travelled += step_m
        t += dt_s
    cols = np.array(rows, dtype=np.float64).reshape(-1, 9).T
    return TrackingTrace(*[np.ascontiguousarray(c) for c in cols])
