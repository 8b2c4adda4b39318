"""Typed host <-> ECU messages and their raw <-> SI scaling: the one place the link converts units.

Kammel et al. 2008 (seed 000) Sec. 2.1 / 3: the main computer sends control requests to the low-level
ECU (there over Ethernet, relayed at 1 kHz through the KogMo-RTDB); Geiger et al. 2012 (seed 003)
Sec. II-j / V-B: the low-level controller receives a reference acceleration from the main computer.
Here the requests and the ECU's status travel as CANopen PDOs (DESIGN section 3); the object
dictionary (`protocol/ecu.eds`, records 0x2000 and 0x2100) fixes the layout, this module fixes what
the integers mean. The EDS repeats each factor and unit (`Factor=`, `Unit=`) for tools and the
generated protocol table; `tests/protocol/test_canopen_link.py` checks that the two agree.

Encoding saturates to the integer range of the wire type (a request of -40 m/s^2 becomes the most
negative INTEGER16, -32.768 m/s^2; the ECU clamps to its own limits anyway) and refuses NaN, which
has no meaning on the wire. Decoding refuses enum values the wire contract does not define.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from enum import IntEnum, IntFlag
from typing import TypeVar

from bywire.protocol.ecu_types import EcuState, Fault, Gear, RequestFlags

# CANopen basic data type codes (CiA 301 table 44), as written in the EDS `DataType=` lines.
INTEGER16 = 0x0003
UNSIGNED8 = 0x0005
UNSIGNED16 = 0x0006
UNSIGNED32 = 0x0007

RAW_RANGE: dict[int, tuple[int, int]] = {
    INTEGER16: (-(1 << 15), (1 << 15) - 1),
    UNSIGNED8: (0, (1 << 8) - 1),
    UNSIGNED16: (0, (1 << 16) - 1),
    UNSIGNED32: (0, (1 << 32) - 1),
}
DATA_TYPE_NAME: dict[int, str] = {
    INTEGER16: "INTEGER16",
    UNSIGNED8: "UNSIGNED8",
    UNSIGNED16: "UNSIGNED16",
    UNSIGNED32: "UNSIGNED32",
}

REQUEST_INDEX = 0x2000  # host request record, mapped into RPDO1
STATUS_INDEX = 0x2100  # ECU status record, mapped into TPDO1..3

COUNTER_MODULO = 256  # alive counters are UNSIGNED8 and wrap 255 -> 0


@dataclass(frozen=True, slots=True)
class FieldSpec:
    """One field of a link record: dataclass attribute, OD sub-index, wire type and scaling."""

    name: str
    subindex: int
    data_type: int
    scale: float  # SI units per raw count
    unit: str
    description: str
    # The wire type's range, RAW_RANGE[data_type]: read for every field of every message, so
    # stored once rather than looked up each time.
    raw_min: int = field(init=False, repr=False, compare=False)
    raw_max: int = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        lo, hi = RAW_RANGE[self.data_type]
        object.__setattr__(self, "raw_min", lo)
        object.__setattr__(self, "raw_max", hi)

    @property
    def phys_min(self) -> float:
        return self.raw_min * self.scale

    @property
    def phys_max(self) -> float:
        return self.raw_max * self.scale


REQUEST_FIELDS: tuple[FieldSpec, ...] = (
    FieldSpec("accel_mps2", 1, INTEGER16, 0.001, "m/s^2", "requested longitudinal acceleration"),
    FieldSpec("steer_angle_rad", 2, INTEGER16, 1e-4, "rad", "requested road-wheel angle, + left"),
    FieldSpec("flags", 3, UNSIGNED8, 1, "", "RequestFlags bits"),
    FieldSpec("counter", 4, UNSIGNED8, 1, "", "alive counter, +1 per request, wraps 255 -> 0"),
)

STATUS_FIELDS: tuple[FieldSpec, ...] = (
    FieldSpec("state", 1, UNSIGNED8, 1, "", "EcuState"),
    FieldSpec("faults", 2, UNSIGNED16, 1, "", "Fault bits"),
    FieldSpec("speed_mps", 3, INTEGER16, 0.01, "m/s", "vehicle speed"),
    FieldSpec("accel_mps2", 4, INTEGER16, 0.001, "m/s^2", "measured longitudinal acceleration"),
    FieldSpec("throttle_pct", 5, UNSIGNED16, 0.1, "%", "throttle pedal applied"),
    FieldSpec("brake_bar", 6, UNSIGNED16, 0.01, "bar", "brake pressure applied"),
    FieldSpec("steer_angle_rad", 7, INTEGER16, 1e-4, "rad", "road-wheel angle applied, + left"),
    FieldSpec("lateness_p99_us", 8, UNSIGNED16, 1, "us", "cyclic executive lateness, 99th percentile"),
    FieldSpec("compute_max_us", 9, UNSIGNED16, 1, "us", "cyclic executive compute time, maximum"),
    FieldSpec("overruns", 10, UNSIGNED32, 1, "", "cyclic executive overruns since boot"),
    # Added after the counter (sub-index 12, TPDO2's last byte) so the older fields keep their layout;
    # listed before it because the node takes the first field as the state and the last as the counter.
    FieldSpec("gear", 12, UNSIGNED8, 1, "", "Gear the gateway reports engaged"),
    FieldSpec("counter", 11, UNSIGNED8, 1, "", "status counter, +1 per status update, wraps"),
)

_REQUEST_BY_NAME = {f.name: f for f in REQUEST_FIELDS}
_STATUS_BY_NAME = {f.name: f for f in STATUS_FIELDS}


def encode_value(value: float, spec: FieldSpec, where: str) -> int:
    """SI value -> raw integer, rounded to the nearest count and saturated to the wire type."""
    if value != value:  # NaN
        raise ValueError(f"{where}.{spec.name} is NaN: NaN cannot be sent on the wire")
    counts = value / spec.scale
    # Compare before rounding: round(inf) raises, and huge values need no rounding anyway.
    if counts >= spec.raw_max:
        return spec.raw_max
    if counts <= spec.raw_min:
        return spec.raw_min
    return round(counts)


def decode_value(raw: int, spec: FieldSpec) -> float:
    """Raw integer -> SI value."""
    return float(raw * spec.scale)


def next_counter(counter: int) -> int:
    """The alive counter that follows `counter` (UNSIGNED8, wraps 255 -> 0)."""
    return (counter + 1) % COUNTER_MODULO


def _check_counter(value: int, where: str) -> None:
    if isinstance(value, bool) or not isinstance(value, int):
        raise TypeError(f"{where}.counter must be an int, got {type(value).__name__}")
    if not 0 <= value < COUNTER_MODULO:
        raise ValueError(f"{where}.counter {value} is outside 0..255 (wrap it with next_counter)")


def _check_not_nan(obj: object, names: tuple[str, ...], where: str) -> None:
    for name in names:
        value = getattr(obj, name)
        if value != value and isinstance(value, float):  # NaN is the one float unequal to itself
            raise ValueError(f"{where}.{name} is NaN")


_E = TypeVar("_E", bound=IntEnum)
_F = TypeVar("_F", bound=IntFlag)

# Every status and request converts its state and flag integers; calling an enum class costs
# microseconds of enum machinery. Valid values are looked up in these tables first (filled on
# first use, bounded by the number of valid values: 2**15 fault combinations at most); anything
# else takes the checked path below.
_FLAG_MEMBERS: dict[type, dict[int, IntFlag]] = {}
_KNOWN_BITS: dict[type, int] = {}


def _as_enum(enum_type: type[_E], value: int, where: str) -> _E:
    member = enum_type._value2member_map_.get(value) if type(value) is int else None
    if member is not None:
        return member  # type: ignore[return-value]  # what enum_type(value) returns
    try:
        return enum_type(value)
    except ValueError:
        valid = ", ".join(f"{m.value}={m.name}" for m in enum_type)
        raise ValueError(f"{where}: {value} is not a {enum_type.__name__} ({valid})") from None


def _as_flags(flag_type: type[_F], value: int, where: str) -> _F:
    members = _FLAG_MEMBERS.get(flag_type)
    if members is None:
        members = _FLAG_MEMBERS[flag_type] = {}
    member = members.get(value) if type(value) is int else None
    if member is not None:
        return member  # type: ignore[return-value]
    known = _KNOWN_BITS.get(flag_type)
    if known is None:
        known = 0
        for m in flag_type:
            known |= m.value
        _KNOWN_BITS[flag_type] = known
    if value & ~known:
        raise ValueError(
            f"{where}: bits 0x{value & ~known:X} of 0x{value:X} are not defined in {flag_type.__name__}"
        )
    checked = flag_type(value)
    if type(value) is int:
        members[value] = checked
    return checked


def _raw_field(raw: Mapping[str, int], spec: FieldSpec, where: str) -> int:
    try:
        value = raw[spec.name]
    except KeyError:
        raise ValueError(f"{where}: raw field {spec.name!r} is missing") from None
    if not spec.raw_min <= value <= spec.raw_max:
        raise ValueError(
            f"{where}.{spec.name}: raw {value} outside {DATA_TYPE_NAME[spec.data_type]} "
            f"range {spec.raw_min}..{spec.raw_max}"
        )
    return value


@dataclass(frozen=True, slots=True)
class HostRequest:
    """What the host asks of the ECU each cycle (RPDO1, object 0x2000)."""

    accel_mps2: float
    steer_angle_rad: float
    flags: RequestFlags
    counter: int

    def __post_init__(self) -> None:
        _check_not_nan(self, ("accel_mps2", "steer_angle_rad"), "HostRequest")
        _check_counter(self.counter, "HostRequest")
        flags = _as_flags(RequestFlags, int(self.flags), "HostRequest.flags")
        if flags is not self.flags:
            object.__setattr__(self, "flags", flags)

    def to_raw(self) -> dict[str, int]:
        """Raw integers keyed by field name (REQUEST_FIELDS), saturated to their wire types."""
        f = _REQUEST_BY_NAME
        return {
            "accel_mps2": encode_value(self.accel_mps2, f["accel_mps2"], "HostRequest"),
            "steer_angle_rad": encode_value(self.steer_angle_rad, f["steer_angle_rad"], "HostRequest"),
            "flags": int(self.flags),
            "counter": self.counter,
        }

    @classmethod
    def from_raw(cls, raw: Mapping[str, int]) -> HostRequest:
        """Inverse of to_raw; ValueError names the field that is missing, out of range or undefined."""
        where = "HostRequest"
        accel, steer, flags, counter = (_raw_field(raw, spec, where) for spec in REQUEST_FIELDS)
        f = _REQUEST_BY_NAME
        return cls(
            decode_value(accel, f["accel_mps2"]),
            decode_value(steer, f["steer_angle_rad"]),
            _as_flags(RequestFlags, flags, f"{where}.flags"),
            counter,
        )


@dataclass(frozen=True, slots=True)
class EcuStatus:
    """What the ECU reports each status period (TPDO1..3, object 0x2100)."""

    state: EcuState
    faults: Fault
    speed_mps: float
    accel_mps2: float
    throttle_pct: float
    brake_bar: float
    steer_angle_rad: float
    lateness_p99_us: float
    compute_max_us: float
    overruns: int
    counter: int
    gear: Gear = Gear.DRIVE  # engaged, as the gateway reports it (the speed is a magnitude)

    def __post_init__(self) -> None:
        where = "EcuStatus"
        _check_not_nan(
            self,
            (
                "speed_mps",
                "accel_mps2",
                "throttle_pct",
                "brake_bar",
                "steer_angle_rad",
                "lateness_p99_us",
                "compute_max_us",
            ),
            where,
        )
        _check_counter(self.counter, where)
        state = _as_enum(EcuState, int(self.state), f"{where}.state")
        if state is not self.state:
            object.__setattr__(self, "state", state)
        faults = _as_flags(Fault, int(self.faults), f"{where}.faults")
        if faults is not self.faults:
            object.__setattr__(self, "faults", faults)
        gear = _as_enum(Gear, int(self.gear), f"{where}.gear")
        if gear is not self.gear:
            object.__setattr__(self, "gear", gear)
        if isinstance(self.overruns, bool) or not isinstance(self.overruns, int):
            raise TypeError(f"{where}.overruns must be an int, got {type(self.overruns).__name__}")

    def to_raw(self) -> dict[str, int]:
        """Raw integers keyed by field name (STATUS_FIELDS), saturated to their wire types."""
        raw: dict[str, int] = {}
        for spec, kind in _STATUS_KINDS:
            value = getattr(self, spec.name)
            if kind is _INTEGER:
                raw[spec.name] = int(value)
            elif kind is _SATURATED:
                raw[spec.name] = min(max(int(value), spec.raw_min), spec.raw_max)
            else:
                raw[spec.name] = encode_value(float(value), spec, "EcuStatus")
        return raw

    @classmethod
    def from_raw(cls, raw: Mapping[str, int]) -> EcuStatus:
        """Inverse of to_raw; ValueError names the field that is missing, out of range or undefined."""
        where = "EcuStatus"
        values = [_raw_field(raw, spec, where) for spec in STATUS_FIELDS]  # every field present, in range
        args: dict[str, object] = {}  # by name: the wire table lists the gear before the counter
        for (spec, kind), value in zip(_STATUS_KINDS, values, strict=True):
            if kind is _SCALED:
                args[spec.name] = decode_value(value, spec)
            elif spec.name == "state":
                args[spec.name] = _as_enum(EcuState, value, f"{where}.state")
            elif spec.name == "faults":
                args[spec.name] = _as_flags(Fault, value, f"{where}.faults")
            elif spec.name == "gear":
                args[spec.name] = _as_enum(Gear, value, f"{where}.gear")
            else:
                args[spec.name] = value
        return cls(**args)  # type: ignore[arg-type]


_INTEGER, _SATURATED, _SCALED = "integer", "saturated", "scaled"
# How each status field goes to the wire: as its integer (enums, bits, the counter), saturated
# to the wire type (overruns), or scaled (the physical values).
_STATUS_KINDS: tuple[tuple[FieldSpec, str], ...] = tuple(
    (
        spec,
        _INTEGER
        if spec.name in ("state", "faults", "counter", "gear")
        else (_SATURATED if spec.name == "overruns" else _SCALED),
    )
    for spec in STATUS_FIELDS
)
# HostRequest.from_raw builds the record by position: its wire table must list the fields in field order.
# EcuStatus.from_raw builds by name (its table lists the gear before the counter, see STATUS_FIELDS),
# and the counter must stay last (the node takes it as the TPDOs' counter).
if [f.name for f in fields(HostRequest)] != [spec.name for spec in REQUEST_FIELDS]:
    raise RuntimeError("HostRequest: its wire table does not list the fields in field order")
if {f.name for f in fields(EcuStatus)} != {spec.name for spec in STATUS_FIELDS} or (
    STATUS_FIELDS[0].name,
    STATUS_FIELDS[-1].name,
) != ("state", "counter"):
    raise RuntimeError("EcuStatus: its wire table must name every field, the state first, the counter last")


# --- EMCY (CiA 301 section 7.2.7): 8 bytes = error code u16 LE, error register u8 (object 0x1001),
# then 5 manufacturer bytes: here the ECU's Fault bits u16 LE and 3 reserved zero bytes.

EMCY_STRUCT = struct.Struct("<HBH3x")

# CiA 301 table 21 emergency error codes; 0xFFxx is the device-specific range.
EMCY_CODE_BY_FAULT: dict[Fault, int] = {
    Fault.HOST_HEARTBEAT: 0x8130,  # life guard / heartbeat error
    Fault.VEHICLE_TIMEOUT: 0x8100,  # communication, generic
    Fault.VEHICLE_CORRUPT: 0x8200,  # protocol error
    Fault.CALIBRATION_INVALID: 0x6300,  # device software: data set
    Fault.OVERRUN: 0x6100,  # internal software
    Fault.ESTOP_DISABLE: 0x9000,  # external error
    Fault.ESTOP_PAUSE: 0x9000,
    Fault.DRIVER_OVERRIDE: 0xFF01,
    Fault.ESTOP_TIMEOUT: 0x9000,
    Fault.REQUEST_INVALID: 0x8250,  # RPDO timeout / not processed
    Fault.HOST_STOP_REQUEST: 0xFF02,
    Fault.GEAR_TIMEOUT: 0xFF03,  # the gateway never confirmed a requested gear
    Fault.LOOP_STALL: 0x6100,  # internal software: the cyclic executive stalled
    Fault.INTERNAL_ERROR: 0x6000,  # device software, generic: an exception inside a cycle
    Fault.TX_GUARD: 0xFF04,  # the transmit guard replaced an unsafe command
}
EMCY_ERROR_RESET = 0x0000

# Faults that are a communication problem set error register bit 4; every fault sets bit 0.
_COMMUNICATION_FAULTS = (
    Fault.HOST_HEARTBEAT
    | Fault.VEHICLE_TIMEOUT
    | Fault.VEHICLE_CORRUPT
    | Fault.ESTOP_TIMEOUT
    | Fault.REQUEST_INVALID
)
_COMMUNICATION_BITS = int(_COMMUNICATION_FAULTS)
ERROR_REGISTER_GENERIC = 1 << 0
ERROR_REGISTER_COMMUNICATION = 1 << 4
ERROR_REGISTER_MANUFACTURER = 1 << 7


def emcy_code_for(faults: Fault) -> int:
    """EMCY error code for a fault set: the code of its lowest fault bit; 0x0000 (reset) if none."""
    for fault in Fault:
        if fault and fault in faults:
            return EMCY_CODE_BY_FAULT[fault]
    return EMCY_ERROR_RESET


def error_register_for(faults: Fault) -> int:
    """Object 0x1001 error register for a fault set (CiA 301 section 7.5.2.2)."""
    bits = int(faults)  # plain ints: every Fault operation costs microseconds of enum machinery
    if not bits:
        return 0
    register = ERROR_REGISTER_GENERIC
    if bits & _COMMUNICATION_BITS:
        register |= ERROR_REGISTER_COMMUNICATION
    if bits & ~_COMMUNICATION_BITS:
        register |= ERROR_REGISTER_MANUFACTURER
    return register


@dataclass(frozen=True, slots=True)
class EmcyRecord:
    """One EMCY frame of the ECU, decoded."""

    code: int
    error_register: int
    faults: Fault

    @property
    def is_reset(self) -> bool:
        """An error-reset EMCY (code 0x00xx): all errors cleared."""
        return self.code & 0xFF00 == 0


def encode_emcy(record: EmcyRecord) -> bytes:
    """EmcyRecord -> the 8 EMCY data bytes."""
    return EMCY_STRUCT.pack(record.code, record.error_register, int(record.faults))


def decode_emcy(data: bytes | bytearray) -> EmcyRecord:
    """The 8 EMCY data bytes -> EmcyRecord; ValueError on a wrong length or undefined fault bits."""
    if len(data) != EMCY_STRUCT.size:
        raise ValueError(f"EMCY frame has {len(data)} data bytes, expected {EMCY_STRUCT.size}")
    code, register, faults = EMCY_STRUCT.unpack(bytes(data))
    return EmcyRecord(code, register, _as_flags(Fault, faults, "EMCY faults"))
