"""V2X codec (cooperative driving, seed 003 III/IV-B): ETSI CAM, GCDC iCLCM, SPATEM/MAPEM in UPER; unit
conversions at the edge, known answers, round trips, range refusals naming the field, the strict canonical
check, and decoder fuzzing."""

from __future__ import annotations

import dataclasses
import math

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bywire.protocol.v2x.codec import (
    MSG_CAM,
    MSG_ICLCM,
    MSG_MAPEM,
    MSG_SPATEM,
    DecodeReason,
    DriveDirection,
    SpeedLimit,
    TrafficLightPhase,
    V2xDecodeError,
    V2xEncodeError,
    VehicleState,
    heading_from_etsi,
    heading_to_etsi,
    peek_header,
    resolve_generation_delta,
    timestamp_its_to_unix,
    unix_to_timestamp_its,
)
from bywire.protocol.v2x.dsrc import IntersectionMap, RoadMap, SignalGroupState, SignalPhases, StopLine
from bywire.protocol.v2x.etsi_cam import LOW_FREQUENCY_INTERVAL_S, LowFrequencyClock
from bywire.protocol.v2x.iclcm import ControllerType, CooperativeState
from bywire.protocol.v2x.schemas import SchemaSet, compiled
from bywire.protocol.v2x.wire import V2xMessage, decode, encode

T0_S = 1_700_000_000.0  # 2023-11-14T22:13:20Z


def _vehicle(**changes: object) -> VehicleState:
    v = VehicleState(
        station_id=4711,
        generation_time_s=T0_S + 0.123,
        lat_deg=49.0123456,
        lon_deg=8.4123456,
        heading_rad=0.3,
        speed_mps=25.0,
        yaw_rate_radps=0.05,
        accel_mps2=-1.2,
        length_m=4.8,
        width_m=1.8,
        drive_direction=DriveDirection.FORWARD,
        lane_position=1,
        station_type=5,
    )
    return dataclasses.replace(v, **changes)  # type: ignore[arg-type]


# ---------------------------------------------------------------------------------------------- time


def test_timestamp_its_known_answers() -> None:
    # CDD TS 102 894-2 v2.4.1, TimestampIts: "The value for TimestampIts for 1 January 2007 00:00:00.000
    # UTC is 94 694 401 000 milliseconds, which includes one leap second insertion since the ITS epoch."
    assert unix_to_timestamp_its(1_167_609_600.0) == 94_694_401_000
    assert timestamp_its_to_unix(94_694_401_000) == 1_167_609_600.0
    assert unix_to_timestamp_its(1_072_915_200.0) == 0  # the ITS epoch
    # "As of 1 January, 2022, TimestampIts is 5 seconds ahead of UTC."
    jan_2022 = 1_640_995_200.0
    assert unix_to_timestamp_its(jan_2022) == (jan_2022 - 1_072_915_200) * 1000 + 5000
    # Just before / after the 2016-12-31 leap second: 4 then 5 leap seconds.
    assert unix_to_timestamp_its(1_483_228_799.0) == (1_483_228_799 - 1_072_915_200) * 1000 + 4000
    assert unix_to_timestamp_its(1_483_228_800.0) == (1_483_228_800 - 1_072_915_200) * 1000 + 5000


@given(st.integers(0, (2_000_000_000 - 1_072_915_200) * 1000))
def test_timestamp_its_round_trip(ms: int) -> None:
    unix = timestamp_its_to_unix(ms)
    back = unix_to_timestamp_its(unix)
    # Inside an inserted leap second (23:59:60) UTC repeats a second: the ms maps 1000 ms later or equal.
    assert back == ms or back - ms == 1000


# ---------------------------------------------------------------------------------------------- heading


@pytest.mark.parametrize(
    ("etsi", "rad"),
    [
        (0, math.pi / 2),
        (900, 0.0),
        (1800, -math.pi / 2),
        (2700, math.pi),
        (450, math.pi / 4),
        (3150, 3 * math.pi / 4),
    ],
)
def test_heading_convention(etsi: int, rad: float) -> None:
    # ETSI: 0.1 deg clockwise from north. Ours: counter-clockwise from east (x east, y north).
    assert heading_from_etsi(etsi) == pytest.approx(rad, abs=1e-12)
    assert heading_to_etsi(rad) == etsi
    assert -math.pi < heading_from_etsi(etsi) <= math.pi


def test_heading_accepts_both_conventions_and_wraps() -> None:
    assert heading_to_etsi(-math.pi) == heading_to_etsi(math.pi) == 2700
    assert heading_to_etsi(3 * math.pi / 2) == heading_to_etsi(-math.pi / 2) == 1800
    assert heading_to_etsi(math.pi / 2 + 1e-9) == 0  # just left of north rounds to 0, never 3600


# ---------------------------------------------------------------------------------------------- CAM


def _cam(data: bytes) -> dict:  # type: ignore[type-arg]
    return compiled(SchemaSet.CAM_V2).decode("CAM", data)  # type: ignore[no-any-return]


def _decode(data: bytes) -> V2xMessage:
    return decode(data, T0_S + 0.2)


def test_cam_known_layout_and_round_trip() -> None:
    v = _vehicle()
    data = encode(v)
    assert data[:6] == bytes([2, MSG_CAM]) + (4711).to_bytes(4, "big")  # ItsPduHeader, byte-aligned
    back = _decode(data)
    assert isinstance(back, VehicleState)
    assert back.station_id == 4711
    assert back.generation_time_s == pytest.approx(T0_S + 0.123, abs=5e-4)
    # The centre goes out as the front reference point and comes back (within the 1e-7 deg grid).
    assert back.lat_deg == pytest.approx(49.0123456, abs=2e-7)
    assert back.lon_deg == pytest.approx(8.4123456, abs=2e-7)
    assert back.heading_rad == pytest.approx(0.3, abs=math.radians(0.05))
    assert back.speed_mps == 25.0
    assert back.yaw_rate_radps == pytest.approx(0.05, abs=math.radians(0.005))
    assert back.accel_mps2 == -1.2
    assert (back.length_m, back.width_m) == (4.8, 1.8)
    assert back.drive_direction is DriveDirection.FORWARD
    assert (back.lane_position, back.station_type) == (1, 5)
    assert encode(back) == data


def test_cam_etsi_units_and_containers_on_the_wire() -> None:
    cam = _cam(encode(_vehicle()))
    assert cam["cam"]["generationDeltaTime"] == unix_to_timestamp_its(T0_S + 0.123) % 65536
    params = cam["cam"]["camParameters"]
    basic = params["basicContainer"]
    assert basic["stationType"] == 5
    ref = basic["referencePosition"]
    # The reference point lies 2.4 m (half the length) ahead of the centre along the heading.
    north_m = (ref["latitude"] / 1e7 - 49.0123456) * 111_195.0
    assert north_m == pytest.approx(2.4 * math.sin(0.3), abs=0.02)
    assert ref["altitude"]["altitudeValue"] == 800_001  # unavailable
    kind, hf = params["highFrequencyContainer"]
    assert kind == "basicVehicleContainerHighFrequency"
    assert hf["speed"] == {"speedValue": 2500, "speedConfidence": 127}  # 0.01 m/s, confidence unavailable
    assert hf["yawRate"]["yawRateValue"] == round(math.degrees(0.05) * 100)  # 0.01 deg/s, to the left
    assert hf["longitudinalAcceleration"]["longitudinalAccelerationValue"] == -12  # 0.1 m/s^2
    assert hf["vehicleLength"]["vehicleLengthValue"] == 48 and hf["vehicleWidth"] == 18  # 0.1 m
    assert hf["heading"]["headingValue"] == round((90 - math.degrees(0.3)) * 10)  # 0.1 deg from north
    # Curvature = yaw rate / speed in 1/10 000 m, computed from the yaw rate.
    assert hf["curvature"]["curvatureValue"] == round(1e4 * 0.05 / 25.0)
    assert hf["curvatureCalculationMode"] == "yawRateUsed"
    assert hf["lanePosition"] == 1
    _, lf = params["lowFrequencyContainer"]
    assert lf == {"vehicleRole": "default", "exteriorLights": (b"\x00", 8), "pathHistory": []}
    assert (
        "lowFrequencyContainer" not in _cam(encode(_vehicle(), low_frequency=False))["cam"]["camParameters"]
    )


def test_unavailable_fields_become_none() -> None:
    v = VehicleState(7, T0_S, None, None, None, None, None, None, None, None)
    data = encode(v)
    back = _decode(data)
    assert back == dataclasses.replace(v, generation_time_s=back.generation_time_s)
    assert back.generation_time_s == pytest.approx(T0_S, abs=5e-4)
    params = _cam(data)["cam"]["camParameters"]
    ref = params["basicContainer"]["referencePosition"]
    hf = params["highFrequencyContainer"][1]
    assert (ref["latitude"], ref["longitude"]) == (900_000_001, 1_800_000_001)
    assert hf["heading"]["headingValue"] == 3601
    assert hf["speed"]["speedValue"] == 16383
    assert hf["yawRate"]["yawRateValue"] == 32767
    assert hf["longitudinalAcceleration"]["longitudinalAccelerationValue"] == 161
    assert hf["vehicleLength"] == {
        "vehicleLengthValue": 1023,
        "vehicleLengthConfidenceIndication": "unavailable",
    }
    assert hf["vehicleWidth"] == 62
    assert hf["driveDirection"] == "unavailable"
    assert hf["curvature"]["curvatureValue"] == 1023 and hf["curvatureCalculationMode"] == "unavailable"
    assert "lanePosition" not in hf


def test_curvature_unavailable_at_standstill_and_saturated() -> None:
    slow = _cam(encode(_vehicle(speed_mps=0.5)))["cam"]["camParameters"]["highFrequencyContainer"][1]
    assert slow["curvature"]["curvatureValue"] == 1023
    tight = _cam(encode(_vehicle(speed_mps=2.0, yaw_rate_radps=1.0)))
    assert tight["cam"]["camParameters"]["highFrequencyContainer"][1]["curvature"]["curvatureValue"] == 1022


def test_low_frequency_container_at_the_etsi_rate() -> None:
    clock = LowFrequencyClock()
    sent = [clock.due(T0_S + 0.04 * k) for k in range(40)]  # 25 Hz for 1.6 s
    assert [k for k, lf in enumerate(sent) if lf] == [0, 13, 26, 39]  # first, then after >= 500 ms
    assert LOW_FREQUENCY_INTERVAL_S == 0.5
    assert clock.due(T0_S)  # time going back (a new run): at once


@pytest.mark.parametrize("offset_ms", [0, 1, 32_767, -32_768, 20_000, -20_000])
def test_generation_delta_resolves_to_the_nearest_instant(offset_ms: int) -> None:
    true_ms = unix_to_timestamp_its(T0_S) + offset_ms
    got = resolve_generation_delta(true_ms % 65536, T0_S)
    assert unix_to_timestamp_its(got) == true_ms


# ---------------------------------------------------------------------------------------------- iCLCM


def test_iclcm_round_trip_and_units() -> None:
    msg = CooperativeState(
        9, T0_S + 0.5, ControllerType.CACC, -2.34, 0.6, 22.22, 3.66, 0.25, 0.1, 8, 17.5, 0.02, -0.75,
        lane=2, platoon_id=1, participants_ready=True,
    )  # fmt: skip
    data = encode(msg)
    assert peek_header(data).message_id == MSG_ICLCM and data[0] == 1
    assert _decode(data) == msg
    raw = compiled(SchemaSet.ICLCM).decode("IGAMECooperativeLaneChangeMessage", data)["iclcm"]
    hf = raw["iclcmParameters"]["vehicleContainerHighFrequency"]
    assert hf["targetLongitudinalAcceleration"] == -234  # 0.01 m/s^2
    assert hf["timeHeadway"] == 6 and hf["cruiseSpeed"] == 2222 and hf["controllerType"] == 3
    mio = raw["iclcmParameters"]["mostImportantObjectContainer"]
    assert mio["mioBearing"] == -10  # 0.02 rad to the left is -10 (1/500 rad, positive to the right)
    assert raw["iclcmParameters"]["vehicleContainerLowFrequency"] == {"participantsReady": 1}
    plain = CooperativeState(9, T0_S)
    back = _decode(encode(plain))
    assert back == plain and back.target_accel_mps2 is None and back.lane is None


def test_iclcm_refusals_name_the_field() -> None:
    with pytest.raises(V2xEncodeError) as err:
        encode(CooperativeState(9, T0_S, target_accel_mps2=10.5))
    assert err.value.field == "CooperativeState.target_accel_mps2"
    with pytest.raises(V2xEncodeError) as err:
        encode(CooperativeState(9, T0_S, lane=4))
    assert err.value.field == "CooperativeState.lane"


# ---------------------------------------------------------------------------------------------- SPATEM/MAPEM


def test_spatem_round_trip_and_phases() -> None:
    groups = (
        SignalGroupState(1234, 5, TrafficLightPhase.RED_AMBER, 12.3),
        SignalGroupState(1234, 6, TrafficLightPhase.GREEN, None),
        SignalGroupState(1234, 7, None, None),
    )
    msg = SignalPhases(9, T0_S + 0.25, groups)
    data = encode(msg)
    assert peek_header(data).message_id == MSG_SPATEM and data[0] == 2
    back = _decode(data)
    assert isinstance(back, SignalPhases)
    assert back == dataclasses.replace(msg, groups=back.groups)
    assert [dataclasses.replace(g, time_to_change_s=None) for g in back.groups] == [
        dataclasses.replace(g, time_to_change_s=None) for g in groups
    ]
    assert back.groups[0].time_to_change_s == pytest.approx(12.3, abs=0.05)  # TimeMark: 0.1 s
    assert back.groups[1].time_to_change_s is None
    raw = compiled(SchemaSet.ROADSIDE).decode("SPATEM", data)["spat"]["intersections"][0]
    assert [m["state-time-speed"][0]["eventState"] for m in raw["states"]] == [
        "pre-Movement", "protected-Movement-Allowed", "unavailable",
    ]  # fmt: skip
    # minute of the year and ms in it; the end of the phase as a TimeMark (0.1 s in the hour)
    assert raw["timeStamp"] == round((T0_S + 0.25) % 60 * 1000)
    assert raw["states"][0]["state-time-speed"][0]["timing"]["minEndTime"] == round(
        ((T0_S + 0.25) % 3600 + 12.3) * 10
    )


def test_mapem_round_trip_stop_lines_and_speed_limits() -> None:
    line = StopLine(5, 49.01, 8.41, 0.4)
    zone = SpeedLimit(9, T0_S, 77, 49.02, 8.42, 80 / 3.6, -1.0)
    msg = RoadMap(9, T0_S + 30.0, (IntersectionMap(1234, (line,)),), (zone,))
    data = encode(msg)
    assert peek_header(data).message_id == MSG_MAPEM
    back = _decode(data)
    assert isinstance(back, RoadMap)
    assert back.generation_time_s == T0_S - T0_S % 60  # the minute
    (m,) = back.intersections
    (got_line,) = m.stop_lines
    assert (m.intersection_id, got_line.signal_group) == (1234, 5)
    assert (got_line.lat_deg, got_line.lon_deg) == (49.01, 8.41)
    assert got_line.heading_rad == pytest.approx(0.4, abs=0.002)
    (got_zone,) = back.speed_limits
    assert got_zone.zone_id == 77 and got_zone.limit_mps == pytest.approx(80 / 3.6, abs=0.01)
    assert (got_zone.lat_deg, got_zone.lon_deg) == (49.02, 8.42)
    assert got_zone.heading_rad == pytest.approx(-1.0, abs=0.002)


def test_roadside_refusals() -> None:
    with pytest.raises(V2xEncodeError, match=r"SignalPhases\.time_to_change_s"):
        encode(SignalPhases(1, T0_S, (SignalGroupState(1, 1, TrafficLightPhase.RED, 3600.1),)))
    with pytest.raises(V2xEncodeError, match=r"SignalPhases\.signal_group"):
        encode(SignalPhases(1, T0_S, (SignalGroupState(1, 256, TrafficLightPhase.RED, 1.0),)))
    with pytest.raises(V2xEncodeError, match=r"RoadMap\.limit_mps"):
        encode(RoadMap(1, T0_S, speed_limits=(SpeedLimit(1, T0_S, 1, 49.0, 8.4, 200.0),)))
    with pytest.raises(TypeError, match="not a VehicleState"):
        encode("state")  # type: ignore[arg-type]


# ---------------------------------------------------------------------------------------------- refusals


@pytest.mark.parametrize(
    ("changes", "field"),
    [
        ({"speed_mps": 163.82}, "VehicleState.speed_mps"),  # 16382 is release 2's outOfRange marker
        ({"speed_mps": -0.01}, "VehicleState.speed_mps"),
        ({"lat_deg": 90.00000006, "heading_rad": None}, "VehicleState.lat_deg"),
        ({"lon_deg": -180.1, "heading_rad": None}, "VehicleState.lon_deg"),
        ({"heading_rad": 7.0}, "VehicleState.heading_rad"),
        ({"heading_rad": math.nan}, "VehicleState.heading_rad"),
        ({"yaw_rate_radps": math.radians(327.66)}, "VehicleState.yaw_rate_radps"),
        ({"accel_mps2": 16.0}, "VehicleState.accel_mps2"),
        ({"length_m": 102.2}, "VehicleState.length_m"),
        ({"length_m": 0.04}, "VehicleState.length_m"),
        ({"width_m": 6.1}, "VehicleState.width_m"),
        ({"station_id": 2**32}, "VehicleState.station_id"),
        ({"station_id": True}, "VehicleState.station_id"),
        ({"lane_position": 15}, "VehicleState.lane_position"),
        ({"station_type": 256}, "VehicleState.station_type"),
        ({"generation_time_s": 1_000_000_000.0}, "VehicleState.generation_time_s"),  # 2001: before 2004
        ({"generation_time_s": math.inf}, "VehicleState.generation_time_s"),
        ({"accel_mps2": "1"}, "VehicleState.accel_mps2"),
    ],
)
def test_out_of_range_is_refused_naming_the_field(changes: dict[str, object], field: str) -> None:
    with pytest.raises(V2xEncodeError) as err:
        encode(_vehicle(**changes))
    assert err.value.field == field
    assert str(err.value).startswith(field + ":")


def test_range_edges_encode() -> None:
    for changes in (
        {"speed_mps": 163.81},
        {"accel_mps2": -15.9},
        {"yaw_rate_radps": -math.radians(327.65)},
        {"lat_deg": -90.0, "lon_deg": 180.0, "heading_rad": None},
        {"length_m": 102.1, "width_m": 6.0},
        {"length_m": 0.1, "width_m": 0.1},
        {"lane_position": -1, "station_type": 255},
    ):
        v = _vehicle(**changes)
        assert encode(_decode(encode(v))) == encode(v)


# ------------------------------------------------------------------------------------------- property tests

_int_ranges = {
    "lat": st.integers(-890_000_000, 890_000_000),  # the front reference point must stay off the poles
    "lon": st.integers(-1_800_000_000, 1_800_000_000),
    "heading": st.integers(0, 3599),
    "speed": st.integers(0, 16381),
    "yaw": st.integers(-32765, 32765),
    "accel": st.integers(-159, 159),
    "length": st.integers(1, 1021),
    "width": st.integers(1, 60),
}


@st.composite
def vehicle_states(draw: st.DrawFn) -> VehicleState:
    """Any VehicleState whose fields lie in the encodable ranges (each may be unavailable)."""

    def maybe(key: str, scale: float, conv: object = None) -> float | None:
        if draw(st.booleans()) and draw(st.booleans()):
            return None
        n = draw(_int_ranges[key])
        # Off the grid by up to 0.49 LSB: rounding must land on n.
        x = (n + draw(st.floats(-0.49, 0.49))) / scale
        return conv(x) if callable(conv) else x  # type: ignore[operator]

    heading = maybe("heading", 10.0)
    return VehicleState(
        station_id=draw(st.integers(0, 2**32 - 1)),
        generation_time_s=draw(st.floats(1_072_915_200.0, 4_000_000_000.0)),
        lat_deg=maybe("lat", 1e7),
        lon_deg=maybe("lon", 1e7),
        heading_rad=None if heading is None else math.pi / 2 - math.radians(heading),
        speed_mps=maybe("speed", 100.0),
        yaw_rate_radps=maybe("yaw", 100.0, math.radians),
        accel_mps2=maybe("accel", 10.0),
        length_m=maybe("length", 10.0),
        width_m=maybe("width", 10.0),
        drive_direction=draw(st.sampled_from([None, *DriveDirection])),
        lane_position=draw(st.one_of(st.none(), st.integers(-1, 14))),
    )


def _close(a: float | None, b: float | None, tol: float) -> bool:
    return (a is None) == (b is None) and (a is None or b is None or abs(a - b) <= tol)


@given(vehicle_states())
@settings(max_examples=150, deadline=None)
def test_every_in_range_state_encodes_and_round_trips(v: VehicleState) -> None:
    data = encode(v)
    back = decode(data, v.generation_time_s + 0.1)
    assert isinstance(back, VehicleState)
    assert encode(back) == data  # stable: the decoded value re-encodes to the same bytes
    assert decode(encode(back), v.generation_time_s + 0.1) == back
    assert back.station_id == v.station_id
    assert abs(back.generation_time_s - v.generation_time_s) <= 5e-4 + 1e-6
    # Each field within half an LSB (+ float noise); the position within the LSB and the shift to the
    # reference point and back over the quantised heading and length (<= 2.6 m * 0.05 deg + 5 cm).
    pos_tol = 0.5e-7 + (0.0 if v.heading_rad is None or v.length_m is None else 1.2e-6)
    assert _close(back.lat_deg, v.lat_deg, pos_tol)
    if back.lon_deg is not None and v.lon_deg is not None and v.lat_deg is not None:
        assert (
            abs(math.remainder(back.lon_deg - v.lon_deg, 360.0)) * math.cos(math.radians(v.lat_deg))
            <= pos_tol
        )
    assert _close(back.speed_mps, v.speed_mps, 0.005 + 1e-12)
    assert _close(back.accel_mps2, v.accel_mps2, 0.05 + 1e-12)
    assert _close(back.length_m, v.length_m, 0.05 + 1e-12)
    assert _close(back.width_m, v.width_m, 0.05 + 1e-12)
    assert _close(back.yaw_rate_radps, v.yaw_rate_radps, math.radians(0.005) + 1e-12)
    if v.heading_rad is not None:
        assert back.heading_rad is not None
        diff = math.remainder(back.heading_rad - v.heading_rad, 2 * math.pi)
        assert abs(diff) <= math.radians(0.05) + 1e-9
    assert back.drive_direction == v.drive_direction
    assert back.lane_position == v.lane_position


@given(
    st.sampled_from(
        ["speed_mps", "accel_mps2", "length_m", "width_m", "lat_deg", "lon_deg", "yaw_rate_radps"]
    ),
    st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.floats(-1e12, 1e12)),
)
@settings(max_examples=300)
def test_any_float_either_encodes_in_range_or_is_refused_with_its_field(name: str, value: float) -> None:
    limits = {
        "speed_mps": (0.0, 163.81, 0.005),
        "accel_mps2": (-15.9, 15.9, 0.05),
        "length_m": (0.1, 102.1, 0.05),
        "width_m": (0.1, 6.0, 0.05),
        "lat_deg": (-90.0, 90.0, 0.5e-7),
        "lon_deg": (-180.0, 180.0, 0.5e-7),
        "yaw_rate_radps": (-math.radians(327.65), math.radians(327.65), math.radians(0.005)),
    }
    lo, hi, half = limits[name]
    try:
        data = encode(_vehicle(**{name: value, "heading_rad": None}))
    except V2xEncodeError as e:
        assert e.field == f"VehicleState.{name}"
        assert not (math.isfinite(value) and lo + half * 0.999 <= value <= hi - half * 0.999)
        return
    assert math.isfinite(value) and lo - half * 1.001 <= value <= hi + half * 1.001
    assert getattr(_decode(data), name) == pytest.approx(value, abs=half * 1.001)


# ---------------------------------------------------------------------------------------------- decode errors


def test_decode_errors_say_what_and_where() -> None:
    good = encode(_vehicle())
    cases = [
        (b"", DecodeReason.TOO_SHORT, "0 bytes"),
        (good[:5], DecodeReason.TOO_SHORT, "needs 6"),
        (good[:-1], DecodeReason.MALFORMED, "out of data"),
        (good + b"\x00", DecodeReason.NON_CANONICAL, f"{len(good) + 1} bytes received"),
        (bytes([3]) + good[1:], DecodeReason.BAD_VERSION, "CAM protocolVersion 3 at byte 0"),
        (bytes([2, 200]) + good[2:], DecodeReason.UNKNOWN_MESSAGE, "messageID 200 at byte 1"),
        (bytes([2, 1]) + good[2:], DecodeReason.UNKNOWN_MESSAGE, "messageID 1 at byte 1"),
        (bytes([2, 10]) + good[2:], DecodeReason.BAD_VERSION, "iCLCM protocolVersion 2"),
    ]
    for data, reason, text in cases:
        with pytest.raises(V2xDecodeError) as err:
            _decode(data)
        assert err.value.reason is reason, data.hex()
        assert text in str(err.value)


def test_markers_and_rsu_cams_are_refused() -> None:
    value = compiled(SchemaSet.CAM_V2).decode("CAM", encode(_vehicle()))
    value["cam"]["camParameters"]["highFrequencyContainer"][1]["speed"]["speedValue"] = 16382
    with pytest.raises(V2xDecodeError) as err:
        _decode(compiled(SchemaSet.CAM_V2).encode("CAM", value))
    assert err.value.reason is DecodeReason.MALFORMED and "speed 16382" in str(err.value)
    value = compiled(SchemaSet.CAM_V2).decode("CAM", encode(_vehicle(), low_frequency=False))
    value["cam"]["camParameters"]["highFrequencyContainer"] = ("rsuContainerHighFrequency", {})
    with pytest.raises(V2xDecodeError) as err:
        _decode(compiled(SchemaSet.CAM_V2).encode("CAM", value))
    assert err.value.reason is DecodeReason.NOT_A_VEHICLE


@given(st.binary(max_size=300))
@settings(max_examples=500, deadline=None, suppress_health_check=[HealthCheck.too_slow])
def test_decode_arbitrary_bytes_only_raises_the_documented_error(data: bytes) -> None:
    try:
        _decode(data)
    except V2xDecodeError as e:
        assert isinstance(e.reason, DecodeReason)


def _valid_frames() -> list[bytes]:
    line = StopLine(2, 49.0, 8.4, 0.3)
    return [
        encode(_vehicle()),
        encode(_vehicle(lane_position=None), low_frequency=False),
        encode(CooperativeState(5, T0_S, ControllerType.CACC, -1.0, 0.6, 20.0, mio_station_id=7)),
        encode(SignalPhases(3, T0_S, (SignalGroupState(1, 2, TrafficLightPhase.GREEN, 5.0),))),
        encode(RoadMap(3, T0_S, (IntersectionMap(1, (line,)),))),
        encode(RoadMap(4, T0_S, speed_limits=(SpeedLimit(4, T0_S, 9, 49.0, 8.4, 25.0, 0.3),))),
    ]


@st.composite
def mutated_frames(draw: st.DrawFn) -> bytes:
    """Valid frames of every kind, then bit flips, truncation, extension or a random byte."""
    frame = bytearray(draw(st.sampled_from(_valid_frames())))
    for _ in range(draw(st.integers(0, 6))):
        op = draw(st.integers(0, 3))
        if op == 0 and frame:
            bit = draw(st.integers(0, len(frame) * 8 - 1))
            frame[bit // 8] ^= 0x80 >> (bit % 8)
        elif op == 1:
            frame = frame[: draw(st.integers(0, len(frame)))]
        elif op == 2:
            frame += draw(st.binary(min_size=1, max_size=20))
        elif frame:
            frame[draw(st.integers(0, len(frame) - 1))] = draw(st.integers(0, 255))
    return bytes(frame)


_TYPES = {
    MSG_CAM: (SchemaSet.CAM_V2, "CAM"),
    MSG_ICLCM: (SchemaSet.ICLCM, "IGAMECooperativeLaneChangeMessage"),
    MSG_SPATEM: (SchemaSet.ROADSIDE, "SPATEM"),
    MSG_MAPEM: (SchemaSet.ROADSIDE, "MAPEM"),
}


@given(mutated_frames())
@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
def test_decode_mutated_frames_gives_a_canonical_message_or_the_documented_error(data: bytes) -> None:
    try:
        msg = _decode(data)
    except V2xDecodeError as e:
        assert isinstance(e.reason, DecodeReason)
        return
    # Whatever is accepted is exactly the canonical encoding of what it decoded to.
    schema, type_name = (SchemaSet.CAM_V1, "CAM") if data[:2] == bytes([1, MSG_CAM]) else _TYPES[data[1]]
    spec = compiled(schema)
    assert bytes(spec.encode(type_name, spec.decode(type_name, data))) == data
    if isinstance(msg, VehicleState) and data[0] == 2:
        again = encode(
            msg, low_frequency="lowFrequencyContainer" in spec.decode("CAM", data)["cam"]["camParameters"]
        )
        assert decode(again, T0_S + 0.2) == msg  # and its SI value is one we send as it is
