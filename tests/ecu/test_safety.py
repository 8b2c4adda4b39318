"""The ECU safety spec (tests/safety_spec.py) run against more than one calibration: the packaged
Passat calibration, and two extreme valid ones with every limit at the high or the low end of the
range the calibration validator accepts. The spec must hold for any calibration the ECU would load.

Spec: ecu/safety.py and ecu/core.py docstrings; DARPA Urban Challenge rules 3.4.2 (E-stop).
"""

from __future__ import annotations

import dataclasses

import plant_model as _pm  # tests/ is on pytest's pythonpath
import pytest
from safety_spec import ALL_SPECS, HELD_LOW, TunedCalibrationSpec, extreme_calibration

from bywire.ecu.calibration import default_calibration
from bywire.ecu.safety import SafetyState, initial_safety_state, safety_step
from bywire.protocol.ecu_types import EcuState, EstopMode, Fault, RequestFlags

healthy_inputs = _pm.healthy_inputs


class TestPassatCalibration(*ALL_SPECS, TunedCalibrationSpec):  # type: ignore[misc]
    CAL = default_calibration()


class TestHighEndCalibration(*ALL_SPECS):  # type: ignore[misc]
    CAL = extreme_calibration("high")


class TestLowEndCalibration(*ALL_SPECS):  # type: ignore[misc]
    CAL = extreme_calibration("low")


def test_the_extreme_calibrations_are_valid_and_at_the_ends() -> None:
    high, low = extreme_calibration("high"), extreme_calibration("low")
    assert high.accel_min_mps2 == -10.0 and low.accel_min_mps2 == -0.5
    assert high.jerk_max_mps3 == 50.0 and low.jerk_max_mps3 == 0.5
    assert high.throttle_lag_s == 2.0 and low.throttle_lag_s == 0.0  # a lag of 0 divides nothing


def test_safety_step_keeps_the_state_object_when_nothing_changes() -> None:
    st = dataclasses.replace(initial_safety_state(), state=EcuState.READY, rearm_prev=False)
    inp = healthy_inputs(request_flags=RequestFlags.NONE)
    cal = default_calibration()
    new, active = safety_step(st, inp, cal)
    assert new.engage_prev is False  # the release was seen: a state change
    again, active = safety_step(new, inp, cal)
    assert again is new and active == 0
    assert initial_safety_state().state == EcuState.OFF


def test_every_edge_input_counts_as_held_at_boot() -> None:
    st = initial_safety_state()
    assert st.engage_prev and st.rearm_prev and st.arm_prev and st.unlatch_prev
    assert isinstance(st, SafetyState) and st.latched == Fault.NONE


def test_inputs_are_frozen_and_keyword_only() -> None:
    inp = healthy_inputs()
    with pytest.raises(dataclasses.FrozenInstanceError):
        inp.speed_mps = 1.0  # type: ignore[misc]
    with pytest.raises(TypeError):
        type(inp)(EstopMode.RUN, True)  # type: ignore[call-arg]
    assert dataclasses.replace(inp, speed_mps=3.0).speed_mps == 3.0
    assert dataclasses.replace(inp) == inp
    assert HELD_LOW & RequestFlags.ENGAGE == 0


def test_safety_step_judges_standstill_with_the_calibration_it_is_given() -> None:
    cal = default_calibration()
    st = dataclasses.replace(initial_safety_state(), state=EcuState.SAFE_STOP, rearm_prev=False)
    inp = healthy_inputs(request_flags=RequestFlags.REARM, speed_mps=0.5 * cal.standstill_speed_mps)
    assert safety_step(st, inp, cal)[0].state == EcuState.READY
    slow = dataclasses.replace(cal, standstill_speed_mps=0.25 * cal.standstill_speed_mps)
    assert safety_step(st, inp, slow)[0].state == EcuState.SAFE_STOP


def test_a_disabled_ecu_keeps_its_state_object_while_the_radio_says_disable() -> None:
    cal = default_calibration()
    st = dataclasses.replace(initial_safety_state(), state=EcuState.DISABLED, latched=Fault.ESTOP_DISABLE)
    inp = healthy_inputs(estop_mode=EstopMode.DISABLE, unlatch=False)
    new, _ = safety_step(st, inp, cal)
    assert new.state == EcuState.DISABLED and not new.unlatched
    assert safety_step(new, inp, cal)[0] is new  # no allocation in the common case


def test_a_state_whose_inputs_are_all_seen_is_returned_as_it_is_in_every_state() -> None:
    # When the flags it remembers already match the inputs, the transition allocates nothing: the
    # same object comes back (the 1 kHz loop's common case), in every state the inputs keep it in.
    cal = default_calibration()
    cases = {
        EcuState.DISABLED: healthy_inputs(estop_mode=EstopMode.DISABLE, request_flags=RequestFlags.NONE),
        EcuState.READY: healthy_inputs(request_flags=RequestFlags.NONE),
        EcuState.MANUAL: healthy_inputs(request_flags=RequestFlags.NONE),
        EcuState.ENGAGED: healthy_inputs(request_flags=RequestFlags.ENGAGE),
    }
    for state, inp in cases.items():
        st = SafetyState(
            state,
            Fault.NONE,
            rearm_prev=False,
            unlatch_prev=False,
            engage_prev=bool(inp.request_flags & RequestFlags.ENGAGE),
            arm_prev=False,
        )
        assert safety_step(st, inp, cal)[0] is st, state
