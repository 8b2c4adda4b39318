"""The ECU safety spec, one test class per behaviour (opendbc style), run through `core_step`
closed around the point-mass plant (tests/plant_model.py).

Spec: ecu/safety.py and ecu/core.py docstrings; DARPA Urban Challenge rules 3.4.2 (E-stop).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, ClassVar

import plant_model as _pm  # tests/ is on pytest's pythonpath
import pytest

from bywire.ecu.accel_controller import brake_bar, coast_accel_mps2
from bywire.ecu.calibration import default_calibration
from bywire.ecu.core import ActuatorCommand, stop_time_bound_s
from bywire.ecu.safety import (
    OVERRUN_STREAK_LIMIT,
    STOP_FAULTS,
    SafetyState,
    active_faults,
    engage_allowed,
    initial_safety_state,
    safety_step,
)
from bywire.protocol.ecu_types import EcuState, EstopMode, Fault, RequestFlags

CoreLoop = _pm.CoreLoop
healthy_inputs = _pm.healthy_inputs

CAL = default_calibration()
ENGAGE = RequestFlags.ENGAGE | RequestFlags.STEER
REARM = ENGAGE | RequestFlags.REARM
NAN = math.nan


def engaged(speed_mps: float = 0.0, *, dt_s: float = 0.001, grade: float = 0.0, **changes: Any) -> Any:
    """A loop that has engaged (OFF -> READY -> ENGAGED) with the plant at speed_mps."""
    loop = CoreLoop(CAL, speed_mps=speed_mps, dt_s=dt_s, grade=grade)
    loop.step(**changes)
    cmd = loop.step(**changes)
    assert cmd.state == EcuState.ENGAGED and cmd.engage
    return loop


def ready(speed_mps: float = 0.0, **changes: Any) -> Any:
    loop = CoreLoop(CAL, speed_mps=speed_mps)
    cmd = loop.step(request_flags=RequestFlags.NONE, **changes)
    assert cmd.state == EcuState.READY
    return loop


def assert_passive(cmd: ActuatorCommand) -> None:
    assert not cmd.engage and not cmd.steer_enable
    assert cmd.throttle_pct == 0.0 and cmd.brake_bar == 0.0


def is_held(cmd: ActuatorCommand) -> bool:
    return cmd.holding and cmd.brake_bar == CAL.hold_brake_bar and cmd.throttle_pct == 0.0


# Engage preconditions, each broken alone (DESIGN section 4; safety.py rule 5).
BREAKERS: dict[str, dict[str, Any]] = {
    "no ENGAGE flag": {"request_flags": RequestFlags.STEER},
    "E-stop PAUSE": {"estop_mode": EstopMode.PAUSE},
    "E-stop DISABLE": {"estop_mode": EstopMode.DISABLE},
    "E-stop INVALID": {"estop_mode": EstopMode.INVALID},
    "E-stop stale": {"estop_fresh": False},
    "host heartbeat lost": {"host_alive": False},
    "request stale": {"request_fresh": False},
    "request accel NaN": {"request_accel_mps2": NAN},
    "request steer inf": {"request_steer_angle_rad": math.inf},
    "vehicle stale": {"vehicle_fresh": False},
    "vehicle corrupt": {"vehicle_corrupt": True},
    "speed NaN": {"speed_mps": NAN},
    "accel NaN": {"accel_meas_mps2": NAN},
    "calibration invalid": {"calibration_valid": False},
    "overrun streak": {"overrun_streak": OVERRUN_STREAK_LIMIT},
    "driver brake": {"driver_brake_pressed": True},
    "driver torque": {"driver_steer_torque_nm": CAL.driver_torque_threshold_nm + 0.01},
    "driver throttle": {"driver_throttle_pct": CAL.driver_throttle_threshold_pct + 0.1},
    "host STOP": {"request_flags": ENGAGE | RequestFlags.STOP},
}

# Faults while ENGAGED: (inputs, latched bit). safety.py rule 6.
FAULTS: dict[str, tuple[dict[str, Any], Fault]] = {
    "host heartbeat lost": ({"host_alive": False}, Fault.HOST_HEARTBEAT),
    "request stale": ({"request_fresh": False}, Fault.REQUEST_INVALID),
    "request accel NaN": ({"request_accel_mps2": NAN}, Fault.REQUEST_INVALID),
    "request steer NaN": ({"request_steer_angle_rad": NAN}, Fault.REQUEST_INVALID),
    "vehicle timeout": ({"vehicle_fresh": False}, Fault.VEHICLE_TIMEOUT),
    "vehicle corrupt": ({"vehicle_corrupt": True}, Fault.VEHICLE_CORRUPT),
    "vehicle speed NaN": ({"speed_mps": NAN}, Fault.VEHICLE_CORRUPT),
    "E-stop stale": ({"estop_fresh": False}, Fault.ESTOP_TIMEOUT),
    "E-stop INVALID": ({"estop_mode": EstopMode.INVALID}, Fault.ESTOP_TIMEOUT),
    "overrun streak": ({"overrun_streak": OVERRUN_STREAK_LIMIT}, Fault.OVERRUN),
    "calibration invalid": ({"calibration_valid": False}, Fault.CALIBRATION_INVALID),
    "host STOP flag": ({"request_flags": ENGAGE | RequestFlags.STOP}, Fault.HOST_STOP_REQUEST),
    "host drops ENGAGE": ({"request_flags": RequestFlags.STEER}, Fault.HOST_STOP_REQUEST),
}
BLIND = {"vehicle timeout", "vehicle corrupt", "vehicle speed NaN"}


def hold_decel_mps2() -> float:
    """What the calibration believes the hold pressure decelerates (inverse brake map)."""
    m = CAL.brake_map
    for d0, d1, p0, p1 in zip(m.decel_mps2, m.decel_mps2[1:], m.bar, m.bar[1:], strict=False):
        if p0 <= CAL.hold_brake_bar <= p1:
            return d0 + (d1 - d0) * (CAL.hold_brake_bar - p0) / (p1 - p0)
    return m.decel_mps2[-1]


class TestBoot:
    def test_boots_off_then_ready_never_engaging_in_the_first_cycle(self) -> None:
        loop = CoreLoop(CAL)
        assert loop.state.safety.state == EcuState.OFF
        cmd = loop.step()
        assert cmd.state == EcuState.READY
        assert_passive(cmd)

    def test_without_a_valid_calibration_it_stays_off(self) -> None:
        loop = CoreLoop(CAL)
        for _ in range(200):
            cmd = loop.step(calibration_valid=False)
            assert cmd.state == EcuState.OFF
            assert_passive(cmd)
        assert cmd.faults_active & Fault.CALIBRATION_INVALID
        assert loop.step().state == EcuState.READY

    def test_ready_goes_off_when_the_calibration_is_lost(self) -> None:
        loop = ready()
        cmd = loop.step(calibration_valid=False, request_flags=RequestFlags.NONE)
        assert cmd.state == EcuState.OFF and cmd.faults_latched == Fault.CALIBRATION_INVALID


class TestEngagePreconditions:
    def test_engages_when_all_hold(self) -> None:
        loop = ready()
        cmd = loop.step()
        assert cmd.state == EcuState.ENGAGED and cmd.engage and cmd.faults_active == Fault.NONE
        assert engage_allowed(loop.last_inputs, CAL)

    @pytest.mark.parametrize("name", sorted(BREAKERS))
    def test_each_missing_precondition_blocks_engage(self, name: str) -> None:
        loop = ready()
        for _ in range(100):
            cmd = loop.step(**BREAKERS[name])
            assert cmd.state != EcuState.ENGAGED
            assert not engage_allowed(loop.last_inputs, CAL)
        assert engage_allowed(healthy_inputs(), CAL)  # that one change was the only obstacle

    def test_overrun_streak_boundary(self) -> None:
        loop = ready()
        assert loop.step(overrun_streak=OVERRUN_STREAK_LIMIT - 1).state == EcuState.ENGAGED
        loop = ready()
        assert loop.step(overrun_streak=OVERRUN_STREAK_LIMIT).state == EcuState.READY

    @pytest.mark.parametrize("start", ["MANUAL", "SAFE_STOP", "DISABLED"])
    def test_engage_only_from_ready(self, start: str) -> None:
        loop = engaged(0.0)
        if start == "MANUAL":
            loop.step(driver_brake_pressed=True)
        elif start == "SAFE_STOP":
            loop.step(host_alive=False)
        else:
            loop.step(estop_mode=EstopMode.DISABLE)
        for _ in range(200):  # the cause is gone and ENGAGE is requested all along
            cmd = loop.step()
            assert cmd.state == EcuState[start]


class TestFaultBits:
    EXPECTED: ClassVar[dict[str, Fault]] = {
        "no ENGAGE flag": Fault.NONE,
        "E-stop PAUSE": Fault.ESTOP_PAUSE,
        "E-stop DISABLE": Fault.ESTOP_DISABLE,
        "E-stop INVALID": Fault.ESTOP_TIMEOUT,
        "E-stop stale": Fault.ESTOP_TIMEOUT,
        "host heartbeat lost": Fault.HOST_HEARTBEAT,
        "request stale": Fault.REQUEST_INVALID,
        "request accel NaN": Fault.REQUEST_INVALID,
        "request steer inf": Fault.REQUEST_INVALID,
        "vehicle stale": Fault.VEHICLE_TIMEOUT,
        "vehicle corrupt": Fault.VEHICLE_CORRUPT,
        "speed NaN": Fault.VEHICLE_CORRUPT,
        "accel NaN": Fault.VEHICLE_CORRUPT,
        "calibration invalid": Fault.CALIBRATION_INVALID,
        "overrun streak": Fault.OVERRUN,
        "driver brake": Fault.DRIVER_OVERRIDE,
        "driver torque": Fault.DRIVER_OVERRIDE,
        "driver throttle": Fault.DRIVER_OVERRIDE,
        "host STOP": Fault.HOST_STOP_REQUEST,
    }

    def test_every_breaker_has_its_bit(self) -> None:
        assert set(self.EXPECTED) == set(BREAKERS)

    @pytest.mark.parametrize("name", sorted(BREAKERS))
    def test_each_condition_reports_exactly_its_bit(self, name: str) -> None:
        assert active_faults(healthy_inputs(**BREAKERS[name]), CAL) == self.EXPECTED[name]

    def test_stale_and_corrupt_report_both(self) -> None:
        inp = healthy_inputs(vehicle_fresh=False, vehicle_corrupt=True)
        assert active_faults(inp, CAL) == Fault.VEHICLE_TIMEOUT | Fault.VEHICLE_CORRUPT

    def test_a_stale_disable_is_reported_as_disable(self) -> None:
        inp = healthy_inputs(estop_mode=EstopMode.DISABLE, estop_fresh=False)
        assert active_faults(inp, CAL) == Fault.ESTOP_DISABLE

    def test_driver_inputs_are_not_believed_from_stale_data(self) -> None:
        inp = healthy_inputs(vehicle_fresh=False, driver_brake_pressed=True)
        assert active_faults(inp, CAL) == Fault.VEHICLE_TIMEOUT

    def test_healthy_is_no_fault(self) -> None:
        assert active_faults(healthy_inputs(), CAL) == Fault.NONE


class TestPauseResume:
    def test_pause_stops_promptly_and_holds_for_hours_on_a_slope(self) -> None:
        loop = engaged(20.0, dt_s=0.01, grade=0.10)
        loop.run(3.0, request_accel_mps2=0.0)
        v0, a0 = loop.plant.speed_mps, loop.cmd.accel_target_mps2
        cmd = loop.step(estop_mode=EstopMode.PAUSE)
        assert cmd.state == EcuState.PAUSED and cmd.throttle_pct == 0.0 and cmd.engage
        assert cmd.faults_latched == Fault.ESTOP_PAUSE
        decels = []
        while loop.plant.speed_mps > 2.0:
            cmd = loop.step(estop_mode=EstopMode.PAUSE)
            if loop.t_s > 4.5:  # past the jerk ramp and the integrator's settling
                decels.append(loop.plant.accel_mps2)
        assert sum(decels) / len(decels) == pytest.approx(-CAL.pause_decel_mps2, abs=0.3)
        bound = stop_time_bound_s(v0, a0, CAL.pause_decel_mps2, CAL)
        assert loop.run_until(is_held, bound, estop_mode=EstopMode.PAUSE) <= bound + loop.dt_s
        loop.dt_s = 1.0  # two hours at 1 Hz
        for _ in range(7200):
            cmd = loop.step(estop_mode=EstopMode.PAUSE)
            assert cmd.state == EcuState.PAUSED and is_held(cmd)
        assert loop.plant.speed_mps == 0.0

    def test_resume_when_run_returns_and_engage_is_still_requested(self) -> None:
        loop = engaged(10.0, dt_s=0.01)
        loop.run(8.0, estop_mode=EstopMode.PAUSE)
        assert loop.plant.speed_mps == 0.0
        cmd = loop.step(request_accel_mps2=1.0)
        assert cmd.state == EcuState.ENGAGED
        loop.run(3.0, request_accel_mps2=1.0)
        assert loop.plant.speed_mps > 1.0

    def test_run_without_engage_request_keeps_holding_until_rearm(self) -> None:
        loop = engaged(10.0, dt_s=0.01)
        loop.run(8.0, estop_mode=EstopMode.PAUSE, request_flags=RequestFlags.NONE)
        assert loop.cmd.state == EcuState.PAUSED  # dropping ENGAGE in a pause is not a fault
        cmd = loop.step(request_flags=RequestFlags.NONE)
        # RUN alone must not release the brakes of a stopped car nobody asks to drive.
        assert cmd.state == EcuState.SAFE_STOP and cmd.faults_latched == Fault.HOST_STOP_REQUEST
        loop.run(5.0, request_flags=RequestFlags.NONE)
        assert loop.cmd.brake_bar >= CAL.hold_brake_bar and loop.plant.speed_mps == 0.0
        loop.step(request_flags=RequestFlags.REARM)
        cmd = loop.step(request_flags=RequestFlags.NONE)
        assert cmd.state == EcuState.READY
        assert_passive(cmd)

    def test_pause_from_ready_brakes(self) -> None:
        loop = ready(15.0)
        cmd = loop.step(estop_mode=EstopMode.PAUSE, request_flags=RequestFlags.NONE)
        assert cmd.state == EcuState.PAUSED and cmd.engage
        loop.run(1.5, estop_mode=EstopMode.PAUSE, request_flags=RequestFlags.NONE)
        assert loop.cmd.brake_bar > 0.0 and not loop.cmd.steer_enable
        assert loop.cmd.state == EcuState.PAUSED

    def test_pause_and_engage_drop_together_is_a_pause(self) -> None:
        loop = engaged(10.0)
        cmd = loop.step(estop_mode=EstopMode.PAUSE, request_flags=RequestFlags.NONE)
        assert cmd.state == EcuState.PAUSED

    @pytest.mark.parametrize("fault", ["host heartbeat lost", "E-stop stale", "vehicle timeout"])
    def test_a_fault_during_a_pause_latches_safe_stop(self, fault: str) -> None:
        loop = engaged(10.0)
        loop.step(estop_mode=EstopMode.PAUSE)
        changes, bit = FAULTS[fault]
        cmd = loop.step(estop_mode=EstopMode.PAUSE, **changes)
        assert cmd.state == EcuState.SAFE_STOP and cmd.faults_latched & bit
        for _ in range(100):
            assert loop.step().state == EcuState.SAFE_STOP  # RUN alone does not resume


class TestDisableLatch:
    @pytest.mark.parametrize("start", ["OFF", "READY", "ENGAGED", "PAUSED", "SAFE_STOP", "MANUAL"])
    def test_disable_from_any_state(self, start: str) -> None:
        loop = CoreLoop(CAL, speed_mps=10.0)
        if start == "OFF":
            loop.step(calibration_valid=False)
        elif start == "READY":
            loop.step(request_flags=RequestFlags.NONE)
        else:
            loop.run(0.002)
            extra = {
                "ENGAGED": {},
                "PAUSED": {"estop_mode": EstopMode.PAUSE},
                "SAFE_STOP": {"host_alive": False},
                "MANUAL": {"driver_brake_pressed": True},
            }[start]
            loop.step(**extra)
        assert loop.cmd.state == EcuState[start]
        cmd = loop.step(estop_mode=EstopMode.DISABLE, driver_brake_pressed=start == "MANUAL")
        assert cmd.state == EcuState.DISABLED and cmd.faults_latched == Fault.ESTOP_DISABLE
        assert cmd.throttle_pct == 0.0 and cmd.engage  # propulsion off, our brakes on

    def test_stops_then_ignition_off_and_park_brake(self) -> None:
        loop = engaged(20.0, dt_s=0.01)
        loop.run(2.0, request_accel_mps2=1.0)
        v0, a0 = loop.plant.speed_mps, loop.cmd.accel_target_mps2
        loop.step(estop_mode=EstopMode.DISABLE)
        bound = stop_time_bound_s(v0, a0, CAL.disable_decel_mps2, CAL)
        decels = []
        while not (cmd := loop.step(estop_mode=EstopMode.DISABLE)).holding:
            assert cmd.throttle_pct == 0.0 and cmd.ignition and not cmd.park_brake
            if loop.t_s > 4.5 and loop.plant.speed_mps > 2.0:
                decels.append(loop.plant.accel_mps2)
        assert loop.t_s - 2.01 <= bound
        assert sum(decels) / len(decels) == pytest.approx(-CAL.disable_decel_mps2, abs=0.4)
        assert not cmd.ignition and cmd.park_brake and cmd.brake_bar == CAL.hold_brake_bar
        loop.run(1.0, estop_mode=EstopMode.DISABLE)
        assert loop.plant.speed_mps == 0.0
        assert not cmd.steer_enable

    def test_latched_until_manual_unlatch_edge_with_radio_not_disable(self) -> None:
        loop = engaged(0.0)
        loop.step(estop_mode=EstopMode.DISABLE)
        for _ in range(50):  # the radio back to RUN, REARM, ENGAGE: none of them unlatches
            assert loop.step(request_flags=REARM).state == EcuState.DISABLED
            assert loop.step().state == EcuState.DISABLED
        cmd = loop.step(estop_mode=EstopMode.DISABLE, unlatch=True)  # radio still DISABLE
        assert cmd.state == EcuState.DISABLED
        cmd = loop.step(unlatch=True)  # radio RUN, but the switch is still the same press
        assert cmd.state == EcuState.DISABLED
        loop.step(unlatch=False)
        cmd = loop.step(unlatch=True, request_flags=RequestFlags.NONE)
        assert cmd.state == EcuState.READY and cmd.ignition and not cmd.park_brake

    def test_unlatch_without_calibration_goes_off(self) -> None:
        loop = engaged(0.0)
        loop.step(estop_mode=EstopMode.DISABLE)
        cmd = loop.step(unlatch=True, calibration_valid=False)
        assert cmd.state == EcuState.OFF

    def test_a_stale_disable_is_still_a_disable(self) -> None:
        loop = engaged(5.0)
        cmd = loop.step(estop_mode=EstopMode.DISABLE, estop_fresh=False)
        assert cmd.state == EcuState.DISABLED

    def test_driver_input_does_not_leave_disabled(self) -> None:
        loop = engaged(5.0)
        loop.step(estop_mode=EstopMode.DISABLE)
        for _ in range(100):
            cmd = loop.step(estop_mode=EstopMode.DISABLE, driver_brake_pressed=True, driver_throttle_pct=50.0)
            assert cmd.state == EcuState.DISABLED and cmd.throttle_pct == 0.0


class TestDriverOverride:
    KINDS: ClassVar[dict[str, dict[str, Any]]] = {
        "brake pedal": {"driver_brake_pressed": True},
        "steer torque left": {"driver_steer_torque_nm": CAL.driver_torque_threshold_nm + 1e-6},
        "steer torque right": {"driver_steer_torque_nm": -CAL.driver_torque_threshold_nm - 1e-6},
        "throttle pedal": {"driver_throttle_pct": CAL.driver_throttle_threshold_pct + 1e-6},
    }

    @pytest.mark.parametrize("kind", sorted(KINDS))
    @pytest.mark.parametrize("start", ["ENGAGED", "PAUSED", "SAFE_STOP"])
    def test_intervention_hands_over_at_once(self, kind: str, start: str) -> None:
        loop = engaged(15.0)
        loop.run(0.5, request_accel_mps2=1.0)
        extra = {"ENGAGED": {}, "PAUSED": {"estop_mode": EstopMode.PAUSE}, "SAFE_STOP": {"host_alive": False}}
        assert loop.step(**extra[start]).state == EcuState[start]
        cmd = loop.step(**extra[start], **self.KINDS[kind])
        assert cmd.state == EcuState.MANUAL and cmd.faults_latched == Fault.DRIVER_OVERRIDE
        assert_passive(cmd)

    @pytest.mark.parametrize("sign", [1.0, -1.0])
    def test_steer_torque_boundary_sweep(self, sign: float) -> None:
        thr = CAL.driver_torque_threshold_nm
        for torque, overrides in ((0.0, False), (thr - 0.01, False), (thr, False), (thr + 0.01, True)):
            loop = engaged(10.0)
            cmd = loop.step(driver_steer_torque_nm=sign * torque)
            assert (cmd.state == EcuState.MANUAL) == overrides, torque

    def test_throttle_boundary_sweep(self) -> None:
        thr = CAL.driver_throttle_threshold_pct
        for pct, overrides in (
            (0.0, False),
            (thr - 0.1, False),
            (thr, False),
            (thr + 0.1, True),
            (100.0, True),
        ):
            loop = engaged(10.0)
            cmd = loop.step(driver_throttle_pct=pct)
            assert (cmd.state == EcuState.MANUAL) == overrides, pct

    def test_latched_until_rearm_edge_without_intervention(self) -> None:
        loop = engaged(10.0)
        loop.step(driver_brake_pressed=True)
        for _ in range(100):  # released, ENGAGE still requested: stays MANUAL
            assert_passive(cmd := loop.step())
            assert cmd.state == EcuState.MANUAL
        cmd = loop.step(request_flags=REARM, driver_brake_pressed=True)
        assert cmd.state == EcuState.MANUAL  # still pressing
        cmd = loop.step(request_flags=REARM)
        assert cmd.state == EcuState.MANUAL  # REARM held since the last cycle: not an edge
        loop.step()
        cmd = loop.step(request_flags=REARM, vehicle_fresh=False)
        assert cmd.state == EcuState.MANUAL  # the driver cannot be seen: not rearmed
        loop.step()
        cmd = loop.step(request_flags=RequestFlags.REARM)
        assert cmd.state == EcuState.READY
        assert loop.step().state == EcuState.ENGAGED

    def test_in_ready_a_driver_only_blocks_engaging(self) -> None:
        loop = ready()
        for _ in range(50):
            cmd = loop.step(driver_brake_pressed=True)
            assert cmd.state == EcuState.READY and cmd.faults_active & Fault.DRIVER_OVERRIDE

    def test_stale_driver_data_is_a_vehicle_fault_not_an_override(self) -> None:
        loop = engaged(10.0)
        cmd = loop.step(vehicle_fresh=False, driver_brake_pressed=True)
        assert cmd.state == EcuState.SAFE_STOP and cmd.faults_latched & Fault.VEHICLE_TIMEOUT


class TestFaultsSafeStop:
    @pytest.mark.parametrize("name", sorted(FAULTS))
    def test_fault_stops_and_holds_within_the_bound(self, name: str) -> None:
        changes, bit = FAULTS[name]
        assert bit & STOP_FAULTS
        loop = engaged(15.0, dt_s=0.01)
        loop.run(2.0, request_accel_mps2=1.0)
        # The stop starts from the speed the ECU measures now, or, blind, from the last it measured.
        v0 = loop.last_inputs.speed_mps if name in BLIND else loop.plant.speed_mps
        a0 = loop.cmd.accel_target_mps2
        cmd = loop.step(**changes)
        assert cmd.state == EcuState.SAFE_STOP and cmd.faults_latched & bit
        # Dropping ENGAGE is an event of the ENGAGED state, not a condition that stays active.
        assert bool(cmd.faults_active & bit) == (name != "host drops ENGAGE")
        assert cmd.throttle_pct == 0.0 and cmd.engage
        bound = stop_time_bound_s(v0, a0, CAL.safe_stop_decel_mps2, CAL)
        assert loop.state.stop_deadline_s == pytest.approx(loop.t_s + bound)
        if name in BLIND:
            t_hold = loop.run_until(is_held, bound + 0.02, **changes)
            assert t_hold <= bound + loop.dt_s
            # Open loop the ECU may hold early or late against reality; the hold pressure then
            # stops what is left (0.5: weaker brakes than identified, downhill).
            loop.run(v0 / (0.5 * hold_decel_mps2()), **changes)
        else:
            t_hold = loop.run_until(
                lambda c: is_held(c) and loop.plant.speed_mps == 0.0, bound + 0.02, **changes
            )
            assert t_hold <= bound + loop.dt_s
        assert loop.plant.speed_mps == 0.0
        for _ in range(6000):  # fault gone, no REARM: still latched and holding, one minute
            cmd = loop.step()
            assert cmd.state == EcuState.SAFE_STOP and is_held(cmd) and cmd.faults_latched & bit
        assert loop.plant.speed_mps == 0.0

    def test_closed_loop_stop_decelerates_at_the_safe_stop_rate(self) -> None:
        loop = engaged(25.0, dt_s=0.01)
        loop.run(1.0)
        t0 = loop.t_s
        decels = []
        while loop.plant.speed_mps > 2.0:
            loop.step(host_alive=False)
            if loop.t_s - t0 > 2.0:
                decels.append(loop.plant.accel_mps2)
        assert sum(decels) / len(decels) == pytest.approx(-CAL.safe_stop_decel_mps2, abs=0.15)

    def test_safe_stop_under_pause_stops_as_hard_as_a_pause(self) -> None:
        loop = engaged(25.0, dt_s=0.01)
        loop.step(host_alive=False)
        loop.run(3.0, estop_mode=EstopMode.PAUSE)
        assert loop.cmd.state == EcuState.SAFE_STOP
        assert loop.cmd.accel_target_mps2 == pytest.approx(-CAL.pause_decel_mps2)


class TestStopLatches:
    def test_a_pause_that_turns_into_a_safe_stop_keeps_its_deceleration(self) -> None:
        loop = engaged(25.0, dt_s=0.01)
        loop.run(2.0, estop_mode=EstopMode.PAUSE)
        loop.run(2.0, estop_mode=EstopMode.RUN, host_alive=False)
        assert loop.cmd.state == EcuState.SAFE_STOP
        assert loop.cmd.accel_target_mps2 == pytest.approx(-CAL.pause_decel_mps2)

    def test_the_hold_does_not_let_go_on_a_speed_glitch(self) -> None:
        loop = engaged(5.0, dt_s=0.01)
        loop.run_until(is_held, 10.0, host_alive=False)
        assert loop.t_s + 1.0 < loop.state.stop_deadline_s  # held on measured standstill
        for _ in range(100):  # wheel-speed sensor noise above standstill_speed
            cmd = loop.step(host_alive=False, speed_mps=0.8, accel_meas_mps2=0.5)
            assert is_held(cmd)


class TestRearm:
    def _stopped(self) -> Any:
        loop = engaged(8.0, dt_s=0.01)
        loop.step(host_alive=False)
        return loop

    def test_rearm_edge_at_standstill_without_faults(self) -> None:
        loop = self._stopped()
        loop.run(10.0)
        assert is_held(loop.cmd)
        cmd = loop.step(request_flags=REARM)
        assert cmd.state == EcuState.READY
        assert loop.step().state == EcuState.ENGAGED

    def test_rearm_while_moving_is_refused_and_a_held_flag_is_not_an_edge(self) -> None:
        loop = self._stopped()
        cmd = loop.step(request_flags=REARM)
        assert cmd.state == EcuState.SAFE_STOP and loop.plant.speed_mps > 1.0
        loop.run(10.0, request_flags=REARM)  # held through standstill
        assert loop.cmd.state == EcuState.SAFE_STOP and is_held(loop.cmd)

    @pytest.mark.parametrize(
        "changes",
        [
            {"host_alive": False},
            {"estop_mode": EstopMode.PAUSE},
            {"request_fresh": False},
            {"vehicle_fresh": False},
        ],
    )
    def test_rearm_with_an_active_fault_is_refused(self, changes: dict[str, Any]) -> None:
        loop = self._stopped()
        loop.run(10.0)
        cmd = loop.step(request_flags=REARM, **changes)
        assert cmd.state == EcuState.SAFE_STOP


class TestSteering:
    def test_rate_limited_while_engaged_with_steer_flag(self) -> None:
        loop = engaged(10.0)
        prev = loop.cmd.steer_angle_rad
        for _ in range(2000):
            cmd = loop.step(request_steer_angle_rad=1.0)
            assert cmd.steer_enable
            assert abs(cmd.steer_angle_rad - prev) <= CAL.steer_rate_max_radps * loop.dt_s + 1e-12
            prev = cmd.steer_angle_rad
        assert cmd.steer_angle_rad == pytest.approx(CAL.steer_max_rad)

    def test_without_steer_flag_the_angle_follows_the_measurement(self) -> None:
        loop = engaged(10.0)
        loop.plant.steer_rad = 0.2
        cmd = loop.step(request_flags=RequestFlags.ENGAGE, request_steer_angle_rad=-0.4)
        assert not cmd.steer_enable and cmd.steer_angle_rad == pytest.approx(0.2)
        cmd = loop.step(request_steer_angle_rad=-0.4)  # enabling starts from there: bumpless
        assert cmd.steer_enable and 0.2 - cmd.steer_angle_rad <= CAL.steer_rate_max_radps * loop.dt_s + 1e-12

    def test_stop_keeps_the_last_angle(self) -> None:
        loop = engaged(10.0, dt_s=0.01)
        loop.run(1.0, request_steer_angle_rad=0.1)
        angle = loop.cmd.steer_angle_rad
        for _ in range(300):
            cmd = loop.step(host_alive=False, request_steer_angle_rad=-0.3)
            assert cmd.steer_enable and cmd.steer_angle_rad == angle

    def test_stop_from_ready_does_not_steer(self) -> None:
        loop = ready(10.0)
        cmd = loop.step(estop_mode=EstopMode.PAUSE)
        assert cmd.state == EcuState.PAUSED and not cmd.steer_enable


class TestBlindStop:
    def test_unknown_speed_assumes_the_top_of_the_calibrated_range(self) -> None:
        # Vehicle data never seen since boot: a pause must brake as if at full speed.
        loop = CoreLoop(CAL, speed_mps=0.0, dt_s=0.01)
        loop.step(vehicle_fresh=False, request_flags=RequestFlags.NONE)
        cmd = loop.step(vehicle_fresh=False, estop_mode=EstopMode.PAUSE)
        assert cmd.state == EcuState.PAUSED
        v_top = CAL.throttle_map.speed_mps[-1]
        bound = stop_time_bound_s(v_top, 0.0, CAL.pause_decel_mps2, CAL)
        t = loop.run_until(is_held, bound + 1.0, vehicle_fresh=False, estop_mode=EstopMode.PAUSE)
        assert v_top / CAL.pause_decel_mps2 < t <= bound + loop.dt_s
        assert loop.cmd.brake_bar == CAL.hold_brake_bar

    def test_recent_speed_is_trusted(self) -> None:
        loop = engaged(12.0, dt_s=0.01)
        loop.run(1.0)
        v0, a0 = loop.last_inputs.speed_mps, loop.cmd.accel_target_mps2
        loop.step(vehicle_fresh=False)
        bound = stop_time_bound_s(v0, a0, CAL.safe_stop_decel_mps2, CAL)
        t = loop.run_until(is_held, bound + 1.0, vehicle_fresh=False)
        # Standstill cannot be measured: it holds at the deadline, not before.
        assert v0 / CAL.safe_stop_decel_mps2 + CAL.stop_margin_s <= t <= bound + loop.dt_s
        assert loop.cmd.brake_bar == CAL.hold_brake_bar

    def test_open_loop_brakes_on_feedforward(self) -> None:
        loop = engaged(15.0, dt_s=0.01)
        loop.run(2.0)
        loop.run(2.0, vehicle_fresh=False)
        cmd = loop.cmd
        # Feedforward on the target, with only a braking-side integrator kept ...
        assert cmd.accel_cmd_mps2 == -CAL.safe_stop_decel_mps2 + min(cmd.integrator_mps2, 0.0)
        # ... through the brake map at the estimated speed, not the stale measurement.
        a_coast = coast_accel_mps2(CAL.coast_map, loop.state.speed_est_mps)
        assert cmd.brake_bar == pytest.approx(
            brake_bar(CAL.brake_map, a_coast - cmd.accel_cmd_mps2), rel=0.01
        )
        assert loop.last_inputs.speed_mps != pytest.approx(loop.state.speed_est_mps, abs=1.0)
        assert cmd.throttle_pct == 0.0


def test_safety_step_keeps_the_state_object_when_nothing_changes() -> None:
    st = SafetyState(EcuState.READY, Fault.NONE, False, False)
    inp = healthy_inputs(request_flags=RequestFlags.NONE)
    new, active = safety_step(st, inp, CAL)
    assert new is st and active == 0
    assert initial_safety_state().state == EcuState.OFF


def test_inputs_are_frozen_and_keyword_only() -> None:
    inp = healthy_inputs()
    with pytest.raises(dataclasses.FrozenInstanceError):
        inp.speed_mps = 1.0  # type: ignore[misc]
    with pytest.raises(TypeError):
        type(inp)(EstopMode.RUN, True)  # type: ignore[call-arg]
    assert dataclasses.replace(inp, speed_mps=3.0).speed_mps == 3.0
    assert dataclasses.replace(inp) == inp
