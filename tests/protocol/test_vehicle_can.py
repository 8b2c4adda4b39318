"""Vehicle-CAN codec and receiver: DBC agreement, round trips, range handling, E2E rejection and counting."""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
import re
from pathlib import Path
from typing import Any

import can
import pytest
from hypothesis import given
from hypothesis import strategies as st

from bywire.protocol.e2e import protect
from bywire.protocol.ecu_types import EcuState, EstopMode
from bywire.protocol.vehicle_can import (
    DbwCommand,
    DriverInputs,
    EstopRadio,
    FrameError,
    Motion,
    RadarTarget,
    RejectReason,
    SteerReport,
    VehicleCodec,
    VehicleFrame,
    VehicleTx,
    WheelSpeeds,
    default_dbc_path,
)
from bywire.protocol.vehicle_rx import FrameMonitor, VehicleRx

CODEC = VehicleCodec()  # loading is pure; one instance keeps hypothesis examples fast

SAMPLES: dict[type, VehicleFrame] = {
    EstopRadio: EstopRadio(mode=EstopMode.RUN),
    DbwCommand: DbwCommand(
        throttle_pct=12.3,
        brake_bar=45.6,
        steer_angle_rad=-0.2,
        engage=True,
        park_brake=False,
        ignition=True,
        steer_enable=True,
        ecu_state=EcuState.ENGAGED,
    ),
    WheelSpeeds: WheelSpeeds(fl_mps=10.01, fr_mps=10.02, rl_mps=9.99, rr_mps=10.0),
    Motion: Motion(long_accel_mps2=-1.234, yaw_rate_radps=0.0521, brake_bar_actual=12.5),
    DriverInputs: DriverInputs(brake_pedal_pressed=True, throttle_pedal_pct=0.0, brake_pedal_pct=33.3),
    SteerReport: SteerReport(steer_angle_rad=0.1234, steer_torque_nm=-2.5),
    RadarTarget: RadarTarget(valid=True, range_m=42.42, range_rate_mps=-3.21, azimuth_rad=0.012),
}
FRAME_TYPES = list(SAMPLES)
MS = 1e-3


def frames_of(frame_type: type) -> st.SearchStrategy[Any]:
    """Any frame of `frame_type` whose values lie inside the DBC ranges (read from the codec)."""
    fields: dict[str, st.SearchStrategy[Any]] = {}
    for sig in CODEC.info(frame_type).signals:
        if sig.kind == "float":
            fields[sig.field] = st.floats(sig.minimum, sig.maximum, allow_nan=False)
        elif sig.kind == "bool":
            fields[sig.field] = st.booleans()
        else:
            assert sig.enum is not None
            fields[sig.field] = st.sampled_from(list(sig.enum))
    return st.builds(frame_type, **fields)


def assert_close(decoded: VehicleFrame, sent: VehicleFrame) -> None:
    assert type(decoded) is type(sent)
    for sig in CODEC.info(type(sent)).signals:
        got, want = getattr(decoded, sig.field), getattr(sent, sig.field)
        if sig.kind == "float":
            assert abs(got - want) <= 0.5 * sig.scale * (1 + 1e-9) + 1e-12, sig.field  # half an LSB
        elif sig.kind == "bool":
            assert got is bool(want), sig.field
        else:
            assert got is want, sig.field  # the enum member itself


def payload(msg: can.Message) -> bytearray:
    return bytearray(msg.data)


def with_data(msg: can.Message, data: bytes | bytearray, **changes: Any) -> can.Message:
    fields: dict[str, Any] = {
        "timestamp": msg.timestamp,
        "arbitration_id": msg.arbitration_id,
        "is_extended_id": msg.is_extended_id,
        "dlc": len(data),
        "data": bytearray(data),
    }
    fields.update(changes)
    return can.Message(**fields)


# -- schema --------------------------------------------------------------------------------------


def test_default_dbc_is_the_packaged_file() -> None:
    assert default_dbc_path().name == "vehicle.dbc"
    assert default_dbc_path().is_file()
    assert CODEC.dbc_path == default_dbc_path()


def test_schema_ids_names_cycle_times_match_the_docstring_table() -> None:
    got = {(m.name, m.frame_id, m.frame_type, m.cycle_time_s) for m in CODEC.messages}
    assert got == {
        ("ESTOP_Radio", 0x0F0, EstopRadio, 0.05),
        ("DBW_Command", 0x100, DbwCommand, 0.01),
        ("GW_WheelSpeeds", 0x120, WheelSpeeds, 0.01),
        ("GW_Motion", 0x121, Motion, 0.01),
        ("GW_Driver", 0x122, DriverInputs, 0.01),
        ("GW_Steer", 0x123, SteerReport, 0.01),
        ("RADAR_Target", 0x300, RadarTarget, 0.05),
    }


def test_info_by_id_name_and_class_and_clear_error() -> None:
    assert CODEC.info(0x121) is CODEC.info("GW_Motion") is CODEC.info(Motion)
    for bad in ("GW_Nope", 0x7FF, int, True):
        with pytest.raises(ValueError, match="not a message of the vehicle DBC"):
            CODEC.info(bad)


def test_received_by_follows_the_dbc_receivers() -> None:
    assert CODEC.received_by("ECU") == ("ESTOP_Radio", "GW_WheelSpeeds", "GW_Motion", "GW_Driver", "GW_Steer")
    assert CODEC.received_by("GATEWAY") == ("ESTOP_Radio", "DBW_Command")
    assert CODEC.received_by("HOST") == ("RADAR_Target",)


def test_wheel_speeds_mean() -> None:
    assert WheelSpeeds(1.0, 2.0, 3.0, 6.0).mean_mps == 3.0


def test_frames_are_frozen() -> None:
    with pytest.raises(dataclasses.FrozenInstanceError):
        SAMPLES[Motion].yaw_rate_radps = 1.0  # type: ignore[misc]


# -- encode / decode ------------------------------------------------------------------------------


@pytest.mark.parametrize("frame_type", FRAME_TYPES, ids=lambda t: t.__name__)
@given(data=st.data(), counter=st.integers(0, 15))
def test_round_trip_within_half_an_lsb(frame_type: type, data: st.DataObject, counter: int) -> None:
    frame = data.draw(frames_of(frame_type))
    msg = CODEC.encode(frame, counter)
    assert_close(CODEC.decode(msg), frame)
    assert msg.data[1] & 0x0F == counter


@pytest.mark.parametrize("frame_type", FRAME_TYPES, ids=lambda t: t.__name__)
def test_encoded_frame_layout(frame_type: type) -> None:
    info = CODEC.info(frame_type)
    msg = CODEC.encode(SAMPLES[frame_type], 7, timestamp_s=1.25)
    assert msg.arbitration_id == info.frame_id
    assert not msg.is_extended_id and not msg.is_remote_frame and not msg.is_fd
    assert msg.dlc == len(msg.data) == 8
    assert msg.timestamp == 1.25
    assert msg.data[1] & 0x0F == 7
    check = bytearray(msg.data)
    protect(info.frame_id, check, 7)
    assert check == msg.data  # byte 0 is the E2E CRC over id + bytes 1..7


@pytest.mark.parametrize("frame_type", FRAME_TYPES, ids=lambda t: t.__name__)
def test_range_ends_encode_exactly_and_one_lsb_beyond_raises(frame_type: type) -> None:
    info = CODEC.info(frame_type)
    for sig in info.signals:
        if sig.kind != "float":
            continue
        for end, beyond in ((sig.minimum, sig.minimum - sig.scale), (sig.maximum, sig.maximum + sig.scale)):
            at_end = dataclasses.replace(SAMPLES[frame_type], **{sig.field: end})
            assert getattr(CODEC.decode(CODEC.encode(at_end, 0)), sig.field) == pytest.approx(end, abs=1e-9)
            too_far = dataclasses.replace(SAMPLES[frame_type], **{sig.field: beyond})
            with pytest.raises(
                ValueError, match=rf"{info.name}\.{sig.signal} \({frame_type.__name__}\.{sig.field}\)"
            ):
                CODEC.encode(too_far, 0)
            clamped = CODEC.decode(CODEC.encode(too_far, 0, saturate=True))
            assert getattr(clamped, sig.field) == pytest.approx(end, abs=1e-9)


def test_within_half_an_lsb_outside_rounds_onto_the_range_end() -> None:
    cmd = dataclasses.replace(SAMPLES[DbwCommand], throttle_pct=100.04)
    assert CODEC.decode(CODEC.encode(cmd, 0)).throttle_pct == pytest.approx(100.0)  # type: ignore[union-attr]


def test_out_of_range_error_names_message_signal_value_and_range() -> None:
    cmd = dataclasses.replace(SAMPLES[DbwCommand], steer_angle_rad=0.7)
    with pytest.raises(ValueError) as err:
        CODEC.encode(cmd, 0)
    assert str(err.value) == (
        "DBW_Command.SteerAngle (DbwCommand.steer_angle_rad): 0.7 rad outside the DBC range [-0.6, 0.6]"
    )


@pytest.mark.parametrize("value", [math.inf, -math.inf])
def test_saturate_clamps_infinities(value: float) -> None:
    frame = WheelSpeeds(value, 1.0, 1.0, 1.0)
    with pytest.raises(ValueError, match="WheelSpeed_FL"):
        CODEC.encode(frame, 0)
    got = CODEC.decode(CODEC.encode(frame, 0, saturate=True))
    assert got.fl_mps == (81.91 if value > 0 else 0.0)  # type: ignore[union-attr]


def test_nan_raises_even_when_saturating() -> None:
    frame = Motion(long_accel_mps2=math.nan, yaw_rate_radps=0.0, brake_bar_actual=0.0)
    for saturate in (False, True):
        with pytest.raises(ValueError, match=r"GW_Motion\.LongAccel .*NaN"):
            CODEC.encode(frame, 0, saturate=saturate)


@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"ecu_state": 7}, r"EcuState \(DbwCommand\.ecu_state\): 7 is not a EcuState"),
        ({"ecu_state": EstopMode.RUN}, "is not a EcuState"),  # an IntEnum of the wrong kind
        ({"engage": 2}, r"Engage .*2 is not a flag"),
        ({"throttle_pct": "full"}, r"ThrottlePedal .*'full' is not a number"),
    ],
)
def test_bad_field_types_raise(changes: dict[str, Any], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        CODEC.encode(dataclasses.replace(SAMPLES[DbwCommand], **changes), 0)


@pytest.mark.parametrize("counter", [-1, 16, True, 1.0])
def test_bad_counter_raises(counter: Any) -> None:
    with pytest.raises(ValueError, match="DBW_Command: alive counter"):
        CODEC.encode(SAMPLES[DbwCommand], counter)


def test_encoding_a_foreign_object_raises_type_error() -> None:
    with pytest.raises(TypeError, match="str"):
        CODEC.encode("DBW_Command", 0)  # type: ignore[arg-type]


def test_vehicle_tx_counts_per_message_and_a_failed_encode_uses_no_counter() -> None:
    tx = VehicleTx(CODEC)
    counters = [tx.encode(SAMPLES[Motion]).data[1] & 0x0F for _ in range(18)]
    assert counters == [*range(16), 0, 1]
    assert tx.encode(SAMPLES[SteerReport]).data[1] & 0x0F == 0
    with pytest.raises(ValueError):
        tx.encode(Motion(long_accel_mps2=99.0, yaw_rate_radps=0.0, brake_bar_actual=0.0))
    assert tx.encode(SAMPLES[Motion]).data[1] & 0x0F == 2


def valid_msg(frame_type: type = WheelSpeeds, counter: int = 0) -> can.Message:
    return CODEC.encode(SAMPLES[frame_type], counter)


@pytest.mark.parametrize(
    ("make", "reason", "match"),
    [
        (lambda m: with_data(m, m.data[:7]), RejectReason.MALFORMED, "DLC 7 with 7 data bytes"),
        (lambda m: with_data(m, m.data, dlc=6), RejectReason.MALFORMED, "DLC 6 with 8 data bytes"),
        (lambda m: with_data(m, m.data, is_remote_frame=True), RejectReason.MALFORMED, "remote frame"),
        (lambda m: with_data(m, m.data, is_extended_id=True), RejectReason.MALFORMED, "extended"),
        (lambda m: with_data(m, m.data, is_fd=True), RejectReason.MALFORMED, "CAN FD"),
        (lambda m: with_data(m, m.data, is_error_frame=True), RejectReason.MALFORMED, "error frame"),
        (lambda m: with_data(m, m.data, arbitration_id=0x7FF), RejectReason.MALFORMED, "unknown frame id"),
        (lambda m: with_data(m, bytes([m.data[0] ^ 1]) + m.data[1:]), RejectReason.CORRUPT, "CRC"),
        (lambda m: with_data(m, m.data, arbitration_id=0x121), RejectReason.CORRUPT, "GW_Motion: CRC"),
    ],
)
def test_decode_raises_frame_error_with_reason(make: Any, reason: RejectReason, match: str) -> None:
    msg = make(valid_msg())
    with pytest.raises(FrameError, match=match) as err:
        CODEC.decode(msg)
    assert err.value.reason is reason
    assert err.value.frame_id == msg.arbitration_id


def forged(frame_type: type, set_raw: dict[str, int], counter: int = 0) -> can.Message:
    """A CRC-valid frame carrying raw values the codec would never send (a faulty transmitter)."""
    info = CODEC.info(frame_type)
    raw = info.message.decode(bytes(valid_msg(frame_type).data), decode_choices=False, scaling=False)
    raw.update(set_raw)
    data = bytearray(info.message.encode(raw, scaling=False, strict=False))
    protect(info.frame_id, data, counter)
    return can.Message(arbitration_id=info.frame_id, is_extended_id=False, data=data)


@pytest.mark.parametrize(
    ("frame_type", "raw", "match"),
    [
        (DbwCommand, {"EcuState": 7}, r"DBW_Command\.EcuState = 7 .*outside the DBC range \[0, 6\]"),
        (DbwCommand, {"ThrottlePedal": 1023}, r"DBW_Command\.ThrottlePedal = 102\.3 % \(raw 1023\) outside"),
        (
            DbwCommand,
            {"SteerAngle": -6001},
            r"SteerAngle = -0\.6001 rad .* outside the DBC range \[-0\.6, 0\.6\]",
        ),
        (DriverInputs, {"BrakePedalDriver": 1001}, r"GW_Driver\.BrakePedalDriver"),
    ],
)
def test_decode_rejects_values_outside_the_dbc_as_malformed(
    frame_type: type, raw: dict[str, int], match: str
) -> None:
    with pytest.raises(FrameError, match=match) as err:
        CODEC.decode(forged(frame_type, raw))
    assert err.value.reason is RejectReason.MALFORMED


# -- DBC validation -------------------------------------------------------------------------------


def dbc_variant(tmp_path: Path, old: str, new: str) -> Path:
    text = default_dbc_path().read_text()
    assert old in text, old
    path = tmp_path / "variant.dbc"
    path.write_text(text.replace(old, new, 1))
    return path


@pytest.mark.parametrize(
    ("old", "new", "match"),
    [
        (
            'SteerAngle : 38|16@1- (0.0001,0) [-0.6|0.6] "rad"',
            'SteerAngle : 38|16@1- (0.0001,0) [-0.6|0.6] "deg"',
            r"DBW_Command \(0x100\) signal SteerAngle: unit 'deg', but field DbwCommand.steer_angle_rad",
        ),
        (
            '2 "ENGAGED"',
            '2 "ENGAGE"',
            r"DBW_Command .* signal EcuState: VAL_ 2 'ENGAGE' does not match EcuState",
        ),
        (
            "GW_Steer_Counter : 8|4@1+",
            "GW_Steer_Counter : 8|3@1+",
            r"GW_Steer .*GW_Steer_Counter must be 8\|4@1\+",
        ),
        ("SG_ GW_Motion_CRC :", "SG_ GW_Motion_Chk :", r"signal GW_Motion_CRC must be 0\|8@1\+"),
        ('BA_ "GenMsgCycleTime" BO_ 291 10;', "", r"GW_Steer \(0x123\): no GenMsgCycleTime"),
        ("[0|204.75]", "[0|300]", r"BrakePressureActual: range \[0, 300\] does not fit 12 unsigned bits"),
        (
            "BO_ 768 RADAR_Target:",
            "BO_ 768 RADAR_Tgt:",
            r"missing from the DBC \['RADAR_Target'\].*\['RADAR_Tgt'\]",
        ),
        (
            ' SG_ TargetValid : 12|1@1+ (1,0) [0|1] "" HOST\n',
            ' SG_ TargetValid : 12|1@1+ (1,0) [0|1] "" HOST\n SG_ Spare : 60|4@1+ (1,0) [0|15] "" HOST\n',
            r"RADAR_Target .*signals \['Spare'\] have no field",
        ),
        ("SG_ WheelSpeed_RR", "SG_ WheelSpeed_XX", r"GW_WheelSpeeds .*signal WheelSpeed_RR .* missing"),
    ],
)
def test_dbc_that_disagrees_with_the_code_is_refused(tmp_path: Path, old: str, new: str, match: str) -> None:
    path = dbc_variant(tmp_path, old, new)
    with pytest.raises(ValueError, match=match) as err:
        VehicleCodec(path)
    assert str(path) in str(err.value)


def test_unreadable_dbc_is_refused(tmp_path: Path) -> None:
    bad = tmp_path / "garbage.dbc"
    bad.write_text("this is not a DBC\n")
    for path in (bad, tmp_path / "absent.dbc"):
        with pytest.raises(ValueError, match=re.escape(f"{path}: cannot load the vehicle DBC")):
            VehicleCodec(path)


def test_an_equivalent_dbc_copy_loads(tmp_path: Path) -> None:
    path = dbc_variant(tmp_path, 'VERSION "', 'VERSION "copy ')
    codec = VehicleCodec(str(path))
    assert codec.dbc_path == path
    assert codec.decode(codec.encode(SAMPLES[RadarTarget], 3)) == CODEC.decode(
        CODEC.encode(SAMPLES[RadarTarget], 3)
    )


# -- receiver -------------------------------------------------------------------------------------


class Stream:
    """A sender of one message type on the receiver's clock, whose counter the test can steer."""

    def __init__(self, frame_type: type = WheelSpeeds, counter: int = 0) -> None:
        self.frame = SAMPLES[frame_type]
        self.counter = counter

    def msg(self, t_s: float, counter: int | None = None) -> can.Message:
        if counter is None:
            counter, self.counter = self.counter, (self.counter + 1) % 16
        return CODEC.encode(self.frame, counter, timestamp_s=t_s)


def outcome_total(rx: VehicleRx, key: str | None = None) -> int:
    counts = rx.counts(key)
    return sum(counts[k] for k in ("accepted", "ignored", *RejectReason))


def test_accepts_a_stream_across_the_counter_wrap() -> None:
    rx, s = VehicleRx(CODEC), Stream(counter=9)
    for i in range(40):
        t = i * 10 * MS
        assert rx.feed(s.msg(t), t) == SAMPLES[WheelSpeeds]
    assert rx.counts("GW_WheelSpeeds") == rx.counts()
    assert rx.counts() == {
        "accepted": 40, "ignored": 0, "malformed": 0, "corrupt": 0, "repeated": 0,
        "out_of_order": 0, "stale": 0, "lost": 0, "resync": 0,
    }  # fmt: skip
    assert rx.error_streak(WheelSpeeds) == 0


def test_repeated_counter_is_rejected_counted_and_streaks() -> None:
    rx, s = VehicleRx(CODEC), Stream()
    assert rx.feed(s.msg(0.0), 0.0) is not None
    frozen = s.msg(0.01)
    assert rx.feed(frozen, 0.01) is not None
    for i in range(3):
        t = 0.02 + i * 0.01
        assert rx.feed(with_data(frozen, frozen.data, timestamp=t), t) is None
    assert rx.counts("GW_WheelSpeeds")["repeated"] == 3
    assert rx.error_streak("GW_WheelSpeeds") == 3
    assert rx.stats()["frames"]["GW_WheelSpeeds"]["last_reject"] == {
        "reason": "repeated", "detail": "GW_WheelSpeeds: counter 1 after 1", "t_s": 0.04,
    }  # fmt: skip
    assert rx.feed(s.msg(0.05), 0.05) is not None
    assert rx.error_streak(0x120) == 0


def test_gap_inside_the_window_is_accepted_and_counted_as_lost() -> None:
    rx, s = VehicleRx(CODEC), Stream(counter=14)
    rx.feed(s.msg(0.0), 0.0)  # 14
    assert rx.feed(s.msg(0.01, counter=1), 0.01) is not None  # 15 and 0 lost, across the wrap
    assert rx.feed(s.msg(0.02, counter=3), 0.02) is not None  # 2 lost
    counts = rx.counts(WheelSpeeds)
    assert (counts["accepted"], counts["lost"], counts["out_of_order"]) == (3, 3, 0)


def test_gap_beyond_the_window_and_steps_back_are_out_of_order() -> None:
    rx, s = VehicleRx(CODEC), Stream(counter=5)
    rx.feed(s.msg(0.0), 0.0)  # 5
    assert rx.feed(s.msg(0.01, counter=9), 0.01) is None  # 3 lost: beyond max_delta 3
    assert rx.feed(s.msg(0.02, counter=4), 0.02) is None  # back
    assert rx.feed(s.msg(0.03, counter=6), 0.03) is not None  # the reference is still 5
    assert rx.counts(WheelSpeeds)["out_of_order"] == 2
    assert rx.counts(WheelSpeeds)["lost"] == 0


def test_wider_window_is_configurable() -> None:
    rx, s = VehicleRx(CODEC, max_delta_counter=5), Stream(counter=5)
    rx.feed(s.msg(0.0), 0.0)
    assert rx.feed(s.msg(0.01, counter=10), 0.01) is not None
    assert rx.counts()["lost"] == 4


def test_corrupt_frame_is_rejected_and_counted() -> None:
    rx, s = VehicleRx(CODEC), Stream()
    msg = s.msg(0.0)
    data = payload(msg)
    data[5] ^= 0x10
    assert rx.feed(with_data(msg, data), 0.0) is None
    assert rx.counts(WheelSpeeds)["corrupt"] == 1
    assert rx.error_streak(WheelSpeeds) == 1
    assert rx.last(WheelSpeeds) is None


def test_stale_frame_is_rejected_by_age_and_future_stamps_are_refused() -> None:
    rx, s = VehicleRx(CODEC), Stream()
    assert rx.feed(s.msg(0.0), 0.010) is not None  # exactly one cycle old: still fresh
    assert rx.feed(s.msg(0.0), 0.0101) is None  # older than one 10 ms cycle
    assert rx.feed(s.msg(5.0), 0.015) is None  # stamped on another clock
    assert rx.counts(WheelSpeeds)["stale"] == 2
    assert (
        "frames must be stamped on the receiver's clock"
        in rx.stats()["frames"]["GW_WheelSpeeds"]["last_reject"]["detail"]
    )
    # the rejected frames did not move the counter reference: counter 3 is a gap of two
    assert rx.feed(s.msg(0.02), 0.02) is not None
    assert rx.counts(WheelSpeeds)["lost"] == 2


def test_stale_limit_scales_with_the_cycle_time_and_rx_time_overrides_the_stamp() -> None:
    rx = VehicleRx(CODEC, max_age_cycles=2.0)
    estop = Stream(EstopRadio)
    assert rx.feed(estop.msg(0.0), 0.099) is not None  # 2 x 50 ms
    assert rx.feed(estop.msg(0.0), 0.101) is None
    assert rx.feed(estop.msg(0.0), 0.101, rx_time_s=0.1) is not None
    assert rx.counts(EstopRadio)["stale"] == 1


def test_a_receive_time_that_is_not_a_number_is_stale() -> None:
    rx, s = VehicleRx(CODEC), Stream()
    assert rx.feed(s.msg(0.0), 0.001, rx_time_s=math.nan) is None
    assert rx.counts(WheelSpeeds)["stale"] == 1
    assert "is not a number" in rx.stats()["frames"]["GW_WheelSpeeds"]["last_reject"]["detail"]


def test_age_check_can_be_turned_off() -> None:
    rx, s = VehicleRx(CODEC, max_age_cycles=None), Stream()
    assert rx.feed(s.msg(0.0), 1000.0) is not None
    assert rx.feed(s.msg(1e9), 1000.01) is not None


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda m: with_data(m, m.data[:4]), "DLC 4"),
        (lambda m: with_data(m, b""), "DLC 0"),
        (lambda m: with_data(m, m.data, is_remote_frame=True), "remote frame"),
        (lambda m: with_data(m, m.data, is_fd=True), "CAN FD"),
        (lambda m: with_data(m, m.data, is_error_frame=True), "error frame"),
        (lambda m: forged(DbwCommand, {"EcuState": 7}), "outside the DBC range [0, 6]"),
    ],
)
def test_malformed_frames_of_a_known_id_count_per_id(make: Any, match: str) -> None:
    rx = VehicleRx(CODEC)
    msg = make(valid_msg(DbwCommand))
    assert rx.feed(msg, 0.0) is None
    assert rx.counts(DbwCommand)["malformed"] == rx.counts()["malformed"] == 1
    assert rx.error_streak(DbwCommand) == 1
    assert match in rx.stats()["frames"]["DBW_Command"]["last_reject"]["detail"]


def test_unknown_and_extended_ids_count_only_in_the_totals() -> None:
    rx = VehicleRx(CODEC)
    msg = valid_msg(WheelSpeeds)
    assert rx.feed(with_data(msg, msg.data, arbitration_id=0x701), 0.0) is None  # e.g. a CANopen heartbeat
    assert rx.feed(with_data(msg, msg.data, is_extended_id=True), 0.0) is None  # 0x120 as a 29-bit id
    assert rx.counts()["malformed"] == 2
    assert all(rx.counts(m.name)["malformed"] == 0 for m in CODEC.messages)
    assert rx.stats()["unknown_ids"] == {"0x701": 1, "0x120x": 1}


def test_unknown_id_list_is_bounded() -> None:
    rx = VehicleRx(CODEC)
    for fid in range(0x400, 0x400 + 40):
        rx.feed(can.Message(arbitration_id=fid, is_extended_id=False, data=bytes(8)), 0.0)
    assert len(rx.stats()["unknown_ids"]) == 16
    assert rx.counts()["malformed"] == 40


def test_timeout_then_resync_accepts_any_counter_but_a_repeat() -> None:
    rx, s = VehicleRx(CODEC), Stream(counter=4)
    assert rx.timed_out(WheelSpeeds, 0.0)  # nothing received yet
    assert rx.age_s(WheelSpeeds, 0.0) == math.inf
    assert rx.feed(s.msg(0.0), 0.0) is not None  # counter 4
    assert rx.timeout_s("GW_WheelSpeeds") == pytest.approx(0.05)
    assert not rx.timed_out(WheelSpeeds, 0.0499)
    assert rx.timed_out(WheelSpeeds, 0.0501)
    # The same counter again is a repeat, before the timeout and after it: a sender frozen on its
    # last frame stays timed out however long it repeats it.
    assert rx.feed(s.msg(0.04, counter=4), 0.04) is None
    assert rx.feed(s.msg(0.06, counter=4), 0.06) is None
    assert rx.timed_out(WheelSpeeds, 0.06) and rx.counts(WheelSpeeds)["repeated"] == 2
    # A restarted sender (any other counter) re-synchronises after the timeout.
    assert rx.feed(s.msg(0.065, counter=0), 0.065) is not None
    assert rx.counts(WheelSpeeds)["resync"] == 1
    assert rx.last_time_s(WheelSpeeds) == 0.065
    assert rx.age_s(WheelSpeeds, 0.07) == pytest.approx(0.005)
    assert rx.feed(s.msg(0.07, counter=0), 0.07) is None  # and the sequence is checked again
    assert rx.counts(WheelSpeeds)["repeated"] == 3


def test_first_frame_is_not_a_resync_and_timeouts_follow_the_cycle_time() -> None:
    rx = VehicleRx(CODEC, timeout_cycles=3)
    assert rx.feed(Stream(EstopRadio, counter=11).msg(1.0), 1.0) is not None
    assert rx.counts()["resync"] == 0
    assert rx.timeout_s(EstopRadio) == pytest.approx(0.15)
    assert not rx.timed_out(EstopRadio, 1.149)
    assert rx.timed_out(EstopRadio, 1.151)


def test_a_sender_that_jumped_is_rejected_until_the_timeout_then_resyncs() -> None:
    rx, s = VehicleRx(CODEC), Stream(counter=0)
    for i in range(5):
        rx.feed(s.msg(i * 0.01), i * 0.01)  # counters 0..4
    s.counter = 12  # out of the window from 4
    results = []
    for i in range(5, 12):
        t = i * 0.01
        results.append(rx.feed(s.msg(t), t) is not None)
    # counters 12..15 and 0 are out of order (0 is delta 12 from 4); at t = 0.10 the last accepted
    # frame (t = 0.04) is 60 ms old: timed out, so counter 1 re-syncs, and 2 follows in order.
    assert results == [False, False, False, False, False, True, True]
    assert rx.counts(WheelSpeeds)["out_of_order"] == 5
    assert rx.counts(WheelSpeeds)["resync"] == 1
    assert rx.error_streak(WheelSpeeds) == 0


def test_error_streak_counts_mixed_rejections_and_resets_on_accept() -> None:
    rx, s = VehicleRx(CODEC), Stream()
    rx.feed(s.msg(0.0), 0.0)
    good = s.msg(0.01)
    bad = payload(good)
    bad[3] ^= 0x01
    rx.feed(with_data(good, bad), 0.01)  # corrupt
    rx.feed(with_data(good, good.data[:5]), 0.01)  # malformed
    rx.feed(s.msg(-1.0, counter=0), 0.01)  # stale
    assert rx.error_streak(WheelSpeeds) == 3
    assert rx.error_streak(Motion) == 0
    assert rx.feed(good, 0.01) is not None
    assert rx.error_streak(WheelSpeeds) == 0


def test_accept_filter_ignores_other_messages_without_streaks() -> None:
    rx = VehicleRx(CODEC, accept=["GW_Motion", 0x120])
    assert rx.feed(valid_msg(DbwCommand), 0.0) is None
    bad = valid_msg(DbwCommand)
    assert rx.feed(with_data(bad, bad.data[:3]), 0.0) is None  # malformed, but not ours: ignored
    assert rx.feed(valid_msg(Motion), 0.0) is not None
    assert rx.feed(valid_msg(WheelSpeeds), 0.0) is not None
    assert rx.counts(DbwCommand)["ignored"] == 2
    assert rx.counts()["ignored"] == 2
    assert rx.error_streak(DbwCommand) == 0
    assert rx.counts()["malformed"] == 0


def test_for_node_accepts_what_the_dbc_says_the_node_receives() -> None:
    ecu = FrameMonitor.for_node(CODEC, "ECU")
    assert ecu.feed(valid_msg(WheelSpeeds), 0.0) is not None
    assert ecu.feed(valid_msg(EstopRadio), 0.0) is not None
    assert ecu.feed(valid_msg(DbwCommand), 0.0) is None
    assert ecu.feed(valid_msg(RadarTarget), 0.0) is None
    assert ecu.counts()["ignored"] == 2
    with pytest.raises(ValueError, match="node 'RADAR' receives no message"):
        VehicleRx.for_node(CODEC, "RADAR")


def test_last_frame_per_message() -> None:
    rx = VehicleRx(CODEC)
    for frame_type in FRAME_TYPES:
        rx.feed(valid_msg(frame_type), 0.0)
    for frame_type in FRAME_TYPES:
        assert_close(rx.last(frame_type), SAMPLES[frame_type])  # type: ignore[arg-type]
    assert rx.counts()["accepted"] == len(FRAME_TYPES)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"timeout_cycles": 0}, "timeout_cycles"),
        ({"max_age_cycles": -1.0}, "max_age_cycles"),
        ({"max_delta_counter": 0}, "max_delta"),
        ({"accept": ["NOPE"]}, "'NOPE' is not a message"),
    ],
)
def test_bad_receiver_configuration_raises(kwargs: dict[str, Any], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        VehicleRx(CODEC, **kwargs)


def test_lookups_of_unknown_messages_raise_clearly() -> None:
    rx = VehicleRx(CODEC)
    with pytest.raises(ValueError, match="'GW_Speed' is not a message of the vehicle DBC"):
        rx.timed_out("GW_Speed", 0.0)


def test_stats_are_json_and_per_message_counts_add_up_to_the_totals() -> None:
    rx = VehicleRx(CODEC)
    streams = [Stream(t) for t in FRAME_TYPES]
    for i in range(30):
        t = i * 0.01
        for s in streams:
            msg = s.msg(t)
            if i % 7 == 3:
                msg = with_data(msg, bytes([msg.data[0] ^ 0x80]) + msg.data[1:])
            rx.feed(msg, t)
    stats = json.loads(json.dumps(rx.stats()))
    total = stats["total"]
    assert total["unexpected_exceptions"] == 0
    for key in ("accepted", "corrupt", "lost", "resync"):
        assert total[key] == sum(f[key] for f in stats["frames"].values())
    assert total["accepted"] + total["corrupt"] == 30 * len(FRAME_TYPES)
    assert total["corrupt"] == 4 * len(FRAME_TYPES)
    assert total["lost"] == 4 * len(FRAME_TYPES)  # each corrupt frame used up a counter value
    assert stats["frames"]["GW_Motion"]["frame_id"] == 0x121
    assert stats["frames"]["GW_Motion"]["last_counter"] == 29 % 16


# -- corruption is caught -----------------------------------------------------------------------------


@pytest.mark.parametrize("frame_type", FRAME_TYPES, ids=lambda t: t.__name__)
def test_every_single_bit_flip_is_rejected_as_corrupt(frame_type: type) -> None:
    rx, s = VehicleRx(CODEC, max_age_cycles=None), Stream(frame_type)
    rx.feed(s.msg(0.0), 0.0)
    good = s.msg(0.0)
    for bit in range(64):
        data = payload(good)
        data[bit // 8] ^= 1 << (bit % 8)
        assert rx.feed(with_data(good, data), 0.0) is None, bit
    assert rx.counts(frame_type)["corrupt"] == 64 == outcome_total(rx) - 1
    assert rx.feed(good, 0.0) is not None
    assert rx.counts(frame_type)["lost"] == 0


@pytest.mark.parametrize("frame_type", FRAME_TYPES, ids=lambda t: t.__name__)
def test_every_double_bit_flip_is_rejected_as_corrupt(frame_type: type) -> None:
    rx, s = VehicleRx(CODEC, max_age_cycles=None), Stream(frame_type)
    rx.feed(s.msg(0.0), 0.0)
    good = s.msg(0.0)
    flips = list(itertools.combinations(range(64), 2))
    for a, b in flips:
        data = payload(good)
        data[a // 8] ^= 1 << (a % 8)
        data[b // 8] ^= 1 << (b % 8)
        rx.feed(with_data(good, data), 0.0)
    assert rx.counts(frame_type)["corrupt"] == len(flips) == 2016
    assert rx.counts()["accepted"] == 1


def test_feed_survives_objects_that_are_not_frames_and_reports_them() -> None:
    rx = VehicleRx(CODEC)
    assert rx.feed(None, 0.0) is None  # type: ignore[arg-type]
    assert rx.counts()["malformed"] == 1
    assert rx.unexpected_exceptions == 1
    assert rx.stats()["last_unexpected_exception"].startswith("AttributeError")


@given(data=st.data())
def test_our_bit_packing_is_cantools_bit_packing(data: st.DataObject) -> None:
    """The codec packs and unpacks bits itself (speed); cantools' model of the DBC stays the oracle:
    every message, random raw values across each signal's full bit range, both directions."""
    info = data.draw(st.sampled_from(CODEC.messages))
    raw: dict[str, int] = {}
    for sig in info.message.signals:
        half = 1 << (sig.length - 1)
        lo, hi = (-half, half - 1) if sig.is_signed else (0, 2 * half - 1)
        raw[sig.name] = data.draw(st.integers(lo, hi), label=sig.name)
    reference = bytes(info.message.encode(raw, scaling=False, strict=False))
    # Decode with ours: every in-range signal comes back with cantools' raw value.
    decoded_by_cantools = info.message.decode(reference, decode_choices=False, scaling=False)
    try:
        frame, counter = CODEC.decode_payload(info, reference)
    except FrameError as exc:
        assert exc.reason is RejectReason.MALFORMED
        assert any(  # a raw value outside the DBC range, or an enumeration value without a member
            not s.raw_min <= decoded_by_cantools[s.signal] <= s.raw_max
            or (s.enum is not None and decoded_by_cantools[s.signal] not in s.enum._value2member_map_)
            for s in info.signals
        )
        return
    assert counter == decoded_by_cantools[info.counter_signal]
    for s in info.signals:
        value = getattr(frame, s.field)
        expected = decoded_by_cantools[s.signal]
        if s.kind == "float":
            assert value == pytest.approx(expected * s.scale + s.offset, abs=1e-12)
        else:
            assert int(value) == expected
    # And encoding the decoded frame gives cantools' bytes back (byte 0 is our CRC, not a signal value).
    ours = CODEC.encode(frame, counter)
    assert bytes(ours.data)[1:] == reference[1:]
