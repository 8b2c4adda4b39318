"""The ECU safety spec as reusable test classes (opendbc's mixins), generic over the calibration.

Each mixin states one part of the spec (ecu/safety.py's and ecu/core.py's docstrings; DARPA Urban
Challenge rules 3.4.2 for the E-stop) through `core_step` closed around the point-mass plant
(tests/plant_model.py). A concrete test class combines the mixins and names a calibration in `CAL`
(tests/ecu/test_safety.py: the packaged Passat calibration and two extreme valid ones, with every
limit at one end of its validated range). Durations are derived from the calibration
(`stop_time_bound_s`), never fixed, so the same spec holds for a gentle and for an aggressive car.
The control-quality checks that only an identified calibration can pass (deceleration accuracy,
holding on a slope) are in `TunedCalibrationSpec`, for the Passat only.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import plant_model as _pm  # tests/ is on pytest's pythonpath
import pytest
from hypothesis import strategies as st

from bywire.ecu.accel_controller import brake_bar, coast_accel_mps2
from bywire.ecu.calibration import (
    Calibration,
    calibration_from_dict,
    calibration_to_dict,
    default_calibration,
)
from bywire.ecu.core import ActuatorCommand, stop_time_bound_s
from bywire.ecu.safety import (
    OVERRUN_STREAK_LIMIT,
    STOP_FAULTS,
    active_faults,
    engage_allowed,
)
from bywire.protocol.ecu_types import EcuState, EstopMode, Fault, RequestFlags

CoreLoop = _pm.CoreLoop
healthy_inputs = _pm.healthy_inputs

ENGAGE = RequestFlags.ENGAGE | RequestFlags.STEER
HELD_LOW = RequestFlags.STEER  # ENGAGE released (the first half of an engage press)
REARM = ENGAGE | RequestFlags.REARM
NAN = math.nan


# Random input sequences for the property tests of the core and of the transmit guard
# (tests/ecu/test_ecu_core_properties.py, tests/ecu/test_tx_guard.py).

# Per input field, the values a random cycle may take instead of the healthy one.
PERTURBATIONS: dict[str, st.SearchStrategy[Any]] = {
    "estop_mode": st.sampled_from([EstopMode.PAUSE, EstopMode.DISABLE, EstopMode.INVALID]),
    "estop_fresh": st.just(False),
    "host_alive": st.just(False),
    "request_accel_mps2": st.just(math.nan),
    "request_steer_angle_rad": st.just(math.inf),
    "request_flags": st.sampled_from(
        [
            RequestFlags.ENGAGE,
            RequestFlags.NONE,
            ENGAGE | RequestFlags.REARM,
            RequestFlags.REARM,
            ENGAGE | RequestFlags.STOP,
        ]
    ),
    "request_fresh": st.just(False),
    "vehicle_fresh": st.just(False),
    "vehicle_corrupt": st.just(True),
    "calibration_valid": st.just(False),
    "overrun_streak": st.sampled_from([OVERRUN_STREAK_LIMIT - 1, OVERRUN_STREAK_LIMIT, 1000]),
    "driver_brake_pressed": st.just(True),
    "driver_throttle_pct": st.floats(0.0, 30.0),
    "driver_steer_torque_nm": st.floats(-4.0, 4.0),
    "unlatch": st.just(True),
    "safety_arm": st.just(True),
    "loop_stall": st.just(True),
    "internal_error": st.just(True),
    "tx_guard_trip": st.just(True),
}


@st.composite
def input_changes(draw: st.DrawFn) -> dict[str, Any]:
    """A healthy cycle's request, with zero to three fields perturbed."""
    changes: dict[str, Any] = {
        "request_accel_mps2": draw(st.floats(-8.0, 5.0)),
        "request_steer_angle_rad": draw(st.floats(-1.0, 1.0)),
    }
    for key in draw(st.lists(st.sampled_from(sorted(PERTURBATIONS)), max_size=3, unique=True)):
        changes[key] = draw(PERTURBATIONS[key])
    return changes


segments = st.lists(st.tuples(st.integers(1, 400), input_changes()), min_size=1, max_size=8)


def extreme_calibration(end: str) -> Calibration:
    """A valid calibration with every scalar limit at the `"high"` or `"low"` end of the range
    `calibration_from_dict` accepts (where one depends on another, as far as it allows)."""
    base = default_calibration()
    if end == "high":
        changes: dict[str, Any] = {
            "accel_min_mps2": -10.0,
            "accel_max_mps2": 5.0,
            "jerk_max_mps3": 50.0,
            "steer_max_rad": 0.6,
            "steer_rate_max_radps": 3.0,
            "pause_decel_mps2": 10.0,
            "disable_decel_mps2": 10.0,
            "safe_stop_decel_mps2": 10.0,
            "hold_brake_bar": 200.0,
            "standstill_speed_mps": 1.0,
            "stop_margin_s": 30.0,
            "driver_torque_threshold_nm": 20.0,
            "driver_throttle_threshold_pct": 50.0,
            "ki_per_s": 20.0,
            "integrator_max_mps2": 5.0,
            "switch_freeze_s": 5.0,
            "throttle_lag_s": 2.0,
            "brake_lag_s": 2.0,
            "pedal_hysteresis_mps2": 1.0,
        }
    elif end == "low":
        changes = {
            "accel_min_mps2": -0.5,
            "accel_max_mps2": 0.5,
            "jerk_max_mps3": 0.5,
            "steer_max_rad": 0.01,
            "steer_rate_max_radps": 0.01,
            "pause_decel_mps2": 0.5,
            "disable_decel_mps2": 0.5,
            "safe_stop_decel_mps2": 0.5,
            "hold_brake_bar": 5.0,
            "standstill_speed_mps": 0.01,
            "stop_margin_s": 0.0,
            "driver_torque_threshold_nm": 0.1,
            "driver_throttle_threshold_pct": 0.1,
            "ki_per_s": 0.0,
            "integrator_max_mps2": 0.0,
            "switch_freeze_s": 0.0,
            "throttle_lag_s": 0.0,
            "brake_lag_s": 0.0,
            "pedal_hysteresis_mps2": 0.0,
        }
    else:
        raise ValueError(end)
    d = calibration_to_dict(base)
    d.update(changes, vehicle=f"extreme calibration ({end} ends)")
    return calibration_from_dict(d, source=f"<extreme {end}>")  # validated like any other


class SafetySpec:
    """Helpers shared by the spec's mixins; `CAL` is the calibration under test."""

    CAL: ClassVar[Calibration] = default_calibration()

    def loop(self, speed_mps: float = 0.0, **kwargs: Any) -> Any:
        return CoreLoop(self.CAL, speed_mps=speed_mps, **kwargs)

    def ready(self, speed_mps: float = 0.0, **changes: Any) -> Any:
        """A loop in READY with ENGAGE released (the next ENGAGE request is an edge)."""
        loop = self.loop(speed_mps)
        cmd = loop.step(request_flags=HELD_LOW, **changes)
        assert cmd.state == EcuState.READY
        return loop

    def engaged(
        self, speed_mps: float = 0.0, *, dt_s: float = 0.001, grade: float = 0.0, **changes: Any
    ) -> Any:
        """A loop that has engaged through an engage press (READY, ENGAGE released, then raised)."""
        loop = self.loop(speed_mps, dt_s=dt_s, grade=grade)
        loop.step(request_flags=HELD_LOW, **changes)
        cmd = loop.step(**changes)
        assert cmd.state == EcuState.ENGAGED and cmd.engage
        return loop

    def is_held(self, cmd: ActuatorCommand) -> bool:
        return cmd.holding and cmd.brake_bar == self.CAL.hold_brake_bar and cmd.throttle_pct == 0.0

    def assert_passive(self, cmd: ActuatorCommand) -> None:
        assert not cmd.engage and not cmd.steer_enable
        assert cmd.throttle_pct == 0.0 and cmd.brake_bar == 0.0

    def stop_bound(self, loop: Any, decel: float, v0: float | None = None) -> float:
        v = loop.plant.speed_mps if v0 is None else v0
        return stop_time_bound_s(v, loop.cmd.accel_target_mps2, decel, self.CAL)

    def hold_decel_mps2(self) -> float:
        """What the calibration believes the hold pressure decelerates (inverse brake map)."""
        cal = self.CAL
        m = cal.brake_map
        for d0, d1, p0, p1 in zip(m.decel_mps2, m.decel_mps2[1:], m.bar, m.bar[1:], strict=False):
            if p0 <= cal.hold_brake_bar <= p1 and p1 > p0:
                return d0 + (d1 - d0) * (cal.hold_brake_bar - p0) / (p1 - p0)
        return m.decel_mps2[-1]

    def settle_held(self, loop: Any, **changes: Any) -> None:
        """Run until the stop holds and the car stands still (the hold pressure stops what is left)."""
        bound = self.stop_bound(loop, self.CAL.safe_stop_decel_mps2) + 1.0
        loop.run_until(lambda c: self.is_held(c) and loop.plant.speed_mps == 0.0, bound + 120.0, **changes)
        assert loop.plant.speed_mps == 0.0 and self.is_held(loop.cmd)

    def breakers(self) -> dict[str, dict[str, Any]]:
        """Engage preconditions, each broken alone (DESIGN section 4; safety.py rule 5)."""
        cal = self.CAL
        return {
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
            "loop stall": {"loop_stall": True},
            "internal error": {"internal_error": True},
            "transmit guard": {"tx_guard_trip": True},
            "driver brake": {"driver_brake_pressed": True},
            "driver torque": {"driver_steer_torque_nm": cal.driver_torque_threshold_nm + 0.01},
            "driver throttle": {"driver_throttle_pct": cal.driver_throttle_threshold_pct + 0.1},
            "host STOP": {"request_flags": ENGAGE | RequestFlags.STOP},
        }


BREAKER_NAMES = sorted(SafetySpec().breakers())
EXPECTED_BITS: dict[str, Fault] = {
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
    "loop stall": Fault.LOOP_STALL,
    "internal error": Fault.INTERNAL_ERROR,
    "transmit guard": Fault.TX_GUARD,
    "driver brake": Fault.DRIVER_OVERRIDE,
    "driver torque": Fault.DRIVER_OVERRIDE,
    "driver throttle": Fault.DRIVER_OVERRIDE,
    "host STOP": Fault.HOST_STOP_REQUEST,
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
    "loop stall": ({"loop_stall": True}, Fault.LOOP_STALL),
    "internal error": ({"internal_error": True}, Fault.INTERNAL_ERROR),
    "transmit guard": ({"tx_guard_trip": True}, Fault.TX_GUARD),
    "calibration invalid": ({"calibration_valid": False}, Fault.CALIBRATION_INVALID),
    "host STOP flag": ({"request_flags": ENGAGE | RequestFlags.STOP}, Fault.HOST_STOP_REQUEST),
    "host drops ENGAGE": ({"request_flags": RequestFlags.STEER}, Fault.HOST_STOP_REQUEST),
}
BLIND = {"vehicle timeout", "vehicle corrupt", "vehicle speed NaN"}
# Events of one cycle: the condition is not active any more in the next (the state latches it).
EVENTS = {"host drops ENGAGE", "loop stall", "internal error", "transmit guard"}


class BootSpec(SafetySpec):
    def test_boots_off_then_ready_never_engaging_in_the_first_cycle(self) -> None:
        loop = self.loop()
        assert loop.state.safety.state == EcuState.OFF
        cmd = loop.step()
        assert cmd.state == EcuState.READY
        self.assert_passive(cmd)

    def test_an_engage_held_through_boot_engages_nothing(self) -> None:
        # An ECU reset while the host holds ENGAGE: no edge, no engagement, however long.
        loop = self.loop()
        for _ in range(500):
            cmd = loop.step()
            assert cmd.state == EcuState.READY
            self.assert_passive(cmd)
        loop.step(request_flags=HELD_LOW)
        assert loop.step().state == EcuState.ENGAGED  # the press the host must make

    def test_without_a_valid_calibration_it_stays_off(self) -> None:
        loop = self.loop()
        for _ in range(200):
            cmd = loop.step(calibration_valid=False)
            assert cmd.state == EcuState.OFF
            self.assert_passive(cmd)
        assert cmd.faults_active & Fault.CALIBRATION_INVALID
        assert loop.step().state == EcuState.READY

    def test_ready_goes_off_when_the_calibration_is_lost(self) -> None:
        loop = self.ready()
        cmd = loop.step(calibration_valid=False, request_flags=RequestFlags.NONE)
        assert cmd.state == EcuState.OFF and cmd.faults_latched == Fault.CALIBRATION_INVALID


class EngageSpec(SafetySpec):
    def test_engages_on_a_rising_edge_when_all_hold(self) -> None:
        loop = self.ready()
        cmd = loop.step()
        assert cmd.state == EcuState.ENGAGED and cmd.engage and cmd.faults_active == Fault.NONE
        assert engage_allowed(loop.last_inputs, self.CAL)

    @pytest.mark.parametrize("name", BREAKER_NAMES)
    def test_each_missing_precondition_blocks_engage(self, name: str) -> None:
        loop = self.ready()
        breaker = self.breakers()[name]
        for _ in range(100):
            cmd = loop.step(**breaker)
            assert cmd.state != EcuState.ENGAGED
            assert not engage_allowed(loop.last_inputs, self.CAL)
        assert engage_allowed(healthy_inputs(), self.CAL)  # that one change was the only obstacle

    @pytest.mark.parametrize(
        "name", [n for n in BREAKER_NAMES if n not in ("no ENGAGE flag", "request stale")]
    )
    def test_an_edge_while_a_precondition_fails_is_spent(self, name: str) -> None:
        # ENGAGE rises while something is wrong; the problem goes away with ENGAGE still held: the
        # level engages nothing, the host must press again. (A stale request carries no edge at
        # all: test_edges_only_between_fresh_requests.)
        loop = self.ready()
        assert loop.step(**self.breakers()[name]).state != EcuState.ENGAGED
        for _ in range(100):
            assert loop.step().state != EcuState.ENGAGED

    def test_edges_only_between_fresh_requests(self) -> None:
        loop = self.loop()
        loop.step()  # READY, ENGAGE held since boot
        for _ in range(50):  # the request goes stale (after an NMT restart there is none at all)
            assert loop.step(request_fresh=False, request_flags=RequestFlags.NONE).state == EcuState.READY
        for _ in range(50):  # fresh again, ENGAGE held as before: not an edge
            assert loop.step().state == EcuState.READY
        loop.step(request_flags=HELD_LOW)
        assert loop.step().state == EcuState.ENGAGED

    def test_overrun_streak_boundary(self) -> None:
        loop = self.ready()
        assert loop.step(overrun_streak=OVERRUN_STREAK_LIMIT - 1).state == EcuState.ENGAGED
        loop = self.ready()
        assert loop.step(overrun_streak=OVERRUN_STREAK_LIMIT).state == EcuState.READY

    @pytest.mark.parametrize("start", ["MANUAL", "SAFE_STOP", "DISABLED"])
    def test_engage_only_from_ready(self, start: str) -> None:
        loop = self.engaged(0.0)
        if start == "MANUAL":
            loop.step(driver_brake_pressed=True)
        elif start == "SAFE_STOP":
            loop.step(host_alive=False)
        else:
            loop.step(estop_mode=EstopMode.DISABLE)
        for k in range(400):  # the cause is gone, ENGAGE is requested, and even pressed again
            cmd = loop.step(request_flags=HELD_LOW if k % 20 == 0 else ENGAGE)
            assert cmd.state == EcuState[start]


class FaultBitsSpec(SafetySpec):
    def test_every_breaker_has_its_bit(self) -> None:
        assert set(EXPECTED_BITS) == set(self.breakers())

    @pytest.mark.parametrize("name", BREAKER_NAMES)
    def test_each_condition_reports_exactly_its_bit(self, name: str) -> None:
        assert active_faults(healthy_inputs(**self.breakers()[name]), self.CAL) == EXPECTED_BITS[name]

    def test_stale_and_corrupt_report_both(self) -> None:
        inp = healthy_inputs(vehicle_fresh=False, vehicle_corrupt=True)
        assert active_faults(inp, self.CAL) == Fault.VEHICLE_TIMEOUT | Fault.VEHICLE_CORRUPT

    def test_a_stale_disable_is_reported_as_disable(self) -> None:
        inp = healthy_inputs(estop_mode=EstopMode.DISABLE, estop_fresh=False)
        assert active_faults(inp, self.CAL) == Fault.ESTOP_DISABLE

    def test_driver_inputs_are_not_believed_from_stale_data(self) -> None:
        inp = healthy_inputs(vehicle_fresh=False, driver_brake_pressed=True)
        assert active_faults(inp, self.CAL) == Fault.VEHICLE_TIMEOUT

    def test_healthy_is_no_fault(self) -> None:
        assert active_faults(healthy_inputs(), self.CAL) == Fault.NONE
        assert active_faults(healthy_inputs(safety_arm=True), self.CAL) == Fault.NONE

    def test_conditions_together_report_every_bit(self) -> None:
        # Every condition that can hold at the same time as the others, all at once: the bits add up.
        together = [
            "host heartbeat lost",
            "request stale",
            "vehicle corrupt",
            "calibration invalid",
            "overrun streak",
            "E-stop DISABLE",
            "host STOP",
            "loop stall",
            "internal error",
            "transmit guard",
        ]
        changes: dict[str, Any] = {}
        want = Fault.NONE
        for name in together:
            changes.update(self.breakers()[name])
            want |= EXPECTED_BITS[name]
        assert active_faults(healthy_inputs(**changes), self.CAL) == want
        # and the ones the vehicle data must be usable for, with a stale radio
        changes = {"driver_brake_pressed": True, "estop_fresh": False, "host_alive": False}
        want = Fault.DRIVER_OVERRIDE | Fault.ESTOP_TIMEOUT | Fault.HOST_HEARTBEAT
        assert active_faults(healthy_inputs(**changes), self.CAL) == want
        changes = {"vehicle_fresh": False, "request_accel_mps2": NAN, "host_alive": False}
        want = Fault.VEHICLE_TIMEOUT | Fault.REQUEST_INVALID | Fault.HOST_HEARTBEAT
        assert active_faults(healthy_inputs(**changes), self.CAL) == want

    def test_the_internal_faults_are_stop_faults(self) -> None:
        for bit in (Fault.LOOP_STALL, Fault.INTERNAL_ERROR, Fault.TX_GUARD):
            assert bit & STOP_FAULTS


class PauseResumeSpec(SafetySpec):
    def test_pause_stops_and_holds(self) -> None:
        loop = self.engaged(min(10.0, self.CAL.throttle_map.speed_mps[-1]), dt_s=0.01)
        v0 = loop.plant.speed_mps
        cmd = loop.step(estop_mode=EstopMode.PAUSE)
        assert cmd.state == EcuState.PAUSED and cmd.throttle_pct == 0.0 and cmd.engage
        assert cmd.faults_latched == Fault.ESTOP_PAUSE
        bound = stop_time_bound_s(v0, 0.0, self.CAL.pause_decel_mps2, self.CAL)
        t = loop.run_until(self.is_held, bound + 0.02, estop_mode=EstopMode.PAUSE)
        assert t <= bound + loop.dt_s
        for _ in range(200):
            cmd = loop.step(estop_mode=EstopMode.PAUSE)
            assert cmd.state == EcuState.PAUSED and cmd.throttle_pct == 0.0

    def test_resume_when_run_returns_and_engage_is_still_requested(self) -> None:
        loop = self.engaged(0.0, dt_s=0.01)
        loop.run(1.0, estop_mode=EstopMode.PAUSE)
        cmd = loop.step(request_accel_mps2=self.CAL.accel_max_mps2)
        assert cmd.state == EcuState.ENGAGED  # DARPA's RUN resumes a pause that began ENGAGED
        loop.run(5.0, request_accel_mps2=self.CAL.accel_max_mps2)
        assert loop.plant.speed_mps > 0.5

    def test_run_without_engage_request_keeps_holding_until_rearm(self) -> None:
        loop = self.engaged(0.0, dt_s=0.01)
        loop.run(1.0, estop_mode=EstopMode.PAUSE, request_flags=RequestFlags.NONE)
        assert loop.cmd.state == EcuState.PAUSED  # dropping ENGAGE in a pause is not a fault
        cmd = loop.step(request_flags=RequestFlags.NONE)
        # RUN alone must not release the brakes of a stopped car nobody asks to drive.
        assert cmd.state == EcuState.SAFE_STOP and cmd.faults_latched == Fault.HOST_STOP_REQUEST
        self.settle_held(loop, request_flags=RequestFlags.NONE)
        loop.step(request_flags=RequestFlags.REARM)
        cmd = loop.step(request_flags=RequestFlags.NONE)
        assert cmd.state == EcuState.READY
        self.assert_passive(cmd)

    def test_pause_from_ready_brakes(self) -> None:
        loop = self.ready(min(15.0, self.CAL.throttle_map.speed_mps[-1]))
        cmd = loop.step(estop_mode=EstopMode.PAUSE, request_flags=RequestFlags.NONE)
        assert cmd.state == EcuState.PAUSED and cmd.engage
        loop.run(1.5, estop_mode=EstopMode.PAUSE, request_flags=RequestFlags.NONE)
        assert loop.cmd.brake_bar > 0.0 and not loop.cmd.steer_enable
        assert loop.cmd.state == EcuState.PAUSED

    def test_a_pause_that_began_in_ready_never_resumes_into_engaged(self) -> None:
        # READY with ENGAGE held (no edge), PAUSE, RUN: back to READY, never ENGAGED on the level.
        loop = self.loop()
        loop.step()
        loop.run(0.5, estop_mode=EstopMode.PAUSE)
        assert loop.cmd.state == EcuState.PAUSED
        for _ in range(200):
            assert loop.step().state == EcuState.READY

    def test_pause_and_engage_drop_together_is_a_pause(self) -> None:
        loop = self.engaged(10.0)
        cmd = loop.step(estop_mode=EstopMode.PAUSE, request_flags=RequestFlags.NONE)
        assert cmd.state == EcuState.PAUSED

    @pytest.mark.parametrize(
        "fault", ["host heartbeat lost", "E-stop stale", "vehicle timeout", "loop stall"]
    )
    def test_a_fault_during_a_pause_latches_safe_stop(self, fault: str) -> None:
        loop = self.engaged(10.0)
        loop.step(estop_mode=EstopMode.PAUSE)
        changes, bit = FAULTS[fault]
        cmd = loop.step(estop_mode=EstopMode.PAUSE, **changes)
        assert cmd.state == EcuState.SAFE_STOP and cmd.faults_latched == bit
        for _ in range(100):
            assert loop.step().state == EcuState.SAFE_STOP  # RUN alone does not resume


class DisableLatchSpec(SafetySpec):
    def disabled_at_standstill(self) -> Any:
        loop = self.engaged(0.0)
        loop.step(estop_mode=EstopMode.DISABLE)
        loop.run(0.2, estop_mode=EstopMode.DISABLE)
        return loop

    @pytest.mark.parametrize("start", ["OFF", "READY", "ENGAGED", "PAUSED", "SAFE_STOP", "MANUAL"])
    def test_disable_from_any_state(self, start: str) -> None:
        loop = self.loop(min(10.0, self.CAL.throttle_map.speed_mps[-1]))
        if start == "OFF":
            loop.step(calibration_valid=False)
        elif start == "READY":
            loop.step(request_flags=RequestFlags.NONE)
        else:
            loop.step(request_flags=HELD_LOW)
            loop.step()
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
        loop = self.engaged(min(20.0, self.CAL.throttle_map.speed_mps[-1]), dt_s=0.01)
        loop.run(2.0, request_accel_mps2=min(1.0, self.CAL.accel_max_mps2))
        v0, a0 = loop.plant.speed_mps, loop.cmd.accel_target_mps2
        t_fault = loop.t_s
        loop.step(estop_mode=EstopMode.DISABLE)
        bound = stop_time_bound_s(v0, a0, self.CAL.disable_decel_mps2, self.CAL)
        while not (cmd := loop.step(estop_mode=EstopMode.DISABLE)).holding:
            assert cmd.throttle_pct == 0.0 and cmd.ignition and not cmd.park_brake
            assert loop.t_s - t_fault <= bound + 2 * loop.dt_s
        assert not cmd.ignition and cmd.park_brake and cmd.brake_bar == self.CAL.hold_brake_bar
        assert not cmd.steer_enable

    def test_only_the_arm_button_after_the_service_unlatch_leaves_disabled(self) -> None:
        loop = self.disabled_at_standstill()
        for _ in range(50):  # the radio back to RUN, REARM, ENGAGE, presses: none of them unlatches
            assert loop.step(request_flags=REARM).state == EcuState.DISABLED
            assert loop.step(request_flags=HELD_LOW).state == EcuState.DISABLED
            assert loop.step().state == EcuState.DISABLED
        cmd = loop.step(unlatch=True)  # the service tool alone: a second factor, never enough
        assert cmd.state == EcuState.DISABLED
        for _ in range(50):
            assert loop.step().state == EcuState.DISABLED
        cmd = loop.step(safety_arm=True)  # the human act on the car completes it
        assert cmd.state == EcuState.READY and cmd.ignition and not cmd.park_brake
        for _ in range(200):  # ENGAGE was held all along: that level engages nothing
            assert loop.step(safety_arm=True).state == EcuState.READY
        loop.step(request_flags=HELD_LOW)
        assert loop.step().state == EcuState.ENGAGED  # a new press does

    def test_the_arm_button_alone_does_not_leave_disabled(self) -> None:
        loop = self.disabled_at_standstill()
        for k in range(200):
            assert loop.step(safety_arm=k % 10 < 5).state == EcuState.DISABLED

    def test_an_unlatch_while_the_radio_says_disable_does_not_count(self) -> None:
        loop = self.disabled_at_standstill()
        loop.step(estop_mode=EstopMode.DISABLE, unlatch=True)
        loop.step()
        assert loop.step(safety_arm=True).state == EcuState.DISABLED

    def test_an_unlatch_while_the_radio_is_not_heard_does_not_count(self) -> None:
        loop = self.disabled_at_standstill()
        loop.step(estop_fresh=False, unlatch=True)
        assert loop.step(safety_arm=True).state == EcuState.DISABLED
        loop.step(unlatch=True)
        assert loop.step(safety_arm=True, estop_fresh=False).state == EcuState.DISABLED

    def test_a_new_disable_forgets_an_unlatch(self) -> None:
        loop = self.disabled_at_standstill()
        loop.step(unlatch=True)
        loop.step(estop_mode=EstopMode.DISABLE)
        loop.step()
        assert loop.step(safety_arm=True).state == EcuState.DISABLED

    def test_an_arm_button_held_through_the_unlatch_is_not_an_edge(self) -> None:
        loop = self.disabled_at_standstill()
        loop.step(safety_arm=True)
        loop.step(safety_arm=True, unlatch=True)
        for _ in range(50):
            assert loop.step(safety_arm=True).state == EcuState.DISABLED
        loop.step()
        assert loop.step(safety_arm=True).state == EcuState.READY

    def test_the_arm_button_is_only_believed_in_usable_vehicle_data(self) -> None:
        loop = self.disabled_at_standstill()
        loop.step(unlatch=True)
        assert loop.step(safety_arm=True, vehicle_fresh=False).state == EcuState.DISABLED
        assert loop.step(safety_arm=True, vehicle_corrupt=True).state == EcuState.DISABLED
        loop.step()
        assert loop.step(safety_arm=True).state == EcuState.READY

    def test_unlatch_without_calibration_goes_off(self) -> None:
        loop = self.disabled_at_standstill()
        loop.step(unlatch=True, calibration_valid=False)
        cmd = loop.step(safety_arm=True, calibration_valid=False)
        assert cmd.state == EcuState.OFF

    def test_a_stale_disable_is_still_a_disable(self) -> None:
        loop = self.engaged(5.0)
        cmd = loop.step(estop_mode=EstopMode.DISABLE, estop_fresh=False)
        assert cmd.state == EcuState.DISABLED

    def test_driver_input_does_not_leave_disabled(self) -> None:
        loop = self.engaged(5.0)
        loop.step(estop_mode=EstopMode.DISABLE)
        for _ in range(100):
            cmd = loop.step(estop_mode=EstopMode.DISABLE, driver_brake_pressed=True, driver_throttle_pct=50.0)
            assert cmd.state == EcuState.DISABLED and cmd.throttle_pct == 0.0


class DriverOverrideSpec(SafetySpec):
    def kinds(self) -> dict[str, dict[str, Any]]:
        cal = self.CAL
        return {
            "brake pedal": {"driver_brake_pressed": True},
            "steer torque left": {"driver_steer_torque_nm": cal.driver_torque_threshold_nm + 1e-6},
            "steer torque right": {"driver_steer_torque_nm": -cal.driver_torque_threshold_nm - 1e-6},
            "throttle pedal": {"driver_throttle_pct": cal.driver_throttle_threshold_pct + 1e-6},
        }

    @pytest.mark.parametrize(
        "kind", ["brake pedal", "steer torque left", "steer torque right", "throttle pedal"]
    )
    @pytest.mark.parametrize("start", ["ENGAGED", "PAUSED", "SAFE_STOP"])
    def test_intervention_hands_over_at_once(self, kind: str, start: str) -> None:
        loop = self.engaged(min(15.0, self.CAL.throttle_map.speed_mps[-1]))
        loop.run(0.5, request_accel_mps2=min(1.0, self.CAL.accel_max_mps2))
        extra = {"ENGAGED": {}, "PAUSED": {"estop_mode": EstopMode.PAUSE}, "SAFE_STOP": {"host_alive": False}}
        assert loop.step(**extra[start]).state == EcuState[start]
        cmd = loop.step(**extra[start], **self.kinds()[kind])
        assert cmd.state == EcuState.MANUAL and cmd.faults_latched == Fault.DRIVER_OVERRIDE
        self.assert_passive(cmd)

    @pytest.mark.parametrize("sign", [1.0, -1.0])
    def test_steer_torque_boundary_sweep(self, sign: float) -> None:
        thr = self.CAL.driver_torque_threshold_nm
        for torque, overrides in ((0.0, False), (thr * 0.99, False), (thr, False), (thr + 0.01, True)):
            loop = self.engaged(10.0)
            cmd = loop.step(driver_steer_torque_nm=sign * torque)
            assert (cmd.state == EcuState.MANUAL) == overrides, torque

    def test_throttle_boundary_sweep(self) -> None:
        thr = self.CAL.driver_throttle_threshold_pct
        for pct, overrides in (
            (0.0, False),
            (thr * 0.99, False),
            (thr, False),
            (thr + 0.01, True),
            (100.0, True),
        ):
            loop = self.engaged(10.0)
            cmd = loop.step(driver_throttle_pct=pct)
            assert (cmd.state == EcuState.MANUAL) == overrides, pct

    def test_only_the_arm_button_without_intervention_leaves_manual(self) -> None:
        loop = self.engaged(10.0)
        loop.step(driver_brake_pressed=True)
        for _ in range(100):  # released, ENGAGE still requested: stays MANUAL
            self.assert_passive(cmd := loop.step())
            assert cmd.state == EcuState.MANUAL
        for _ in range(20):  # the host's REARM (edges and levels) is not a human act
            assert loop.step(request_flags=REARM).state == EcuState.MANUAL
            assert loop.step().state == EcuState.MANUAL
        cmd = loop.step(safety_arm=True, driver_brake_pressed=True)
        assert cmd.state == EcuState.MANUAL  # still pressing the brake
        cmd = loop.step(safety_arm=True)
        assert cmd.state == EcuState.MANUAL  # the button held since the last cycle: not an edge
        loop.step()
        cmd = loop.step(safety_arm=True, vehicle_fresh=False)
        assert cmd.state == EcuState.MANUAL  # the driver cannot be seen: not re-armed
        loop.step()
        cmd = loop.step(safety_arm=True)
        assert cmd.state == EcuState.READY
        for _ in range(100):  # ENGAGE held throughout: no engagement without a new press
            assert loop.step().state == EcuState.READY
        loop.step(request_flags=HELD_LOW)
        assert loop.step().state == EcuState.ENGAGED

    def test_in_ready_a_driver_only_blocks_engaging(self) -> None:
        loop = self.ready()
        for _ in range(50):
            cmd = loop.step(driver_brake_pressed=True)
            assert cmd.state == EcuState.READY and cmd.faults_active & Fault.DRIVER_OVERRIDE

    def test_stale_driver_data_is_a_vehicle_fault_not_an_override(self) -> None:
        loop = self.engaged(10.0)
        cmd = loop.step(vehicle_fresh=False, driver_brake_pressed=True)
        assert cmd.state == EcuState.SAFE_STOP and cmd.faults_latched & Fault.VEHICLE_TIMEOUT


class FaultsSafeStopSpec(SafetySpec):
    @pytest.mark.parametrize("name", sorted(FAULTS))
    def test_fault_stops_and_holds_within_the_bound(self, name: str) -> None:
        changes, bit = FAULTS[name]
        assert bit & STOP_FAULTS
        cal = self.CAL
        loop = self.engaged(min(15.0, cal.throttle_map.speed_mps[-1]), dt_s=0.01)
        loop.run(2.0, request_accel_mps2=min(1.0, cal.accel_max_mps2))
        # The stop starts from the speed the ECU measures now, or, blind, from the last it measured.
        v0 = loop.last_inputs.speed_mps if name in BLIND else loop.plant.speed_mps
        a0 = loop.cmd.accel_target_mps2
        cmd = loop.step(**changes)
        # The latched cause is exactly the stop fault(s) of the cycle, nothing added.
        assert cmd.state == EcuState.SAFE_STOP and cmd.faults_latched == bit
        assert bool(cmd.faults_active & bit) == (name not in {"host drops ENGAGE"})
        assert cmd.throttle_pct == 0.0 and cmd.engage
        bound = stop_time_bound_s(v0, a0, cal.safe_stop_decel_mps2, cal)
        assert loop.state.stop_deadline_s == pytest.approx(loop.t_s + bound)
        during = {} if name in EVENTS else changes  # an event is gone in the next cycle
        t_hold = loop.run_until(self.is_held, bound + 0.02, **during)
        assert t_hold <= bound + loop.dt_s
        # Open loop the ECU may hold early or late against reality; the hold pressure then stops what
        # is left (0.5: weaker brakes than identified, downhill).
        loop.run(max(loop.plant.speed_mps, v0) / (0.5 * self.hold_decel_mps2()) + 1.0, **during)
        assert loop.plant.speed_mps == 0.0
        for _ in range(3000):  # fault gone, no REARM: still latched and holding, half a minute
            cmd = loop.step()
            assert cmd.state == EcuState.SAFE_STOP and self.is_held(cmd) and cmd.faults_latched & bit
        assert loop.plant.speed_mps == 0.0

    def test_safe_stop_under_pause_stops_as_hard_as_a_pause(self) -> None:
        loop = self.engaged(min(25.0, self.CAL.throttle_map.speed_mps[-1]), dt_s=0.01)
        loop.step(host_alive=False)
        loop.run(3.0, estop_mode=EstopMode.PAUSE)
        assert loop.cmd.state == EcuState.SAFE_STOP
        if not loop.cmd.holding:
            want = max(self.CAL.pause_decel_mps2, self.CAL.safe_stop_decel_mps2)
            assert loop.cmd.accel_target_mps2 == pytest.approx(-want)


class StopLatchesSpec(SafetySpec):
    def test_a_pause_that_turns_into_a_safe_stop_keeps_its_deceleration(self) -> None:
        cal = self.CAL
        loop = self.engaged(min(25.0, cal.throttle_map.speed_mps[-1]), dt_s=0.01)
        loop.run(1.0, estop_mode=EstopMode.PAUSE)
        loop.run(1.0, estop_mode=EstopMode.RUN, host_alive=False)
        assert loop.cmd.state == EcuState.SAFE_STOP
        if not loop.cmd.holding:
            want = max(cal.pause_decel_mps2, cal.safe_stop_decel_mps2)
            assert loop.cmd.accel_target_mps2 <= -min(want, cal.jerk_max_mps3 * 1.0) + 1e-9

    def test_the_hold_does_not_let_go_on_a_speed_glitch(self) -> None:
        loop = self.engaged(0.0, dt_s=0.01)
        loop.run_until(self.is_held, 10.0, host_alive=False)
        for _ in range(100):  # wheel-speed sensor noise above standstill_speed
            cmd = loop.step(
                host_alive=False, speed_mps=self.CAL.standstill_speed_mps + 0.8, accel_meas_mps2=0.5
            )
            assert self.is_held(cmd)


class RearmSpec(SafetySpec):
    def stopped(self) -> Any:
        loop = self.engaged(min(8.0, self.CAL.throttle_map.speed_mps[-1]), dt_s=0.01)
        loop.step(host_alive=False)
        self.settle_held(loop)
        return loop

    def test_rearm_with_engage_goes_straight_back_to_engaged_holding(self) -> None:
        loop = self.stopped()
        cmd = loop.step(request_flags=REARM)
        # No passive cycle in between: the held car stays braked while control resumes.
        assert cmd.state == EcuState.ENGAGED and cmd.engage and cmd.brake_bar >= self.CAL.hold_brake_bar
        assert cmd.throttle_pct == 0.0
        loop.run(5.0, request_accel_mps2=self.CAL.accel_max_mps2)
        assert loop.cmd.state == EcuState.ENGAGED and loop.plant.speed_mps > 0.1

    def test_rearm_without_engage_goes_to_ready(self) -> None:
        loop = self.stopped()
        cmd = loop.step(request_flags=RequestFlags.REARM)
        assert cmd.state == EcuState.READY
        self.assert_passive(cmd)

    def test_rearm_while_moving_is_refused_and_a_held_flag_is_not_an_edge(self) -> None:
        loop = self.engaged(min(8.0, self.CAL.throttle_map.speed_mps[-1]), dt_s=0.01)
        loop.step(host_alive=False)
        cmd = loop.step(request_flags=REARM)
        assert cmd.state == EcuState.SAFE_STOP and loop.plant.speed_mps > self.CAL.standstill_speed_mps
        self.settle_held(loop, request_flags=REARM)  # held through standstill
        assert loop.cmd.state == EcuState.SAFE_STOP and self.is_held(loop.cmd)

    @pytest.mark.parametrize(
        "changes",
        [
            {"host_alive": False},
            {"estop_mode": EstopMode.PAUSE},
            {"request_fresh": False},
            {"vehicle_fresh": False},
            {"loop_stall": True},
            {"internal_error": True},
            {"tx_guard_trip": True},
        ],
    )
    def test_rearm_with_an_active_fault_is_refused(self, changes: dict[str, Any]) -> None:
        loop = self.stopped()
        cmd = loop.step(request_flags=REARM, **changes)
        assert cmd.state == EcuState.SAFE_STOP

    def test_rearm_needs_the_speed_below_standstill(self) -> None:
        v = self.CAL.standstill_speed_mps
        loop = self.stopped()
        loop.step(request_flags=REARM, speed_mps=v)  # at the boundary: not standstill
        assert loop.cmd.state == EcuState.SAFE_STOP
        loop.step()
        loop.step(request_flags=REARM, speed_mps=v * 0.999)
        assert loop.cmd.state == EcuState.ENGAGED

    def test_a_rearm_in_a_stale_request_is_not_an_edge(self) -> None:
        loop = self.stopped()
        loop.run(0.1, request_fresh=False, request_flags=RequestFlags.NONE)
        loop.step(request_fresh=False, request_flags=REARM)
        assert loop.cmd.state == EcuState.SAFE_STOP


class SteeringSpec(SafetySpec):
    def test_rate_limited_while_engaged_with_steer_flag(self) -> None:
        cal = self.CAL
        loop = self.engaged(10.0)
        prev = loop.cmd.steer_angle_rad
        for _ in range(round(2.0 * cal.steer_max_rad / cal.steer_rate_max_radps / loop.dt_s) + 10):
            cmd = loop.step(request_steer_angle_rad=1.0)
            assert cmd.steer_enable
            assert abs(cmd.steer_angle_rad - prev) <= cal.steer_rate_max_radps * loop.dt_s + 1e-12
            assert abs(cmd.steer_angle_rad) <= cal.steer_max_rad
            prev = cmd.steer_angle_rad
        assert cmd.steer_angle_rad == pytest.approx(cal.steer_max_rad)

    def test_without_steer_flag_the_angle_follows_the_measurement(self) -> None:
        cal = self.CAL
        loop = self.engaged(10.0)
        loop.plant.steer_rad = 0.5 * cal.steer_max_rad
        cmd = loop.step(request_flags=RequestFlags.ENGAGE, request_steer_angle_rad=-cal.steer_max_rad)
        assert not cmd.steer_enable and cmd.steer_angle_rad == pytest.approx(0.5 * cal.steer_max_rad)
        cmd = loop.step(request_steer_angle_rad=-cal.steer_max_rad)  # enabling starts from there
        assert cmd.steer_enable
        assert 0.5 * cal.steer_max_rad - cmd.steer_angle_rad <= cal.steer_rate_max_radps * loop.dt_s + 1e-12

    def test_stop_keeps_the_last_angle(self) -> None:
        loop = self.engaged(10.0, dt_s=0.01)
        loop.run(1.0, request_steer_angle_rad=0.5 * self.CAL.steer_max_rad)
        angle = loop.cmd.steer_angle_rad
        for _ in range(300):
            cmd = loop.step(host_alive=False, request_steer_angle_rad=-self.CAL.steer_max_rad)
            assert cmd.steer_enable and cmd.steer_angle_rad == angle

    def test_a_measured_angle_that_is_not_a_number_keeps_the_last_angle(self) -> None:
        loop = self.ready(10.0)
        loop.plant.steer_rad = 0.5 * self.CAL.steer_max_rad
        before = loop.step(request_flags=HELD_LOW).steer_angle_rad
        cmd = loop.step(request_flags=HELD_LOW, steer_angle_meas_rad=NAN)
        assert cmd.steer_angle_rad == before and not cmd.steer_enable

    def test_stop_from_ready_does_not_steer(self) -> None:
        loop = self.ready(10.0)
        cmd = loop.step(estop_mode=EstopMode.PAUSE)
        assert cmd.state == EcuState.PAUSED and not cmd.steer_enable


class BlindStopSpec(SafetySpec):
    def test_unknown_speed_assumes_the_top_of_the_calibrated_range(self) -> None:
        cal = self.CAL
        # Vehicle data never seen since boot: a pause must brake as if at full speed.
        loop = self.loop(0.0, dt_s=0.01)
        loop.step(vehicle_fresh=False, request_flags=RequestFlags.NONE)
        cmd = loop.step(vehicle_fresh=False, estop_mode=EstopMode.PAUSE)
        assert cmd.state == EcuState.PAUSED
        v_top = cal.throttle_map.speed_mps[-1]
        bound = stop_time_bound_s(v_top, 0.0, cal.pause_decel_mps2, cal)
        t = loop.run_until(self.is_held, bound + 1.0, vehicle_fresh=False, estop_mode=EstopMode.PAUSE)
        assert v_top / cal.pause_decel_mps2 < t <= bound + loop.dt_s
        assert loop.cmd.brake_bar == cal.hold_brake_bar

    def test_recent_speed_is_trusted(self) -> None:
        cal = self.CAL
        loop = self.engaged(min(12.0, cal.throttle_map.speed_mps[-1]), dt_s=0.01)
        loop.run(1.0)
        v0, a0 = loop.last_inputs.speed_mps, loop.cmd.accel_target_mps2
        loop.step(vehicle_fresh=False)
        bound = stop_time_bound_s(v0, a0, cal.safe_stop_decel_mps2, cal)
        t = loop.run_until(self.is_held, bound + 1.0, vehicle_fresh=False)
        # Standstill cannot be measured: it holds at the deadline, not before.
        assert v0 / cal.safe_stop_decel_mps2 + cal.stop_margin_s <= t <= bound + loop.dt_s
        assert loop.cmd.brake_bar == cal.hold_brake_bar

    def test_open_loop_brakes_on_feedforward(self) -> None:
        cal = self.CAL
        loop = self.engaged(min(15.0, cal.throttle_map.speed_mps[-1]), dt_s=0.01)
        loop.run(2.0)
        loop.run(0.5, vehicle_fresh=False)
        cmd = loop.cmd
        if cmd.holding:
            return  # an extreme calibration may have stopped already: nothing open-loop to check
        # Feedforward on the target, with only a braking-side integrator kept ...
        assert cmd.accel_cmd_mps2 == cmd.accel_target_mps2 + min(cmd.integrator_mps2, 0.0)
        # ... through the brake map at the estimated speed, not the stale measurement.
        a_coast = coast_accel_mps2(cal.coast_map, loop.state.speed_est_mps)
        assert cmd.brake_bar == pytest.approx(
            brake_bar(cal.brake_map, a_coast - cmd.accel_cmd_mps2), rel=0.01
        )
        assert cmd.throttle_pct == 0.0


class TunedCalibrationSpec(SafetySpec):
    """Control quality that only an identified calibration (the plant's) can show."""

    def test_pause_decelerates_at_the_pause_rate_and_holds_for_hours_on_a_slope(self) -> None:
        cal = self.CAL
        loop = self.engaged(20.0, dt_s=0.01, grade=0.10)
        loop.run(3.0, request_accel_mps2=0.0)
        v0, a0 = loop.plant.speed_mps, loop.cmd.accel_target_mps2
        loop.step(estop_mode=EstopMode.PAUSE)
        decels = []
        while loop.plant.speed_mps > 2.0:
            loop.step(estop_mode=EstopMode.PAUSE)
            if loop.t_s > 4.5:  # past the jerk ramp and the integrator's settling
                decels.append(loop.plant.accel_mps2)
        assert sum(decels) / len(decels) == pytest.approx(-cal.pause_decel_mps2, abs=0.3)
        bound = stop_time_bound_s(v0, a0, cal.pause_decel_mps2, cal)
        assert loop.run_until(self.is_held, bound, estop_mode=EstopMode.PAUSE) <= bound + loop.dt_s
        loop.dt_s = 1.0  # two hours at 1 Hz
        for _ in range(7200):
            cmd = loop.step(estop_mode=EstopMode.PAUSE)
            assert cmd.state == EcuState.PAUSED and self.is_held(cmd)
        assert loop.plant.speed_mps == 0.0

    def test_closed_loop_stop_decelerates_at_the_safe_stop_rate(self) -> None:
        loop = self.engaged(25.0, dt_s=0.01)
        loop.run(1.0)
        t0 = loop.t_s
        decels = []
        while loop.plant.speed_mps > 2.0:
            loop.step(host_alive=False)
            if loop.t_s - t0 > 2.0:
                decels.append(loop.plant.accel_mps2)
        assert sum(decels) / len(decels) == pytest.approx(-self.CAL.safe_stop_decel_mps2, abs=0.15)

    def test_disable_decelerates_at_the_disable_rate(self) -> None:
        loop = self.engaged(20.0, dt_s=0.01)
        loop.run(2.0, request_accel_mps2=1.0)
        decels = []
        while not loop.step(estop_mode=EstopMode.DISABLE).holding:
            if loop.t_s > 4.5 and loop.plant.speed_mps > 2.0:
                decels.append(loop.plant.accel_mps2)
        assert sum(decels) / len(decels) == pytest.approx(-self.CAL.disable_decel_mps2, abs=0.4)


ALL_SPECS: tuple[type, ...] = (
    BootSpec,
    EngageSpec,
    FaultBitsSpec,
    PauseResumeSpec,
    DisableLatchSpec,
    DriverOverrideSpec,
    FaultsSafeStopSpec,
    StopLatchesSpec,
    RearmSpec,
    SteeringSpec,
    BlindStopSpec,
)

__all__ = ["ALL_SPECS", "TunedCalibrationSpec", "extreme_calibration"]
