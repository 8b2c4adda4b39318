"""Vehicle-CAN codec: typed frames <-> `protocol/vehicle.dbc`, with E2E protection.

DESIGN section 3. The DBC is the single source of truth for ids, signals, scaling, ranges and cycle
times; this module only names each signal's field in a typed frame (SI units in the field names) and
checks on load that the DBC and the code agree (units, enum values, CRC/counter layout), so a DBC edit
that would change a meaning fails loudly instead of silently rescaling a command.

Two vehicle profiles (`VEHICLE_PROFILES`) say what is spoken on the bus. `bywire` (the default, below):
every message is ours, our drive-by-wire gateway reports the car. `pq` (`vehicle_pq`): the car's own
VW PQ messages (opendbc's `vw_pq.dbc`) for what the car reports, with their XOR checksums and
counters where the car has them, and ours (`vehicle_pq.dbc`) for the gateway's command, the E-stop,
the INS, the arm button and the radar. A typed frame means the same in both; which message carries
it is the profile's.

Messages of the bywire profile (all 8 bytes, byte 0 = CRC, byte 1 low nibble = alive counter, see `e2e`):

    ESTOP_Radio    0x0F0  ESTOP   -> ECU, GATEWAY  50 ms  `EstopRadio`
    DBW_Command    0x100  ECU     -> GATEWAY       10 ms  `DbwCommand`
    GW_WheelSpeeds 0x120  GATEWAY -> ECU           10 ms  `WheelSpeeds`
    GW_Motion      0x121  GATEWAY -> ECU           10 ms  `Motion`
    GW_Driver      0x122  GATEWAY -> ECU           10 ms  `DriverInputs`
    GW_Steer       0x123  GATEWAY -> ECU           10 ms  `SteerReport`
    RADAR_Target   0x300  RADAR   -> HOST          50 ms  `RadarTarget`

Senders use `VehicleCodec.encode` (or `VehicleTx`, which also keeps the alive counters). Receivers
use `vehicle_rx.VehicleRx` (alias `FrameMonitor`), which never raises on bus input: it rejects
malformed, corrupt, stale, repeated and out-of-order frames, counts each kind, and tracks freshness
per message.

Signal packing is cantools' (non-strict encode after our own range check on raw integers, which is
exact where float comparisons at the range ends are not). Range checks work on raw values: a value
within half an LSB outside the DBC range rounds onto the range end and is accepted.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from enum import IntEnum
from importlib import resources
from pathlib import Path
from typing import Any, Final, Literal, NamedTuple

import can
import cantools
import cantools.database

from bywire.protocol.e2e import (
    COUNTER_MODULO,
    RejectReason,
    TxCounter,
    e2e_crc,
)
from bywire.protocol.ecu_types import EcuState, EstopMode, Gear
from bywire.protocol.timebase import data_frame

__all__ = [
    "VEHICLE_PROFILES",
    "BrakePressure",
    "BrakeSwitch",
    "DbwCommand",
    "DriverInputs",
    "EstopRadio",
    "FrameError",
    "GasPedal",
    "GearReport",
    "InertialReport",
    "Motion",
    "RadarTarget",
    "RejectReason",
    "SafetyArmButton",
    "SteerReport",
    "VehicleCodec",
    "VehicleFrame",
    "VehicleTx",
    "WheelSpeeds",
    "default_dbc_path",
    "xor_checksum",
]

CRC_START_BIT, CRC_BITS = 0, 8  # the E2E layout every message of ours must have (checked at load)
COUNTER_START_BIT, COUNTER_BITS = 8, 4
VEHICLE_PROFILES = ("bywire", "pq")  # what the vehicle CAN speaks: see the module docstring
# How a message is protected (MessageInfo.checksum): our E2E CRC-8 over the frame id and bytes 1..,
# the VW PQ XOR of the other data bytes, or nothing (a car message that carries no checksum).
CHECKSUM_E2E, CHECKSUM_XOR, CHECKSUM_NONE = "e2e_crc8", "xor", "none"
# Packaged DBCs that only load with cantools' strict checks off: opendbc's vw_pq.dbc writes Motor_2's
# multiplexer as `m`, not `M`, so strict cantools calls the multiplexed signals overlapping.
LENIENT_DBCS = frozenset({"vw_pq.dbc"})


# -- typed frames ---------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class EstopRadio:
    """ESTOP_Radio (0x0F0): E-stop radio receiver state (DARPA Urban Challenge rules 3.4.2)."""

    mode: EstopMode


@dataclass(frozen=True, slots=True)
class DbwCommand:
    """DBW_Command (0x100): the ECU's actuator command to the drive-by-wire gateway."""

    throttle_pct: float  # ThrottlePedal, 0..100 %
    brake_bar: float  # BrakePressure, master-cylinder pressure request, 0..200 bar
    steer_angle_rad: float  # SteerAngle, road-wheel angle, positive left (ISO 8855), +-0.6 rad
    engage: bool
    park_brake: bool
    ignition: bool
    steer_enable: bool
    ecu_state: EcuState
    gear_request: Gear = Gear.DRIVE  # GearRequest: the gateway shifts only at standstill, brake applied


@dataclass(frozen=True, slots=True)
class WheelSpeeds:
    """GW_WheelSpeeds (0x120): wheel speed magnitudes, unsigned; the direction of travel is the engaged
    gear (`Motion.gear_engaged`)."""

    fl_mps: float
    fr_mps: float
    rl_mps: float
    rr_mps: float

    @property
    def mean_mps(self) -> float:
        return (self.fl_mps + self.fr_mps + self.rl_mps + self.rr_mps) / 4.0

    @property
    def max_mps(self) -> float:
        """The fastest wheel: the car is at standstill only when every wheel is."""
        return max(self.fl_mps, self.fr_mps, self.rl_mps, self.rr_mps)


@dataclass(frozen=True, slots=True)
class Motion:
    """GW_Motion (0x121): INS longitudinal acceleration (gravity removed, signed in the vehicle frame,
    + forward), yaw rate, brake pressure, and the gear the gateway reports engaged."""

    long_accel_mps2: float
    yaw_rate_radps: float
    brake_bar_actual: float
    gear_engaged: Gear = Gear.DRIVE


@dataclass(frozen=True, slots=True)
class DriverInputs:
    """GW_Driver (0x122): the driver's pedals, for driver-intervention detection, and the safety
    driver's arm button (the human act that re-arms the ECU after DISABLE or MANUAL)."""

    brake_pedal_pressed: bool
    throttle_pedal_pct: float
    brake_pedal_pct: float
    safety_arm: bool = False


@dataclass(frozen=True, slots=True)
class SteerReport:
    """GW_Steer (0x123): measured road-wheel angle and the driver's steering torque."""

    steer_angle_rad: float
    steer_torque_nm: float


@dataclass(frozen=True, slots=True)
class RadarTarget:
    """RADAR_Target (0x300): the front radar's nearest in-lane target."""

    valid: bool
    range_m: float
    range_rate_mps: float
    azimuth_rad: float


@dataclass(frozen=True, slots=True)
class InertialReport:
    """GW_Inertial (profile pq): the INS's longitudinal acceleration (gravity removed, vehicle frame,
    + forward) and yaw rate: `Motion`'s INS half, which no PQ message of the car carries."""

    long_accel_mps2: float
    yaw_rate_radps: float


@dataclass(frozen=True, slots=True)
class SafetyArmButton:
    """GW_Arm (profile pq): the safety driver's arm button on our gateway (`DriverInputs.safety_arm`)."""

    safety_arm: bool


@dataclass(frozen=True, slots=True)
class BrakePressure:
    """Bremse_5 (profile pq): the ESP's measured brake pressure."""

    brake_bar_actual: float


@dataclass(frozen=True, slots=True)
class GearReport:
    """Getriebe_1 (profile pq): the gearbox's selector position, as the gear the ECU drives in."""

    gear_engaged: Gear


@dataclass(frozen=True, slots=True)
class BrakeSwitch:
    """Motor_2 (profile pq): the brake light switch, the driver's foot on the brake pedal."""

    brake_pedal_pressed: bool


@dataclass(frozen=True, slots=True)
class GasPedal:
    """Motor_3 (profile pq): the accelerator pedal as the engine reads it."""

    throttle_pedal_pct: float


VehicleFrame = (
    EstopRadio
    | DbwCommand
    | WheelSpeeds
    | Motion
    | DriverInputs
    | SteerReport
    | RadarTarget
    | InertialReport
    | SafetyArmButton
    | BrakePressure
    | GearReport
    | BrakeSwitch
    | GasPedal
)
FrameKey = int | str | type  # a frame id, a DBC message name, or a typed-frame class


# -- the code's half of the schema: which field is which signal, in which unit -----------------------

# float, bool, enum: one signal each. magnitude (profile pq): a float sent as a magnitude signal and
# a sign signal (1 = negative), as VW does. mapped (profile pq): an enum whose raw values are the
# car's, not the enum's own (a selector position -> Gear).
_Kind = Literal["float", "bool", "enum", "magnitude", "mapped"]


@dataclass(frozen=True, slots=True)
class _Field:
    name: str
    signal: str
    kind: _Kind
    unit: str | None = None  # the unit the DBC must declare (floats)
    enum: type[IntEnum] | None = None


def _num(name: str, signal: str, unit: str) -> _Field:
    return _Field(name, signal, "float", unit=unit)


def _flag(name: str, signal: str) -> _Field:
    return _Field(name, signal, "bool")


def _enum(name: str, signal: str, enum: type[IntEnum]) -> _Field:
    return _Field(name, signal, "enum", enum=enum)


_ESTOP: Final = ("ESTOP_Radio", (_enum("mode", "EstopMode", EstopMode),))
_COMMAND: Final = (
    "DBW_Command",
    (
        _num("throttle_pct", "ThrottlePedal", "%"),
        _num("brake_bar", "BrakePressure", "bar"),
        _num("steer_angle_rad", "SteerAngle", "rad"),
        _flag("engage", "Engage"),
        _flag("park_brake", "ParkBrake"),
        _flag("ignition", "Ignition"),
        _flag("steer_enable", "SteerEnable"),
        _enum("ecu_state", "EcuState", EcuState),
        _enum("gear_request", "GearRequest", Gear),
    ),
)
_RADAR: Final = (
    "RADAR_Target",
    (
        _flag("valid", "TargetValid"),
        _num("range_m", "Range", "m"),
        _num("range_rate_mps", "RangeRate", "m/s"),
        _num("azimuth_rad", "Azimuth", "rad"),
    ),
)

_Layout = dict[type, tuple[str, tuple[_Field, ...]]]
_LAYOUT: Final[_Layout] = {
    EstopRadio: _ESTOP,
    DbwCommand: _COMMAND,
    WheelSpeeds: (
        "GW_WheelSpeeds",
        (
            _num("fl_mps", "WheelSpeed_FL", "m/s"),
            _num("fr_mps", "WheelSpeed_FR", "m/s"),
            _num("rl_mps", "WheelSpeed_RL", "m/s"),
            _num("rr_mps", "WheelSpeed_RR", "m/s"),
        ),
    ),
    Motion: (
        "GW_Motion",
        (
            _num("long_accel_mps2", "LongAccel", "m/s2"),
            _num("yaw_rate_radps", "YawRate", "rad/s"),
            _num("brake_bar_actual", "BrakePressureActual", "bar"),
            _enum("gear_engaged", "GearEngaged", Gear),
        ),
    ),
    DriverInputs: (
        "GW_Driver",
        (
            _flag("brake_pedal_pressed", "BrakePedalPressed"),
            _num("throttle_pedal_pct", "ThrottlePedalDriver", "%"),
            _num("brake_pedal_pct", "BrakePedalDriver", "%"),
            _flag("safety_arm", "SafetyArm"),
        ),
    ),
    SteerReport: (
        "GW_Steer",
        (
            _num("steer_angle_rad", "SteerAngleActual", "rad"),
            _num("steer_torque_nm", "SteerTorqueDriver", "Nm"),
        ),
    ),
    RadarTarget: _RADAR,
}
# Profile pq: the messages that stay ours (`vehicle_pq.dbc`); the car's are in `vehicle_pq`.
_PQ_OWN_LAYOUT: Final[_Layout] = {
    EstopRadio: _ESTOP,
    DbwCommand: _COMMAND,
    InertialReport: (
        "GW_Inertial",
        (_num("long_accel_mps2", "LongAccel", "m/s2"), _num("yaw_rate_radps", "YawRate", "rad/s")),
    ),
    SafetyArmButton: ("GW_Arm", (_flag("safety_arm", "SafetyArm"),)),
    RadarTarget: _RADAR,
}


# -- errors -------------------------------------------------------------------------------------


class FrameError(ValueError):
    """A received frame that cannot be used: `frame_id`, `reason` (a RejectReason) and `detail`."""

    def __init__(self, frame_id: int, reason: RejectReason, detail: str) -> None:
        super().__init__(f"vehicle CAN frame {frame_id:#05x}: {reason.value}: {detail}")
        self.frame_id = frame_id
        self.reason = reason
        self.detail = detail


# -- the compiled schema --------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class SignalInfo:
    """One DBC signal as the codec uses it: scaling and the allowed raw range (DBC min/max)."""

    field: str
    signal: str
    kind: _Kind
    enum: type[IntEnum] | None
    scale: float
    offset: float
    minimum: float
    maximum: float
    raw_min: int
    raw_max: int
    unit: str
    # Where the raw value sits in the payload read as one little-endian integer (DBC @1 signals):
    # taken from cantools' model of the DBC, so the codec packs bits itself instead of going through
    # cantools' general-purpose encoder for every frame (a third of a SIL millisecond).
    start: int = 0
    mask: int = 0
    sign_bit: int = 0  # 0 for unsigned signals
    sign_start: int = -1  # kind "magnitude": the start bit of its 1-bit sign signal (1 = negative)
    mapping: tuple[tuple[int, IntEnum], ...] = ()  # kind "mapped": (raw value, member) pairs

    def mapping_text(self) -> str:
        """The raw values a "mapped" signal takes, for error messages: `5 (DRIVE), 7 (REVERSE)`."""
        return ", ".join(f"{raw} ({member.name})" for raw, member in self.mapping)


@dataclass(frozen=True, slots=True)
class MessageInfo:
    """One DBC message as the codec uses it."""

    name: str
    frame_id: int
    frame_type: type
    length: int
    cycle_time_s: float
    receivers: frozenset[str]
    senders: tuple[str, ...]
    crc_signal: str  # "" where the message has no checksum
    counter_signal: str  # "" where the message has no alive counter
    signals: tuple[SignalInfo, ...]
    message: Any  # cantools.database.can.Message (cantools ships no type stubs)
    checksum: str = CHECKSUM_E2E  # CHECKSUM_E2E | CHECKSUM_XOR | CHECKSUM_NONE
    checksum_byte: int = CRC_START_BIT // 8
    counter_start: int | None = COUNTER_START_BIT  # None: the message has no alive counter
    # The payload bits (data read as one little-endian integer) that are neither checksum nor counter:
    # decoding is a function of these alone.
    value_mask: int = -1 << (COUNTER_START_BIT + COUNTER_BITS)


def default_dbc_path(name: str = "vehicle.dbc") -> Path:
    """The packaged `vehicle.dbc` (or another DBC of bywire.protocol)."""
    return Path(str(resources.files("bywire.protocol").joinpath(name)))


def _bit_range(length: int, signed: bool) -> tuple[int, int]:
    return (-(1 << (length - 1)), (1 << (length - 1)) - 1) if signed else (0, (1 << length) - 1)


def _compile(db: Any, where: str, layout: _Layout = _LAYOUT) -> dict[int, MessageInfo]:
    by_name = {m.name: m for m in db.messages}
    expected = {name for name, _ in layout.values()}
    missing = sorted(expected - by_name.keys())
    extra = sorted(by_name.keys() - expected)
    if missing or extra:
        raise ValueError(
            f"{where}: DBC and bywire.protocol.vehicle_can disagree: "
            f"messages missing from the DBC {missing}, messages without a typed frame {extra}"
        )
    infos: dict[int, MessageInfo] = {}
    for frame_type, (name, fields) in layout.items():
        msg = by_name[name]
        here = f"{where}: message {name} ({msg.frame_id:#05x})"
        if msg.is_extended_frame or msg.frame_id > 0x7FF:
            raise ValueError(f"{here}: must be a standard 11-bit frame (the E2E data id is 2 bytes)")
        if msg.length < 2:
            raise ValueError(f"{here}: length {msg.length} cannot hold the CRC and counter bytes")
        if not msg.cycle_time or msg.cycle_time <= 0:
            raise ValueError(f"{here}: no GenMsgCycleTime (receivers derive timeouts from it)")
        sigs = {s.name: s for s in msg.signals}
        for suffix, start, length in (
            ("_CRC", CRC_START_BIT, CRC_BITS),
            ("_Counter", COUNTER_START_BIT, COUNTER_BITS),
        ):
            s = sigs.get(name + suffix)
            if s is None or (s.start, s.length, s.byte_order, s.is_signed, s.scale, s.offset) != (
                start,
                length,
                "little_endian",
                False,
                1,
                0,
            ):
                raise ValueError(
                    f"{here}: signal {name}{suffix} must be {start}|{length}@1+ (1,0) for the E2E layout"
                )
        infos_sig = []
        for f in fields:
            s = sigs.get(f.signal)
            if s is None:
                raise ValueError(f"{here}: signal {f.signal} (field {frame_type.__name__}.{f.name}) missing")
            sig_where = f"{here} signal {f.signal}"
            if s.is_float or s.byte_order != "little_endian":
                raise ValueError(f"{sig_where}: only little-endian integer signals are supported")
            if s.start < COUNTER_START_BIT + COUNTER_BITS:
                raise ValueError(f"{sig_where}: overlaps the E2E CRC byte or counter nibble")
            unit = s.unit or ""
            if f.kind == "float" and unit != f.unit:
                raise ValueError(
                    f"{sig_where}: unit {unit!r}, but field {frame_type.__name__}.{f.name} is in {f.unit!r}"
                )
            if f.kind == "bool" and (s.length != 1 or s.scale != 1 or s.offset != 0):
                raise ValueError(f"{sig_where}: a flag must be 1 bit, (1,0)")
            if f.kind == "enum":
                assert f.enum is not None
                if s.scale != 1 or s.offset != 0:
                    raise ValueError(f"{sig_where}: an enumeration must be scaled (1,0)")
                for value, label in (s.choices or {}).items():
                    member = f.enum._value2member_map_.get(value)
                    if member is None or member.name != str(label):
                        raise ValueError(
                            f"{sig_where}: VAL_ {value} {str(label)!r} does not match {f.enum.__name__}"
                        )
            lo_bits, hi_bits = _bit_range(s.length, s.is_signed)
            minimum = s.minimum if s.minimum is not None else lo_bits * s.scale + s.offset
            maximum = s.maximum if s.maximum is not None else hi_bits * s.scale + s.offset
            # The range ends need not sit on the LSB grid: keep only raw values whose physical value
            # is inside [min, max] (the 1e-6 LSB slack absorbs binary rounding of e.g. 81.91 / 0.01).
            raw_min = math.ceil((minimum - s.offset) / s.scale - 1e-6)
            raw_max = math.floor((maximum - s.offset) / s.scale + 1e-6)
            if raw_min < lo_bits or raw_max > hi_bits or raw_min > raw_max:
                raise ValueError(
                    f"{sig_where}: range [{minimum}, {maximum}] does not fit {s.length} "
                    f"{'signed' if s.is_signed else 'unsigned'} bits at scale {s.scale}"
                )
            infos_sig.append(
                SignalInfo(
                    field=f.name,
                    signal=f.signal,
                    kind=f.kind,
                    enum=f.enum,
                    scale=s.scale,
                    offset=s.offset,
                    minimum=minimum,
                    maximum=maximum,
                    raw_min=raw_min,
                    raw_max=raw_max,
                    unit=unit,
                    start=s.start,
                    mask=(1 << s.length) - 1,
                    sign_bit=(1 << (s.length - 1)) if s.is_signed else 0,
                )
            )
        undecoded = sorted(sigs.keys() - {f.signal for f in fields} - {name + "_CRC", name + "_Counter"})
        if undecoded:
            raise ValueError(f"{here}: signals {undecoded} have no field in {frame_type.__name__}")
        infos[msg.frame_id] = MessageInfo(
            name=name,
            frame_id=msg.frame_id,
            frame_type=frame_type,
            length=msg.length,
            cycle_time_s=msg.cycle_time / 1000.0,
            receivers=frozenset(msg.receivers),
            senders=tuple(msg.senders),
            crc_signal=name + "_CRC",
            counter_signal=name + "_Counter",
            signals=tuple(infos_sig),
            message=msg,
        )
    return infos


def load_dbc(dbc_path: Path | None, resource_name: str, *, strict: bool = True) -> Any:
    """A cantools database from `dbc_path`, or from the packaged `resource_name` when None (read
    through importlib.resources: inside the firmware zipapp the DBC is not a file); ValueError
    naming the file if it cannot be loaded."""
    where = dbc_path if dbc_path is not None else resource_name
    try:
        resource = (
            resources.files("bywire.protocol").joinpath(resource_name) if dbc_path is None else dbc_path
        )
        return cantools.database.load_string(
            resource.read_text(encoding="utf-8"), database_format="dbc", strict=strict
        )
    except (OSError, UnicodeDecodeError, cantools.database.Error) as exc:
        raise ValueError(f"{where}: cannot load the vehicle DBC: {exc}") from exc


class VehicleCodec:
    """Typed frames <-> CAN messages per the vehicle DBC (default: the packaged `vehicle.dbc`).

    `profile` "pq" speaks the VW PQ car's own reports (`vehicle_pq`): `dbc_path` then names our half
    (default the packaged `vehicle_pq.dbc`), the car's half is the packaged `vw_pq.dbc`.
    Loading checks that the DBC and the typed frames agree; any mismatch raises ValueError naming the
    file, message and signal.
    """

    def __init__(self, dbc_path: Path | str | None = None, *, profile: str = "bywire") -> None:
        if profile not in VEHICLE_PROFILES:
            raise ValueError(f"vehicle profile {profile!r}: expected one of {', '.join(VEHICLE_PROFILES)}")
        self.profile = profile
        path = Path(dbc_path) if dbc_path is not None else None
        if profile == "pq":
            from bywire.protocol.vehicle_pq import PQ_DBC_RESOURCE, compile_pq

            self.dbc_path = path if path is not None else default_dbc_path("vehicle_pq.dbc")
            own = _compile(load_dbc(path, "vehicle_pq.dbc"), str(self.dbc_path), _PQ_OWN_LAYOUT)
            lenient = PQ_DBC_RESOURCE in LENIENT_DBCS
            car = compile_pq(load_dbc(None, PQ_DBC_RESOURCE, strict=not lenient), PQ_DBC_RESOURCE)
            clash = sorted(own.keys() & car.keys())
            if clash:
                raise ValueError(f"{self.dbc_path}: frame ids {clash} are the car's (vw_pq.dbc)")
            self._by_id = {**own, **car}
        else:
            self.dbc_path = path if path is not None else default_dbc_path()
            self._by_id = _compile(load_dbc(path, "vehicle.dbc"), str(self.dbc_path))
        self._by_name = {info.name: info for info in self._by_id.values()}
        self._by_type = {info.frame_type: info for info in self._by_id.values()}
        self._packers = {info.frame_id: _generate_packers(info) for info in self._by_id.values()}

    # -- schema lookups --

    @property
    def messages(self) -> tuple[MessageInfo, ...]:
        """All messages, in frame-id order."""
        return tuple(self._by_id[k] for k in sorted(self._by_id))

    def info(self, key: FrameKey) -> MessageInfo:
        """The message named by a frame id, a DBC message name or a typed-frame class."""
        found: MessageInfo | None
        if isinstance(key, bool):
            found = None
        elif isinstance(key, int):
            found = self._by_id.get(key)
        elif isinstance(key, str):
            found = self._by_name.get(key)
        else:
            found = self._by_type.get(key)
        if found is None:
            raise ValueError(f"{key!r} is not a message of the vehicle DBC {self.dbc_path}")
        return found

    def lookup_id(self, frame_id: int) -> MessageInfo | None:
        """The message with standard frame id `frame_id`, or None."""
        return self._by_id.get(frame_id)

    def received_by(self, node: str) -> tuple[str, ...]:
        """Names of the messages the DBC lists `node` (e.g. "ECU") as a receiver of."""
        return tuple(info.name for info in self.messages if node in info.receivers)

    # -- encoding --

    def encode(
        self, frame: VehicleFrame, counter: int, *, saturate: bool = False, timestamp_s: float = 0.0
    ) -> can.Message:
        """The CAN message for `frame` with alive `counter` (0..15) and its CRC.

        Values outside the DBC range raise ValueError naming message, signal and field, unless
        `saturate` (a simulated sensor clamps to its range like a real one). NaN always raises.
        """
        info = self._by_type.get(type(frame))
        if info is None:
            raise TypeError(f"cannot encode {type(frame).__name__}: not a vehicle-CAN frame type")
        if isinstance(counter, bool) or not isinstance(counter, int) or not 0 <= counter < COUNTER_MODULO:
            raise ValueError(f"{info.name}: alive counter {counter!r} outside 0..{COUNTER_MODULO - 1}")
        packers = self._packers[info.frame_id]
        start = info.counter_start
        counted = counter << start if start is not None else 0
        payload = (packers.pack_saturating if saturate else packers.pack)(frame, counted)
        if payload is None:  # a value the generated packer does not take as it is
            payload = pack_general(info, frame, counted, saturate)
        data = bytearray(payload.to_bytes(info.length, "little"))
        if info.checksum == CHECKSUM_E2E:
            data[0] = e2e_crc(info.frame_id, data)
        elif info.checksum == CHECKSUM_XOR:
            data[info.checksum_byte] = xor_checksum(data, info.checksum_byte)
        return data_frame(info.frame_id, data, timestamp_s)

    # -- decoding --

    def check_structure(self, msg: can.Message) -> MessageInfo:
        """The message `msg` claims to be; FrameError(malformed) if it cannot be one of ours."""
        frame_id = msg.arbitration_id
        if msg.is_error_frame:
            raise FrameError(frame_id, RejectReason.MALFORMED, "error frame")
        if msg.is_extended_id:
            raise FrameError(frame_id, RejectReason.MALFORMED, "extended (29-bit) id: vehicle CAN is 11-bit")
        info = self._by_id.get(frame_id)
        if info is None:
            raise FrameError(frame_id, RejectReason.MALFORMED, "unknown frame id")
        if msg.is_remote_frame:
            raise FrameError(frame_id, RejectReason.MALFORMED, f"{info.name}: remote frame")
        if msg.is_fd:
            raise FrameError(frame_id, RejectReason.MALFORMED, f"{info.name}: CAN FD frame on classical CAN")
        n = len(msg.data)
        if n != info.length or msg.dlc != info.length:
            raise FrameError(
                frame_id,
                RejectReason.MALFORMED,
                f"{info.name}: DLC {msg.dlc} with {n} data bytes, expected {info.length}",
            )
        return info

    def check_crc(self, info: MessageInfo, data: bytes | bytearray) -> None:
        """FrameError(corrupt) unless `data` carries its message's checksum: byte 0 the E2E CRC of
        `info`'s frame id and data, or (profile pq) the XOR of the other bytes; nothing to check for
        a car message without a checksum."""
        if info.checksum == CHECKSUM_E2E:
            expected = e2e_crc(info.frame_id, data)
        elif info.checksum == CHECKSUM_XOR:
            expected = xor_checksum(data, info.checksum_byte)
        else:
            return
        if data[info.checksum_byte] != expected:
            raise crc_error(info, data, expected)

    def decode_payload(self, info: MessageInfo, data: bytes | bytearray) -> tuple[VehicleFrame, int | None]:
        """(typed frame, alive counter or None for a message without one) of a structurally valid
        payload; FrameError(malformed) if a value lies outside its DBC range or names no enum member.
        The checksum is not checked here."""
        payload = int.from_bytes(data, "little")
        start = info.counter_start
        counter = (payload >> start) & (COUNTER_MODULO - 1) if start is not None else None
        frame = self._packers[info.frame_id].unpack(payload)
        if frame is not None:
            return frame, counter
        return unpack_general(info, payload), counter

    def decode(self, msg: can.Message) -> VehicleFrame:
        """The typed frame in `msg`, checking structure, CRC and DBC ranges (not the counter or age:
        that needs receiver state, see `VehicleRx`). Raises FrameError(frame_id, reason, detail)."""
        info = self.check_structure(msg)
        self.check_crc(info, msg.data)
        return self.decode_payload(info, msg.data)[0]


def pack_general(info: MessageInfo, frame: VehicleFrame, payload: int, saturate: bool) -> int:
    """`payload` with the raw value of every signal of `frame` or'ed in, signal by signal through
    `_to_raw`; ValueError naming message, signal and field for a value that cannot be sent. The
    reference for the generated packers, and their fallback for anything but the plain case."""
    for sig in info.signals:
        try:
            raw = _to_raw(sig, getattr(frame, sig.field), saturate)
        except ValueError as exc:
            where = f"{info.name}.{sig.signal} ({info.frame_type.__name__}.{sig.field})"
            raise ValueError(f"{where}: {exc}") from None
        if sig.kind == "magnitude":
            # _to_raw gave the signed count; VW sends its magnitude and a sign bit (1 = negative).
            if raw < 0:
                payload |= 1 << sig.sign_start
            raw = -raw if raw < 0 else raw
        payload |= (raw & sig.mask) << sig.start
    return payload


def unpack_general(info: MessageInfo, payload: int) -> VehicleFrame:
    """The typed frame in `payload` (the data bytes read as one little-endian integer), signal by
    signal; FrameError(malformed) naming the signal if a value lies outside its DBC range or names
    no enum member. The reference for the generated `unpack`, and what says why it declined."""
    values: dict[str, object] = {}
    for sig in info.signals:
        r = (payload >> sig.start) & sig.mask
        if r & sig.sign_bit:
            r -= sig.mask + 1
        if sig.kind == "mapped":
            found = dict(sig.mapping).get(r)
            if found is None:
                raise FrameError(
                    info.frame_id,
                    RejectReason.MALFORMED,
                    f"{info.name}.{sig.signal} = {r} is none of {sig.mapping_text()}",
                )
            values[sig.field] = found
            continue
        if not sig.raw_min <= r <= sig.raw_max:
            raise FrameError(
                info.frame_id,
                RejectReason.MALFORMED,
                f"{info.name}.{sig.signal} = {r * sig.scale + sig.offset:g} {sig.unit} (raw {r}) "
                f"outside the DBC range [{sig.minimum:g}, {sig.maximum:g}]",
            )
        if sig.kind == "float":
            values[sig.field] = r * sig.scale + sig.offset
        elif sig.kind == "magnitude":
            v = r * sig.scale + sig.offset
            values[sig.field] = -v if (payload >> sig.sign_start) & 1 else v
        elif sig.kind == "bool":
            values[sig.field] = bool(r)
        else:
            assert sig.enum is not None
            member = sig.enum._value2member_map_.get(r)
            if member is None:
                raise FrameError(
                    info.frame_id,
                    RejectReason.MALFORMED,
                    f"{info.name}.{sig.signal} = {r} is not a {sig.enum.__name__}",
                )
            values[sig.field] = member
    return info.frame_type(**values)  # type: ignore[no-any-return]


class _Packers(NamedTuple):
    pack: Callable[[Any, int], int | None]
    pack_saturating: Callable[[Any, int], int | None]
    unpack: Callable[[int], Any]


def _generate_packers(info: MessageInfo) -> _Packers:
    """Straight-line packers for one message, generated from its SignalInfo when the DBC is loaded.

    `pack(frame, payload)` / `pack_saturating(...)` return `payload` with every signal's raw value
    or'ed in, as `pack_general` computes it (the same expressions on the same constants, so the
    same bits); `unpack(payload)` returns the typed frame as `unpack_general` builds it. Each
    returns None for anything but the plain case (a value of another type, out of range, NaN, an
    unknown enum value), and the general code then computes the result or raises its precise
    error: the generated code only ever takes the fast path, it never decides an error.
    The general loop, with a function call and a getattr per signal, cost about half of a frame's
    encoding; tests/protocol/test_vehicle_can_packers.py holds the two to the same results.
    """
    if any(sig.kind not in ("float", "bool", "enum") for sig in info.signals):
        # The car's VW messages (profile pq) go through the general code: a sign-magnitude pair or a
        # selector table has no straight-line form here, and the receiver caches decoded frames.
        return _Packers(_decline_pack, _decline_pack, _decline_unpack)
    ns: dict[str, Any] = {"_T": info.frame_type, "_float": float}
    pack: list[str] = []
    pack_sat: list[str] = []
    unpack: list[str] = []
    args: list[str] = []
    for k, sig in enumerate(info.signals):
        ns.update({f"_O{k}": sig.offset, f"_S{k}": sig.scale, f"_LO{k}": sig.raw_min, f"_HI{k}": sig.raw_max})
        get = f"    v = frame.{sig.field}\n"
        put = f"    p |= (r & {sig.mask}) << {sig.start}\n"
        if sig.kind == "float":
            conv = "    if type(v) is not float:\n        v = _float(v)\n"
            pack.append(
                get + conv + f"    r = round((v - _O{k}) / _S{k})\n"
                f"    if not _LO{k} <= r <= _HI{k}:\n        return None\n" + put
            )
            pack_sat.append(
                get + conv + "    if v != v:\n        return None\n"
                f"    s = (v - _O{k}) / _S{k}\n"
                f"    r = round(_LO{k} if s < _LO{k} else (_HI{k} if s > _HI{k} else s))\n" + put
            )
        elif sig.kind == "bool":
            code = get + "    if v is not True and v is not False:\n        return None\n"
            code += f"    if v:\n        p |= {1 << sig.start}\n"
            pack.append(code)
            pack_sat.append(code)
        else:
            assert sig.enum is not None
            ns[f"_E{k}"] = sig.enum
            ns[f"_M{k}"] = sig.enum._value2member_map_
            code = get + f"    if type(v) is not _E{k}:\n        return None\n    r = v._value_\n"
            code += f"    if not _LO{k} <= r <= _HI{k}:\n        return None\n" + put
            pack.append(code)
            pack_sat.append(code)
        extract = f"    r = (p >> {sig.start}) & {sig.mask}\n"
        if sig.sign_bit:
            extract += f"    if r & {sig.sign_bit}:\n        r -= {sig.mask + 1}\n"
        extract += f"    if not _LO{k} <= r <= _HI{k}:\n        return None\n"
        if sig.kind == "float":
            extract += f"    a{k} = r * _S{k} + _O{k}\n"
        elif sig.kind == "bool":
            extract += f"    a{k} = r != 0\n"
        else:
            extract += f"    a{k} = _M{k}.get(r)\n    if a{k} is None:\n        return None\n"
        unpack.append(extract)
        args.append(f"{sig.field}=a{k}")
    guard = "    try:\n" + "".join("    " + line + "\n" for line in "".join(pack).splitlines())
    guard_sat = "    try:\n" + "".join("    " + line + "\n" for line in "".join(pack_sat).splitlines())
    # float() of a non-number and round() of NaN or an infinity raise: the general path says what.
    catch = "    except (TypeError, ValueError, OverflowError):\n        return None\n    return p\n"
    src = (
        f"def pack(frame, p):\n{guard}{catch}"
        f"def pack_saturating(frame, p):\n{guard_sat}{catch}"
        f"def unpack(p):\n{''.join(unpack)}    return _T({', '.join(args)})\n"
    )
    exec(compile(src, f"<packers of {info.name}>", "exec"), ns)
    return _Packers(ns["pack"], ns["pack_saturating"], ns["unpack"])


def _decline_pack(frame: Any, payload: int) -> None:
    return None


def _decline_unpack(payload: int) -> None:
    return None


def crc_error(info: MessageInfo, data: bytes | bytearray, expected: int) -> FrameError:
    what = "CRC" if info.checksum == CHECKSUM_E2E else "checksum"
    return FrameError(
        info.frame_id,
        RejectReason.CORRUPT,
        f"{info.name}: {what} {data[info.checksum_byte]:#04x}, expected {expected:#04x}",
    )


def xor_checksum(data: bytes | bytearray | memoryview, checksum_byte: int) -> int:
    """The VW PQ checksum: the XOR of every data byte but the checksum's own (opendbc's
    `xor_checksum`, panda's `volkswagen_pq_compute_checksum`)."""
    x = 0
    for i, byte in enumerate(data):
        if i != checksum_byte:
            x ^= byte
    return x


def _to_raw(sig: SignalInfo, value: object, saturate: bool) -> int:
    """The raw integer for a field value; ValueError (without the where, see `encode`) if invalid."""
    kind = sig.kind
    if kind == "bool":
        if value not in (0, 1):
            raise ValueError(f"{value!r} is not a flag (bool)")
        return 1 if value else 0
    if kind == "mapped":
        for raw_value, member in sig.mapping:
            if value is member:
                return raw_value
        raise ValueError(f"{value!r} is none of {sig.mapping_text()}")
    if kind == "enum":
        assert sig.enum is not None
        if type(value) is sig.enum:
            member = value  # already a member: what sig.enum(value) would return, at no cost
        else:
            if isinstance(value, IntEnum) and not isinstance(value, sig.enum):
                raise ValueError(f"{value!r} is not a {sig.enum.__name__}")
            try:
                member = sig.enum(value)  # type: ignore[arg-type]
            except ValueError:
                raise ValueError(f"{value!r} is not a {sig.enum.__name__}") from None
        if not sig.raw_min <= member.value <= sig.raw_max:
            raise ValueError(f"{member!r} does not fit the DBC range")
        return int(member.value)
    if type(value) is float:
        v = value
    else:
        try:
            v = float(value)  # type: ignore[arg-type]
        except (TypeError, ValueError):
            raise ValueError(f"{value!r} is not a number") from None
    if v != v:
        raise ValueError("NaN")
    negative = kind == "magnitude" and v < 0.0
    if negative:
        v = -v  # the range is the magnitude's; the sign goes in its own bit (pack_general)
    scaled = (v - sig.offset) / sig.scale
    if saturate:
        lo, hi = sig.raw_min, sig.raw_max
        clamped = round(lo if scaled < lo else (hi if scaled > hi else scaled))
        return -clamped if negative else clamped
    raw = round(scaled) if math.isfinite(scaled) else None
    if raw is None or not sig.raw_min <= raw <= sig.raw_max:
        shown = -v if negative else v
        span = "magnitude " if kind == "magnitude" else ""
        raise ValueError(f"{shown} {sig.unit} outside the DBC {span}range [{sig.minimum:g}, {sig.maximum:g}]")
    return -raw if negative else raw


class VehicleTx:
    """A sender's side: encodes typed frames with the next alive counter of each message."""

    def __init__(self, codec: VehicleCodec | None = None) -> None:
        self.codec = codec if codec is not None else VehicleCodec()
        self.counters = TxCounter()

    def encode(self, frame: VehicleFrame, *, saturate: bool = False, timestamp_s: float = 0.0) -> can.Message:
        """`codec.encode` with this sender's next counter for the frame's message; a frame that
        fails to encode does not use up a counter value."""
        info = self.codec._by_type.get(type(frame))
        frame_id = (info if info is not None else self.codec.info(type(frame))).frame_id
        msg = self.codec.encode(
            frame, self.counters.peek(frame_id), saturate=saturate, timestamp_s=timestamp_s
        )
        self.counters.next(frame_id)
        return msg
