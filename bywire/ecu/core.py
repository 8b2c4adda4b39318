"""The ECU's pure core: one function from (state, inputs, time, calibration) to (state, commands).

Paper: seed 003 Sec. II-d and V-B (actuator control, driver intervention handling, fail-safe
functions and the low-level acceleration controller on the real-time computer); DARPA rules
3.4.2 for the stops; DESIGN section 4. The cyclic executive calls `core_step` every millisecond;
SIL calls the same function on a simulated clock. Nothing here reads a clock, a bus or a file.

What each state commands (`ActuatorCommand`):

- OFF, READY, MANUAL: passive. engage off, no throttle, no brake, no steering; the controller is
  reset and follows the measured acceleration and steering angle so that engaging is bumpless.
- ENGAGED: the host's request through the acceleration controller (clamp, jerk limit, feedforward
  maps, integrator); steering clamped and rate-limited while the STEER flag is set. Entered from
  the hold of a SAFE_STOP (re-armed with REARM and ENGAGE together) the integrator starts at zero
  as from READY and the target from where the stop left it (jerk-limited across the switch), the
  hold kept until the target rises above zero.
- PAUSED, SAFE_STOP, DISABLED (stops): the controller's target goes, jerk-limited, to -d with
  d = pause_decel (PAUSED), safe_stop_decel (SAFE_STOP) or disable_decel (DISABLED), the largest
  that applies (a SAFE_STOP while the radio says PAUSE stops at least as hard as a pause), and
  never less than earlier in the same stop (PAUSED -> SAFE_STOP keeps the pause's d). A stop
  never uses the throttle (propulsion never helps a stop; DARPA 3.4.2 "shuts down all
  propulsion" for DISABLE). Steering keeps its last commanded angle if it was enabled when the
  stop began in ENGAGED. DISABLED at standstill also turns the ignition off and sets the park
  brake; steering is released with the ignition.

The hold. A stop latches into the hold (hold_brake_bar, until the state changes) when the
measured speed falls below standstill_speed, and at the latest at the deadline fixed when the
stop begins:

    T = (a0 + d) / j + (v0 + max(a0, 0)^2 / (2 j)) / d + stop_margin_s

(`stop_time_bound_s`; v0 the speed and a0 the controller's target when the stop began, j =
jerk_max): the jerk ramp from a0 to -d, the time to lose v0 plus what the ramp can still add at
d, and a margin for the integrator to correct the maps. So every stop holds within T whatever
the car does; if it is still rolling then (a brake weaker than calibrated, a slope steeper than
the integrator covers) the hold pressure takes over.

Gears (`ecu.gear`, for urban driving: backing out of a parking spot). ENGAGED drives only while the gear the
host wants (RequestFlags.REVERSE), the gear the ECU asks the gateway for (`DBW_Command.GearRequest`)
and the gear the gateway reports engaged (`GW_Motion.GearEngaged`) agree. Otherwise it shifts: it
brakes at SHIFT_DECEL_MPS2 without throttle to standstill (every wheel below
SHIFT_STANDSTILL_SPEED_MPS), holds, asks for the new gear once the hold pressure has settled, and
drives on once the gateway reports that gear; a gear not confirmed within GEAR_CONFIRM_TIMEOUT_S is
the stop fault GEAR_TIMEOUT. Every other state asks for the engaged gear (no shift outside
ENGAGED). The controller always sees the speed magnitude (the wheel speeds are unsigned) and the
acceleration along the direction of travel of the engaged gear (LongAccel is signed in the vehicle
frame, so it flips in reverse); in reverse the request is capped to keep the speed below
REVERSE_SPEED_MAX_MPS. The stops are the same in either direction: the brakes oppose the motion.

Stops without vehicle data (timeout, corruption) run open loop on the brake feedforward, the
speed for the maps estimated from the last trusted speed (measured at most
BLIND_SPEED_MAX_AGE_S before, else the top of the calibrated speed range as v0) integrated with
the jerk-limited target. Standstill cannot be measured, so they hold at the deadline T: the
ECU "assumes standstill after v0/d + margin" (plus the ramp).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

from bywire.ecu.accel_controller import (
    ControllerState,
    PedalMode,
    controller_cycle,
    controller_passive,
    initial_controller_state,
    steer_step,
    step_dt_s,
)
from bywire.ecu.calibration import Calibration, fast_frozen_init
from bywire.ecu.gear import (
    GEAR_CONFIRM_TIMEOUT_S,
    SHIFT_BRAKE_SETTLE_S,
    SHIFT_DECEL_MPS2,
    SHIFT_STANDSTILL_SPEED_MPS,
    accel_along_travel_mps2,
    reverse_accel_limit_mps2,
)
from bywire.ecu.safety import (
    STOP_STATES,
    EcuInputs,
    SafetyState,
    active_fault_bits,
    initial_safety_state,
    safety_transition,
    vehicle_usable,
)
from bywire.protocol.ecu_types import EcuState, Fault, Gear, RequestFlags

__all__ = [
    "BLIND_SPEED_MAX_AGE_S",
    "ActuatorCommand",
    "CoreState",
    "EcuInputs",
    "InputVerdict",
    "clamp_steer",
    "core_step",
    "initial_core_state",
    "judge_inputs",
    "stop_decel_mps2",
    "stop_time_bound_s",
]

# A blind stop trusts the last measured speed only if it is this recent; older, the car may have
# sped up since (a driver in READY) and the top of the calibrated speed range is assumed.
BLIND_SPEED_MAX_AGE_S = 1.0

_STEER = int(RequestFlags.STEER)
_REVERSE_FLAG = int(RequestFlags.REVERSE)
_GEAR_TIMEOUT = int(Fault.GEAR_TIMEOUT)
_DRIVE, _REVERSE = Gear.DRIVE, Gear.REVERSE
_HOLD, _NONE = PedalMode.HOLD, PedalMode.NONE
_ESTOP_PAUSE = int(Fault.ESTOP_PAUSE)
_ENGAGED = EcuState.ENGAGED
_PAUSED = EcuState.PAUSED
_SAFE_STOP = EcuState.SAFE_STOP
_DISABLED = EcuState.DISABLED
_INF = math.inf

# Fault(int) costs 1-2 us (enum machinery); the few combinations that occur are cached.
_FAULTS: dict[int, Fault] = {}


def _fault(bits: int) -> Fault:
    f = _FAULTS.get(bits)
    if f is None:
        f = _FAULTS[bits] = Fault(bits)
    return f


class ActuatorCommand(NamedTuple):
    """The core's output for one cycle: the DBW_Command frame's content plus diagnostics.

    A NamedTuple rather than a frozen dataclass like the other records: one is built every
    millisecond, and a tuple of 17 fields builds in a third of the time (0.4 vs 1.2 us)."""

    state: EcuState
    faults_active: Fault  # this cycle's fault conditions
    faults_latched: Fault  # the cause of the current state
    throttle_pct: float  # 0..100
    brake_bar: float  # 0..200
    steer_angle_rad: float  # road wheel, + left; within +-steer_max_rad
    engage: bool  # the gateway applies our commands (else passes the driver through)
    steer_enable: bool
    ignition: bool
    park_brake: bool
    accel_target_mps2: float  # jerk-limited target
    accel_cmd_mps2: float  # what the pedal maps were asked for (target + integrator)
    integrator_mps2: float
    pedal: PedalMode
    holding: bool  # a stop or a shift has reached standstill and holds
    gear_request: Gear  # DBW_Command.GearRequest
    shifting: bool  # ENGAGED but not driving: the wanted, requested and engaged gears differ


@dataclass(frozen=True, slots=True)
class InputVerdict:
    """What the core concludes from one inputs object under one calibration: the active fault
    bits and whether the vehicle data is usable. Both are functions of the two frozen objects
    alone, so the same objects always give the same verdict: the executive passes the same
    inputs object for as long as nothing was received and nothing fresh expired (nine cycles in
    ten), and the core reuses the verdict instead of judging the same values again."""

    inputs: EcuInputs
    cal: Calibration
    active: int  # safety.active_fault_bits(inputs, cal)
    faults: Fault  # the same bits as a Fault, for the command
    usable: bool  # safety.vehicle_usable(inputs)
    steer_requested: bool  # the request's STEER flag
    wanted_gear: Gear  # the request's REVERSE flag as a gear
    accel_along_mps2: float  # the measured acceleration along the engaged gear's direction of travel
    standstill: bool  # usable and every wheel below SHIFT_STANDSTILL_SPEED_MPS


def judge_inputs(inp: EcuInputs, cal: Calibration) -> InputVerdict:
    active = active_fault_bits(inp, cal)
    flags = int(inp.request_flags)
    usable = vehicle_usable(inp)
    return InputVerdict(
        inp,
        cal,
        active,
        _fault(active),
        usable,
        bool(flags & _STEER),
        _REVERSE if flags & _REVERSE_FLAG else _DRIVE,
        accel_along_travel_mps2(inp.accel_meas_mps2, inp.gear_engaged),
        usable and inp.wheel_speed_max_mps < SHIFT_STANDSTILL_SPEED_MPS,
    )


@fast_frozen_init
@dataclass(frozen=True, slots=True)
class CoreState:
    safety: SafetyState
    controller: ControllerState
    steer_angle_rad: float  # last commanded road-wheel angle
    steer_enable: bool  # last cycle's steer_enable
    holding: bool  # the current stop holds at standstill
    blind: bool  # the current stop runs without usable vehicle data
    speed_est_mps: float  # last trusted speed; during a blind stop the open-loop estimate
    speed_trusted_t_s: float  # when the speed was last measured (-inf: never)
    stop_decel_mps2: float  # the current stop's deceleration (the largest cause so far)
    stop_deadline_s: float  # the current stop holds at the latest then (inf: no stop)
    gear_request: Gear  # what the last cycle asked the gateway for
    gear_wait_s: float  # since when the requested gear differs from the engaged one (inf: it does not)
    shift_hold_s: float  # since when a shift holds at standstill (inf: it does not)
    # The last cycle's verdict on its inputs (None at boot): reused while the inputs are the same
    # object. A cache, not state: it never changes what a cycle computes.
    verdict: InputVerdict | None = field(compare=False, repr=False)


def initial_core_state(now_s: float) -> CoreState:
    """The state at boot: OFF, passive, speed unknown."""
    return CoreState(
        safety=initial_safety_state(),
        controller=initial_controller_state(now_s),
        steer_angle_rad=0.0,
        steer_enable=False,
        holding=False,
        blind=False,
        speed_est_mps=0.0,
        speed_trusted_t_s=-_INF,
        stop_decel_mps2=0.0,
        stop_deadline_s=_INF,
        gear_request=Gear.DRIVE,
        gear_wait_s=_INF,
        shift_hold_s=_INF,
        verdict=None,
    )


def stop_decel_mps2(state: EcuState, active: Fault | int, cal: Calibration) -> float:
    """The deceleration a stop in `state` aims for (the largest of the causes that apply)."""
    if state == _DISABLED:
        d = cal.disable_decel_mps2
    elif state == _PAUSED:
        d = cal.pause_decel_mps2
    else:
        d = cal.safe_stop_decel_mps2
    if int(active) & _ESTOP_PAUSE and cal.pause_decel_mps2 > d:
        d = cal.pause_decel_mps2
    return d


def stop_time_bound_s(
    speed_mps: float, accel_target_mps2: float, decel_mps2: float, cal: Calibration
) -> float:
    """The stop deadline T: a stop that begins at speed_mps with the controller's target at
    accel_target_mps2 and decelerates at decel_mps2 holds at the latest T seconds later (see the
    module docstring)."""
    j = cal.jerk_max_mps3
    a0 = min(max(accel_target_mps2, cal.accel_min_mps2), cal.accel_max_mps2)
    ramp_s = max(a0 + decel_mps2, 0.0) / j
    v_peak = max(speed_mps, 0.0) + (a0 * a0 / (2.0 * j) if a0 > 0.0 else 0.0)
    return ramp_s + v_peak / decel_mps2 + cal.stop_margin_s


def clamp_steer(x: float, prev: float, cal: Calibration) -> float:
    """The road-wheel angle a cycle without a steering request commands: the measured angle `x`
    within +-steer_max (the last command `prev` if `x` is not finite)."""
    if not math.isfinite(x):
        return prev
    lim = cal.steer_max_rad
    return lim if x > lim else (-lim if x < -lim else x)


def core_step(
    st: CoreState, inp: EcuInputs, now_s: float, cal: Calibration
) -> tuple[CoreState, ActuatorCommand]:
    """One ECU cycle. `cal` must always be a Calibration: with `inp.calibration_valid` False the
    executive passes its fallback (default_calibration()) and the core stops or stays OFF.

    The safety transition first, then what the new state commands: `_step_engaged`, `_step_stop`
    (PAUSED, SAFE_STOP, DISABLED) or `_step_passive` (OFF, READY, MANUAL)."""
    verdict = st.verdict
    if verdict is None or verdict.inputs is not inp or verdict.cal is not cal:
        verdict = judge_inputs(inp, cal)
    active = verdict.active
    faults = verdict.faults
    if now_s - st.gear_wait_s > GEAR_CONFIRM_TIMEOUT_S and st.safety.state == _ENGAGED:
        # Last cycle's request is still not engaged: the selector does not answer (a stop fault).
        active |= _GEAR_TIMEOUT
        faults = _fault(active)
    saf = safety_transition(st.safety, inp, active, cal)
    s = saf.state
    if verdict.usable:
        v_est, trusted_t = inp.speed_mps, now_s
    else:
        v_est, trusted_t = st.speed_est_mps, st.speed_trusted_t_s
    if s == _ENGAGED:
        return _step_engaged(st, inp, now_s, cal, verdict, saf, faults, v_est, trusted_t)
    if s in STOP_STATES:
        return _step_stop(st, inp, now_s, cal, verdict, saf, active, faults, v_est, trusted_t)
    return _step_passive(st, inp, now_s, cal, verdict, saf, faults, v_est, trusted_t)


# The 1 kHz path: the controller by position, its output as a tuple, and the command built by
# position (field order of ActuatorCommand, named in the comments): building these objects is
# most of a cycle's cost, and keywords cost almost as much again. Each takes what core_step worked
# out: the cycle's verdict on its inputs (`ok`: the vehicle data is usable), the safety state it
# moved to, the fault bits (and in a stop, `active` as an int), and the speed estimate with when the
# speed was last measured.


def _step_engaged(
    st: CoreState,
    inp: EcuInputs,
    now_s: float,
    cal: Calibration,
    verdict: InputVerdict,
    saf: SafetyState,
    faults: Fault,
    v_est: float,
    trusted_t: float,
) -> tuple[CoreState, ActuatorCommand]:
    """ENGAGED: the host's request through the controller, or a shift while the gears differ."""
    ok = verdict.usable
    accel_along = verdict.accel_along_mps2
    engaged_gear = inp.gear_engaged
    ctl_prev = st.controller
    if st.safety.state == _SAFE_STOP:
        # Re-armed straight from the hold: the integrator starts afresh as from READY, the target
        # from where the stop left it (the jerk limit holds across the switch), so the hold stays
        # on until the target has risen above zero.
        target = ctl_prev.accel_target_mps2
        ctl_prev = controller_passive(ctl_prev.t_s, accel_along if ok else 0.0, cal)._replace(
            accel_target_mps2=target, accel_ref_mps2=target
        )
    wanted = verdict.wanted_gear
    gear_req = st.gear_request if st.safety.state == _ENGAGED else engaged_gear
    shifting = not (wanted == gear_req == engaged_gear)
    shift_hold_s = _INF
    if shifting:
        # Brake to standstill and hold (no throttle); ask for the new gear once the hold has
        # built up; drive once the gateway reports it (module docstring, ecu.gear).
        hold = verdict.standstill
        if hold:
            shift_hold_s = st.shift_hold_s if st.shift_hold_s <= now_s else now_s
            if gear_req != wanted and now_s - shift_hold_s >= SHIFT_BRAKE_SETTLE_S:
                gear_req = wanted
        ctl, thr, brk, pedal, a_tgt, a_cmd, integ = controller_cycle(
            ctl_prev,
            now_s,
            -SHIFT_DECEL_MPS2,  # accel_request_mps2
            accel_along,  # accel_meas_mps2
            inp.speed_mps,  # speed_mps
            True,  # closed_loop
            False,  # throttle_allowed
            hold,  # hold
            cal,
        )
        thr = 0.0
    else:
        a_req = inp.request_accel_mps2
        if engaged_gear == _REVERSE:
            a_lim = reverse_accel_limit_mps2(inp.speed_mps)
            if a_req > a_lim:
                a_req = a_lim
        ctl, thr, brk, pedal, a_tgt, a_cmd, integ = controller_cycle(
            ctl_prev,
            now_s,
            a_req,
            accel_along,
            inp.speed_mps,
            True,  # closed_loop
            True,  # throttle_allowed
            False,  # hold
            cal,
        )
    # An if, not a ternary: coverage measures the branches of an if (tools/safety_coverage.py).
    if gear_req == engaged_gear:  # noqa: SIM108
        gear_wait_s = _INF
    else:
        gear_wait_s = st.gear_wait_s if st.gear_wait_s <= now_s else now_s
    if verdict.steer_requested:
        dt = step_dt_s(st.controller.t_s, now_s)
        steer, steer_en = steer_step(st.steer_angle_rad, inp.request_steer_angle_rad, dt, cal), True
    else:
        steer, steer_en = clamp_steer(inp.steer_angle_meas_rad, st.steer_angle_rad, cal), False
    new = CoreState(
        saf,
        ctl,
        steer,
        steer_en,
        False,
        False,
        v_est,
        trusted_t,
        0.0,
        _INF,
        gear_req,
        gear_wait_s,
        shift_hold_s,
        verdict,
    )
    cmd = ActuatorCommand(
        saf.state,  # state
        faults,  # faults_active
        saf.latched,  # faults_latched
        thr,  # throttle_pct
        brk,  # brake_bar
        steer,  # steer_angle_rad
        True,  # engage
        steer_en,  # steer_enable
        True,  # ignition
        False,  # park_brake
        a_tgt,  # accel_target_mps2
        a_cmd,  # accel_cmd_mps2
        integ,  # integrator_mps2
        pedal,  # pedal
        shifting and pedal == _HOLD,  # holding
        gear_req,  # gear_request
        shifting,  # shifting
    )
    return new, cmd


def _step_stop(
    st: CoreState,
    inp: EcuInputs,
    now_s: float,
    cal: Calibration,
    verdict: InputVerdict,
    saf: SafetyState,
    active: int,
    faults: Fault,
    v_est: float,
    trusted_t: float,
) -> tuple[CoreState, ActuatorCommand]:
    """PAUSED, SAFE_STOP, DISABLED: brake at the stop's deceleration to the hold, without throttle."""
    s = saf.state
    ok = verdict.usable
    accel_along = verdict.accel_along_mps2
    engaged_gear = inp.gear_engaged
    entering = st.safety.state not in STOP_STATES
    blind = not ok
    if blind and (entering or not st.blind) and now_s - trusted_t > BLIND_SPEED_MAX_AGE_S:
        v_est = cal.throttle_map.speed_mps[-1]
    # A stop never softens: PAUSED -> SAFE_STOP keeps the pause's deceleration.
    decel = stop_decel_mps2(s, active, cal)
    if entering:
        holding = False
        deadline = now_s + stop_time_bound_s(v_est, st.controller.accel_target_mps2, decel, cal)
    else:
        holding = st.holding
        deadline = st.stop_deadline_s
        if st.stop_decel_mps2 > decel:
            decel = st.stop_decel_mps2
    if (ok and inp.speed_mps < cal.standstill_speed_mps) or now_s >= deadline:
        holding = True
    ctl, _, brk, pedal, a_tgt, a_cmd, integ = controller_cycle(
        st.controller,
        now_s,
        -decel,  # accel_request_mps2
        accel_along if ok else 0.0,  # accel_meas_mps2
        inp.speed_mps if ok else v_est,  # speed_mps
        ok,  # closed_loop
        False,  # throttle_allowed
        holding,  # hold
        cal,
    )
    if blind and not holding:
        v_est += a_tgt * step_dt_s(st.controller.t_s, now_s)
        if v_est < 0.0:
            v_est = 0.0
    off = s == _DISABLED and holding
    if st.steer_enable and not off:
        steer, steer_en = st.steer_angle_rad, True
    else:
        steer, steer_en = clamp_steer(inp.steer_angle_meas_rad, st.steer_angle_rad, cal), False
    new = CoreState(
        saf,
        ctl,
        steer,
        steer_en,
        holding,
        blind,
        v_est,
        trusted_t,
        decel,
        deadline,
        engaged_gear,  # a stop never shifts
        _INF,
        _INF,
        verdict,
    )
    cmd = ActuatorCommand(
        s,  # state
        faults,  # faults_active
        saf.latched,  # faults_latched
        0.0,  # throttle_pct: a stop never uses the throttle
        brk,  # brake_bar
        steer,  # steer_angle_rad
        True,  # engage
        steer_en,  # steer_enable
        not off,  # ignition
        off,  # park_brake
        a_tgt,  # accel_target_mps2
        a_cmd,  # accel_cmd_mps2
        integ,  # integrator_mps2
        pedal,  # pedal
        pedal == _HOLD,  # holding
        engaged_gear,  # gear_request
        False,  # shifting
    )
    return new, cmd


def _step_passive(
    st: CoreState,
    inp: EcuInputs,
    now_s: float,
    cal: Calibration,
    verdict: InputVerdict,
    saf: SafetyState,
    faults: Fault,
    v_est: float,
    trusted_t: float,
) -> tuple[CoreState, ActuatorCommand]:
    """OFF, READY, MANUAL: hands off; the gear stays as the car has it."""
    ok = verdict.usable
    accel_along = verdict.accel_along_mps2
    engaged_gear = inp.gear_engaged
    ctl = controller_passive(now_s, accel_along if ok else 0.0, cal)
    steer = clamp_steer(inp.steer_angle_meas_rad, st.steer_angle_rad, cal)
    new = CoreState(
        saf, ctl, steer, False, False, False, v_est, trusted_t, 0.0, _INF, engaged_gear, _INF, _INF, verdict
    )
    cmd = ActuatorCommand(
        saf.state,  # state
        faults,  # faults_active
        saf.latched,  # faults_latched
        0.0,  # throttle_pct
        0.0,  # brake_bar
        steer,  # steer_angle_rad
        False,  # engage
        False,  # steer_enable
        True,  # ignition
        False,  # park_brake
        ctl.accel_target_mps2,  # accel_target_mps2
        ctl.accel_target_mps2,  # accel_cmd_mps2
        0.0,  # integrator_mps2
        _NONE,  # pedal
        False,  # holding
        engaged_gear,  # gear_request
        False,  # shifting
    )
    return new, cmd
