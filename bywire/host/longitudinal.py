"""Longitudinal override controller: velocity, following, stopping and position control (seed 000 Sec. 11.2).

Every controller outputs the vehicle's acceleration a (m/s²); the ECU turns it into pedal and brake
(the paper's cascaded acceleration controller). The vehicle "drives on rails" (Sec. 11): the only
inputs are the own speed v, the desired speed v_d, an optional lead vehicle (gap d_f, speed v_B)
and an optional stop point at distance d_stop along the path. Forward driving only (the paper's
direction changes are not implemented).

Velocity controller (eq 31): a_v = -c_v (v - v_d), a PT1 speed loop. The paper gives no c_v; we
use 0.5 1/s: with the 0.3 s first-order actuator lag of a real drivetrain the loop
0.3 s² + s + c_v stays overdamped (no overshoot) for c_v <= 1 / (4 * 0.3) = 0.83 1/s.

Following controller (eqs 24-28): a_f = c0 (d_f - d_fd) + c1 (v_B - v), d_fd = d_f0 + tau v (eq 25).
DARPA's separation rule, one vehicle length plus one length per additional 10 mph (4.4704 m/s),
gives d_f0 = L and tau = L / 4.4704 m/s (L = 4.77 m for the Passat Variant: tau = 1.067 s).
With v = v_B - d_f', eq 28's characteristic polynomial is lambda² + (c0 tau + c1) lambda + c0.
Placing a double eigenvalue at -omega_f, (lambda + omega_f)² = lambda² + 2 omega_f lambda + omega_f²:

    c0 = omega_f²,    c1 = 2 omega_f - omega_f² tau

The paper's choice omega_f = 1 1/s gives c0 = 1 1/s², c1 = 2 - tau = 0.933 1/s. c1 > 0 needs
tau < 2 / omega_f, checked in LongitudinalParams.

Stopping controller (eq 30): a_s = -v² / (2 (d_stop - d_delta)) brakes at the constant
deceleration b that brings v to zero at d_delta before the stop point (b = v² / (2 (d_stop -
d_delta)) is invariant under the law). Its singularity at d_stop = d_delta is avoided by a PD
position controller a_p = k_p d_stop - k_d v aiming at the line, "that takes over via a
min-operator" near the stop point. How we make that work:

- A min hands over only to a controller that brakes harder, so the PD must take over *before*
  the singularity. Along the law's path (v² = 2 b (d_stop - d_delta)) a critically damped PD
  (k_p = w², k_d = 2 w) asks for a_p = w² d - 2 w v, whose minimum over d is -2 b (at
  d = 2 b / w², for d_delta = 0): the PD always takes over, at d_1 = (3 + 2 sqrt 2) b / w²
  with v_1 = (2 + sqrt 2) b / w. There v_1 <= w d_1, so the PD's own, critically damped motion
  reaches the line without crossing it. The price, inherent to a PD taking over by a min: the
  command rises to about 2 b during the hand-over (hence a_s,max = 1.5 m/s²: peaks near 3 m/s²
  with a 0.3 s actuator lag).
- We put the singularity *beyond* the line: d_delta = -`stop_aim_beyond_m` (0.5 m). With
  d_delta >= 0, a_s would be evaluated at 0/0 right where the car stops and a tiny speed error
  would make the min pick an unbounded braking demand; beyond the line a_s stays bounded
  (-v² / (2 * 0.5 m)) while the PD is in charge. A car past the aim point gets a_min.
  (Measured in the closed-loop test with 0.2 m/s speed noise: aim 1 mm beyond the line, the
  stopping law switched 62 times in one stop; aim 0.5 m beyond, twice.)
- Within `stop_hold_zone_m` of the line (and past it) the PD never asks to accelerate: it would
  otherwise creep, and speed noise (a negative measured v) would ratchet the car over the line.
  Inside the zone the car rolls or stands, and the ECU holds it at standstill.
- The PD is active whenever a stop point is given: far away it asks for more than a_max and is
  never selected; it also carries low-speed approaches that never need a_s,max, starting to brake
  at d = 2 v / w and peaking at 0.37 w v.

Hysteresis (Fig. 22): the constant-deceleration law is switched on only once the deceleration it
needs, b, reaches a_s,max (`stop_decel_on_mps2`), so the car does not creep towards a far stop
point with a tiny deceleration ("decelerating too soon"), and it is switched off only when b
falls below a_s,min (`stop_decel_off_mps2`), so speed noise or actuator lag around one threshold
cannot make it chatter. Under the law b stays constant, so it switches off only when the stop
point moves away or the car has nearly stopped, where the PD is in charge anyway. The switch-on
is a step in the command (from a_v to -a_s,max), as in the paper; the ECU's jerk limit smooths it.

Override (Fig. 22, Sec. 11.2.4): a = sat_[a_min, a_max]( min(a_v, a_f, a_s, a_p) ), where a
controller that does not apply (no lead, no stop point, stopping law switched off) is left out.
The figure is not in our text of the paper, so here is how its operators read: selecting the
controller with the lowest acceleration is the same as selecting the highest deceleration; the
paper's "max operator" that gives the bumpless transfer between velocity and following/stopping
control is this selector read in decelerations (-a), and its "min-operator" through which the PD
takes over is the same selector read in accelerations. The transfer is bumpless because a min of
continuous signals is continuous: at a hand-over both candidates are equal. a_max / a_min default
to the ECU's own clamp (DESIGN Sec. 4: -4.5 .. 2.0 m/s²) so that the ECU never silently cuts what
this controller believes it commanded.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from bywire.host.limits import ACCEL_MAX_MPS2, ACCEL_MIN_MPS2

__all__ = [
    "ActiveController",
    "LeadObservation",
    "LongitudinalInputs",
    "LongitudinalParams",
    "LongitudinalState",
    "following_accel",
    "longitudinal_step",
    "position_accel",
    "stopping_accel",
    "stopping_required_decel",
    "velocity_accel",
]

ActiveController = Literal["velocity", "following", "stopping", "position"]

MPH10_MPS = 4.4704  # 10 mph: DARPA's unit of "one more vehicle length" of separation
PASSAT_VARIANT_LENGTH_M = 4.77  # VW Passat B6 Variant (AnnieWAY), bumper to bumper


@dataclass(frozen=True)
class LongitudinalParams:
    """Gains and limits. Paper values where Sec. 11.2 gives them, else our documented choices."""

    follow_d0_m: float = PASSAT_VARIANT_LENGTH_M  # d_f0: one vehicle length at standstill (eq 25)
    follow_tau_s: float = PASSAT_VARIANT_LENGTH_M / MPH10_MPS  # tau: one length per 10 mph (eq 25)
    follow_eigenvalue_per_s: float = 1.0  # double eigenvalue -1 of eq 28 (paper)
    velocity_gain_per_s: float = 0.5  # c_v of eq 31 (ours: overdamped with a 0.3 s actuator lag)
    stop_decel_on_mps2: float = 1.5  # a_s,max: switch the stopping law on at this deceleration (ours)
    stop_decel_off_mps2: float = 0.5  # a_s,min: switch it off below this deceleration (ours)
    stop_aim_beyond_m: float = 0.5  # -d_delta of eq 30: aim point of a_s beyond the stop line (ours)
    stop_hold_zone_m: float = 0.2  # within this of the line the PD only brakes, never creeps (ours)
    position_omega_per_s: float = 1.5  # PD double pole w: k_p = w², k_d = 2 w (ours)
    accel_min_mps2: float = ACCEL_MIN_MPS2  # a_min (host.limits)
    accel_max_mps2: float = ACCEL_MAX_MPS2  # a_max

    def __post_init__(self) -> None:
        positive = (
            "follow_eigenvalue_per_s",
            "velocity_gain_per_s",
            "stop_decel_on_mps2",
            "stop_aim_beyond_m",
            "position_omega_per_s",
            "accel_max_mps2",
        )
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"LongitudinalParams.{name} = {value}: must be finite and > 0")
        for name in ("follow_d0_m", "follow_tau_s", "stop_decel_off_mps2", "stop_hold_zone_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"LongitudinalParams.{name} = {value}: must be finite and >= 0")
        if not (math.isfinite(self.accel_min_mps2) and self.accel_min_mps2 < 0.0):
            raise ValueError(f"LongitudinalParams.accel_min_mps2 = {self.accel_min_mps2}: must be < 0")
        if self.stop_decel_off_mps2 > self.stop_decel_on_mps2:
            raise ValueError(
                f"LongitudinalParams.stop_decel_off_mps2 = {self.stop_decel_off_mps2} above "
                f"stop_decel_on_mps2 = {self.stop_decel_on_mps2}: the hysteresis would be inverted"
            )
        if self.follow_c1_per_s <= 0.0:
            raise ValueError(
                f"LongitudinalParams.follow_tau_s = {self.follow_tau_s}: c1 = 2 omega - omega² tau "
                f"= {self.follow_c1_per_s:.3f} <= 0; needs tau < 2 / follow_eigenvalue_per_s"
            )

    @classmethod
    def for_vehicle_length(cls, vehicle_length_m: float, **overrides: float) -> LongitudinalParams:
        """DARPA's separation rule for another car: d_f0 = L, tau = L per 10 mph."""
        if not (math.isfinite(vehicle_length_m) and vehicle_length_m > 0.0):
            raise ValueError(f"LongitudinalParams.for_vehicle_length: {vehicle_length_m} m must be > 0")
        return cls(follow_d0_m=vehicle_length_m, follow_tau_s=vehicle_length_m / MPH10_MPS, **overrides)

    @property
    def follow_c0_per_s2(self) -> float:
        """c0 = omega_f² (double eigenvalue -omega_f of eq 28)."""
        return self.follow_eigenvalue_per_s**2

    @property
    def follow_c1_per_s(self) -> float:
        """c1 = 2 omega_f - omega_f² tau (double eigenvalue -omega_f of eq 28)."""
        w = self.follow_eigenvalue_per_s
        return 2.0 * w - w * w * self.follow_tau_s

    @property
    def position_kp_per_s2(self) -> float:
        return self.position_omega_per_s**2

    @property
    def position_kd_per_s(self) -> float:
        return 2.0 * self.position_omega_per_s


@dataclass(frozen=True)
class LeadObservation:
    """The vehicle ahead on our path: bumper-to-bumper gap d_f and its speed v_B."""

    gap_m: float
    v_lead_mps: float


@dataclass(frozen=True)
class LongitudinalInputs:
    """One control cycle's inputs; `lead` / `stop_distance_m` None when there is none."""

    v_mps: float
    v_des_mps: float
    lead: LeadObservation | None = None
    stop_distance_m: float | None = None  # along the path to the stop line; negative once past it


@dataclass(frozen=True)
class LongitudinalState:
    """The controller's only memory: whether the stopping law's hysteresis is switched on."""

    stopping_active: bool = False


def velocity_accel(v_mps: float, v_des_mps: float, params: LongitudinalParams) -> float:
    """Eq 31: a_v = -c_v (v - v_d)."""
    return -params.velocity_gain_per_s * (v_mps - v_des_mps)


def following_accel(v_mps: float, lead: LeadObservation, params: LongitudinalParams) -> float:
    """Eqs 25-27: a_f = c0 (d_f - (d_f0 + tau v)) + c1 (v_B - v)."""
    gap_des_m = params.follow_d0_m + params.follow_tau_s * v_mps
    return params.follow_c0_per_s2 * (lead.gap_m - gap_des_m) + params.follow_c1_per_s * (
        lead.v_lead_mps - v_mps
    )


def stopping_required_decel(v_mps: float, stop_distance_m: float, params: LongitudinalParams) -> float:
    """b = v² / (2 (d_stop - d_delta)) >= 0, the deceleration eq 30 asks for; inf past its aim point."""
    span_m = stop_distance_m + params.stop_aim_beyond_m
    if span_m <= 0.0:
        return math.inf
    v = max(v_mps, 0.0)
    return v * v / (2.0 * span_m)


def stopping_accel(v_mps: float, stop_distance_m: float, params: LongitudinalParams) -> float:
    """Eq 30: a_s = -b; at and past the singularity, full braking a_min."""
    return max(-stopping_required_decel(v_mps, stop_distance_m, params), params.accel_min_mps2)


def position_accel(v_mps: float, stop_distance_m: float, params: LongitudinalParams) -> float:
    """PD position controller aiming at the stop line: a_p = k_p d_stop - k_d v, <= 0 in the hold zone."""
    a_p = params.position_kp_per_s2 * stop_distance_m - params.position_kd_per_s * v_mps
    if stop_distance_m <= params.stop_hold_zone_m:
        return min(a_p, 0.0)
    return a_p


def _check_finite(name: str, value: float) -> None:
    if not math.isfinite(value):
        raise ValueError(f"LongitudinalInputs.{name} = {value}: must be finite")


def _validate(inputs: LongitudinalInputs) -> None:
    _check_finite("v_mps", inputs.v_mps)
    _check_finite("v_des_mps", inputs.v_des_mps)
    if inputs.v_des_mps < 0.0:
        raise ValueError(
            f"LongitudinalInputs.v_des_mps = {inputs.v_des_mps}: forward driving only, must be >= 0"
        )
    if inputs.lead is not None:
        _check_finite("lead.gap_m", inputs.lead.gap_m)
        _check_finite("lead.v_lead_mps", inputs.lead.v_lead_mps)
    if inputs.stop_distance_m is not None:
        _check_finite("stop_distance_m", inputs.stop_distance_m)


def longitudinal_step(
    state: LongitudinalState, inputs: LongitudinalInputs, params: LongitudinalParams
) -> tuple[LongitudinalState, float, ActiveController]:
    """One cycle of the override strategy: (new state, saturated acceleration m/s², controller in charge).

    Pure: the same (state, inputs, params) always give the same result. Raises ValueError naming
    the field for non-finite inputs or a negative desired speed.
    """
    _validate(inputs)
    v = inputs.v_mps
    # NaN can only come from float overflow on absurd (yet finite) inputs: fail towards braking.
    a_floor = params.accel_min_mps2

    active: ActiveController = "velocity"
    accel = velocity_accel(v, inputs.v_des_mps, params)
    if math.isnan(accel):
        accel = a_floor

    if inputs.lead is not None:
        a_f = following_accel(v, inputs.lead, params)
        if math.isnan(a_f) or a_f < accel:
            accel, active = (a_floor if math.isnan(a_f) else a_f), "following"

    stopping_active = False
    d_stop = inputs.stop_distance_m
    if d_stop is not None:
        b = stopping_required_decel(v, d_stop, params)
        if state.stopping_active:
            stopping_active = b > params.stop_decel_off_mps2
        else:
            stopping_active = b >= params.stop_decel_on_mps2
        if stopping_active:
            a_s = stopping_accel(v, d_stop, params)
            if a_s < accel:
                accel, active = a_s, "stopping"
        a_p = position_accel(v, d_stop, params)
        if math.isnan(a_p) or a_p < accel:
            accel, active = (a_floor if math.isnan(a_p) else a_p), "position"

    accel = min(max(accel, params.accel_min_mps2), params.accel_max_mps2)
    return LongitudinalState(stopping_active=stopping_active), accel, active
