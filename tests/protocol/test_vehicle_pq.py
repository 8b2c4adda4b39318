"""Vehicle profile pq: the VW PQ car's own messages (opendbc's vw_pq.dbc) beside our own.

Encode/decode on both halves, the XOR checksum and counters as opendbc and panda compute and read
them, cantools' reading of the frames the plant sends, the receiver's checks on the car's messages,
and frame ids that leave the real PQ bus alone.
"""

from __future__ import annotations

import dataclasses
import math
import uuid

import can
import pytest

from bywire.hil.plant import Plant
from bywire.hil.scenario import load_scenario
from bywire.hil.scenario_vehicle import open_scenario_vehicle
from bywire.protocol.ecu_types import EcuState, EstopMode, Gear
from bywire.protocol.vehicle_can import (
    CHECKSUM_E2E,
    CHECKSUM_NONE,
    CHECKSUM_XOR,
    BrakePressure,
    BrakeSwitch,
    DbwCommand,
    EstopRadio,
    FrameError,
    GasPedal,
    GearReport,
    InertialReport,
    RadarTarget,
    RejectReason,
    SafetyArmButton,
    SteerReport,
    VehicleCodec,
    VehicleFrame,
    WheelSpeeds,
    xor_checksum,
)
from bywire.protocol.vehicle_pq import REPORT_MESSAGES, STEERING_RATIO, report_messages
from bywire.protocol.vehicle_rx import VehicleRx

PQ = VehicleCodec(profile="pq")
BYWIRE = VehicleCodec()

# Every frame id of opendbc's complete vw_pq.dbc (opendbc 0.3.1): what a real PQ bus may carry.
VW_PQ_IDS = frozenset(
    {
        80, 192, 194, 196, 208, 210, 256, 258, 260, 262, 268, 274, 416, 424, 428, 608, 640, 644, 648,
        672, 680, 704, 800, 835, 864, 870, 872, 896, 900, 904, 906, 912, 914, 928, 954, 976, 978, 980,
        1056, 1088, 1096, 1136, 1152, 1160, 1175, 1184, 1192, 1280, 1298, 1300, 1312, 1324, 1326, 1328,
        1332, 1336, 1340, 1344, 1352, 1360, 1386, 1392, 1394, 1400, 1408, 1416, 1424, 1432, 1440, 1463,
        1464, 1470, 1472, 1488, 1490, 1496, 1500, 1502, 1504, 1550, 1792, 1796, 1810, 1984, 1986, 2000,
    }
)  # fmt: skip

CAR_FRAMES: dict[str, VehicleFrame] = {
    "Lenkhilfe_3": SteerReport(steer_angle_rad=-0.1234, steer_torque_nm=-2.37),
    "Motor_2": BrakeSwitch(brake_pedal_pressed=True),
    "Motor_3": GasPedal(throttle_pedal_pct=12.4),
    "Getriebe_1": GearReport(gear_engaged=Gear.REVERSE),
    "Bremse_3": WheelSpeeds(fl_mps=10.0, fr_mps=10.1, rl_mps=9.9, rr_mps=10.05),
    "Bremse_5": BrakePressure(brake_bar_actual=35.2),
}
OWN_FRAMES: dict[str, VehicleFrame] = {
    "ESTOP_Radio": EstopRadio(mode=EstopMode.PAUSE),
    "DBW_Command": DbwCommand(
        throttle_pct=12.0,
        brake_bar=0.0,
        steer_angle_rad=0.05,
        engage=True,
        park_brake=False,
        ignition=True,
        steer_enable=True,
        ecu_state=EcuState.ENGAGED,
    ),
    "GW_Inertial": InertialReport(long_accel_mps2=-1.25, yaw_rate_radps=0.05),
    "GW_Arm": SafetyArmButton(safety_arm=True),
    "RADAR_Target": RadarTarget(valid=True, range_m=40.0, range_rate_mps=-2.0, azimuth_rad=0.01),
}


def _close(a: VehicleFrame, b: VehicleFrame, tol: float) -> bool:
    for f in dataclasses.fields(a):  # type: ignore[arg-type]
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, float):
            if not math.isclose(x, y, abs_tol=tol):
                return False
        elif x != y:
            return False
    return True


# -- the profile's messages --------------------------------------------------------------------------


def test_the_profile_has_the_cars_messages_and_ours() -> None:
    names = {info.name for info in PQ.messages}
    assert names == set(CAR_FRAMES) | set(OWN_FRAMES)
    assert set(PQ.received_by("ECU")) == set(CAR_FRAMES) | {"ESTOP_Radio", "GW_Inertial", "GW_Arm"}
    assert PQ.received_by("GATEWAY") == ("ESTOP_Radio", "DBW_Command")


def test_our_frame_ids_leave_the_pq_bus_alone() -> None:
    own = {PQ.info(name).frame_id for name in OWN_FRAMES}
    assert not own & VW_PQ_IDS
    # the bywire profile's command sits on the PQ engine message MSG_1: the reason for the profile
    assert BYWIRE.info("DBW_Command").frame_id in VW_PQ_IDS
    assert {PQ.info(name).frame_id for name in CAR_FRAMES} <= VW_PQ_IDS


def test_protection_is_opendbcs_rule_for_vw_pq() -> None:
    """A signal named CHECKSUM is the XOR checksum, one named COUNTER the alive counter."""
    expected = {
        "Lenkhilfe_3": (CHECKSUM_XOR, 0, 12),
        "Bremse_5": (CHECKSUM_XOR, 7, 52),
        "Getriebe_1": (CHECKSUM_NONE, 0, 51),
        "Motor_2": (CHECKSUM_NONE, 0, None),
        "Motor_3": (CHECKSUM_NONE, 0, None),
        "Bremse_3": (CHECKSUM_NONE, 0, None),
    }
    for name, (checksum, byte, counter) in expected.items():
        info = PQ.info(name)
        assert (info.checksum, info.checksum_byte, info.counter_start) == (checksum, byte, counter), name
    for name in OWN_FRAMES:
        assert PQ.info(name).checksum == CHECKSUM_E2E


def test_cycle_times_are_the_cars() -> None:
    cycles = {name: PQ.info(name).cycle_time_s for name in CAR_FRAMES}
    assert cycles == {
        "Lenkhilfe_3": 0.01,
        "Motor_2": 0.02,
        "Motor_3": 0.01,
        "Getriebe_1": 0.01,
        "Bremse_3": 0.01,
        "Bremse_5": 0.02,
    }


# -- encode / decode -----------------------------------------------------------------------------------


@pytest.mark.parametrize("name", [*CAR_FRAMES, *OWN_FRAMES])
def test_round_trip(name: str) -> None:
    frame = {**CAR_FRAMES, **OWN_FRAMES}[name]
    msg = PQ.encode(frame, 9)
    assert msg.arbitration_id == PQ.info(name).frame_id
    decoded = PQ.decode(msg)
    assert type(decoded) is type(frame)
    # one LSB: 0.15 deg of steering wheel / 14, 0.01 km/h, 0.4 %, 0.1 bar, 0.01 Nm
    assert _close(decoded, frame, tol=0.2), (decoded, frame)


@pytest.mark.parametrize("name", ["ESTOP_Radio", "DBW_Command", "RADAR_Target"])
def test_our_messages_mean_the_same_in_both_profiles(name: str) -> None:
    frame = OWN_FRAMES[name]
    a, b = PQ.encode(frame, 3), BYWIRE.encode(frame, 3)
    assert bytes(a.data)[1:] == bytes(b.data)[1:]  # same payload; the CRC covers the frame id too


@pytest.mark.parametrize(
    "name", [n for n, i in ((n, PQ.info(n)) for n in CAR_FRAMES) if i.checksum != CHECKSUM_NONE]
)
def test_xor_checksum_is_opendbcs(name: str) -> None:
    msg = PQ.encode(CAR_FRAMES[name], 5)
    info = PQ.info(name)
    data = bytes(msg.data)
    x = 0
    for i, byte in enumerate(data):  # opendbc's xor_checksum, written out
        if i != info.checksum_byte:
            x ^= byte
    assert data[info.checksum_byte] == x == xor_checksum(data, info.checksum_byte)


@pytest.mark.parametrize("name", [n for n in CAR_FRAMES if n != "Motor_2"])
def test_cantools_reads_what_we_write(name: str) -> None:
    """opendbc's DBC read by cantools gives the same raw signals (Motor_2's multiplexer is written
    `m` in opendbc's file, which cantools cannot decode; panda's reading covers it below)."""
    frame = CAR_FRAMES[name]
    info = PQ.info(name)
    msg = PQ.encode(frame, 11)
    raw = info.message.decode(bytes(msg.data), decode_choices=False, scaling=False)
    if info.counter_start is not None:
        assert raw["COUNTER"] == 11
    if info.checksum != CHECKSUM_NONE:
        assert raw["CHECKSUM"] == msg.data[info.checksum_byte]
    for sig in info.signals:
        value = getattr(frame, sig.field)
        if sig.kind == "mapped":
            assert raw[sig.signal] == dict((m, r) for r, m in sig.mapping)[value]
        elif sig.kind == "bool":
            assert raw[sig.signal] == int(value)
        else:
            assert raw[sig.signal] == round(abs(value) / sig.scale)
            if sig.kind == "magnitude":
                sign_name = info.message.signals[
                    [s.start for s in info.message.signals].index(sig.sign_start)
                ].name
                assert raw[sign_name] == int(value < 0)


def test_panda_reads_the_signals_it_reads() -> None:
    """The bit expressions of panda's volkswagen_pq safety mode (opendbc/safety/modes/volkswagen_pq.h)."""
    lh3 = PQ.encode(SteerReport(steer_angle_rad=0.0, steer_torque_nm=-2.37), 0).data
    torque = lh3[2] | ((lh3[3] & 0x3) << 8)
    assert torque == 237 and (lh3[3] & 0x4) >> 2 == 1  # centi-Nm, sign bit
    assert (lh3[1] & 0xF0) >> 4 == 0  # panda's counter of Lenkhilfe_3
    assert PQ.encode(GasPedal(throttle_pedal_pct=40.0), 0).data[2] == 100  # MO3_Pedalwert, 0.4 %
    assert PQ.encode(BrakeSwitch(brake_pedal_pressed=True), 0).data[2] & 0x1 == 1  # MO2_BLS
    assert PQ.encode(BrakeSwitch(brake_pedal_pressed=False), 0).data[2] & 0x1 == 0


def test_conversions_into_si() -> None:
    wheels = PQ.encode(WheelSpeeds(10.0, 0.0, 0.0, 0.0), 0)
    assert PQ.info("Bremse_3").message.decode(bytes(wheels.data))["Radgeschw__VL_4_1"] == pytest.approx(36.0)
    steer = PQ.encode(
        SteerReport(steer_angle_rad=math.radians(30.0) / STEERING_RATIO, steer_torque_nm=0.0), 0
    )
    decoded = PQ.info("Lenkhilfe_3").message.decode(bytes(steer.data))
    assert decoded["LH3_BLW"] == pytest.approx(30.0) and decoded["LH3_BLWSign"] == 0  # left is positive


def test_a_value_the_car_cannot_send_is_refused_with_where() -> None:
    with pytest.raises(ValueError, match=r"Motor_3\.MO3_Pedalwert \(GasPedal\.throttle_pedal_pct\): 120"):
        PQ.encode(GasPedal(throttle_pedal_pct=120.0), 0)
    with pytest.raises(ValueError, match=r"Lenkhilfe_3\.LH3_BLW .*magnitude range"):
        PQ.encode(SteerReport(steer_angle_rad=-0.9, steer_torque_nm=0.0), 0)
    saturated = PQ.decode(PQ.encode(GasPedal(throttle_pedal_pct=120.0), 0, saturate=True))
    assert isinstance(saturated, GasPedal) and saturated.throttle_pedal_pct == pytest.approx(101.6)


def test_a_selector_in_p_or_n_is_no_gear_the_ecu_drives_in() -> None:
    msg = PQ.encode(GearReport(gear_engaged=Gear.DRIVE), 0)
    data = bytearray(msg.data)
    data[1] = (data[1] & 0x0F) | (8 << 4)  # GE1_Wahl_Pos 8: P
    with pytest.raises(FrameError, match=r"GE1_Wahl_Pos = 8 is none of 5 \(DRIVE\), 7 \(REVERSE\)") as err:
        PQ.decode(can.Message(arbitration_id=msg.arbitration_id, data=data, is_extended_id=False))
    assert err.value.reason is RejectReason.MALFORMED


# -- the receiver on the car's messages ------------------------------------------------------------------


def _rx() -> VehicleRx:
    return VehicleRx.for_node(PQ, "ECU", max_age_cycles=None)


def test_a_spoiled_xor_checksum_is_corrupt() -> None:
    rx = _rx()
    msg = PQ.encode(CAR_FRAMES["Bremse_5"], 1)
    data = bytearray(msg.data)
    data[2] ^= 0x01  # one bit of BR5_Bremsdruck
    assert (
        rx.feed(can.Message(arbitration_id=msg.arbitration_id, data=data, is_extended_id=False), 0.0) is None
    )
    assert rx.counts("Bremse_5")["corrupt"] == 1
    assert rx.feed(msg, 0.0) == CAR_FRAMES["Bremse_5"]


def test_a_repeated_car_counter_is_never_fresh() -> None:
    rx = _rx()
    first = PQ.encode(CAR_FRAMES["Lenkhilfe_3"], 4)
    assert rx.feed(first, 0.00) is not None
    assert rx.feed(first, 0.01) is None
    assert rx.counts("Lenkhilfe_3")["repeated"] == 1
    # and after the timeout a frozen sender stays timed out, exactly as on our own messages
    assert rx.feed(first, 1.0) is None and rx.timed_out("Lenkhilfe_3", 1.0)
    assert rx.feed(PQ.encode(CAR_FRAMES["Lenkhilfe_3"], 5), 1.01) is not None


def test_a_car_message_without_a_counter_is_judged_by_its_age() -> None:
    rx = _rx()
    msg = PQ.encode(CAR_FRAMES["Bremse_3"], 0)
    assert rx.feed(msg, 0.00) is not None
    assert rx.feed(msg, 0.01) is not None  # the car's Bremse_3 has no counter: identical frames are news
    assert not rx.timed_out("Bremse_3", 0.01 + 0.05)
    assert rx.timed_out("Bremse_3", 0.01 + 0.051)  # 5 cycles of 10 ms after the last one


# -- the plant speaks the car ------------------------------------------------------------------------------


def test_the_plant_sends_what_the_car_sends() -> None:
    """A plant on profile pq for 0.2 s: every car message at its cycle time, each frame accepted by the
    ECU's receiver and read by cantools from opendbc's DBC as we decode it."""
    scenario = dataclasses.replace(load_scenario("grade"), vehicle_profile="pq")
    channel = f"pq-{uuid.uuid4().hex[:8]}"
    with (
        can.Bus(interface="virtual", channel=channel) as plant_bus,
        can.Bus(interface="virtual", channel=channel) as listener,
        open_scenario_vehicle(scenario) as vehicle,
    ):
        plant = Plant(scenario, vehicle, plant_bus, t0_s=0.0)
        for k in range(200):
            plant.step(k * 0.001)
        speed_mps = plant.outputs.speed_mps
        frames = []
        while (msg := listener.recv(timeout=0)) is not None:
            frames.append(msg)
    rx = VehicleRx.for_node(PQ, "ECU", max_age_cycles=None)
    seen: dict[str, int] = {}
    for msg in frames:
        info = PQ.lookup_id(msg.arbitration_id)
        assert info is not None, f"{msg.arbitration_id:#x} is no message of the pq profile"
        seen[info.name] = seen.get(info.name, 0) + 1
        if "ECU" in info.receivers:
            assert rx.feed(msg, msg.timestamp) is not None, rx.stats()["frames"][info.name]["last_reject"]
        if info.name in CAR_FRAMES and info.name != "Motor_2":
            ours = PQ.decode(msg)
            theirs = info.message.decode(bytes(msg.data), decode_choices=False)
            for sig in info.signals:
                value = getattr(ours, sig.field)
                if sig.kind in ("float", "magnitude"):
                    assert theirs[sig.signal] * sig.scale / info.message.get_signal_by_name(
                        sig.signal
                    ).scale == (pytest.approx(abs(value), abs=1e-9))
    assert rx.counts()["accepted"] == sum(n for name, n in seen.items() if "ECU" in PQ.info(name).receivers)
    # 200 ms: the 10 ms reports 20 times, the 20 ms ones 10 times; no gateway report of the bywire profile
    assert {name: seen[name] for name in CAR_FRAMES} == {
        "Lenkhilfe_3": 20,
        "Motor_2": 10,
        "Motor_3": 20,
        "Getriebe_1": 20,
        "Bremse_3": 20,
        "Bremse_5": 10,
    }
    assert seen["GW_Inertial"] == seen["GW_Arm"] == 20
    wheels = rx.last("Bremse_3")
    # the FMU's speed at the end (10 ms after the last report; the wheel-speed noise is 0.02 m/s)
    assert isinstance(wheels, WheelSpeeds) and wheels.mean_mps == pytest.approx(speed_mps, abs=0.1)
    assert rx.last("Getriebe_1") == GearReport(gear_engaged=Gear.DRIVE)


def test_gateway_reports_name_the_pq_messages_that_carry_them() -> None:
    assert report_messages(("GW_WheelSpeeds", "GW_Motion")) == (
        "Bremse_3",
        "GW_Inertial",
        "Bremse_5",
        "Getriebe_1",
    )
    assert report_messages(("Bremse_5", "GW_Steer")) == ("Bremse_5", "Lenkhilfe_3")
    carried = {name for names in REPORT_MESSAGES.values() for name in names}
    assert carried == set(PQ.received_by("ECU")) - {"ESTOP_Radio"}


def test_the_firmware_self_test_loads_opendbcs_file_as_the_codec_does() -> None:
    from bywire.ecu import firmware
    from bywire.protocol import vehicle_can

    assert firmware.LENIENT_DBCS == vehicle_can.LENIENT_DBCS == {"vw_pq.dbc"}
