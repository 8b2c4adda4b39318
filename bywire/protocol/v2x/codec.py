"""V2V/V2I message codec: our CAM-shaped ASN.1 messages in UPER (seed 003, Sec. III, IV-B).

Seed 003 Sec. IV-B: every GCDC vehicle broadcast its state vector (l, w, phi, lambda, psi, v, psi-dot, a)
with its GPS time; the road side broadcast traffic-light states and speed limits. The 2011 message set was
never published in machine-readable form, so our wire format (`bywire_v2x.asn`, next to this file) is an
ETSI ITS-G5 CAM (EN 302 637-2) cut down to that state vector, with the ETSI common data dictionary's
(TS 102 894-2) units and "unavailable" values. `etsi_cam.from_etsi_cam` reads real CAMs (protocolVersion
1 and 2) into the same `VehicleState`, so the receiver takes both.

Conventions on our side (SI, converted here and nowhere else):

- `generation_time_s`: UNIX seconds (POSIX, UTC). On the wire: TimestampIts, ms since 2004-01-01 00:00:00
  UTC counted without leap-second jumps (CDD v2.x: TAI milliseconds; 5 leap seconds ahead of UTC since
  2017, the ETSI example 2007-01-01T00:00Z = 94 694 401 000 is a test). A future leap second needs an entry
  in LEAP_SECONDS_UNIX_S (none announced since 2016; the CGPM decided in 2022 to stop them by 2035).
- `heading_rad`: counter-clockwise from east (x east, y north) in the east-north tangent plane at the
  vehicle, wrapped to (-pi, pi]: a true bearing; a map projection's grid convergence is the map's to add.
  ETSI HeadingValue is clockwise from north in 0.1 deg: heading_rad = pi/2 - radians(0.1 n).
- `yaw_rate_radps`: counter-clockwise positive, the same sense as ETSI YawRateValue (positive = to the
  left, ISO 8855), so only the unit changes (0.01 deg/s).
- `speed_mps` is the magnitude (ETSI SpeedValue), >= 0; `drive_direction` says forward/backward.
- `accel_mps2`: longitudinal, positive = speeding up forward. `None` wherever the wire said "unavailable".

Deviations from the ETSI CAM, and why:

- Absolute generation time (42-bit TimestampIts) instead of the CAM's 16-bit GenerationDeltaTime
  (TimestampIts mod 65536): with 65.536 s wrap a receiver cannot tell a replayed or day-old message from a
  fresh one (seed 003 III-B: "only accepted packages that were sent with a timestamp of today"). For real
  CAMs, `etsi_cam.from_etsi_cam` resolves the wrap against a reference time (the receive time) to the
  candidate nearest to it, so a CAM's age is only known modulo 65.536 s.
- Position = geometric centre of the vehicle (seed 003 IV-B), not the ETSI reference point (ground
  centre of the front of the bounding box). `from_etsi_cam` moves a CAM's reference point back by half the
  vehicle length along the heading when both are available, else keeps it (then the position is up to
  half a car length ahead of the centre).
- Rounding to the nearest LSB (error <= LSB/2), where ETSI specifies "<= n LSB and > (n-1) LSB" (error
  < 1 LSB); values that would land on an "outOfRange" marker or beyond are refused, not clamped. Received
  outOfRange markers decode to their bound (e.g. speed 163.82 m/s), which the receiver's physical checks
  reject.
- No confidence values and no low-frequency / special-vehicle containers; lane position and platoon id are
  optional extensions. Our messageIds 200..202 sit in the ItsPduHeader layout (as GCDC 2016 put iCLCM at
  messageID 10), so bytes 0..5 tell ours and ETSI CAMs apart without an ASN.1 decoder (`peek_header`).
- Strict decoding of our messages: the datagram must be exactly the canonical UPER encoding of what it
  decodes to (asn1tools ignores trailing bytes; a datagram with bytes appended, non-zero padding or an
  extension we do not know is corrupt: `PDU_BITS`). ETSI CAMs from other stacks are not held to this.

Every failure to decode raises `V2xDecodeError` with a `reason` (the receiver's count key); asn1tools
raises more than its DecodeError on garbage (ValueError, IndexError, NotImplementedError, ...): all of it
is caught here, per datagram. Encoding a value outside its range raises `V2xEncodeError` naming the field.
"""

from __future__ import annotations

import bisect
import functools
import math
import struct
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any, Final

import asn1tools

# ---------------------------------------------------------------------------------------------- header

PROTOCOL_VERSION: Final = 1  # bywire-v2x version in ItsPduHeader.protocolVersion for messageIds 200..202
MSG_ETSI_CAM: Final = 2
MSG_VEHICLE_STATE: Final = 200
MSG_TRAFFIC_LIGHT: Final = 201
MSG_SPEED_LIMIT: Final = 202
OUR_MESSAGE_IDS: Final = frozenset({MSG_VEHICLE_STATE, MSG_TRAFFIC_LIGHT, MSG_SPEED_LIMIT})
# ItsPduHeader in UPER: protocolVersion (8 bits), messageId (8 bits), stationId (32 bits), byte-aligned at
# offset 0 because the top-level SEQUENCE has no extension marker and no OPTIONAL component.
HEADER: Final = struct.Struct(">BBI")
STATION_ID_MAX: Final = 0xFFFF_FFFF

ASN1_PATH: Final = Path(__file__).with_name("bywire_v2x.asn")
_PDU_TYPE = {
    MSG_VEHICLE_STATE: "VehicleStateMessage",
    MSG_TRAFFIC_LIGHT: "TrafficLightMessage",
    MSG_SPEED_LIMIT: "SpeedLimitMessage",
}

# ---------------------------------------------------------------------------------------------- time

ITS_EPOCH_UNIX_S: Final = 1_072_915_200  # 2004-01-01T00:00:00Z
TIMESTAMP_ITS_MAX: Final = 4_398_046_511_103  # 2^42 - 1 ms, ~139 years after 2004
# UNIX time of the first UTC second after each leap second inserted since the ITS epoch
# (IERS Bulletin C: 2005-12-31, 2008-12-31, 2012-06-30, 2015-06-30, 2016-12-31).
LEAP_SECONDS_UNIX_S: Final = (1_136_073_600, 1_230_768_000, 1_341_100_800, 1_435_708_800, 1_483_228_800)
# The same instants on the TimestampIts scale (ms): at the k-th boundary k+1 leap seconds have passed.
_LEAP_BOUNDARIES_ITS_MS: Final = tuple(
    (t - ITS_EPOCH_UNIX_S) * 1000 + (k + 1) * 1000 for k, t in enumerate(LEAP_SECONDS_UNIX_S)
)
GEN_TIME_RESOLUTION_S: Final = 1e-3  # TimestampIts counts ms: stamps closer than this may encode equal
GENERATION_DELTA_MODULO: Final = 65_536  # CAM GenerationDeltaTime = TimestampIts mod 2^16


def unix_to_timestamp_its(unix_s: float) -> int:
    """UNIX seconds (UTC) -> ETSI TimestampIts (TAI ms since 2004-01-01T00:00Z), rounded to the ms."""
    leaps = bisect.bisect_right(LEAP_SECONDS_UNIX_S, unix_s)
    return round((unix_s - ITS_EPOCH_UNIX_S) * 1000.0) + 1000 * leaps


def timestamp_its_to_unix(timestamp_its_ms: int) -> float:
    """ETSI TimestampIts (ms) -> UNIX seconds (UTC). A leap second (23:59:60, which UNIX time cannot name)
    maps onto the second after it."""
    leaps = bisect.bisect_right(_LEAP_BOUNDARIES_ITS_MS, timestamp_its_ms)
    # One division of an exact integer: the nearest double to the ms instant, stable under re-encoding.
    return (timestamp_its_ms - 1000 * leaps + ITS_EPOCH_UNIX_S * 1000) / 1000.0


# ---------------------------------------------------------------------------------------------- errors


class V2xError(ValueError):
    """Base of the codec's errors."""


class V2xEncodeError(V2xError):
    """A message field that cannot be encoded; `field` names it ("VehicleState.speed_mps")."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__(f"{field}: {message}")
        self.field = field


class DecodeReason(StrEnum):
    """Why a datagram did not decode; the values are the receiver's rejection count keys."""

    TOO_SHORT = "too_short"  # shorter than the 6-byte ItsPduHeader
    OVERSIZE = "oversize"  # longer than any message we accept (checked by the receiver)
    UNKNOWN_MESSAGE = "unknown_message"  # messageId that is neither ours nor an ETSI CAM
    BAD_VERSION = "bad_version"  # our messageId with another protocolVersion, or a CAM version we lack
    MALFORMED = "malformed"  # asn1tools DecodeError / ConstraintsError (out of data, bad enum, range)
    DECODER_FAULT = "decoder_fault"  # any other exception asn1tools raised on the bytes
    NON_CANONICAL = "non_canonical"  # bytes appended, or padding / extension content we do not know
    NOT_A_VEHICLE = "not_a_vehicle"  # an ETSI CAM without a basic vehicle high-frequency container


class V2xDecodeError(V2xError):
    """A datagram that is not a valid message; `reason` is a DecodeReason, the text says what and where."""

    def __init__(self, reason: DecodeReason, detail: str) -> None:
        super().__init__(f"{reason.value}: {detail}")
        self.reason = reason
        self.detail = detail


# ---------------------------------------------------------------------------------------------- messages


class DriveDirection(StrEnum):
    FORWARD = "forward"
    BACKWARD = "backward"


class TrafficLightPhase(StrEnum):
    RED = "red"
    RED_AMBER = "redAmber"  # red and amber together before green (Germany, UK, ...)
    GREEN = "green"
    AMBER = "amber"


@dataclass(frozen=True, slots=True)
class VehicleState:
    """One vehicle's broadcast state (seed 003 IV-B state vector plus station id and generation time).

    lat/lon: WGS84 degrees of the vehicle's geometric centre. heading_rad: counter-clockwise from east
    (true, in the tangent plane at the vehicle), (-pi, pi]. speed_mps: magnitude >= 0 (drive_direction
    gives the sense). yaw_rate_radps: counter-clockwise positive. accel_mps2: longitudinal.
    lane_position: ETSI LanePosition (-1 off road, 0 hard shoulder, 1 outermost driving lane, ...).
    None: the sender said "unavailable".
    """

    station_id: int
    generation_time_s: float
    lat_deg: float | None
    lon_deg: float | None
    heading_rad: float | None
    speed_mps: float | None
    yaw_rate_radps: float | None
    accel_mps2: float | None
    length_m: float | None
    width_m: float | None
    drive_direction: DriveDirection | None = None
    lane_position: int | None = None
    platoon_id: int | None = None


@dataclass(frozen=True, slots=True)
class TrafficLightState:
    """A signal group's phase at an intersection (GCDC road side). lat/lon: its stop line.

    time_to_change_s: from generation_time_s to the next phase change (None: unknown).
    """

    station_id: int
    generation_time_s: float
    intersection_id: int
    signal_group: int
    lat_deg: float | None
    lon_deg: float | None
    phase: TrafficLightPhase | None
    time_to_change_s: float | None
    lane_position: int | None = None


@dataclass(frozen=True, slots=True)
class SpeedLimit:
    """A speed-limit zone (GCDC road side): where it starts, on which lane (None: all), the limit."""

    station_id: int
    generation_time_s: float
    zone_id: int
    lat_deg: float | None
    lon_deg: float | None
    limit_mps: float
    lane_position: int | None = None


V2xMessage = VehicleState | TrafficLightState | SpeedLimit


@dataclass(frozen=True, slots=True)
class Header:
    protocol_version: int
    message_id: int
    station_id: int


def peek_header(data: bytes) -> Header:
    """The ItsPduHeader of a datagram (ours or an ETSI CAM) without ASN.1 decoding."""
    if len(data) < HEADER.size:
        raise V2xDecodeError(
            DecodeReason.TOO_SHORT, f"{len(data)} bytes, the ItsPduHeader alone needs {HEADER.size}"
        )
    return Header(*HEADER.unpack_from(data, 0))


# ---------------------------------------------------------------------------------------------- scaling

# Integer ranges that carry a value (ETSI markers excluded); marker values are named constants.
LAT_UNAVAILABLE: Final = 900_000_001
LON_UNAVAILABLE: Final = 1_800_000_001
HEADING_UNAVAILABLE: Final = 3601
SPEED_OUT_OF_RANGE: Final = 16_382
SPEED_UNAVAILABLE: Final = 16_383
YAW_RATE_OUT_OF_RANGE: Final = 32_766
YAW_RATE_UNAVAILABLE: Final = 32_767
ACCEL_OUT_OF_RANGE: Final = 160
ACCEL_UNAVAILABLE: Final = 161
LENGTH_OUT_OF_RANGE: Final = 1022
LENGTH_UNAVAILABLE: Final = 1023
WIDTH_OUT_OF_RANGE: Final = 61
WIDTH_UNAVAILABLE: Final = 62
TIME_TO_CHANGE_UNAVAILABLE: Final = 36_001
LANE_POSITION_RANGE: Final = (-1, 14)
PLATOON_ID_RANGE: Final = (1, 255)
SPEED_LIMIT_KMH_RANGE: Final = (1, 255)
KMH_PER_MPS: Final = 3.6
_HEADING_DOMAIN_RAD = 2.0 * math.pi + 1e-9  # accept both (-pi, pi] and [0, 2 pi) conventions


def _finite(owner: str, name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise V2xEncodeError(f"{owner}.{name}", f"{value!r} is not a number")
    if not math.isfinite(value):
        raise V2xEncodeError(f"{owner}.{name}", f"{value!r} is not a finite number")
    return float(value)


def _scaled(
    owner: str, name: str, value: float | None, per_unit: float, lo: int, hi: int, unavailable: int, unit: str
) -> int:
    """value * per_unit rounded to an integer in lo..hi; None -> the unavailable marker."""
    if value is None:
        return unavailable
    x = _finite(owner, name, value) * per_unit  # may overflow to inf: then the range test refuses it
    if not (lo - 1 <= x <= hi + 1 and lo <= round(x) <= hi):
        raise V2xEncodeError(
            f"{owner}.{name}",
            f"{value!r} {unit} is outside the encodable range {lo / per_unit:g}..{hi / per_unit:g} {unit}",
        )
    return round(x)


def _integer(owner: str, name: str, value: int, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise V2xEncodeError(f"{owner}.{name}", f"{value!r} is not an integer")
    if not lo <= value <= hi:
        raise V2xEncodeError(f"{owner}.{name}", f"{value} is outside {lo}..{hi}")
    return value


def _optional_integer(owner: str, name: str, value: int | None, bounds: tuple[int, int]) -> int | None:
    return None if value is None else _integer(owner, name, value, *bounds)


def _generation_time(owner: str, value: float) -> int:
    t = _finite(owner, "generation_time_s", value)
    ms = unix_to_timestamp_its(t)
    if not 0 <= ms <= TIMESTAMP_ITS_MAX:
        raise V2xEncodeError(
            f"{owner}.generation_time_s", f"{value!r} s is outside the TimestampIts range (2004 .. 2143)"
        )
    return ms


def heading_to_etsi(heading_rad: float) -> int:
    """Counter-clockwise-from-east radians -> ETSI HeadingValue (0.1 deg clockwise from north, 0..3599)."""
    return round((math.degrees(math.pi / 2.0 - heading_rad) % 360.0) * 10.0) % 3600


def heading_from_etsi(value: int) -> float:
    """ETSI HeadingValue (0.1 deg clockwise from north) -> radians counter-clockwise from east, (-pi, pi]."""
    h = math.remainder(math.pi / 2.0 - math.radians(value / 10.0), 2.0 * math.pi)
    return math.pi if h == -math.pi else h


def _encode_heading(owner: str, value: float | None) -> int:
    if value is None:
        return HEADING_UNAVAILABLE
    h = _finite(owner, "heading_rad", value)
    if abs(h) > _HEADING_DOMAIN_RAD:
        raise V2xEncodeError(f"{owner}.heading_rad", f"{value!r} rad is outside -2 pi .. 2 pi")
    return heading_to_etsi(h)


def _position(owner: str, lat: float | None, lon: float | None) -> tuple[int, int]:
    return (
        _scaled(owner, "lat_deg", lat, 1e7, -900_000_000, 900_000_000, LAT_UNAVAILABLE, "deg"),
        _scaled(owner, "lon_deg", lon, 1e7, -1_800_000_000, 1_800_000_000, LON_UNAVAILABLE, "deg"),
    )


def lat_from_etsi(n: int) -> float | None:
    """ETSI Latitude (0.1 microdegree) -> degrees; None for unavailable."""
    return None if n == LAT_UNAVAILABLE else n / 1e7


def lon_from_etsi(n: int) -> float | None:
    """ETSI Longitude (0.1 microdegree) -> degrees; None for unavailable."""
    return None if n == LON_UNAVAILABLE else n / 1e7


def scaled_from_etsi(n: int, unavailable: int, per_unit: float) -> float | None:
    """An ETSI value counted in 1/per_unit of its SI unit -> SI; None for its unavailable marker."""
    return None if n == unavailable else n / per_unit


def _encode_yaw_rate(owner: str, value: float | None) -> int:
    """rad/s -> ETSI YawRateValue (0.01 deg/s); the range check is on the degree value."""
    if value is None:
        return YAW_RATE_UNAVAILABLE
    hi = YAW_RATE_OUT_OF_RANGE - 1
    x = math.degrees(_finite(owner, "yaw_rate_radps", value)) * 100.0
    if not (-hi - 1 <= x <= hi + 1 and -hi <= round(x) <= hi):
        raise V2xEncodeError(
            f"{owner}.yaw_rate_radps",
            f"{value!r} rad/s is outside the encodable range +-{math.radians(hi / 100.0):.6g} rad/s "
            f"(+-{hi / 100.0:g} deg/s)",
        )
    return round(x)


def yaw_rate_from_etsi(n: int) -> float | None:
    """ETSI YawRateValue (0.01 deg/s, counter-clockwise) -> rad/s; None for unavailable."""
    return None if n == YAW_RATE_UNAVAILABLE else math.radians(n / 100.0)


# ---------------------------------------------------------------------------------------------- our codec


@functools.cache
def compiled_spec() -> Any:
    """Our ASN.1 module compiled for UPER (once per process, ~0.1 s)."""
    return asn1tools.compile_files(str(ASN1_PATH), "uper")


def _header(message_id: int, owner: str, station_id: int) -> dict[str, int]:
    return {
        "protocolVersion": PROTOCOL_VERSION,
        "messageId": message_id,
        "stationId": _integer(owner, "station_id", station_id, 0, STATION_ID_MAX),
    }


def _vehicle_body(msg: VehicleState) -> dict[str, Any]:
    o = "VehicleState"
    lat, lon = _position(o, msg.lat_deg, msg.lon_deg)
    body: dict[str, Any] = {
        "generationTime": _generation_time(o, msg.generation_time_s),
        "latitude": lat,
        "longitude": lon,
        "heading": _encode_heading(o, msg.heading_rad),
        "speed": _scaled(
            o, "speed_mps", msg.speed_mps, 100.0, 0, SPEED_OUT_OF_RANGE - 1, SPEED_UNAVAILABLE, "m/s"
        ),
        "driveDirection": "unavailable"
        if msg.drive_direction is None
        else DriveDirection(msg.drive_direction).value,
        "yawRate": _encode_yaw_rate(o, msg.yaw_rate_radps),
        "longitudinalAcceleration": _scaled(
            o,
            "accel_mps2",
            msg.accel_mps2,
            10.0,
            -(ACCEL_OUT_OF_RANGE - 1),
            ACCEL_OUT_OF_RANGE - 1,
            ACCEL_UNAVAILABLE,
            "m/s^2",
        ),
        "vehicleLength": _scaled(
            o, "length_m", msg.length_m, 10.0, 1, LENGTH_OUT_OF_RANGE - 1, LENGTH_UNAVAILABLE, "m"
        ),
        "vehicleWidth": _scaled(
            o, "width_m", msg.width_m, 10.0, 1, WIDTH_OUT_OF_RANGE - 1, WIDTH_UNAVAILABLE, "m"
        ),
    }
    lane = _optional_integer(o, "lane_position", msg.lane_position, LANE_POSITION_RANGE)
    if lane is not None:
        body["lanePosition"] = lane
    platoon = _optional_integer(o, "platoon_id", msg.platoon_id, PLATOON_ID_RANGE)
    if platoon is not None:
        body["platoonId"] = platoon
    return {"header": _header(MSG_VEHICLE_STATE, o, msg.station_id), "state": body}


def _traffic_light_body(msg: TrafficLightState) -> dict[str, Any]:
    o = "TrafficLightState"
    lat, lon = _position(o, msg.lat_deg, msg.lon_deg)
    body: dict[str, Any] = {
        "generationTime": _generation_time(o, msg.generation_time_s),
        "intersectionId": _integer(o, "intersection_id", msg.intersection_id, 0, 65_535),
        "signalGroup": _integer(o, "signal_group", msg.signal_group, 0, 255),
        "latitude": lat,
        "longitude": lon,
        "phase": "unavailable" if msg.phase is None else TrafficLightPhase(msg.phase).value,
        "timeToChange": _scaled(
            o,
            "time_to_change_s",
            msg.time_to_change_s,
            10.0,
            0,
            TIME_TO_CHANGE_UNAVAILABLE - 1,
            TIME_TO_CHANGE_UNAVAILABLE,
            "s",
        ),
    }
    lane = _optional_integer(o, "lane_position", msg.lane_position, LANE_POSITION_RANGE)
    if lane is not None:
        body["lanePosition"] = lane
    return {"header": _header(MSG_TRAFFIC_LIGHT, o, msg.station_id), "light": body}


def _speed_limit_body(msg: SpeedLimit) -> dict[str, Any]:
    o = "SpeedLimit"
    lat, lon = _position(o, msg.lat_deg, msg.lon_deg)
    kmh = _finite(o, "limit_mps", msg.limit_mps) * KMH_PER_MPS
    lo, hi = SPEED_LIMIT_KMH_RANGE
    if not (lo - 1 <= kmh <= hi + 1 and lo <= round(kmh) <= hi):
        raise V2xEncodeError(
            f"{o}.limit_mps", f"{msg.limit_mps!r} m/s ({kmh:g} km/h) is outside {lo}..{hi} km/h"
        )
    body: dict[str, Any] = {
        "generationTime": _generation_time(o, msg.generation_time_s),
        "zoneId": _integer(o, "zone_id", msg.zone_id, 0, 65_535),
        "latitude": lat,
        "longitude": lon,
        "speedLimit": round(kmh),
    }
    lane = _optional_integer(o, "lane_position", msg.lane_position, LANE_POSITION_RANGE)
    if lane is not None:
        body["lanePosition"] = lane
    return {"header": _header(MSG_SPEED_LIMIT, o, msg.station_id), "limit": body}


def encode(msg: V2xMessage) -> bytes:
    """A message -> its UPER datagram. V2xEncodeError names the field that is out of range."""
    if isinstance(msg, VehicleState):
        return bytes(
            compiled_spec().encode("VehicleStateMessage", _vehicle_body(msg), check_constraints=True)
        )
    if isinstance(msg, TrafficLightState):
        return bytes(
            compiled_spec().encode("TrafficLightMessage", _traffic_light_body(msg), check_constraints=True)
        )
    if isinstance(msg, SpeedLimit):
        return bytes(
            compiled_spec().encode("SpeedLimitMessage", _speed_limit_body(msg), check_constraints=True)
        )
    raise TypeError(f"encode: {type(msg).__name__} is not a VehicleState, TrafficLightState or SpeedLimit")


def _refuse_out_of_range_markers(s: dict[str, Any]) -> None:
    """The ETSI out-of-range markers (speed 16382, acceleration +-160, yaw rate +-32766, length 1022,
    width 61) say "beyond the field's range", which no VehicleState carries: such a datagram is refused
    (our encoder never sends them, and a value taken as the marker's number would not encode again)."""
    markers = (
        ("speed", (SPEED_OUT_OF_RANGE,)),
        ("longitudinalAcceleration", (ACCEL_OUT_OF_RANGE, -ACCEL_OUT_OF_RANGE)),
        ("yawRate", (YAW_RATE_OUT_OF_RANGE, -YAW_RATE_OUT_OF_RANGE)),
        ("vehicleLength", (LENGTH_OUT_OF_RANGE,)),
        ("vehicleWidth", (WIDTH_OUT_OF_RANGE,)),
    )
    for name, values in markers:
        if s.get(name) in values:
            raise V2xDecodeError(
                DecodeReason.MALFORMED, f"VehicleState.{name}: {s[name]} is the ETSI out-of-range marker"
            )


def _vehicle_from_dict(station_id: int, s: dict[str, Any]) -> VehicleState:
    _refuse_out_of_range_markers(s)
    direction = s["driveDirection"]
    return VehicleState(
        station_id=station_id,
        generation_time_s=timestamp_its_to_unix(s["generationTime"]),
        lat_deg=lat_from_etsi(s["latitude"]),
        lon_deg=lon_from_etsi(s["longitude"]),
        heading_rad=None if s["heading"] == HEADING_UNAVAILABLE else heading_from_etsi(s["heading"]),
        speed_mps=scaled_from_etsi(s["speed"], SPEED_UNAVAILABLE, 100.0),
        yaw_rate_radps=yaw_rate_from_etsi(s["yawRate"]),
        accel_mps2=scaled_from_etsi(s["longitudinalAcceleration"], ACCEL_UNAVAILABLE, 10.0),
        length_m=scaled_from_etsi(s["vehicleLength"], LENGTH_UNAVAILABLE, 10.0),
        width_m=scaled_from_etsi(s["vehicleWidth"], WIDTH_UNAVAILABLE, 10.0),
        drive_direction=None if direction == "unavailable" else DriveDirection(direction),
        lane_position=s.get("lanePosition"),
        platoon_id=s.get("platoonId"),
    )


def _phase(name: str) -> TrafficLightPhase | None:
    if name == "unavailable":
        return None
    try:
        return TrafficLightPhase(name)
    except ValueError:  # an extension value from a newer sender: decoded by asn1tools as None/unknown
        raise V2xDecodeError(DecodeReason.NON_CANONICAL, f"traffic-light phase {name!r} is unknown") from None


def _traffic_light_from_dict(station_id: int, b: dict[str, Any]) -> TrafficLightState:
    return TrafficLightState(
        station_id=station_id,
        generation_time_s=timestamp_its_to_unix(b["generationTime"]),
        intersection_id=b["intersectionId"],
        signal_group=b["signalGroup"],
        lat_deg=lat_from_etsi(b["latitude"]),
        lon_deg=lon_from_etsi(b["longitude"]),
        phase=_phase(b["phase"]),
        time_to_change_s=scaled_from_etsi(b["timeToChange"], TIME_TO_CHANGE_UNAVAILABLE, 10.0),
        lane_position=b.get("lanePosition"),
    )


def _speed_limit_from_dict(station_id: int, b: dict[str, Any]) -> SpeedLimit:
    return SpeedLimit(
        station_id=station_id,
        generation_time_s=timestamp_its_to_unix(b["generationTime"]),
        zone_id=b["zoneId"],
        lat_deg=lat_from_etsi(b["latitude"]),
        lon_deg=lon_from_etsi(b["longitude"]),
        limit_mps=b["speedLimit"] / KMH_PER_MPS,
        lane_position=b.get("lanePosition"),
    )


def asn1_decode(spec: Any, type_name: str, data: bytes, what: str) -> dict[str, Any]:
    """`spec.decode(type_name, data)`, every asn1tools failure a V2xDecodeError naming `what`."""
    try:
        value = spec.decode(type_name, data, check_constraints=True)
    except (asn1tools.DecodeError, asn1tools.ConstraintsError) as e:
        raise V2xDecodeError(DecodeReason.MALFORMED, f"{what}: {e}") from None
    except Exception as e:  # asn1tools on garbage: ValueError, IndexError, NotImplementedError, ...
        raise V2xDecodeError(DecodeReason.DECODER_FAULT, f"{what}: {type(e).__name__}: {e}") from None
    if not isinstance(value, dict):
        raise V2xDecodeError(DecodeReason.DECODER_FAULT, f"{what}: decoder returned {type(value).__name__}")
    return value


# UPER size of our PDUs in bits without their OPTIONAL components, and what each present one adds.
# Every component is a fixed-width constrained integer or a root enumeration, so the encoding of a value
# is unique: a datagram is canonical iff the body's extension bit is 0, its length is this size rounded
# up to whole bytes and the padding bits are 0. That check replaces a re-encode (~40 us of ~80 us per
# datagram); tests compare it with asn1tools for every shape, so a schema edit that breaks it fails them.
#   header 8+8+32; VehicleStateBody ext 1, optional bitmap 2, generationTime 42, latitude 31, longitude 32,
#   heading 12, speed 14, driveDirection 2, yawRate 16, longitudinalAcceleration 9, length 10, width 6;
#   TrafficLightBody ext 1, bitmap 1, time 42, intersection 16, signal group 8, lat 31, lon 32, phase 1+3,
#   timeToChange 16; SpeedLimitBody ext 1, bitmap 1, time 42, zone 16, lat 31, lon 32, limit 8.
PDU_BITS: Final = {
    MSG_VEHICLE_STATE: (225, (("lanePosition", 4), ("platoonId", 8))),
    MSG_TRAFFIC_LIGHT: (199, (("lanePosition", 4),)),
    MSG_SPEED_LIMIT: (179, (("lanePosition", 4),)),
}
_BODY_KEY: Final = {MSG_VEHICLE_STATE: "state", MSG_TRAFFIC_LIGHT: "light", MSG_SPEED_LIMIT: "limit"}
_BODY_EXTENSION_BIT: Final = 0x80  # first bit after the 6-byte header


def pdu_bits(message_id: int, body: dict[str, Any]) -> int:
    """The UPER size in bits of one of our PDUs whose body (asn1tools value) is `body`."""
    base, optionals = PDU_BITS[message_id]
    return base + sum(bits for name, bits in optionals if name in body)


def _check_canonical(message_id: int, body: dict[str, Any], data: bytes, what: str) -> None:
    bits = pdu_bits(message_id, body)
    size = (bits + 7) // 8
    if len(data) != size:
        raise V2xDecodeError(
            DecodeReason.NON_CANONICAL, f"{what}: {len(data)} bytes received, its content is {size} bytes"
        )
    padding = size * 8 - bits
    if padding and data[-1] & ((1 << padding) - 1):
        raise V2xDecodeError(
            DecodeReason.NON_CANONICAL, f"{what}: the {padding} padding bits of byte {size - 1} are not 0"
        )


def decode(data: bytes) -> V2xMessage:
    """One of our datagrams -> VehicleState / TrafficLightState / SpeedLimit, or V2xDecodeError."""
    data = bytes(data)
    header = peek_header(data)
    type_name = _PDU_TYPE.get(header.message_id)
    if type_name is None:
        raise V2xDecodeError(
            DecodeReason.UNKNOWN_MESSAGE,
            f"messageId {header.message_id} at byte 1 is not one of ours ({sorted(OUR_MESSAGE_IDS)})",
        )
    if header.protocol_version != PROTOCOL_VERSION:
        raise V2xDecodeError(
            DecodeReason.BAD_VERSION,
            f"protocolVersion {header.protocol_version} at byte 0, ours is {PROTOCOL_VERSION}",
        )
    # Checked before decoding: asn1tools would parse the extension additions (and raises
    # NotImplementedError on some random ones).
    if len(data) > HEADER.size and data[HEADER.size] & _BODY_EXTENSION_BIT:
        raise V2xDecodeError(
            DecodeReason.NON_CANONICAL,
            f"{type_name}: extension bit set at byte {HEADER.size} (v{PROTOCOL_VERSION} has none)",
        )
    value = asn1_decode(compiled_spec(), type_name, data, type_name)
    _check_canonical(header.message_id, value[_BODY_KEY[header.message_id]], data, type_name)
    station = header.station_id
    try:
        if header.message_id == MSG_VEHICLE_STATE:
            return _vehicle_from_dict(station, value["state"])
        if header.message_id == MSG_TRAFFIC_LIGHT:
            return _traffic_light_from_dict(station, value["light"])
        return _speed_limit_from_dict(station, value["limit"])
    except (KeyError, TypeError, ValueError) as e:
        if isinstance(e, V2xDecodeError):
            raise
        raise V2xDecodeError(DecodeReason.DECODER_FAULT, f"{type_name}: {type(e).__name__}: {e}") from None
