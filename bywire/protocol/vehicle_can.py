"""Vehicle-CAN codec: typed frames <-> `protocol/vehicle.dbc`, with E2E protection.

DESIGN section 3. The DBC is the single source of truth for ids, signals, scaling, ranges and cycle
times; this module only names each signal's field in a typed frame (SI units in the field names) and
checks on load that the DBC and the code agree (units, enum values, CRC/counter layout), so a DBC edit
that would change a meaning fails loudly instead of silently rescaling a command.

Messages (all 8 bytes, byte 0 = CRC, byte 1 low nibble = alive counter, see `e2e`):

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
    "DbwCommand",
    "DriverInputs",
    "EstopRadio",
    "FrameError",
    "Motion",
    "RadarTarget",
    "RejectReason",
    "SteerReport",
    "VehicleCodec",
    "VehicleFrame",
    "VehicleTx",
    "WheelSpeeds",
    "default_dbc_path",
]

CRC_START_BIT, CRC_BITS = 0, 8  # the E2E layout every message must have (checked at load)
COUNTER_START_BIT, COUNTER_BITS = 8, 4


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


VehicleFrame = EstopRadio | DbwCommand | WheelSpeeds | Motion | DriverInputs | SteerReport | RadarTarget
FrameKey = int | str | type  # a frame id, a DBC message name, or a typed-frame class


# -- the code's half of the schema: which field is which signal, in which unit -----------------------

_Kind = Literal["float", "bool", "enum"]


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


_LAYOUT: Final[dict[type, tuple[str, tuple[_Field, ...]]]] = {
    EstopRadio: ("ESTOP_Radio", (_enum("mode", "EstopMode", EstopMode),)),
    DbwCommand: (
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
    ),
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
    RadarTarget: (
        "RADAR_Target",
        (
            _flag("valid", "TargetValid"),
            _num("range_m", "Range", "m"),
            _num("range_rate_mps", "RangeRate", "m/s"),
            _num("azimuth_rad", "Azimuth", "rad"),
        ),
    ),
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
    crc_signal: str
    counter_signal: str
    signals: tuple[SignalInfo, ...]
    message: Any  # cantools.database.can.Message (cantools ships no type stubs)


def default_dbc_path() -> Path:
    """The packaged `vehicle.dbc` (bywire.protocol)."""
    return Path(str(resources.files("bywire.protocol").joinpath("vehicle.dbc")))


def _bit_range(length: int, signed: bool) -> tuple[int, int]:
    return (-(1 << (length - 1)), (1 << (length - 1)) - 1) if signed else (0, (1 << length) - 1)


def _compile(db: Any, where: str) -> dict[int, MessageInfo]:
    by_name = {m.name: m for m in db.messages}
    expected = {name for name, _ in _LAYOUT.values()}
    missing = sorted(expected - by_name.keys())
    extra = sorted(by_name.keys() - expected)
    if missing or extra:
        raise ValueError(
            f"{where}: DBC and bywire.protocol.vehicle_can disagree: "
            f"messages missing from the DBC {missing}, messages without a typed frame {extra}"
        )
    infos: dict[int, MessageInfo] = {}
    for frame_type, (name, fields) in _LAYOUT.items():
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


class VehicleCodec:
    """Typed frames <-> CAN messages per the vehicle DBC (default: the packaged `vehicle.dbc`).

    Loading checks that the DBC and the typed frames agree; any mismatch raises ValueError naming the
    file, message and signal.
    """

    def __init__(self, dbc_path: Path | str | None = None) -> None:
        self.dbc_path = Path(dbc_path) if dbc_path is not None else default_dbc_path()
        try:
            # Read through importlib.resources: inside the firmware zipapp the DBC is not a file.
            resource = (
                resources.files("bywire.protocol").joinpath("vehicle.dbc")
                if dbc_path is None
                else self.dbc_path
            )
            db = cantools.database.load_string(
                resource.read_text(encoding="utf-8"), database_format="dbc", strict=True
            )
        except (OSError, UnicodeDecodeError, cantools.database.Error) as exc:
            raise ValueError(f"{self.dbc_path}: cannot load the vehicle DBC: {exc}") from exc
        self._by_id = _compile(db, str(self.dbc_path))
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
        payload = (packers.pack_saturating if saturate else packers.pack)(frame, counter << COUNTER_START_BIT)
        if payload is None:  # a value the generated packer does not take as it is
            payload = pack_general(info, frame, counter << COUNTER_START_BIT, saturate)
        data = bytearray(payload.to_bytes(info.length, "little"))
        data[0] = e2e_crc(info.frame_id, data)
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
        """FrameError(corrupt) unless byte 0 of `data` is the E2E CRC of `info`'s frame id and data."""
        expected = e2e_crc(info.frame_id, data)
        if data[0] != expected:
            raise crc_error(info, data, expected)

    def decode_payload(self, info: MessageInfo, data: bytes | bytearray) -> tuple[VehicleFrame, int]:
        """(typed frame, alive counter) of a structurally valid payload; FrameError(malformed) if a
        value lies outside its DBC range or names no enum member. The CRC is not checked here."""
        payload = int.from_bytes(data, "little")
        frame = self._packers[info.frame_id].unpack(payload)
        if frame is not None:
            return frame, (payload >> COUNTER_START_BIT) & (COUNTER_MODULO - 1)
        return unpack_general(info, payload), (payload >> COUNTER_START_BIT) & (COUNTER_MODULO - 1)

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
        if not sig.raw_min <= r <= sig.raw_max:
            raise FrameError(
                info.frame_id,
                RejectReason.MALFORMED,
                f"{info.name}.{sig.signal} = {r * sig.scale + sig.offset:g} {sig.unit} (raw {r}) "
                f"outside the DBC range [{sig.minimum:g}, {sig.maximum:g}]",
            )
        if sig.kind == "float":
            values[sig.field] = r * sig.scale + sig.offset
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


def crc_error(info: MessageInfo, data: bytes | bytearray, expected: int) -> FrameError:
    return FrameError(
        info.frame_id, RejectReason.CORRUPT, f"{info.name}: CRC {data[0]:#04x}, expected {expected:#04x}"
    )


def _to_raw(sig: SignalInfo, value: object, saturate: bool) -> int:
    """The raw integer for a field value; ValueError (without the where, see `encode`) if invalid."""
    kind = sig.kind
    if kind == "bool":
        if value not in (0, 1):
            raise ValueError(f"{value!r} is not a flag (bool)")
        return 1 if value else 0
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
    scaled = (v - sig.offset) / sig.scale
    if saturate:
        lo, hi = sig.raw_min, sig.raw_max
        return round(lo if scaled < lo else (hi if scaled > hi else scaled))
    raw = round(scaled) if math.isfinite(scaled) else None
    if raw is None or not sig.raw_min <= raw <= sig.raw_max:
        raise ValueError(f"{v} {sig.unit} outside the DBC range [{sig.minimum:g}, {sig.maximum:g}]")
    return raw


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
