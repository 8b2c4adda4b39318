"""Cascaded acceleration controller: pedal feedforward maps plus an anti-windup integrator.

Paper: seed 003 Sec. V-B. "Two feedforward controllers translating setpoint accelerations into
virtual actuations for brake and throttle pedals, respectively [...]. An integral anti-windup
feedback controller compensates for disturbances from wind, slope, etc." The paper gives no
equations; this module writes them down:

1. a_req    = clamp(request, accel_min, accel_max)                          (seed 003 V-A limits)
   a_target = a_target_prev + clamp(a_req - a_target_prev, -j dt, +j dt)    (jerk limit j)
   The rate limiter is closed-form, one clamp per cycle. Not ruckig: the firmware is a pure-Python
   zipapp (no compiled wheels), and a first-order rate limit is all a 1 kHz loop on a single
   acceleration needs; the host shapes what it asks upstream (its manoeuvres drive off along ruckig's
   jerk-limited profile, `host/navigation/trajectory.py`), and this limit holds whatever it asks.
2. a_cmd = a_target + i. Pedal arbitration around the coasting acceleration a_coast(v) with a
   hysteresis h: throttle when a_cmd > a_coast + h, brake when a_cmd < a_coast - h, otherwise the
   current pedal. Throttle: pct = throttle_map(a_cmd, v) (bilinear, clamped 0..100). Brake:
   bar = brake_map(a_coast(v) - a_cmd) (1-D, deceleration beyond coasting). Never both.
3. i += ki (a_ref - a_meas) dt, the integrator living in the acceleration domain so that a pedal
   switch keeps a_cmd continuous (bumpless). a_ref is a reference model: a_target through a
   first-order lag with the active pedal's identified lag (throttle_lag_s, brake_lag_s). The
   feedforward is expected to lag that much; integrating the expected lag itself wound the
   integrator up on every step (measured on the plant: +0.33 m/s^2 overshoot after a +2 m/s^2
   step with a_target in place of a_ref). a_ref restarts from a_meas whenever the model has
   nothing to predict (holding, pedal saturated, just taken over). Anti-windup:
   - no integration while the active pedal is saturated in the error's direction (throttle at its
     top with a_meas too low; brake at its top with a_meas too high; with throttle forbidden, as in
     a stop, also brake at zero with a_meas too low). A throttle at zero is *not* saturation: the
     brake takes over below a_coast - h, so the integrator must be free to get there (and the
     same for a brake at zero in normal driving);
   - none for switch_freeze_s after a pedal switch (the new pedal's lag hides its effect);
   - clamped to +-integrator_max and to the headroom left to the active pedal (opendbc pid.py's
     "clip i to what the limits leave after feedforward"). Deviation from pid.py: the headroom
     clamp only stops the integrator from *growing* past the pedal's limit; a value already
     outside it because the target moved (a long full-throttle request at high speed) is kept,
     because it is the estimate of the slope and model error and is needed again as soon as
     the request comes back within reach. Together with the saturation freeze this is what keeps
     the grade compensation intact through a long saturation.
   The integrator is reset when the controller is passive and starts at 0 on engage.
   Without a trusted measurement (vehicle data lost during a stop) the loop runs open on the
   feedforward: no integration, and only a negative (braking-side) integrator is kept, so an
   open-loop stop errs on the strong side.
4. Standstill: measured speed < standstill_speed and a_target <= 0 -> hold at hold_brake_bar, no
   throttle; the integrator is frozen while holding (a_meas is 0 against any negative target).
   The caller can also force the hold (a stop that has latched its hold).
5. Steering: clamp to +-steer_max and rate-limit at steer_rate_max (`steer_step`).

Non-finite inputs do not propagate: a NaN request keeps the previous target, a NaN steering
request the previous angle, a NaN measurement opens the loop (the safety layer has already
stopped on all three; this is for callers that use the controller alone).
"""

from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass
from enum import IntEnum
from typing import NamedTuple

from bywire.ecu.calibration import (
    BRAKE_BAR_MAX,
    THROTTLE_PCT_MAX,
    BrakeMap,
    Calibration,
    CoastMap,
    ThrottleMap,
    fast_frozen_init,
)

__all__ = [
    "DT_MAX_S",
    "ControllerOutput",
    "ControllerState",
    "PedalMode",
    "SpeedTerms",
    "brake_accel_min_mps2",
    "brake_bar",
    "coast_accel_mps2",
    "controller_cycle",
    "controller_passive",
    "controller_step",
    "initial_controller_state",
    "jerk_limit",
    "rate_limit",
    "speed_terms",
    "steer_step",
    "step_dt_s",
    "throttle_accel_max_mps2",
    "throttle_pct",
]

# A gap between two steps longer than this (a stalled executive, the first step) is not turned
# into one big jerk- or rate-limit step: the limiters advance by at most DT_MAX_S.
DT_MAX_S = 0.05
_EPS = 1e-9


class PedalMode(IntEnum):
    """Which pedal the controller drives (diagnostics; HOLD is the standstill brake hold)."""

    NONE = 0
    THROTTLE = 1
    BRAKE = 2
    HOLD = 3


# Enum attribute lookups cost a few hundred ns each; the 1 kHz loop reads these globals instead.
_NONE, _THROTTLE, _BRAKE, _HOLD = PedalMode.NONE, PedalMode.THROTTLE, PedalMode.BRAKE, PedalMode.HOLD


class ControllerState(NamedTuple):
    """The longitudinal loop's memory between cycles (a NamedTuple: built every millisecond, see
    core.ActuatorCommand)."""

    t_s: float  # time of the last step
    accel_target_mps2: float  # jerk-limited target
    accel_ref_mps2: float  # the target through the active pedal's lag: what a_meas should show
    integrator_mps2: float
    pedal: PedalMode  # NONE, THROTTLE or BRAKE (the arbitration's memory)
    pedal_switch_t_s: float  # when `pedal` last changed


@fast_frozen_init
@dataclass(frozen=True, slots=True)
class ControllerOutput:
    """What one cycle of the loop commands, with the values behind it (diagnostics)."""

    throttle_pct: float
    brake_bar: float
    pedal: PedalMode  # as driven this cycle, HOLD at standstill
    accel_target_mps2: float
    accel_cmd_mps2: float  # target + integrator: what the pedal maps were asked for
    integrator_mps2: float


def initial_controller_state(now_s: float) -> ControllerState:
    return ControllerState(now_s, 0.0, 0.0, 0.0, _NONE, -math.inf)


# --- limiters -------------------------------------------------------------------------------------


def step_dt_s(prev_t_s: float, now_s: float) -> float:
    """Time since the previous step, clamped to 0 .. DT_MAX_S (time never runs backwards here)."""
    dt = now_s - prev_t_s
    if dt <= 0.0:
        return 0.0
    return dt if dt < DT_MAX_S else DT_MAX_S


def rate_limit(prev: float, target: float, dt_s: float, rate_max: float) -> float:
    """Move from prev towards target by at most rate_max * dt_s (closed form)."""
    step = rate_max * dt_s
    delta = target - prev
    if delta > step:
        return prev + step
    if delta < -step:
        return prev - step
    return target


def jerk_limit(a_prev_mps2: float, a_req_mps2: float, dt_s: float, jerk_max_mps3: float) -> float:
    """The acceleration target's rate limit: |da/dt| <= jerk_max."""
    return rate_limit(a_prev_mps2, a_req_mps2, dt_s, jerk_max_mps3)


def steer_step(prev_rad: float, request_rad: float, dt_s: float, cal: Calibration) -> float:
    """Road-wheel angle command: clamp to +-steer_max, then rate-limit at steer_rate_max."""
    lim = cal.steer_max_rad
    if request_rad != request_rad:  # NaN: hold the angle
        request_rad = prev_rad
    req = lim if request_rad > lim else (-lim if request_rad < -lim else request_rad)
    out = rate_limit(prev_rad, req, dt_s, cal.steer_rate_max_radps)
    # prev may come from outside the clamp (a passive state tracking the measured angle).
    return lim if out > lim else (-lim if out < -lim else out)


# --- maps -----------------------------------------------------------------------------------------


def _cell(xs: tuple[float, ...], x: float) -> tuple[int, float]:
    """Lower index and weight of x on a strictly increasing grid, clamped to its ends (NaN: the
    low end, so that no value at all can index outside the grid)."""
    if not x > xs[0]:
        return 0, 0.0
    n = len(xs)
    if x >= xs[-1]:
        return n - 2, 1.0
    i = bisect_right(xs, x) - 1
    x0 = xs[i]
    return i, (x - x0) / (xs[i + 1] - x0)


def _interp(xs: tuple[float, ...], ys: tuple[float, ...], x: float) -> float:
    i, w = _cell(xs, x)
    y0 = ys[i]
    return y0 + (ys[i + 1] - y0) * w


def coast_accel_mps2(m: CoastMap, speed_mps: float) -> float:
    """Acceleration with both pedals released (level road) at this speed."""
    return _interp(m.speed_mps, m.accel_mps2, speed_mps)


def throttle_pct(m: ThrottleMap, accel_mps2: float, speed_mps: float) -> float:
    """Throttle feedforward: bilinear in (speed, acceleration), clamped to 0..100 %."""
    i, wv = _cell(m.speed_mps, speed_mps)
    return _throttle_pct_in_row(m, i, wv, accel_mps2)


def _throttle_pct_in_row(m: ThrottleMap, i: int, wv: float, accel_mps2: float) -> float:
    """`throttle_pct` with the speed cell (row i, weight wv) already known."""
    j, wa = _cell(m.accel_mps2, accel_mps2)
    r0 = m.pct[i]
    r1 = m.pct[i + 1]
    p0 = r0[j] + (r0[j + 1] - r0[j]) * wa
    p1 = r1[j] + (r1[j + 1] - r1[j]) * wa
    p = p0 + (p1 - p0) * wv
    if p <= 0.0:
        return 0.0
    return p if p < THROTTLE_PCT_MAX else THROTTLE_PCT_MAX


def throttle_accel_max_mps2(m: ThrottleMap, speed_mps: float) -> float:
    """The lowest acceleration at which the throttle map reaches its top at this speed: asking for
    more changes nothing (the throttle pedal's saturation point).

    Both rows of the speed cell are non-decreasing, so their blend reaches its top exactly at the
    grid point where the later of the two rows reaches its own (`ThrottleMap.top_index`)."""
    i, wv = _cell(m.speed_mps, speed_mps)
    if wv == 0.0:
        k = m.top_index[i]
    elif wv == 1.0:
        k = m.top_index[i + 1]
    else:
        k = max(m.top_index[i], m.top_index[i + 1])
    return m.accel_mps2[k]


def brake_bar(m: BrakeMap, decel_mps2: float) -> float:
    """Brake feedforward: pressure for a deceleration beyond coasting (0 bar at or below zero)."""
    if decel_mps2 <= 0.0:
        return 0.0
    p = _interp(m.decel_mps2, m.bar, decel_mps2)
    return p if p < BRAKE_BAR_MAX else BRAKE_BAR_MAX


def brake_accel_min_mps2(cal: Calibration, speed_mps: float) -> float:
    """The lowest acceleration the brake map can ask for at this speed (the brake's saturation)."""
    return coast_accel_mps2(cal.coast_map, speed_mps) - cal.brake_map.decel_top_mps2


# --- the loop -------------------------------------------------------------------------------------


def controller_passive(now_s: float, accel_meas_mps2: float, cal: Calibration) -> ControllerState:
    """State while the ECU does not actuate: integrator reset, target following the measured
    acceleration (clamped to the limits; 0 if not finite) so that taking over is bumpless."""
    a = accel_meas_mps2
    if not math.isfinite(a):
        a = 0.0
    lo, hi = cal.accel_min_mps2, cal.accel_max_mps2
    a = lo if a < lo else (hi if a > hi else a)
    return ControllerState(now_s, a, a, 0.0, _NONE, -math.inf)


class SpeedTerms(NamedTuple):
    """The map values that depend on the speed alone, for one calibration: what `controller_step`
    needs of the maps apart from the throttle map's acceleration axis."""

    cal: Calibration
    speed_mps: float
    coast_accel_mps2: float  # coast_accel_mps2(cal.coast_map, speed)
    throttle_top_accel_mps2: float  # throttle_accel_max_mps2(cal.throttle_map, speed)
    brake_min_accel_mps2: float  # brake_accel_min_mps2(cal, speed)
    row: int  # the throttle map's speed cell: rows row and row + 1 ...
    row_w: float  # ... blended with this weight


def speed_terms(cal: Calibration, speed_mps: float) -> SpeedTerms:
    """The speed-dependent map values, computed exactly as the functions named in SpeedTerms do."""
    global _last_terms
    t = _last_terms
    if t is not None and t.speed_mps == speed_mps and t.cal is cal:
        return t
    tm = cal.throttle_map
    a_coast = coast_accel_mps2(cal.coast_map, speed_mps)
    row, row_w = _cell(tm.speed_mps, speed_mps)
    t = _last_terms = SpeedTerms(
        cal,
        speed_mps,
        a_coast,
        throttle_accel_max_mps2(tm, speed_mps),
        a_coast - cal.brake_map.decel_top_mps2,
        row,
        row_w,
    )
    return t


# One entry: the speed comes from a 100 Hz report, the controller runs at 1 kHz, so the same
# speed is asked for ten times in a row. Keyed by the (frozen) calibration's identity and the
# speed's value, it returns what the computation would; it never changes a result.
_last_terms: SpeedTerms | None = None


def controller_step(
    st: ControllerState,
    *,
    now_s: float,
    accel_request_mps2: float,
    accel_meas_mps2: float,
    speed_mps: float,
    closed_loop: bool,
    throttle_allowed: bool,
    hold: bool,
    cal: Calibration,
) -> tuple[ControllerState, ControllerOutput]:
    """One cycle of the acceleration loop (see the module docstring for the equations).

    closed_loop: accel_meas_mps2 and speed_mps are trusted (else speed_mps is an estimate and the
    loop runs on feedforward); throttle_allowed: False in stops (propulsion never helps a stop);
    hold: force the standstill hold (a stop that has reached standstill)."""
    new, thr, brk, pedal, a_tgt, a_cmd, i = controller_cycle(
        st, now_s, accel_request_mps2, accel_meas_mps2, speed_mps, closed_loop, throttle_allowed, hold, cal
    )
    return new, ControllerOutput(thr, brk, pedal, a_tgt, a_cmd, i)


def controller_cycle(
    st: ControllerState,
    now_s: float,
    accel_request_mps2: float,
    accel_meas_mps2: float,
    speed_mps: float,
    closed_loop: bool,
    throttle_allowed: bool,
    hold: bool,
    cal: Calibration,
) -> tuple[ControllerState, float, float, PedalMode, float, float, float]:
    """`controller_step` for the 1 kHz loop: the same computation, arguments by position, and the
    output as the tuple (state, throttle_pct, brake_bar, pedal, accel_target_mps2, accel_cmd_mps2,
    integrator_mps2) rather than a ControllerOutput (one object less per cycle)."""
    dt = now_s - st.t_s  # step_dt_s, inline
    if dt <= 0.0:
        dt = 0.0
    elif not dt < DT_MAX_S:
        dt = DT_MAX_S
    if closed_loop and not math.isfinite(accel_meas_mps2):
        closed_loop = False

    lo, hi = cal.accel_min_mps2, cal.accel_max_mps2
    a_prev = st.accel_target_mps2
    a_req = accel_request_mps2
    if a_req != a_req:  # NaN
        a_req = a_prev
    a_req = lo if a_req < lo else (hi if a_req > hi else a_req)
    a_tgt = jerk_limit(a_prev, a_req, dt, cal.jerk_max_mps3)

    v = speed_mps if speed_mps > 0.0 else 0.0
    terms = speed_terms(cal, v)
    a_coast = terms.coast_accel_mps2
    # Standstill is only believed when measured: an open-loop estimate reaching zero is not a stop.
    holding = hold or (closed_loop and v < cal.standstill_speed_mps and a_tgt <= 0.0)
    pedal = st.pedal
    i = st.integrator_mps2
    # Reference model: the feedforward is expected to lag the target by the pedal's lag; only the
    # rest is disturbance or model error for the integrator.
    tau = cal.brake_lag_s if pedal == _BRAKE else cal.throttle_lag_s
    a_ref = st.accel_ref_mps2
    if dt > 0.0:  # a step whose time does not advance moves nothing (and a lag of 0 divides by dt)
        a_ref += (a_tgt - a_ref) * (dt / (tau + dt))

    # Integrate with last cycle's pedal: its saturation is what this cycle's measurement shows.
    if closed_loop and not holding and pedal != _NONE:
        a_meas = accel_meas_mps2
        di = cal.ki_per_s * (a_ref - a_meas) * dt
        a_cmd0 = a_tgt + i
        saturated = False
        if pedal == _THROTTLE:
            if di > 0.0:
                head = terms.throttle_top_accel_mps2 - a_tgt
                saturated = a_cmd0 >= a_tgt + head - _EPS
        elif di < 0.0:
            head = terms.brake_min_accel_mps2 - a_tgt
            saturated = a_cmd0 <= a_tgt + head + _EPS
        else:  # a brake at zero is saturated only where the throttle may not take over (a stop)
            saturated = not throttle_allowed and a_cmd0 >= a_coast - _EPS
        if saturated:
            # The car does what the pedal's limit gives, not what the model expects: restart the
            # reference from the measurement, so that leaving the limit starts without an error.
            a_ref = a_meas
        elif now_s - st.pedal_switch_t_s >= cal.switch_freeze_s:
            i_new = i + di
            # Grow at most up to the active pedal's limit (head), never cut what is already there.
            if di > 0.0 and pedal == _THROTTLE:
                i = i_new if i_new < head else (head if head > i else i)
            elif di < 0.0 and pedal == _BRAKE:
                i = i_new if i_new > head else (head if head < i else i)
            else:
                i = i_new
            imax = cal.integrator_max_mps2
            i = imax if i > imax else (-imax if i < -imax else i)
    else:
        # Holding, open loop or just taken over: nothing for the model to predict from.
        a_ref = accel_meas_mps2 if closed_loop else a_tgt

    a_cmd = a_tgt + i if closed_loop else a_tgt + (i if i < 0.0 else 0.0)

    # Pedal arbitration with hysteresis around coasting; a stop only ever brakes.
    h = cal.pedal_hysteresis_mps2
    if not throttle_allowed:
        new_pedal = _BRAKE
    elif a_cmd > a_coast + h:
        new_pedal = _THROTTLE
    elif a_cmd < a_coast - h:
        new_pedal = _BRAKE
    elif pedal == _NONE:
        new_pedal = _THROTTLE if a_cmd >= a_coast else _BRAKE
    else:
        new_pedal = pedal
    if holding:
        new_pedal = _BRAKE  # leaving the hold is a switch to throttle, with its freeze
    switch_t = st.pedal_switch_t_s if new_pedal == pedal else now_s

    if holding:
        thr, brk, out_pedal = 0.0, cal.hold_brake_bar, _HOLD
    elif new_pedal == _THROTTLE:
        thr, brk, out_pedal = (
            _throttle_pct_in_row(cal.throttle_map, terms.row, terms.row_w, a_cmd),
            0.0,
            new_pedal,
        )
    else:
        thr, brk, out_pedal = 0.0, brake_bar(cal.brake_map, a_coast - a_cmd), new_pedal

    return ControllerState(now_s, a_tgt, a_ref, i, new_pedal, switch_t), thr, brk, out_pedal, a_tgt, a_cmd, i
