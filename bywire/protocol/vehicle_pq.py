"""Vehicle profile `pq`: the VW PQ35/PQ46 (Passat B6) car's own reports, read from opendbc's `vw_pq.dbc`.

DESIGN section 3: the car's own signals can be spoken in the real VW PQ messages of opendbc's
`vw_pq.dbc` with their real counters and checksums; the drive-by-wire gateway's command and the
E-stop stay ours (`vehicle_pq.dbc`, on ids the PQ bus does not use). `vw_pq.dbc` here is a subset of
opendbc's file (MIT, `vw_pq.LICENSE`), its messages unchanged; `vehicle_can.VehicleCodec(profile="pq")`
loads both halves.

What the car reports, and where (`PQ_LAYOUT`); a typed frame means what it means in the bywire profile:

    Lenkhilfe_3  0x0D0  10 ms  XOR + counter  `SteerReport`    LH3_BLW/LH3_BLWSign, LH3_LM/LH3_LMSign
    Motor_2      0x288  20 ms  -              `BrakeSwitch`    MO2_BLS
    Motor_3      0x380  10 ms  -              `GasPedal`       MO3_Pedalwert
    Getriebe_1   0x440  10 ms  counter        `GearReport`     GE1_Wahl_Pos (D 5, R 7)
    Bremse_3     0x4A0  10 ms  -              `WheelSpeeds`    Radgeschw__{VL,VR,HL,HR}_4_1
    Bremse_5     0x4A8  20 ms  XOR + counter  `BrakePressure`  BR5_Bremsdruck/BR5_Sign_Druck

Checksums and counters are opendbc's rule for `vw_pq` (opendbc/can/dbc.py): a signal named CHECKSUM is
the XOR of the other data bytes (`vehicle_can.xor_checksum`), a signal named COUNTER the 4-bit alive
counter; both are checked exactly as our own CRC and counter are (`vehicle_rx`). Where the car sends
neither (Bremse_3, Motor_2, Motor_3; panda checks them by timing alone), a receiver can judge a frame
only by its structure, its ranges and its age: a frozen sender there repeats a valid frame unseen.

Conversions at the edge, into the SI fields: km/h -> m/s, degrees -> radians, the steering-wheel angle
-> the road-wheel angle through `STEERING_RATIO`, the EPS's driver torque in cNm (opendbc's panda
limits: 300 = 3.0 Nm) -> Nm. Signs are VW's: a magnitude and a sign bit, 1 = negative (to the right).
The selector position maps D to `Gear.DRIVE` and R to `Gear.REVERSE`; any other position (P, N,
the sport and tiptronic gates) is a frame the ECU cannot drive on and is refused as malformed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Final

from bywire.protocol.ecu_types import Gear
from bywire.protocol.vehicle_can import (
    CHECKSUM_NONE,
    CHECKSUM_XOR,
    COUNTER_BITS,
    BrakePressure,
    BrakeSwitch,
    GasPedal,
    GearReport,
    MessageInfo,
    SignalInfo,
    SteerReport,
    WheelSpeeds,
    _bit_range,
)

__all__ = [
    "PQ_DBC_RESOURCE",
    "PQ_LAYOUT",
    "REPORT_MESSAGES",
    "STEERING_RATIO",
    "compile_pq",
    "report_messages",
]

PQ_DBC_RESOURCE = "vw_pq.dbc"
CHECKSUM_SIGNAL, COUNTER_SIGNAL = "CHECKSUM", "COUNTER"  # opendbc's names for vw_pq
# Steering-wheel angle per road-wheel angle: the Passat model's ratio (vehicle_models/passat/README.md,
# about 14). A car with another rack needs its own: the EPS reports the wheel in the driver's hands.
STEERING_RATIO = 14.0
_KMH = 1.0 / 3.6
_DEG = math.pi / 180.0
_CNM = 0.01


@dataclass(frozen=True, slots=True)
class PqField:
    """One field of a typed frame in one car signal: `factor` converts the DBC's unit into the field's
    SI unit; `sign` names the sign signal of a magnitude; `mapping` the raw values of a selector."""

    name: str
    signal: str
    unit: str  # the unit the DBC declares ("" where opendbc leaves it out)
    si_unit: str = ""  # the field's unit, what errors show
    factor: float = 1.0
    sign: str | None = None
    mapping: tuple[tuple[int, Gear], ...] = ()
    flag: bool = False


def _wheel(name: str, signal: str) -> PqField:
    return PqField(name, signal, "km/h", "m/s", _KMH)


# Typed frame -> (message, fields); every message's receivers are the ECU (the car's reports).
PQ_LAYOUT: Final[dict[type, tuple[str, tuple[PqField, ...]]]] = {
    SteerReport: (
        "Lenkhilfe_3",
        (
            PqField("steer_angle_rad", "LH3_BLW", "", "rad", _DEG / STEERING_RATIO, sign="LH3_BLWSign"),
            PqField("steer_torque_nm", "LH3_LM", "", "Nm", _CNM, sign="LH3_LMSign"),
        ),
    ),
    BrakeSwitch: ("Motor_2", (PqField("brake_pedal_pressed", "MO2_BLS", "", flag=True),)),
    GasPedal: ("Motor_3", (PqField("throttle_pedal_pct", "MO3_Pedalwert", "%", "%"),)),
    GearReport: (
        "Getriebe_1",
        (PqField("gear_engaged", "GE1_Wahl_Pos", "", mapping=((5, Gear.DRIVE), (7, Gear.REVERSE))),),
    ),
    WheelSpeeds: (
        "Bremse_3",
        (
            _wheel("fl_mps", "Radgeschw__VL_4_1"),
            _wheel("fr_mps", "Radgeschw__VR_4_1"),
            _wheel("rl_mps", "Radgeschw__HL_4_1"),
            _wheel("rr_mps", "Radgeschw__HR_4_1"),
        ),
    ),
    BrakePressure: (
        "Bremse_5",
        (PqField("brake_bar_actual", "BR5_Bremsdruck", "bar", "bar", sign="BR5_Sign_Druck"),),
    ),
}

# The bywire profile's gateway reports and the messages that carry the same on the PQ bus: a scenario's
# frame faults name the former and hit the latter (GW_Motion's INS half stays ours, GW_Inertial).
REPORT_MESSAGES: Final[dict[str, tuple[str, ...]]] = {
    "GW_WheelSpeeds": ("Bremse_3",),
    "GW_Motion": ("GW_Inertial", "Bremse_5", "Getriebe_1"),
    "GW_Driver": ("Motor_2", "Motor_3", "GW_Arm"),
    "GW_Steer": ("Lenkhilfe_3",),
}


def report_messages(names: tuple[str, ...]) -> tuple[str, ...]:
    """`names` with each bywire gateway report replaced by the PQ profile's messages that carry it."""
    out: list[str] = []
    for name in names:
        for msg in REPORT_MESSAGES.get(name, (name,)):
            if msg not in out:
                out.append(msg)
    return tuple(out)


def _signal_info(f: PqField, s: Any, sigs: dict[str, Any], where: str) -> SignalInfo:
    here = f"{where} signal {f.signal}"
    if s.is_float or s.byte_order != "little_endian" or s.is_signed:
        raise ValueError(f"{here}: only unsigned little-endian integer signals are read")
    if (s.unit or "") != f.unit:
        raise ValueError(f"{here}: unit {s.unit!r}, expected {f.unit!r} (the conversion to SI assumes it)")
    sign_start = -1
    if f.sign is not None:
        sign = sigs.get(f.sign)
        if sign is None or sign.length != 1 or sign.byte_order != "little_endian":
            raise ValueError(f"{where}: sign signal {f.sign} of {f.signal} missing or not 1 bit")
        sign_start = sign.start
    if f.mapping:
        if s.scale != 1 or s.offset != 0:
            raise ValueError(f"{here}: a selector must be scaled (1,0)")
        labels = {int(v): str(name) for v, name in (s.choices or {}).items()}
        for raw, member in f.mapping:
            if raw not in labels:
                raise ValueError(f"{here}: value {raw} ({member.name}) has no VAL_ entry")
    if f.flag and (s.length != 1 or s.scale != 1 or s.offset != 0):
        raise ValueError(f"{here}: a flag must be 1 bit, (1,0)")
    # opendbc's ranges may reach past what the bits hold (LH3_BLW: [0|615] deg in 12 bits of 0.15 deg,
    # 614.25 at most): the range is what both allow.
    lo_bits, hi_bits = _bit_range(s.length, False)
    raw_min = (
        lo_bits if s.minimum is None else max(lo_bits, math.ceil((s.minimum - s.offset) / s.scale - 1e-6))
    )
    raw_max = (
        hi_bits if s.maximum is None else min(hi_bits, math.floor((s.maximum - s.offset) / s.scale + 1e-6))
    )
    minimum, maximum = raw_min * s.scale + s.offset, raw_max * s.scale + s.offset
    kind = "mapped" if f.mapping else "bool" if f.flag else "magnitude" if f.sign else "float"
    return SignalInfo(
        field=f.name,
        signal=f.signal,
        kind=kind,  # type: ignore[arg-type]
        enum=Gear if f.mapping else None,
        scale=s.scale * f.factor,
        offset=s.offset * f.factor,
        minimum=minimum * f.factor,
        maximum=maximum * f.factor,
        raw_min=raw_min,
        raw_max=raw_max,
        unit=f.si_unit,
        start=s.start,
        mask=(1 << s.length) - 1,
        sign_start=sign_start,
        mapping=tuple(f.mapping),
    )


def compile_pq(db: Any, where: str) -> dict[int, MessageInfo]:
    """The car's messages of `PQ_LAYOUT` from opendbc's vw_pq database `db`, as the codec uses them;
    ValueError naming the file, message and signal where the DBC is not what the layout reads."""
    by_name = {m.name: m for m in db.messages}
    infos: dict[int, MessageInfo] = {}
    for frame_type, (name, fields) in PQ_LAYOUT.items():
        msg = by_name.get(name)
        if msg is None:
            raise ValueError(f"{where}: message {name} ({frame_type.__name__}) missing")
        here = f"{where}: message {name} ({msg.frame_id:#05x})"
        if msg.is_extended_frame or not msg.cycle_time:
            raise ValueError(f"{here}: must be a standard frame with a GenMsgCycleTime")
        sigs = {s.name: s for s in msg.signals}
        checksum = sigs.get(CHECKSUM_SIGNAL)
        counter = sigs.get(COUNTER_SIGNAL)
        if checksum is not None and (checksum.length != 8 or checksum.start % 8):
            raise ValueError(f"{here}: CHECKSUM must be a whole byte")
        if counter is not None and counter.length != COUNTER_BITS:
            raise ValueError(f"{here}: COUNTER must be {COUNTER_BITS} bits")
        protected = 0
        if checksum is not None:
            protected |= 0xFF << checksum.start
        if counter is not None:
            protected |= ((1 << COUNTER_BITS) - 1) << counter.start
        signals = []
        for f in fields:
            s = sigs.get(f.signal)
            if s is None:
                raise ValueError(f"{here}: signal {f.signal} (field {frame_type.__name__}.{f.name}) missing")
            signals.append(_signal_info(f, s, sigs, here))
        full = (1 << (8 * msg.length)) - 1
        info = MessageInfo(
            name=name,
            frame_id=msg.frame_id,
            frame_type=frame_type,
            length=msg.length,
            cycle_time_s=msg.cycle_time / 1000.0,
            receivers=frozenset({"ECU"}),
            senders=("CAR",),
            crc_signal=CHECKSUM_SIGNAL if checksum is not None else "",
            counter_signal=COUNTER_SIGNAL if counter is not None else "",
            signals=tuple(signals),
            message=msg,
            checksum=CHECKSUM_XOR if checksum is not None else CHECKSUM_NONE,
            checksum_byte=checksum.start // 8 if checksum is not None else 0,
            counter_start=counter.start if counter is not None else None,
            value_mask=full & ~protected,
        )
        infos[msg.frame_id] = info
    return infos
