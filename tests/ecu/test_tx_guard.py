"""The transmit guard (ecu/tx_guard.py): every rule refuses what breaks it, the replacement always
passes, a healthy core never trips it, and a deliberately broken core always does."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import plant_model as _pm  # tests/ is on pytest's pythonpath
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from safety_spec import HELD_LOW, extreme_calibration, segments

from bywire.ecu.app import command_frame
from bywire.ecu.calibration import Calibration, default_calibration
from bywire.ecu.core import ActuatorCommand
from bywire.ecu.tx_guard import FALLBACK_BRAKE_RAMP_S, TxGuard, check_command
from bywire.protocol.ecu_types import EcuState, Gear
from bywire.protocol.vehicle_can import DbwCommand

CAL = default_calibration()
CALS = {"passat": CAL, "high": extreme_calibration("high"), "low": extreme_calibration("low")}
SEND_PERIOD_S = 0.010


def command(**changes: Any) -> DbwCommand:
    """A healthy ENGAGED command."""
    fields: dict[str, Any] = {
        "throttle_pct": 20.0,
        "brake_bar": 0.0,
        "steer_angle_rad": 0.0,
        "engage": True,
        "park_brake": False,
        "ignition": True,
        "steer_enable": True,
        "ecu_state": EcuState.ENGAGED,
        "gear_request": Gear.DRIVE,
    }
    fields.update(changes)
    return DbwCommand(**fields)


def check(cmd: DbwCommand, state: EcuState = EcuState.ENGAGED, **kw: Any) -> str | None:
    args: dict[str, Any] = {
        "gear_engaged": Gear.DRIVE,
        "cal": CAL,
        "prev": None,
        "dt_s": SEND_PERIOD_S,
        "steer_continuous": True,
    }
    args.update(kw)
    return check_command(cmd, state, **args)


PASSIVE = {"engage": False, "throttle_pct": 0.0, "brake_bar": 0.0, "steer_enable": False}

# (rule broken, command, state, extra check arguments)
VIOLATIONS: dict[str, tuple[DbwCommand, EcuState, dict[str, Any]]] = {
    "throttle NaN": (command(throttle_pct=math.nan), EcuState.ENGAGED, {}),
    "brake inf": (command(throttle_pct=0.0, brake_bar=math.inf), EcuState.ENGAGED, {}),
    "steer NaN": (command(steer_angle_rad=math.nan), EcuState.ENGAGED, {}),
    "throttle above 100 %": (command(throttle_pct=100.1), EcuState.ENGAGED, {}),
    "throttle negative": (command(throttle_pct=-0.1), EcuState.ENGAGED, {}),
    "brake above 200 bar": (command(throttle_pct=0.0, brake_bar=200.1), EcuState.ENGAGED, {}),
    "brake negative": (command(throttle_pct=0.0, brake_bar=-1.0), EcuState.ENGAGED, {}),
    "steer beyond the calibration": (command(steer_angle_rad=CAL.steer_max_rad + 1e-6), EcuState.ENGAGED, {}),
    "frame state differs": (command(ecu_state=EcuState.READY), EcuState.ENGAGED, {}),
    "engage in READY": (command(**{**PASSIVE, "engage": True}, ecu_state=EcuState.READY), EcuState.READY, {}),
    "brake in MANUAL": (
        command(**{**PASSIVE, "brake_bar": 5.0}, ecu_state=EcuState.MANUAL),
        EcuState.MANUAL,
        {},
    ),
    "steering in OFF": (
        command(**{**PASSIVE, "steer_enable": True}, ecu_state=EcuState.OFF),
        EcuState.OFF,
        {},
    ),
    "a stop released": (
        command(engage=False, throttle_pct=0.0, brake_bar=30.0, ecu_state=EcuState.SAFE_STOP),
        EcuState.SAFE_STOP,
        {},
    ),
    "throttle in a stop": (command(ecu_state=EcuState.PAUSED), EcuState.PAUSED, {}),
    "throttle with brake": (command(brake_bar=1.0), EcuState.ENGAGED, {}),
    "throttle with the ignition off": (command(ignition=False), EcuState.ENGAGED, {}),
    "steering rate": (
        command(steer_angle_rad=0.1),
        EcuState.ENGAGED,
        {"prev": command(steer_angle_rad=0.0), "dt_s": 0.1 / CAL.steer_rate_max_radps * 0.9},
    ),
    "park brake outside DISABLED": (
        command(throttle_pct=0.0, brake_bar=50.0, park_brake=True, ecu_state=EcuState.SAFE_STOP),
        EcuState.SAFE_STOP,
        {},
    ),
    "ignition off outside DISABLED": (
        command(throttle_pct=0.0, brake_bar=50.0, ignition=False, ecu_state=EcuState.PAUSED),
        EcuState.PAUSED,
        {},
    ),
    "shift with throttle": (command(gear_request=Gear.REVERSE), EcuState.ENGAGED, {}),
    "shift without brake": (command(throttle_pct=0.0, gear_request=Gear.REVERSE), EcuState.ENGAGED, {}),
    "shift in a stop": (
        command(throttle_pct=0.0, brake_bar=50.0, gear_request=Gear.REVERSE, ecu_state=EcuState.SAFE_STOP),
        EcuState.SAFE_STOP,
        {},
    ),
}


@pytest.mark.parametrize("name", sorted(VIOLATIONS))
def test_each_rule_refuses_what_breaks_it(name: str) -> None:
    cmd, state, kw = VIOLATIONS[name]
    assert check(cmd, state, **kw) is not None


@pytest.mark.parametrize(
    ("cmd", "state", "kw"),
    [
        (command(), EcuState.ENGAGED, {}),
        (command(throttle_pct=0.0, brake_bar=40.0, gear_request=Gear.REVERSE), EcuState.ENGAGED, {}),
        (command(throttle_pct=0.0, brake_bar=200.0, ecu_state=EcuState.SAFE_STOP), EcuState.SAFE_STOP, {}),
        (
            command(
                throttle_pct=0.0,
                brake_bar=50.0,
                park_brake=True,
                ignition=False,
                steer_enable=False,
                ecu_state=EcuState.DISABLED,
            ),
            EcuState.DISABLED,
            {},
        ),
        (command(**PASSIVE, ecu_state=EcuState.READY, steer_angle_rad=-0.2), EcuState.READY, {}),
        # The rate rule compares only angles that one continuous enabled motion joins.
        (command(steer_angle_rad=0.3), EcuState.ENGAGED, {"prev": command(), "steer_continuous": False}),
        (command(steer_angle_rad=0.3), EcuState.ENGAGED, {"prev": command(steer_enable=False)}),
        (
            command(steer_angle_rad=CAL.steer_rate_max_radps * SEND_PERIOD_S),
            EcuState.ENGAGED,
            {"prev": command()},
        ),
    ],
)
def test_what_the_rules_allow(cmd: DbwCommand, state: EcuState, kw: dict[str, Any]) -> None:
    assert check(cmd, state, **kw) is None


@pytest.mark.parametrize("name", sorted(VIOLATIONS))
def test_the_replacement_of_a_refused_command_passes_the_guard(name: str) -> None:
    cmd, state, kw = VIOLATIONS[name]
    guard = TxGuard(CAL)
    if kw.get("prev") is not None:
        guard.guard(
            kw["prev"], state if kw["prev"].ecu_state == state else kw["prev"].ecu_state, Gear.DRIVE, 0.0
        )
    frame, reason = guard.guard(cmd, state, Gear.DRIVE, kw.get("dt_s", SEND_PERIOD_S))
    assert reason is not None and guard.trips == 1
    assert frame.throttle_pct == 0.0
    if state in (EcuState.OFF, EcuState.READY, EcuState.MANUAL):
        assert not frame.engage and frame.brake_bar == 0.0 and frame.ecu_state == state
    else:
        assert frame.engage and frame.ecu_state == EcuState.SAFE_STOP
    assert check(frame, frame.ecu_state, prev=None) is None


def test_the_safe_stop_ramps_the_brake_to_the_hold_pressure_and_keeps_the_angle() -> None:
    guard = TxGuard(CAL)
    guard.guard(command(steer_angle_rad=0.05, throttle_pct=10.0), EcuState.ENGAGED, Gear.DRIVE, 0.0)
    bad = command(steer_angle_rad=0.05, throttle_pct=10.0, brake_bar=5.0)
    brakes = []
    for k in range(1, 80):
        frame, reason = guard.guard(bad, EcuState.ENGAGED, Gear.DRIVE, k * SEND_PERIOD_S)
        assert reason is not None and frame.steer_enable and frame.steer_angle_rad == 0.05
        brakes.append(frame.brake_bar)
    assert brakes == sorted(brakes) and brakes[0] < CAL.hold_brake_bar
    assert brakes[-1] == CAL.hold_brake_bar
    reached = next(i for i, b in enumerate(brakes) if b == CAL.hold_brake_bar)
    assert reached * SEND_PERIOD_S <= FALLBACK_BRAKE_RAMP_S
    # A good command again: the guard lets it through and forgets the fallback.
    good = command(throttle_pct=0.0, brake_bar=60.0, steer_angle_rad=0.05, ecu_state=EcuState.SAFE_STOP)
    frame, reason = guard.guard(good, EcuState.SAFE_STOP, Gear.DRIVE, 1.0)
    assert reason is None and frame is good


# --- the guard against the core ------------------------------------------------------------------


def _run_core_through_guard(
    cal: Calibration, segs: list[tuple[int, dict[str, Any]]], v0: float, break_core: Any = None
) -> tuple[int, int, list[str]]:
    """The core closed around the plant, every 10th command through the guard as the application
    sends it; returns (commands sent, refused, reasons)."""
    loop = _pm.CoreLoop(cal, speed_mps=v0, dt_s=0.001)
    guard = TxGuard(cal)
    sent = refused = 0
    reasons: list[str] = []
    loop.step(request_flags=HELD_LOW)
    for n, changes in segs:
        for _ in range(n):
            cmd: ActuatorCommand = loop.step(**changes)
            if break_core is not None:
                cmd = break_core(cmd)
            guard.note_cycle(cmd.steer_enable)
            if round(loop.t_s * 1000) % 10:
                continue
            frame = command_frame(cmd)
            _, reason = guard.guard(frame, cmd.state, loop.last_inputs.gear_engaged, loop.t_s)
            sent += 1
            if reason is not None:
                refused += 1
                reasons.append(reason)
    return sent, refused, reasons


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(segs=segments, v0=st.floats(0.0, 30.0), cal_name=st.sampled_from(sorted(CALS)))
def test_the_guard_never_refuses_a_healthy_core(
    segs: list[tuple[int, dict[str, Any]]], v0: float, cal_name: str
) -> None:
    _, refused, reasons = _run_core_through_guard(CALS[cal_name], segs, v0)
    assert refused == 0, reasons[:3]


BREAKAGES = {
    "throttle in every state": lambda c: c._replace(throttle_pct=30.0, brake_bar=0.0),
    "throttle and brake together": lambda c: c._replace(throttle_pct=10.0, brake_bar=10.0),
    "steering beyond its limit": lambda c: c._replace(steer_angle_rad=CAL.steer_max_rad * 1.5),
    "no brakes in a stop": lambda c: c._replace(engage=False),
    "park brake while driving": lambda c: c._replace(park_brake=True),
    "reverse asked for at speed": lambda c: c._replace(gear_request=Gear.REVERSE),
    "a NaN pedal": lambda c: c._replace(brake_bar=math.nan),
}


@pytest.mark.parametrize("name", sorted(BREAKAGES))
def test_the_guard_catches_a_deliberately_broken_core(name: str) -> None:
    # The car engages, drives, then a host fault stops it: every state's commands go through.
    segs: list[tuple[int, dict[str, Any]]] = [
        (500, {"request_accel_mps2": 1.0}),
        (500, {"host_alive": False}),
        (200, {}),
    ]
    sent, refused, _ = _run_core_through_guard(CAL, segs, 10.0, break_core=BREAKAGES[name])
    assert refused > 0, name
    # Every breakage that applies in every state is refused every time it is sent.
    if name in ("throttle and brake together", "steering beyond its limit", "a NaN pedal"):
        assert refused == sent


def test_a_broken_core_in_a_passive_state_gets_the_passive_command() -> None:
    guard = TxGuard(CAL)
    frame, reason = guard.guard(command(ecu_state=EcuState.READY), EcuState.READY, Gear.DRIVE, 0.0)
    assert reason is not None and not frame.engage and frame.brake_bar == 0.0 and frame.throttle_pct == 0.0


def test_calibration_limits_are_the_guards_limits() -> None:
    narrow = dataclasses.replace(CAL, steer_max_rad=0.1)
    assert check(command(steer_angle_rad=0.2), cal=CAL) is None
    assert check(command(steer_angle_rad=0.2), cal=narrow) is not None


def test_a_fallback_that_begins_above_the_hold_pressure_keeps_its_brake() -> None:
    guard = TxGuard(CAL)
    strong = command(throttle_pct=0.0, brake_bar=150.0, ecu_state=EcuState.SAFE_STOP)
    guard.guard(strong, EcuState.SAFE_STOP, Gear.DRIVE, 0.0)
    for k in range(1, 20):
        frame, reason = guard.guard(
            command(ecu_state=EcuState.SAFE_STOP), EcuState.SAFE_STOP, Gear.DRIVE, k * 0.01
        )
        assert reason is not None and frame.brake_bar == 150.0  # never softer than what was braking


# --- the boundaries and the memory of the guard (each line pins one rule down) ------------------


def test_the_limits_themselves_are_allowed() -> None:
    assert check(command(throttle_pct=100.0)) is None
    assert check(command(throttle_pct=0.0, brake_bar=200.0)) is None
    assert check(command(steer_angle_rad=CAL.steer_max_rad)) is None
    assert check(command(steer_angle_rad=-CAL.steer_max_rad)) is None
    step = CAL.steer_rate_max_radps * SEND_PERIOD_S + 0.0001  # the rate limit plus one DBC step
    assert check(command(steer_angle_rad=step), prev=command()) is None
    assert check(command(steer_angle_rad=step * 1.001), prev=command()) is not None


@pytest.mark.parametrize("field", ["throttle_pct", "brake_bar"])
def test_any_pedal_at_all_is_refused_in_a_passive_state(field: str) -> None:
    passive = command(**PASSIVE, ecu_state=EcuState.READY)
    assert check(passive, EcuState.READY) is None
    assert check(dataclasses.replace(passive, **{field: 0.01}), EcuState.READY) is not None


def test_any_throttle_at_all_is_refused_in_a_stop() -> None:
    stop = command(throttle_pct=0.01, brake_bar=0.0, ecu_state=EcuState.PAUSED)
    assert "propulsion only while ENGAGED" in (check(stop, EcuState.PAUSED) or "")


def test_a_shift_needs_only_some_brake() -> None:
    cmd = command(throttle_pct=0.0, brake_bar=0.01, gear_request=Gear.REVERSE)
    assert check(cmd) is None


def test_the_rate_rule_reports_the_interval_in_milliseconds() -> None:
    reason = check(command(steer_angle_rad=0.4), prev=command(), dt_s=0.1)
    assert reason is not None and "in 100.0 ms" in reason


def test_the_guard_measures_the_rate_between_the_commands_it_sent() -> None:
    guard = TxGuard(CAL)
    assert guard.last_reason is None and guard.trips == 0
    guard.guard(command(), EcuState.ENGAGED, Gear.DRIVE, 10.0)
    too_far = CAL.steer_rate_max_radps * 0.01 * 1.5
    _, reason = guard.guard(command(steer_angle_rad=too_far), EcuState.ENGAGED, Gear.DRIVE, 10.01)
    assert reason is not None and guard.trips == 1 and guard.last_reason == reason
    _, reason2 = guard.guard(command(throttle_pct=5.0, brake_bar=5.0), EcuState.ENGAGED, Gear.DRIVE, 10.02)
    assert reason2 is not None and guard.trips == 2 and guard.last_reason == reason2


def test_steering_interrupted_between_two_sends_may_start_anywhere() -> None:
    guard = TxGuard(CAL)
    guard.guard(command(), EcuState.ENGAGED, Gear.DRIVE, 0.0)
    for _ in range(9):
        guard.note_cycle(True)  # enabled in every cycle: one continuous motion
    _, reason = guard.guard(command(steer_angle_rad=0.2), EcuState.ENGAGED, Gear.DRIVE, 0.01)
    assert reason is not None
    guard = TxGuard(CAL)
    guard.guard(command(), EcuState.ENGAGED, Gear.DRIVE, 0.0)
    guard.note_cycle(True)
    guard.note_cycle(False)  # released for a cycle: the next angle starts from the measurement
    guard.note_cycle(True)
    _, reason = guard.guard(command(steer_angle_rad=0.2), EcuState.ENGAGED, Gear.DRIVE, 0.01)
    assert reason is None


def test_the_passive_replacement_is_exactly_passive_and_remembered() -> None:
    guard = TxGuard(CAL)
    frame, reason = guard.guard(command(ecu_state=EcuState.READY), EcuState.READY, Gear.REVERSE, 3.0)
    assert reason is not None
    assert frame == DbwCommand(0.0, 0.0, 0.0, False, False, True, False, EcuState.READY, Gear.REVERSE)
    assert frame.engage is False and frame.park_brake is False and frame.steer_enable is False
    assert guard.last_sent is frame and guard.last_sent_s == 3.0
    # A later safe stop starts afresh, from the (released) brake of that passive command.
    frame, reason = guard.guard(command(ecu_state=EcuState.SAFE_STOP), EcuState.SAFE_STOP, Gear.REVERSE, 3.01)
    assert reason is not None and frame.brake_bar == 0.0 and frame.engage


def test_the_safe_stop_command_field_by_field() -> None:
    guard = TxGuard(CAL)  # nothing sent yet: the ramp starts from a released brake
    frame, _ = guard.guard(command(ecu_state=EcuState.SAFE_STOP), EcuState.SAFE_STOP, Gear.REVERSE, 10.0)
    assert frame == DbwCommand(0.0, 0.0, 0.0, True, False, True, False, EcuState.SAFE_STOP, Gear.REVERSE)
    assert frame.park_brake is False and frame.steer_enable is False
    guard = TxGuard(CAL)
    guard.guard(
        command(throttle_pct=0.0, brake_bar=20.0, steer_enable=False), EcuState.ENGAGED, Gear.DRIVE, 10.0
    )
    bad = command(brake_bar=5.0, steer_enable=False)  # throttle and brake together
    half = FALLBACK_BRAKE_RAMP_S / 2
    first, _ = guard.guard(bad, EcuState.ENGAGED, Gear.DRIVE, 10.0)
    mid, _ = guard.guard(bad, EcuState.ENGAGED, Gear.DRIVE, 10.0 + half)
    end, _ = guard.guard(bad, EcuState.ENGAGED, Gear.DRIVE, 10.0 + 2 * FALLBACK_BRAKE_RAMP_S)
    assert first.brake_bar == 20.0
    assert mid.brake_bar == pytest.approx(20.0 + (CAL.hold_brake_bar - 20.0) / 2)
    assert end.brake_bar == CAL.hold_brake_bar and not end.steer_enable
