"""The reverse gear end to end (urban driving: backing out of a parking spot): the protocol's gear signals,
the ECU's gear rules, the Passat plant's reverse physics and a closed loop that backs the car 10 m.

Rules under test (ecu/gear.py): a shift only at standstill with the brake held, the ECU braking and
holding while the wanted, requested and engaged gears differ, GEAR_TIMEOUT when the gateway never
confirms, the reverse speed limit, the E-stop in reverse, READY/DISABLE keeping the engaged gear.
"""

from __future__ import annotations

import math

import plant_model as _pm  # tests/ is on pytest's pythonpath
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bywire.ecu.calibration import default_calibration
from bywire.ecu.core import core_step, initial_core_state, judge_inputs
from bywire.ecu.gear import (
    GEAR_CONFIRM_TIMEOUT_S,
    REVERSE_SPEED_MAX_MPS,
    SHIFT_BRAKE_SETTLE_S,
    accel_along_travel_mps2,
    reverse_accel_limit_mps2,
)
from bywire.hil.plant import SHIFT_DELAY_S
from bywire.protocol.ecu_types import EcuState, EstopMode, Fault, Gear, RequestFlags
from bywire.protocol.host_link import EcuStatus, HostRequest
from bywire.protocol.vehicle_can import DbwCommand, FrameError, Motion, VehicleCodec

CAL = default_calibration()
ENGAGE = RequestFlags.ENGAGE | RequestFlags.STEER
REVERSE = ENGAGE | RequestFlags.REVERSE


# -- protocol -----------------------------------------------------------------------------------------


def _dbw(gear: Gear) -> DbwCommand:
    return DbwCommand(12.3, 4.5, -0.1, True, False, True, True, EcuState.ENGAGED, gear)


def test_gear_signals_round_trip_and_leave_the_old_signals_bit_identical() -> None:
    codec = VehicleCodec()
    drive, reverse = codec.encode(_dbw(Gear.DRIVE), 3), codec.encode(_dbw(Gear.REVERSE), 3)
    assert codec.decode(reverse) == _dbw(Gear.REVERSE) and codec.decode(drive) == _dbw(Gear.DRIVE)
    # Only bit 57 (GearRequest) and the CRC byte differ: every older signal keeps its bits.
    diff = int.from_bytes(drive.data, "little") ^ int.from_bytes(reverse.data, "little")
    assert diff & ~0xFF == 1 << 57
    m = Motion(-1.234, 0.05, 12.0, Gear.REVERSE)
    motion = codec.encode(m, 7)
    assert codec.decode(motion) == m
    m_fwd = codec.encode(Motion(-1.234, 0.05, 12.0, Gear.DRIVE), 7)
    diff = int.from_bytes(motion.data, "little") ^ int.from_bytes(m_fwd.data, "little")
    assert diff & ~0xFF == 1 << 60
    # LongAccel is signed in the vehicle frame: a reversing car speeding up reads negative.
    assert codec.decode(motion).long_accel_mps2 == pytest.approx(-1.234)  # type: ignore[union-attr]


def test_status_and_request_carry_the_gear() -> None:
    status = EcuStatus(
        EcuState.ENGAGED, Fault.GEAR_TIMEOUT, 1.5, -0.3, 0, 20.0, 0.1, 50, 80, 0, 9, Gear.REVERSE
    )
    raw = status.to_raw()
    assert raw["gear"] == 1 and raw["faults"] == 1 << 11
    assert EcuStatus.from_raw(raw) == status
    with pytest.raises(ValueError, match=r"EcuStatus\.gear: 2 is not a Gear"):
        EcuStatus.from_raw({**raw, "gear": 2})
    req = HostRequest(-0.5, 0.0, REVERSE, 1)
    assert HostRequest.from_raw(req.to_raw()).flags & RequestFlags.REVERSE


@settings(max_examples=300, deadline=None)
@given(data=st.binary(min_size=0, max_size=10), frame_id=st.sampled_from([0x100, 0x121]))
def test_gear_frames_decode_or_raise_frame_error(data: bytes, frame_id: int) -> None:
    import can

    codec = VehicleCodec()
    msg = can.Message(arbitration_id=frame_id, data=data, is_extended_id=False)
    try:
        frame = codec.decode(msg)
    except FrameError:
        return
    assert isinstance(frame, DbwCommand | Motion)


# -- the ECU's gear rules ---------------------------------------------------------------------------------


def _engaged_loop(**kw: object) -> _pm.CoreLoop:
    loop = _pm.CoreLoop(CAL, **kw)  # type: ignore[arg-type]
    loop.step(request_flags=RequestFlags.STEER)  # an engage press: ENGAGE released, then raised
    loop.run(0.05, request_flags=ENGAGE)
    assert loop.cmd is not None and loop.cmd.state == EcuState.ENGAGED
    return loop


def test_accel_is_taken_along_the_direction_of_travel() -> None:
    assert accel_along_travel_mps2(-0.8, Gear.REVERSE) == 0.8
    assert accel_along_travel_mps2(-0.8, Gear.DRIVE) == -0.8
    inp = _pm.healthy_inputs(accel_meas_mps2=-0.8, gear_engaged=Gear.REVERSE, request_flags=REVERSE)
    verdict = judge_inputs(inp, CAL)
    assert verdict.accel_along_mps2 == 0.8 and verdict.wanted_gear == Gear.REVERSE
    assert reverse_accel_limit_mps2(REVERSE_SPEED_MAX_MPS) == 0.0 and reverse_accel_limit_mps2(3.0) < 0.0


def test_no_shift_while_moving_brake_to_standstill_then_reverse() -> None:
    loop = _engaged_loop()
    loop.run(3.0, request_accel_mps2=1.0, request_flags=ENGAGE)
    assert loop.plant.v_mps > 2.0
    t_switch = loop.t_s
    asked_at: float | None = None
    engaged_at: float | None = None
    while loop.t_s - t_switch < 6.0:
        cmd = loop.step(request_accel_mps2=1.0, request_flags=REVERSE)
        if asked_at is None and cmd.gear_request == Gear.REVERSE:
            asked_at = loop.t_s
            # never while moving, and only with the hold pressure on
            assert abs(loop.plant.v_mps) < 0.05 and cmd.brake_bar >= CAL.hold_brake_bar * 0.99
        if asked_at is None or engaged_at is None:
            assert cmd.throttle_pct == 0.0 and cmd.shifting
            if asked_at is not None:
                assert cmd.brake_bar >= CAL.hold_brake_bar * 0.99 and cmd.holding
        if engaged_at is None and loop.plant.gear == Gear.REVERSE:
            engaged_at = loop.t_s
    assert asked_at is not None and engaged_at is not None
    assert engaged_at - asked_at == pytest.approx(SHIFT_DELAY_S, abs=0.005)
    # then it drives backwards: the plant's signed speed is negative, the position decreases
    assert loop.plant.v_mps < -1.0 and loop.cmd is not None and not loop.cmd.shifting
    assert loop.cmd.state == EcuState.ENGAGED and loop.cmd.faults_active == Fault.NONE


def test_shift_waits_for_the_brake_to_settle_and_for_every_wheel() -> None:
    # Pure core: at standstill the request changes only after SHIFT_BRAKE_SETTLE_S of hold, and a
    # wheel still turning (or unknown) blocks it.
    st_ = initial_core_state(0.0)
    t = 0.0
    for k in range(20):
        t += 0.001
        flags = RequestFlags.STEER if k == 0 else ENGAGE  # an engage press
        st_, cmd = core_step(st_, _pm.healthy_inputs(wheel_speed_max_mps=0.0, request_flags=flags), t, CAL)
    assert cmd.state == EcuState.ENGAGED
    for wheels in (0.3, math.inf):
        s2, t2 = st_, t
        for _ in range(1000):
            t2 += 0.001
            s2, cmd = core_step(
                s2, _pm.healthy_inputs(request_flags=REVERSE, wheel_speed_max_mps=wheels), t2, CAL
            )
        assert cmd.gear_request == Gear.DRIVE and cmd.shifting and cmd.throttle_pct == 0.0
    t0 = t
    while cmd.gear_request != Gear.REVERSE:
        t += 0.001
        st_, cmd = core_step(st_, _pm.healthy_inputs(request_flags=REVERSE, wheel_speed_max_mps=0.0), t, CAL)
    assert t - t0 == pytest.approx(SHIFT_BRAKE_SETTLE_S, abs=0.0015)


def test_a_gear_never_confirmed_is_a_gear_timeout_stop() -> None:
    loop = _engaged_loop(selector=_pm.GearSelector(stuck=True))
    t0 = loop.t_s
    dt = loop.run_until(lambda c: c.state == EcuState.SAFE_STOP, 5.0, request_flags=REVERSE)
    assert dt == pytest.approx(SHIFT_BRAKE_SETTLE_S + GEAR_CONFIRM_TIMEOUT_S, abs=0.01)
    cmd = loop.cmd
    assert cmd is not None and cmd.faults_latched == Fault.GEAR_TIMEOUT
    assert cmd.gear_request == Gear.DRIVE  # a stop asks for the engaged gear
    assert loop.t_s > t0 and abs(loop.plant.v_mps) == 0.0
    # the cause is gone once the ECU no longer asks: re-arm at standstill works
    loop.run(0.1, request_flags=RequestFlags.REARM)
    assert loop.cmd is not None and loop.cmd.state == EcuState.READY


def _reversing_loop(speed_mps: float) -> _pm.CoreLoop:
    loop = _engaged_loop()
    loop.run(1.5, request_flags=REVERSE)  # shift
    assert loop.plant.gear == Gear.REVERSE
    loop.run_until(
        lambda c: loop.plant.v_mps < -speed_mps, 10.0, request_accel_mps2=1.0, request_flags=REVERSE
    )
    return loop


def test_reverse_speed_is_limited_by_the_ecu() -> None:
    loop = _reversing_loop(1.0)
    v_min = 0.0
    for _ in range(15000):
        loop.step(request_accel_mps2=2.0, request_flags=REVERSE)
        v_min = min(v_min, loop.plant.v_mps)
    assert -REVERSE_SPEED_MAX_MPS - 0.15 < v_min < -REVERSE_SPEED_MAX_MPS + 0.2
    assert loop.plant.v_mps == pytest.approx(-REVERSE_SPEED_MAX_MPS, abs=0.15)


@pytest.mark.parametrize("mode", [EstopMode.PAUSE, EstopMode.DISABLE])
def test_estop_in_reverse_stops_and_keeps_the_gear(mode: EstopMode) -> None:
    loop = _reversing_loop(2.0)
    x0 = loop.plant.x_m
    dt = loop.run_until(lambda c: c.holding, 5.0, estop_mode=mode, request_flags=REVERSE)
    assert dt < 2.0 and loop.plant.x_m < x0  # holds (below the standstill speed) within 2 s
    loop.run(1.0, estop_mode=mode, request_flags=REVERSE)
    cmd = loop.cmd
    assert cmd is not None and cmd.throttle_pct == 0.0 and loop.plant.v_mps == 0.0
    assert cmd.state == (EcuState.PAUSED if mode == EstopMode.PAUSE else EcuState.DISABLED)
    assert cmd.gear_request == Gear.REVERSE and loop.plant.gear == Gear.REVERSE


def test_ready_keeps_the_engaged_gear_and_the_driver_still_overrides() -> None:
    loop = _reversing_loop(1.0)
    loop.run(2.0, request_flags=RequestFlags.STEER)  # the host lets go: SAFE_STOP
    loop.run(0.1, request_flags=RequestFlags.REARM)
    assert loop.cmd is not None and loop.cmd.state == EcuState.READY
    assert loop.cmd.gear_request == Gear.REVERSE and loop.plant.gear == Gear.REVERSE
    # a driver on the brake while reversing: MANUAL at once, hands off
    loop = _reversing_loop(1.0)
    cmd = loop.step(driver_brake_pressed=True, request_flags=REVERSE)
    assert cmd.state == EcuState.MANUAL and not cmd.engage and cmd.gear_request == Gear.REVERSE


# -- the plant ----------------------------------------------------------------------------------------------


def test_passat_fmu_reverses_consistently() -> None:
    from bywire.vehicle_models.fmu_vehicle import VehicleInputs, open_vehicle

    with open_vehicle() as car:
        out = car.outputs()
        for _ in range(300):
            out = car.step(0.01, VehicleInputs(throttle_pct=15.0, gear=-1.0))
        assert out.speed_mps < -0.5 and out.accel_mps2 < 0.0  # signed: backwards and speeding up
        assert out.x_m < -0.5 and out.distance_m == pytest.approx(out.x_m)
        assert min(out.wheel_speed_fl_mps, out.wheel_speed_rr_mps) < 0.0
        v_prev = out.speed_mps
        for i in range(300):
            out = car.step(0.01, VehicleInputs(brake_bar=40.0, gear=-1.0))
            assert out.speed_mps <= 0.0  # the brake stops the car, it never reverses it
            if i >= 50:  # once the drive force has decayed (0.25 s lag) the speed only shrinks
                assert out.speed_mps >= v_prev - 1e-9
            v_prev = out.speed_mps
        assert out.speed_mps == 0.0
        # forward gear again: it drives forward
        for _ in range(200):
            out = car.step(0.01, VehicleInputs(throttle_pct=15.0, gear=1.0))
        assert out.speed_mps > 0.3


def test_python_twin_matches_the_fmu_in_reverse() -> None:
    from bywire.vehicle_models.fmu_vehicle import VehicleInputs, open_vehicle

    twin = _pm.PointMassPlant()
    twin.gear = Gear.REVERSE
    with open_vehicle() as car:
        for _ in range(3000):
            out = car.step(0.001, VehicleInputs(throttle_pct=20.0, gear=-1.0))
            twin.step(0.001, 20.0, 0.0)
    assert twin.v_mps == pytest.approx(out.speed_mps, rel=0.02)
    assert twin.x_m == pytest.approx(out.x_m, rel=0.02)


# -- closed loop: ECU core + Passat FMU + the gateway's selector ---------------------------------------------


def test_sil_backs_the_car_10_m_straight_and_stops() -> None:
    """A host that backs 10 m with a stop-at-distance law (the orbital path is not needed straight):
    the ECU shifts, reverses under its speed limit, and the car stops within 0.3 m."""
    from bywire.hil.plant import SHIFT_BRAKE_MIN_BAR, SHIFT_STANDSTILL_SPEED_MPS
    from bywire.vehicle_models.fmu_vehicle import VehicleInputs, open_vehicle

    target_m, dt = -10.0, 0.001
    with open_vehicle() as car:
        out = car.outputs()
        state = initial_core_state(0.0)
        gear, shift_to, shift_done = Gear.DRIVE, None, math.inf
        t = 0.0
        stopped_at = None
        while t < 25.0:
            t += dt
            # The host's engage press: ENGAGE released in the first cycle, then held.
            flags = RequestFlags.STEER if t < 1.5 * dt else REVERSE
            togo = max(out.x_m - target_m, 0.0)  # metres still to back
            v = abs(out.speed_mps)
            v_des = min(2.0, math.sqrt(2.0 * 0.5 * togo))
            accel = 2.5 * (v_des - v) if togo > 0.05 else -2.0
            inp = _pm.healthy_inputs(
                request_flags=flags,
                request_accel_mps2=accel,
                speed_mps=v,
                wheel_speed_max_mps=max(abs(out.wheel_speed_fl_mps), abs(out.wheel_speed_rr_mps)),
                accel_meas_mps2=out.accel_mps2,
                steer_angle_meas_rad=out.steer_angle_rad_actual,
                gear_engaged=gear,
            )
            state, cmd = core_step(state, inp, t, CAL)
            held = v < SHIFT_STANDSTILL_SPEED_MPS and cmd.brake_bar >= SHIFT_BRAKE_MIN_BAR
            if cmd.gear_request != gear and held:
                if shift_to != cmd.gear_request:
                    shift_to, shift_done = cmd.gear_request, t + SHIFT_DELAY_S
                elif t >= shift_done:
                    gear, shift_to = cmd.gear_request, None
            else:
                shift_to = None
            out = car.step(
                dt,
                VehicleInputs(
                    throttle_pct=cmd.throttle_pct if cmd.engage else 0.0,
                    brake_bar=cmd.brake_bar if cmd.engage else 0.0,
                    steer_angle_rad=cmd.steer_angle_rad,
                    gear=-1.0 if gear == Gear.REVERSE else 1.0,
                ),
            )
            assert cmd.state in (EcuState.READY, EcuState.ENGAGED), (t, cmd)
            assert out.speed_mps <= 1e-9  # never forward
            assert abs(out.speed_mps) <= REVERSE_SPEED_MAX_MPS + 0.1
            if stopped_at is None and togo <= 0.05 and out.speed_mps == 0.0 and t > 2.0:
                stopped_at = t
            if stopped_at is not None and t - stopped_at > 1.0:
                break
    assert stopped_at is not None, f"never stopped: x {out.x_m:.2f} m, v {out.speed_mps:.2f} m/s"
    assert out.x_m == pytest.approx(target_m, abs=0.3)
    assert abs(out.y_m) < 0.05 and abs(out.heading_rad) < 0.01
