"""V2V/V2I messages in SI and the ETSI common data dictionary's units (seed 003, Sec. III, IV-B).

Seed 003 Sec. IV-B: every GCDC vehicle broadcast its state vector (l, w, phi, lambda, psi, v, psi-dot, a)
with its GPS time; the road side broadcast traffic-light states and speed limits. On the air these are the
field's standard messages (`wire`): an ETSI CAM (EN 302 637-2, `etsi_cam`) for the state vector, the
GCDC 2016 iCLCM (`iclcm`) for what a platoon needs beyond it, SPATEM/MAPEM (ETSI TS 103 301 over ISO TS
19091, `dsrc`) for the road side. This module holds what they share: the SI dataclasses, the ItsPduHeader
peek, the errors, TimestampIts, and the conversions of the ETSI common data dictionary (TS 102 894-2)
units and "unavailable" markers, done here and nowhere else.

Conventions on our side (SI):

- `generation_time_s`: UNIX seconds (POSIX, UTC). TimestampIts is ms since 2004-01-01 00:00:00 UTC counted
  without leap-second jumps (CDD v2.x: TAI milliseconds; 5 leap seconds ahead of UTC since 2017, the ETSI
  example 2007-01-01T00:00Z = 94 694 401 000 is a test); a CAM carries it mod 65536 (GenerationDeltaTime).
  A future leap second needs an entry in LEAP_SECONDS_UNIX_S (none announced since 2016).
- `heading_rad`: counter-clockwise from east (x east, y north) in the east-north tangent plane at the
  vehicle, wrapped to (-pi, pi]: a true bearing. ETSI HeadingValue is clockwise from north in 0.1 deg:
  heading_rad = pi/2 - radians(0.1 n).
- `yaw_rate_radps`: counter-clockwise positive, the sense of ETSI YawRateValue (positive = to the left).
- `speed_mps` is the magnitude (ETSI SpeedValue), >= 0; `drive_direction` says forward/backward.
- `accel_mps2`: longitudinal, positive = speeding up forward. `None` wherever the wire said "unavailable".
- Vehicle positions are the geometric centre of the vehicle (seed 003 IV-B); the CAM's reference point
  (ground centre of the front of the bounding box) is converted at the CAM's edge (`etsi_cam`).
- Rounding to the nearest LSB (error <= LSB/2), where ETSI specifies "<= n LSB and > (n-1) LSB"; values
  that would land on an "outOfRange" marker or beyond are refused, not clamped.

Every failure to decode raises `V2xDecodeError` with a `reason` (the receiver's count key); encoding a
value outside its range raises `V2xEncodeError` naming the field.
"""

from __future__ import annotations

import bisect
import collections
import functools
import math
import struct
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, Final

import asn1tools

from .fast_uper import Unsupported, compile_decoder, compile_encoder

# ---------------------------------------------------------------------------------------------- header

# ItsPduHeader.messageID (CDD TS 102 894-2 v1.3.1; iclcm(10) is the GCDC 2016's own assignment).
MSG_DENM: Final = 1
MSG_CAM: Final = 2
MSG_ETSI_CAM: Final = MSG_CAM
MSG_SPATEM: Final = 4
MSG_MAPEM: Final = 5
# The CDD gives 10 to SSEM (signal status, since v1.3.1): off the GCDC, a stack reads our iCLCM as a
# broken SSEM, which is why only the GCDC profile sends it (host/modules/io/v2v.py).
MSG_ICLCM: Final = 10
# protocolVersion each message is sent with, and the ones we read.
CAM_PROTOCOL_VERSION: Final = 2  # EN 302 637-2 v1.4.1
DSRC_PROTOCOL_VERSION: Final = 2  # TS 103 301: SPATEM / MAPEM "shall be set to 2"
ICLCM_PROTOCOL_VERSION: Final = 1  # GCDC 2016 iCLCM v1.0: currentVersion(1)
READ_VERSIONS: Final = {
    MSG_CAM: frozenset({1, 2}),
    MSG_SPATEM: frozenset({1, 2}),
    MSG_MAPEM: frozenset({1, 2}),
    MSG_ICLCM: frozenset({1}),
}
MESSAGE_NAMES: Final = {MSG_CAM: "CAM", MSG_SPATEM: "SPATEM", MSG_MAPEM: "MAPEM", MSG_ICLCM: "iCLCM"}
ROADSIDE_MESSAGE_IDS: Final = frozenset({MSG_SPATEM, MSG_MAPEM})
# ItsPduHeader in UPER: protocolVersion (8 bits), messageID (8 bits), stationID (32 bits), byte-aligned at
# offset 0 in every PDU we read (each is SEQUENCE { header, body } without extension marker or OPTIONAL).
HEADER: Final = struct.Struct(">BBI")
STATION_ID_MAX: Final = 0xFFFF_FFFF

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
    UNKNOWN_MESSAGE = "unknown_message"  # a messageID we do not take (CAM, SPATEM, MAPEM, iCLCM)
    BAD_VERSION = "bad_version"  # a protocolVersion we have no schema for
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


STATION_TYPE_PASSENGER_CAR: Final = 5  # CDD StationType passengerCar(5)


@dataclass(frozen=True, slots=True)
class VehicleState:
    """One vehicle's broadcast state (seed 003 IV-B state vector plus station id and generation time): a CAM.

    lat/lon: WGS84 degrees of the vehicle's geometric centre. heading_rad: counter-clockwise from east
    (true, in the tangent plane at the vehicle), (-pi, pi]. speed_mps: magnitude >= 0 (drive_direction
    gives the sense). yaw_rate_radps: counter-clockwise positive. accel_mps2: longitudinal.
    lane_position: ETSI LanePosition (-1 off road, 0 hard shoulder, 1 innermost driving lane, ...).
    station_type: CDD StationType (5 passenger car, 8 heavy truck, ...). None: the sender said "unavailable".
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
    station_type: int = STATION_TYPE_PASSENGER_CAR


@dataclass(frozen=True, slots=True)
class TrafficLightState:
    """A signal group's phase at its stop line: a SPATEM's movement placed by its intersection's MAPEM.

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


@dataclass(frozen=True, slots=True)
class SpeedLimit:
    """A speed-limit zone (a MAPEM road segment's regulatory limit): where it starts, the limit, and the
    direction of travel it applies to (heading_rad counter-clockwise from east; None: not said)."""

    station_id: int
    generation_time_s: float
    zone_id: int
    lat_deg: float | None
    lon_deg: float | None
    limit_mps: float
    heading_rad: float | None = None


@dataclass(frozen=True, slots=True)
class Header:
    protocol_version: int
    message_id: int
    station_id: int


def peek_header(data: bytes) -> Header:
    """The ItsPduHeader of a datagram without ASN.1 decoding."""
    if len(data) < HEADER.size:
        raise V2xDecodeError(
            DecodeReason.TOO_SHORT, f"{len(data)} bytes, the ItsPduHeader alone needs {HEADER.size}"
        )
    return Header(*HEADER.unpack_from(data, 0))


def header_value(message_id: int, protocol_version: int, owner: str, station_id: int) -> dict[str, int]:
    """The CDD ItsPduHeader as asn1tools takes it."""
    return {
        "protocolVersion": protocol_version,
        "messageID": message_id,
        "stationID": checked_integer(owner, "station_id", station_id, 0, STATION_ID_MAX),
    }


# A compiled spec's `fast_uper` decoder and encoder per type, built once (a spec is keyed, and kept, by
# its identity)
@functools.lru_cache(maxsize=32)
def _fast_decoder(spec: Any, type_name: str) -> Callable[[bytes], Any]:
    return compile_decoder(spec.types[type_name])


def asn1_decode(spec: Any, type_name: str, data: bytes, what: str, fast: bool = False) -> dict[str, Any]:
    """`spec.decode(type_name, data)`, every asn1tools failure a V2xDecodeError naming `what`.
    `fast`: first `fast_uper`'s decoder, which gives asn1tools' value or leaves the datagram to it."""
    if fast:
        try:
            fast_value: dict[str, Any] = _fast_decoder(spec, type_name)(data)
            return fast_value
        except Unsupported:
            pass
    try:
        value = spec.decode(type_name, data, check_constraints=True)
    except (asn1tools.DecodeError, asn1tools.ConstraintsError) as e:
        raise V2xDecodeError(DecodeReason.MALFORMED, f"{what}: {e}") from None
    except Exception as e:  # asn1tools on garbage: ValueError, IndexError, NotImplementedError, ...
        raise V2xDecodeError(DecodeReason.DECODER_FAULT, f"{what}: {type(e).__name__}: {e}") from None
    if not isinstance(value, dict):
        raise V2xDecodeError(DecodeReason.DECODER_FAULT, f"{what}: decoder returned {type(value).__name__}")
    return value


@functools.lru_cache(maxsize=32)
def _fast_encoder(spec: Any, type_name: str) -> Callable[[Any], bytes]:
    return compile_encoder(spec.types[type_name])


def asn1_encode(spec: Any, type_name: str, value: dict[str, Any], what: str, fast: bool = False) -> bytes:
    """`spec.encode` with constraints checked; a value our builders let through is a V2xEncodeError.
    `fast`: first `fast_uper`'s encoder, which gives asn1tools' bytes or leaves the value to it."""
    if fast:
        try:
            # Not remembered: the canonical check re-encodes such a value faster than it compares.
            return _fast_encoder(spec, type_name)(value)
        except Unsupported:
            pass
    try:
        data = bytes(spec.encode(type_name, value, check_constraints=True))
    except (asn1tools.EncodeError, asn1tools.ConstraintsError) as e:
        raise V2xEncodeError(what, str(e)) from None
    _ENCODED.remember(data, spec, type_name, value)
    return data


def _exact(value: Any) -> str:
    """`value` (an asn1tools value: dicts, lists, tuples, ints, strings, bytes, bools, floats) written out
    so that two values have the same text only if every node has the same type and content (True is
    not 1, 1 is not 1.0, 0.0 is not -0.0, a list is not a tuple, a float by its shortest exact digits),
    in the same order: two values with the same text take the same path through the encoder and give
    the same bytes. Written in C (the builtins' repr), a fifth of an encoding's cost."""
    return repr(value)


class _RecentEncodings:
    """The last datagrams encoded in this process, each with the value it is the encoding of.

    `check_canonical` re-encodes every datagram it decodes (asn1tools' encoder, the costliest step of a
    reception). A datagram this process encoded itself a moment ago (SIL: the simulated senders and the
    host share one process) is already known to be the encoding of its value: when the decoded value is
    that value, node for node and type for type, encoding it again is the same function on the same
    input, and would give the same bytes. Anything else (another process's datagram, a mutated or replayed
    one whose value differs, an entry pushed out) is re-encoded as before, so the verdict never changes.

    Off unless a process turns it on (`remember_own_encodings`): where sender and receiver are separate
    processes (HIL, a car) it would never be asked about its own datagrams, and remembering each one
    (a `repr` of the value) would be pure cost on every encode."""

    # Datagrams are decoded soon after they are sent (the GCDC heat: ~400 a second, delivered within
    # half a second): the newest thousand are plenty.
    SIZE: Final = 1024

    def __init__(self) -> None:
        # An OrderedDict drops its oldest entry in O(1); a dict's first key is found past the slots
        # of every entry deleted since it was last resized.
        self._by_data: collections.OrderedDict[bytes, tuple[Any, str, str]] = collections.OrderedDict()
        self.enabled = False

    def remember(self, data: bytes, spec: Any, type_name: str, value: Any) -> None:
        if not self.enabled:
            return
        entries = self._by_data
        entries.pop(data, None)
        if len(entries) >= self.SIZE:
            entries.popitem(last=False)  # the oldest
        entries[data] = (spec, type_name, _exact(value))

    def clear(self) -> None:
        self._by_data.clear()

    def __len__(self) -> int:
        return len(self._by_data)

    def known(self, data: bytes, spec: Any, type_name: str, value: Any) -> bool:
        """Whether `data` is this process's encoding of `value` by `spec` as `type_name`."""
        entry = self._by_data.get(data)
        return entry is not None and entry[0] is spec and entry[1] == type_name and entry[2] == _exact(value)


_ENCODED = _RecentEncodings()


def remember_own_encodings(enabled: bool = True) -> None:
    """Let the canonical check skip re-encoding the datagrams this process encoded (see
    `_RecentEncodings`): for a process that both sends and receives V2X, as SIL does."""
    _ENCODED.enabled = enabled
    if not enabled:
        _ENCODED.clear()


def check_canonical(
    spec: Any, type_name: str, value: dict[str, Any], data: bytes, what: str, fast: bool = False
) -> None:
    """The datagram must be exactly the UPER encoding of what it decoded to: asn1tools ignores trailing
    bytes, non-zero padding and extension additions it does not know, so a datagram with bytes appended,
    flipped padding bits or unknown extensions is refused (NON_CANONICAL) rather than taken as another.
    `fast`: re-encode with `fast_uper` where it can (its bytes are asn1tools' with its constraints
    checked, which asn1tools without the check gives too), before asking the memory of our own
    encodings: a CAM re-encodes in less time than its value takes to write out for the comparison."""
    again: bytes | None = None
    if fast:
        try:
            again = _fast_encoder(spec, type_name)(value)
        except Unsupported:
            again = None
    if again is None and _ENCODED.known(data, spec, type_name, value):
        return
    try:
        if again is None:
            again = bytes(spec.encode(type_name, value))
    except Exception as e:  # a decoded value that does not encode again: the decoder let garbage through
        raise V2xDecodeError(DecodeReason.NON_CANONICAL, f"{what}: does not encode again ({e})") from None
    if again != data:
        raise V2xDecodeError(
            DecodeReason.NON_CANONICAL,
            f"{what}: {len(data)} bytes received, their canonical encoding is {len(again)} bytes"
            + ("" if len(again) != len(data) else " with other bits (padding or extensions)"),
        )


def resolve_generation_delta(delta_ms: int, reference_time_s: float) -> float:
    """CAM/iCLCM GenerationDeltaTime (TimestampIts mod 65536) -> the UNIX time nearest reference_time_s."""
    ref = unix_to_timestamp_its(reference_time_s)
    back = (ref - delta_ms) % GENERATION_DELTA_MODULO  # how far the latest matching ms lies behind ref
    ts = ref - back if back <= GENERATION_DELTA_MODULO // 2 else ref - back + GENERATION_DELTA_MODULO
    return timestamp_its_to_unix(ts)


def generation_delta(owner: str, generation_time_s: float) -> int:
    """UNIX seconds -> GenerationDeltaTime (TimestampIts mod 65536, EN 302 637-2 B.3)."""
    return timestamp_its_of(owner, generation_time_s) % GENERATION_DELTA_MODULO


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
LANE_POSITION_RANGE: Final = (-1, 14)
_HEADING_DOMAIN_RAD = 2.0 * math.pi + 1e-9  # accept both (-pi, pi] and [0, 2 pi) conventions


def finite(owner: str, name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise V2xEncodeError(f"{owner}.{name}", f"{value!r} is not a number")
    if not math.isfinite(value):
        raise V2xEncodeError(f"{owner}.{name}", f"{value!r} is not a finite number")
    return float(value)


def scaled_to_etsi(
    owner: str, name: str, value: float | None, per_unit: float, lo: int, hi: int, unavailable: int, unit: str
) -> int:
    """value * per_unit rounded to an integer in lo..hi; None -> the unavailable marker."""
    if value is None:
        return unavailable
    x = finite(owner, name, value) * per_unit  # may overflow to inf: then the range test refuses it
    if not (lo - 1 <= x <= hi + 1 and lo <= round(x) <= hi):
        raise V2xEncodeError(
            f"{owner}.{name}",
            f"{value!r} {unit} is outside the encodable range {lo / per_unit:g}..{hi / per_unit:g} {unit}",
        )
    return round(x)


def checked_integer(owner: str, name: str, value: int, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise V2xEncodeError(f"{owner}.{name}", f"{value!r} is not an integer")
    if not lo <= value <= hi:
        raise V2xEncodeError(f"{owner}.{name}", f"{value} is outside {lo}..{hi}")
    return value


def optional_integer(owner: str, name: str, value: int | None, bounds: tuple[int, int]) -> int | None:
    return None if value is None else checked_integer(owner, name, value, *bounds)


def timestamp_its_of(owner: str, value: float) -> int:
    t = finite(owner, "generation_time_s", value)
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


def heading_to_etsi_value(owner: str, value: float | None) -> int:
    if value is None:
        return HEADING_UNAVAILABLE
    h = finite(owner, "heading_rad", value)
    if abs(h) > _HEADING_DOMAIN_RAD:
        raise V2xEncodeError(f"{owner}.heading_rad", f"{value!r} rad is outside -2 pi .. 2 pi")
    return heading_to_etsi(h)


def position_to_etsi(owner: str, lat: float | None, lon: float | None) -> tuple[int, int]:
    return (
        scaled_to_etsi(owner, "lat_deg", lat, 1e7, -900_000_000, 900_000_000, LAT_UNAVAILABLE, "deg"),
        scaled_to_etsi(owner, "lon_deg", lon, 1e7, -1_800_000_000, 1_800_000_000, LON_UNAVAILABLE, "deg"),
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


def yaw_rate_to_etsi(owner: str, value: float | None) -> int:
    """rad/s -> ETSI YawRateValue (0.01 deg/s); the range check is on the degree value."""
    if value is None:
        return YAW_RATE_UNAVAILABLE
    hi = YAW_RATE_OUT_OF_RANGE - 1
    x = math.degrees(finite(owner, "yaw_rate_radps", value)) * 100.0
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
