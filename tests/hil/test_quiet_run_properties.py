"""`QuietRun` against `core_step` on random states and inputs.

A quiet run (`hil.sil_ecu`) follows only part of the core's state across the cycles it stands in
for, and hands the last cycle to `core_step`. Here, from random core states and inputs (every ECU
state, blind and seeing, steering or not, either gear, three calibrations), whenever `quiet_mode`
says the next cycles on the same inputs are quiet: each quiet cycle's controller, steering command
and speed estimate, and the state and command after the run's last cycle, equal those of the same
cycles run through `core_step`, bit for bit.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from hypothesis import HealthCheck, assume, event, given, settings
from hypothesis import strategies as st
from safety_spec import extreme_calibration  # tests/ is on pytest's pythonpath

from bywire.ecu.accel_controller import ControllerState, PedalMode
from bywire.ecu.calibration import Calibration, default_calibration
from bywire.ecu.core import CoreState, core_step
from bywire.ecu.safety import EcuInputs, SafetyState
from bywire.hil.sil_ecu import PASSIVE, QuietRun, quiet_deadline_s, quiet_mode
from bywire.protocol.ecu_types import EcuState, EstopMode, Fault, Gear, RequestFlags

CALS = {
    "passat": default_calibration(),
    "high": extreme_calibration("high"),
    "low": extreme_calibration("low"),
}

finite = st.floats(-30.0, 40.0, allow_nan=False)
speeds = st.one_of(st.floats(0.0, 40.0), st.sampled_from([0.0, 0.005, 0.05]))
# Any combination, ENGAGE (with or without STEER, either gear) most often.
engage = RequestFlags.ENGAGE
flags = st.one_of(
    st.builds(RequestFlags, st.integers(0, 31)),
    st.sampled_from(
        [
            engage,
            engage | RequestFlags.STEER,
            engage | RequestFlags.REVERSE,
            engage | RequestFlags.STEER | RequestFlags.REVERSE,
        ]
    ),
)
faults = st.sampled_from(
    [
        Fault.NONE,
        Fault.ESTOP_PAUSE,
        Fault.ESTOP_DISABLE,
        Fault.VEHICLE_TIMEOUT,
        Fault.HOST_STOP_REQUEST,
        Fault.DRIVER_OVERRIDE,
        Fault.CALIBRATION_INVALID,
    ]
)

# Mostly healthy (else the ECU seldom engages), each way of not being so now and then.
mostly = st.sampled_from([True] * 9 + [False])


def seldom_nan(values: st.SearchStrategy[float]) -> st.SearchStrategy[float]:
    """`values`, or NaN one time in ten."""
    return st.tuples(st.integers(0, 9), values).map(lambda p: math.nan if p[0] == 9 else p[1])


rarely = st.sampled_from([False] * 9 + [True])

inputs_strategy = st.builds(
    EcuInputs,
    estop_mode=st.sampled_from([EstopMode.RUN] * 4 + list(EstopMode)),
    estop_fresh=mostly,
    host_alive=mostly,
    request_accel_mps2=seldom_nan(st.floats(-6.0, 4.0)),
    request_steer_angle_rad=seldom_nan(st.floats(-0.6, 0.6)),
    request_flags=flags,
    request_fresh=mostly,
    vehicle_fresh=mostly,
    vehicle_corrupt=rarely,
    calibration_valid=mostly,
    overrun_streak=st.just(0),
    driver_brake_pressed=rarely,
    driver_throttle_pct=st.sampled_from([0.0, 0.0, 30.0]),
    driver_steer_torque_nm=st.sampled_from([0.0, 0.0, 6.0]),
    speed_mps=speeds,
    accel_meas_mps2=seldom_nan(st.floats(-8.0, 4.0)),
    steer_angle_meas_rad=seldom_nan(st.floats(-0.6, 0.6)),
    unlatch=rarely,
    gear_engaged=st.sampled_from(list(Gear)),
    wheel_speed_max_mps=st.one_of(speeds, st.just(math.inf)),
    safety_arm=rarely,
)


@st.composite
def core_states(draw: Any, t_s: float, cal: Calibration) -> CoreState:
    safety = SafetyState(
        state=draw(st.sampled_from([EcuState.ENGAGED] * 4 + list(EcuState))),
        latched=draw(faults),
        rearm_prev=draw(st.booleans()),
        unlatch_prev=draw(st.booleans()),
        engage_prev=draw(st.booleans()),
        arm_prev=draw(st.booleans()),
        unlatched=draw(st.booleans()),
        resume=draw(st.booleans()),
    )
    stop_decels = [cal.pause_decel_mps2, cal.safe_stop_decel_mps2, cal.disable_decel_mps2]
    controller = ControllerState(
        t_s - draw(st.sampled_from([0.001, 0.001, 0.01, 0.2])),
        # anywhere, or where a stop's target settles (the jerk limit keeps the rest far from it)
        draw(st.one_of(st.floats(-6.0, 3.0), st.sampled_from([-d for d in stop_decels]))),
        draw(st.floats(-6.0, 3.0)),
        draw(st.floats(-1.0, 1.0)),
        draw(st.sampled_from([PedalMode.NONE, PedalMode.THROTTLE, PedalMode.BRAKE])),
        t_s - draw(st.sampled_from([0.0, 0.1, 5.0, math.inf])),
    )
    return CoreState(
        safety=safety,
        controller=controller,
        steer_angle_rad=draw(st.floats(-0.6, 0.6)),
        steer_enable=draw(st.booleans()),
        holding=draw(st.booleans()),
        blind=draw(st.booleans()),
        speed_est_mps=draw(speeds),
        speed_trusted_t_s=t_s - draw(st.sampled_from([0.001, 0.5, 3.0, math.inf])),
        stop_decel_mps2=draw(st.sampled_from([0.0, 1.0, 6.0, *stop_decels])),
        stop_deadline_s=t_s + draw(st.sampled_from([0.003, 0.02, 5.0, math.inf])),
        gear_request=draw(st.sampled_from(list(Gear))),
        gear_wait_s=draw(st.sampled_from([math.inf, math.inf, t_s - 0.5, t_s - 3.0])),
        shift_hold_s=draw(st.sampled_from([math.inf, math.inf, t_s - 0.1, t_s - 1.0])),
        verdict=None,
    )


def _view(core: CoreState) -> tuple:
    return (
        core.controller,
        core.steer_angle_rad,
        core.steer_enable,
        core.speed_est_mps,
        core.speed_trusted_t_s,
    )


def _same(a: Any, b: Any) -> bool:
    return a == b or repr(a) == repr(b)  # NaN equals NaN here


def check_quiet_run(
    st0: CoreState, inputs: EcuInputs, cal: Calibration, t0: float, settle_cycles: int, n: int, step_s: float
) -> None:
    """From `st0`, `settle_cycles` full cycles on `inputs`; then, if quiet, `n` cycles both ways."""
    # A few full cycles on these inputs: the state a full cycle leaves (edges taken, stop entered).
    core0 = st0
    t = t0
    for _ in range(settle_cycles):
        core0, _ = core_step(core0, inputs, t, cal)
        t += step_s
    mode = quiet_mode(core0, inputs, cal)
    assume(mode is not None)
    assert mode is not None
    times = [t + k * step_s for k in range(n)]
    times = [x for x in times if x < quiet_deadline_s(core0)]
    assume(times)
    verdict = core0.verdict
    assert verdict is not None
    event(f"{mode}, {'seeing' if verdict.usable else 'blind'}, {'holding' if core0.holding else 'rolling'}")
    reference = []
    ref = core0
    for x in times:
        ref, cmd = core_step(ref, inputs, x, cal)
        reference.append((ref, cmd))
    run = QuietRun.start(mode, core0, inputs, cal)
    for x, (ref_state, _) in zip(times[:-1], reference, strict=False):
        run.advance(x)
        if mode != PASSIVE:
            assert _same(_view(run.state()), _view(ref_state)), (mode, x)
    last, cmd = core_step(run.state(), inputs, times[-1], cal)
    assert _same(last, reference[-1][0]), mode
    assert _same(cmd, reference[-1][1]), mode


SETTINGS = settings(
    max_examples=500, deadline=None, suppress_health_check=[HealthCheck.filter_too_much, HealthCheck.too_slow]
)


@SETTINGS
@given(
    data=st.data(),
    inputs=inputs_strategy,
    cal_name=st.sampled_from(sorted(CALS)),
    t0=st.floats(0.5, 100.0),
    settle_cycles=st.integers(1, 3),
    n=st.integers(1, 25),
    step_s=st.sampled_from([0.001, 0.001, 0.004]),
)
def test_a_quiet_run_ends_where_core_step_does(
    data: Any, inputs: EcuInputs, cal_name: str, t0: float, settle_cycles: int, n: int, step_s: float
) -> None:
    """Any state, any inputs: mostly stops and hands-off states (driving needs everything healthy)."""
    cal = CALS[cal_name]
    check_quiet_run(data.draw(core_states(t0, cal)), inputs, cal, t0, settle_cycles, n, step_s)


@SETTINGS
@given(
    data=st.data(),
    request_accel_mps2=st.floats(-6.0, 4.0),
    request_steer_angle_rad=st.floats(-0.7, 0.7),
    steer=st.booleans(),
    reverse=st.booleans(),
    speed_mps=speeds,
    accel_meas_mps2=st.floats(-8.0, 4.0),
    steer_angle_meas_rad=seldom_nan(st.floats(-0.7, 0.7)),
    cal_name=st.sampled_from(sorted(CALS)),
    t0=st.floats(0.5, 100.0),
    n=st.integers(1, 25),
    step_s=st.sampled_from([0.001, 0.001, 0.004]),
)
def test_a_quiet_drive_ends_where_core_step_does(
    data: Any,
    request_accel_mps2: float,
    request_steer_angle_rad: float,
    steer: bool,
    reverse: bool,
    speed_mps: float,
    accel_meas_mps2: float,
    steer_angle_meas_rad: float,
    cal_name: str,
    t0: float,
    n: int,
    step_s: float,
) -> None:
    """Driving, healthy: either gear (the reverse speed cap), steering or not; and shifting (the
    wanted, requested and engaged gears not all the same), which is never quiet."""
    cal = CALS[cal_name]
    gear = Gear.REVERSE if reverse else Gear.DRIVE
    engaged_gear, requested_gear = data.draw(
        st.sampled_from([(gear, gear)] * 6 + [(a, b) for a in Gear for b in Gear])
    )
    flags = RequestFlags.ENGAGE
    if steer:
        flags |= RequestFlags.STEER
    if reverse:
        flags |= RequestFlags.REVERSE
    inputs = EcuInputs(
        estop_mode=EstopMode.RUN,
        estop_fresh=True,
        host_alive=True,
        request_accel_mps2=request_accel_mps2,
        request_steer_angle_rad=request_steer_angle_rad,
        request_flags=flags,
        request_fresh=True,
        vehicle_fresh=True,
        vehicle_corrupt=False,
        calibration_valid=True,
        overrun_streak=0,
        driver_brake_pressed=False,
        driver_throttle_pct=0.0,
        driver_steer_torque_nm=0.0,
        speed_mps=speed_mps,
        accel_meas_mps2=accel_meas_mps2,
        steer_angle_meas_rad=steer_angle_meas_rad,
        unlatch=False,
        gear_engaged=engaged_gear,
        wheel_speed_max_mps=speed_mps,
        safety_arm=False,
    )
    engaged = SafetyState(
        EcuState.ENGAGED, Fault.NONE, rearm_prev=False, unlatch_prev=False, engage_prev=True, arm_prev=False
    )
    st0 = dataclasses.replace(
        data.draw(core_states(t0, cal)),
        safety=engaged,
        gear_request=requested_gear,
        holding=False,
        blind=False,
    )
    check_quiet_run(st0, inputs, cal, t0, 1, n, step_s)
