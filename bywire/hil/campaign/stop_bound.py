"""The stopping distance an ECU stop may take, derived from the calibration (docs/stopping_distance.md).

A stop that begins when a fault hits at speed v, with the host asking a0 (clamped to the calibration's
limits), detected t_d later, runs in three phases (`ecu.core` module docstring, DARPA rules 3.4.2):

1. detection, t_d: the car still follows the last request, s1 = v t_d + a0+ t_d^2 / 2, and reaches
   v1 = v + a0+ t_d (a0+ = max(a0, 0): a request to slow down is not counted on);
2. the jerk-limited ramp of the target from a0+ to -d, t_r = (a0+ + d) / j, and the brake's lag tau
   (the calibration's identified brake_lag_s plus the plant's actuator delay): no deceleration is
   counted, and the speed may still rise by a0+^2 / (2 j) to v_pk = v1 + a0+^2 / (2 j),
   s2 = v_pk (t_r + tau);
3. braking at d less the downhill component of gravity the brake maps do not know (the integrator
   removes it over about 1 / ki seconds; not counted on): d_eff = d - g max(0, -grade),
   s3 = v_pk^2 / (2 d_eff);

plus a margin of 1 m for the evaluation's sampling (10 ms at 25 m/s is 0.25 m) and its standstill
threshold. d is the calibration's deceleration of the state the ECU stopped in (PAUSED: pause_decel,
SAFE_STOP: safe_stop_decel, DISABLED: disable_decel); a driver's stop (MANUAL) is the driver's, and
has no bound here. With a0 = 0 this is the familiar v^2 / (2 d) + v t_detect + margin, the margin
being the ramp and the lag.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from bywire.ecu.calibration import Calibration
from bywire.hil.scenario import Scenario
from bywire.profiles import ramp_value, step_value

G_MPS2 = 9.81
MARGIN_M = 1.0


@dataclass(frozen=True)
class StopBound:
    bound_m: float
    decel_mps2: float  # d of the stop
    decel_effective_mps2: float  # d_eff: less the steepest downhill grade during the stop
    accel_at_fault_mps2: float  # a0+


def stop_decel_for(state: str, cal: Calibration) -> float | None:
    """d of a stop in `state` (an ECU state's name); None for a stop that is not the ECU's."""
    return {
        "PAUSED": cal.pause_decel_mps2,
        "SAFE_STOP": cal.safe_stop_decel_mps2,
        "DISABLED": cal.disable_decel_mps2,
    }.get(state)


def stop_distance_bound(
    v_mps: float,
    detect_s: float,
    decel_mps2: float,
    cal: Calibration,
    accel_mps2: float = 0.0,
    grade_pct: float = 0.0,
    actuator_delay_s: float = 0.0,
) -> StopBound:
    """The bound (see the module docstring); `grade_pct` the steepest grade during the stop (negative:
    downhill); `accel_mps2` the host's request when the fault hit."""
    j = cal.jerk_max_mps3
    a0 = min(max(accel_mps2, 0.0), cal.accel_max_mps2)
    d_eff = decel_mps2 - G_MPS2 * max(0.0, -grade_pct / 100.0)
    v1 = v_mps + a0 * detect_s
    v_pk = v1 + a0 * a0 / (2.0 * j)
    s1 = v_mps * detect_s + 0.5 * a0 * detect_s**2
    s2 = v_pk * ((a0 + decel_mps2) / j + cal.brake_lag_s + actuator_delay_s)
    s3 = v_pk * v_pk / (2.0 * d_eff) if d_eff > 0.0 else math.inf
    return StopBound(s1 + s2 + s3 + MARGIN_M, decel_mps2, d_eff, a0)


def _steepest_downhill_pct(scenario: Scenario, t0_s: float) -> float:
    """The lowest grade from t0_s to the end (the profile's points after t0 and its value at t0)."""
    points = [g for t, g in scenario.grade_pct if t >= t0_s] + [ramp_value(scenario.grade_pct, t0_s)]
    return min(points)


def stop_bound_metrics(
    scenario: Scenario, metrics: dict[str, Any], cal: Calibration | None
) -> dict[str, Any]:
    """`stop_distance_bound_m` and `stop_distance_excess_m` (measured minus bound: <= 0 is within) of a
    run whose fault the ECU stopped for; {} where there is no such stop or no calibration."""
    v = metrics.get("speed_at_fault_mps")
    detect_ms = metrics.get("fault_detect_ms")
    state = metrics.get("stop_state")
    if cal is None or scenario.fault_ref_s is None or v is None or detect_ms is None or state is None:
        return {}
    d = stop_decel_for(str(state), cal)
    if d is None:
        return {}
    t0 = scenario.fault_ref_s
    # the host's request when the fault hit: the script's; a driving host may ask up to the limit
    a0 = step_value(scenario.accel_profile, t0) if scenario.host_mode == "script" else cal.accel_max_mps2
    bound = stop_distance_bound(
        float(v),
        float(detect_ms) / 1000.0,
        d,
        cal,
        accel_mps2=a0,
        grade_pct=_steepest_downhill_pct(scenario, t0),
        actuator_delay_s=scenario.actuator_delay_ms / 1000.0,
    )
    out: dict[str, Any] = {"stop_distance_bound_m": round(bound.bound_m, 3)}
    measured = metrics.get("stop_distance_m")
    out["stop_distance_excess_m"] = None if measured is None else round(float(measured) - bound.bound_m, 3)
    return out


__all__ = ["StopBound", "stop_bound_metrics", "stop_decel_for", "stop_distance_bound"]
