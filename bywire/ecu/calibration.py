"""Vehicle calibration of the ECU: limits, controller gains and the pedal feedforward maps.

Paper: seed 003 Sec. V-B (the low-level controller's two pedal feedforward couplings, which "largely
differ between both pedals", are data, identified per vehicle); the limits follow DESIGN section 4
and seed 003 Sec. V-A (-4.5 <= a <= 2.0 m/s^2).

A `Calibration` can only be built through `calibration_from_dict`, which validates everything the
controller relies on (finite numbers, ranges, grid shapes, monotone maps), so the 1 kHz code never
re-checks. On disk and over SDO it is canonical JSON with a CRC-32:

    canonical(d) = json.dumps(d, sort_keys=True, separators=(",", ":"), ensure_ascii=True)
    crc32        = zlib.crc32(canonical(file without its "crc32" key)) as an unsigned integer

The CRC is computed over the parsed document, so indentation does not matter but every value does
(50 and 50.0 are different documents). `format` names the schema (`FORMAT`); `version` is the
calibration's own revision number (an integer >= 1, bumped on every re-identification), which the
store may use to refuse downgrades.

Pure Python and stdlib only: the firmware is a zipapp without numpy.
"""

from __future__ import annotations

import datetime
import functools
import json
import math
import os
import re
import zlib
from dataclasses import MISSING, dataclass, field, fields
from importlib import resources
from typing import Any, TypeVar

__all__ = [
    "FORMAT",
    "BrakeMap",
    "Calibration",
    "CalibrationError",
    "CoastMap",
    "ThrottleMap",
    "calibration_from_dict",
    "calibration_to_dict",
    "default_calibration",
    "dumps_calibration",
    "load_calibration",
    "loads_calibration",
]

FORMAT = "bywire.calibration/1"

# Wire ranges of the vehicle-CAN command frame (protocol/vehicle.dbc BO_ 256 DBW_Command): nothing
# in a calibration may ask for more than the frame can carry.
THROTTLE_PCT_MAX = 100.0  # ThrottlePedal [0|100] %
BRAKE_BAR_MAX = 200.0  # BrakePressure [0|200] bar
STEER_ANGLE_WIRE_MAX_RAD = 0.6  # SteerAngle [-0.6|0.6] rad


_T = TypeVar("_T")


def fast_frozen_init(cls: type[_T]) -> type[_T]:
    """Give a frozen, slotted dataclass an __init__ that stores through the slot descriptors.

    Used on the dataclasses built every 1 ms cycle (inputs, states, commands). The __init__ that
    dataclasses generates for a frozen class calls object.__setattr__ once per field: about
    0.45 us per field on the target machine, 8 us for the 18 fields of the ECU inputs. The slot
    descriptors' __set__ stores the same in about a quarter of that. The class stays a frozen
    dataclass (eq, repr, replace, no assignment after construction); plain field defaults are
    kept, default factories are not supported. (Lives here because every ecu module already
    imports this one.)"""
    fs = fields(cls)  # type: ignore[arg-type]
    if any(f.default_factory is not MISSING for f in fs):
        raise TypeError(f"{cls.__name__}: fast_frozen_init does not support default factories")
    names = [f.name for f in fs]
    # Plain defaults (immutable values) are kept: dataclass already checked their order.
    params = ", ".join(f"{f.name}=_d_{f.name}" if f.default is not MISSING else f.name for f in fs)
    if all(f.kw_only for f in fs):
        params = "*, " + params
    ns: dict[str, Any] = {f"_set_{n}": getattr(cls, n).__set__ for n in names}
    ns.update({f"_d_{f.name}": f.default for f in fs if f.default is not MISSING})
    src = f"def __init__(self, {params}):\n" + "".join(f"    _set_{n}(self, {n})\n" for n in names)
    exec(src, ns)
    ns["__init__"].__qualname__ = f"{cls.__qualname__}.__init__"
    cls.__init__ = ns["__init__"]  # type: ignore[method-assign]
    return cls


class CalibrationError(ValueError):
    """A calibration was refused. `field` is the dotted path ("brake_map.bar[3]", "" for the whole
    document), `source` the file or "<dict>"; the message says what was expected."""

    def __init__(self, field: str, source: str, message: str) -> None:
        self.field = field
        self.source = source
        self.message = message
        where = f"{source}: {field}" if field else source
        super().__init__(f"{where}: {message}")


@dataclass(frozen=True, slots=True)
class ThrottleMap:
    """Throttle pedal needed to reach an acceleration at a speed on a level road (bilinear).

    `pct[i][j]` is for `speed_mps[i]` and `accel_mps2[j]`; each row is non-decreasing in
    acceleration. Outside the grid the nearest edge value holds."""

    speed_mps: tuple[float, ...]
    accel_mps2: tuple[float, ...]
    pct: tuple[tuple[float, ...], ...]
    # Derived: per row, the first index at which the row reaches its last (top) value, so that the
    # controller finds the throttle's saturation point in O(1).
    top_index: tuple[int, ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "top_index", tuple(row.index(row[-1]) for row in self.pct))


@dataclass(frozen=True, slots=True)
class BrakeMap:
    """Brake pressure needed for a deceleration beyond coasting (1-D, non-decreasing)."""

    decel_mps2: tuple[float, ...]
    bar: tuple[float, ...]
    # Derived: the deceleration at which the map reaches its top pressure (the brake's saturation).
    decel_top_mps2: float = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "decel_top_mps2", self.decel_mps2[self.bar.index(self.bar[-1])])


@dataclass(frozen=True, slots=True)
class CoastMap:
    """Acceleration with both pedals released on a level road (drag + rolling), by speed."""

    speed_mps: tuple[float, ...]
    accel_mps2: tuple[float, ...]


@dataclass(frozen=True, slots=True)
class Calibration:
    """One vehicle's ECU calibration; build it with `calibration_from_dict` (validated)."""

    format: str
    version: int
    vehicle: str
    created: str  # ISO 8601 date or date-time
    # limits
    accel_min_mps2: float  # request clamp, seed 003 V-A: -4.5
    accel_max_mps2: float  # request clamp, seed 003 V-A: 2.0
    jerk_max_mps3: float  # rate limit of the acceleration target
    steer_max_rad: float  # road-wheel angle clamp
    steer_rate_max_radps: float  # road-wheel angle rate clamp
    pause_decel_mps2: float  # E-stop PAUSE "prompt stop" (DARPA rules 3.4.2)
    disable_decel_mps2: float  # E-stop DISABLE "prompt stop"
    safe_stop_decel_mps2: float  # controlled stop on a fault
    hold_brake_bar: float  # standstill hold pressure, sized for a steep slope
    standstill_speed_mps: float  # below this the car is taken as stopped and held
    stop_margin_s: float  # slack in every stop's deadline (core.stop_time_bound_s)
    driver_torque_threshold_nm: float  # |driver steer torque| above this is an override
    driver_throttle_threshold_pct: float  # driver throttle above this is an override
    # gains
    ki_per_s: float  # integral gain of the acceleration loop, (m/s^2 per s) per (m/s^2)
    integrator_max_mps2: float  # integrator clamp
    switch_freeze_s: float  # no integration this long after a pedal switch
    throttle_lag_s: float  # identified drive-force lag behind the throttle (reference model)
    brake_lag_s: float  # identified brake-pressure lag (reference model)
    pedal_hysteresis_mps2: float  # half-width of the pedal-switch band around coasting
    # maps
    throttle_map: ThrottleMap
    brake_map: BrakeMap
    coast_map: CoastMap


# name -> (min, max, why). Bounds are inclusive; a bound of None is open-ended.
_RANGES: dict[str, tuple[float, float, str]] = {
    "accel_min_mps2": (-10.0, -0.5, "a deceleration limit, about -1 g .. -0.5 m/s^2"),
    "accel_max_mps2": (0.5, 5.0, "an acceleration limit, 0.5 .. 5 m/s^2"),
    "jerk_max_mps3": (0.5, 50.0, "a jerk limit, 0.5 .. 50 m/s^3"),
    "steer_max_rad": (0.01, STEER_ANGLE_WIRE_MAX_RAD, "a road-wheel angle 0.01 .. 0.6 rad (DBC range)"),
    "steer_rate_max_radps": (0.01, 3.0, "a road-wheel rate 0.01 .. 3 rad/s"),
    "pause_decel_mps2": (0.5, 10.0, "a positive deceleration, 0.5 .. 10 m/s^2"),
    "disable_decel_mps2": (0.5, 10.0, "a positive deceleration, 0.5 .. 10 m/s^2"),
    "safe_stop_decel_mps2": (0.5, 10.0, "a positive deceleration, 0.5 .. 10 m/s^2"),
    "hold_brake_bar": (5.0, BRAKE_BAR_MAX, "a hold pressure 5 .. 200 bar"),
    "standstill_speed_mps": (0.01, 1.0, "a speed 0.01 .. 1 m/s"),
    "stop_margin_s": (0.0, 30.0, "a time 0 .. 30 s"),
    "driver_torque_threshold_nm": (0.1, 20.0, "a torque 0.1 .. 20 Nm (DBC SteerTorqueDriver range)"),
    "driver_throttle_threshold_pct": (0.1, 50.0, "a pedal position 0.1 .. 50 %"),
    "ki_per_s": (0.0, 20.0, "an integral gain 0 .. 20 1/s"),
    "integrator_max_mps2": (0.0, 5.0, "an acceleration 0 .. 5 m/s^2"),
    "switch_freeze_s": (0.0, 5.0, "a time 0 .. 5 s"),
    "throttle_lag_s": (0.0, 2.0, "a time constant 0 .. 2 s"),
    "brake_lag_s": (0.0, 2.0, "a time constant 0 .. 2 s"),
    "pedal_hysteresis_mps2": (0.0, 1.0, "an acceleration 0 .. 1 m/s^2"),
}
_MAP_KEYS: dict[str, tuple[str, ...]] = {
    "throttle_map": ("speed_mps", "accel_mps2", "pct"),
    "brake_map": ("decel_mps2", "bar"),
    "coast_map": ("speed_mps", "accel_mps2"),
}
_TOP_KEYS = ("format", "version", "vehicle", "created", *_RANGES, *_MAP_KEYS)
_NUMBER_ARRAY = re.compile(r"\[\s*([-+0-9.eE,\s]+?)\s*\]")
_MAX_GRID = 64  # per axis; keeps a map lookup cheap inside the 1 ms cycle


def _check_keys(
    d: Any, where: str, expected: tuple[str, ...], source: str, extra: tuple[str, ...] = ()
) -> None:
    if not isinstance(d, dict):
        raise CalibrationError(where, source, f"expected a JSON object, got {type(d).__name__}")
    for k in d:
        if k not in expected and k not in extra:
            path = f"{where}.{k}" if where else str(k)
            raise CalibrationError(path, source, f"unknown key (expected one of: {', '.join(expected)})")
    for k in expected:
        if k not in d:
            path = f"{where}.{k}" if where else k
            raise CalibrationError(path, source, "missing")


def _number(x: Any, path: str, source: str) -> float:
    # bool is an int in Python; `true` is never a valid calibration number.
    if isinstance(x, bool) or not isinstance(x, int | float):
        raise CalibrationError(path, source, f"expected a number, got {type(x).__name__} {x!r}")
    v = float(x)
    if not math.isfinite(v):
        raise CalibrationError(path, source, f"expected a finite number, got {x!r}")
    return v


def _ranged(x: Any, path: str, source: str, lo: float, hi: float, what: str) -> float:
    v = _number(x, path, source)
    if not lo <= v <= hi:
        raise CalibrationError(path, source, f"{v!r} out of range: expected {what}")
    return v


def _vector(x: Any, path: str, source: str, lo: float, hi: float, unit: str) -> tuple[float, ...]:
    if not isinstance(x, list):
        raise CalibrationError(path, source, f"expected a JSON array of numbers, got {type(x).__name__}")
    if not 2 <= len(x) <= _MAX_GRID:
        raise CalibrationError(path, source, f"expected 2 .. {_MAX_GRID} values, got {len(x)}")
    out = tuple(_number(v, f"{path}[{i}]", source) for i, v in enumerate(x))
    for i, v in enumerate(out):
        if not lo <= v <= hi:
            raise CalibrationError(
                f"{path}[{i}]", source, f"{v!r} out of range: expected {lo} .. {hi} {unit}"
            )
    return out


def _monotone(v: tuple[float, ...], path: str, source: str, *, strict: bool, increasing: bool) -> None:
    if increasing:
        kind = "strictly increasing" if strict else "non-decreasing"
    else:
        kind = "strictly decreasing" if strict else "non-increasing"
    for i in range(1, len(v)):
        step = v[i] - v[i - 1] if increasing else v[i - 1] - v[i]
        if step < 0.0 or (strict and step == 0.0):
            raise CalibrationError(
                f"{path}[{i}]", source, f"expected {kind} values: {v[i]!r} after {v[i - 1]!r}"
            )


def calibration_from_dict(d: dict[str, Any], source: str = "<dict>") -> Calibration:
    """Validate a calibration document (without "crc32") and build the `Calibration`.

    Refuses unknown and missing keys, non-finite numbers, values out of range, grids of the wrong
    shape and maps that are not monotone; the `CalibrationError` names the field."""
    _check_keys(d, "", _TOP_KEYS, source)
    if d["format"] != FORMAT:
        raise CalibrationError("format", source, f"expected {FORMAT!r}, got {d['format']!r}")
    version = d["version"]
    if isinstance(version, bool) or not isinstance(version, int) or version < 1:
        raise CalibrationError("version", source, f"expected an integer >= 1, got {version!r}")
    for key in ("vehicle", "created"):
        if not isinstance(d[key], str) or not d[key].strip():
            raise CalibrationError(key, source, f"expected a non-empty string, got {d[key]!r}")
    try:
        datetime.datetime.fromisoformat(d["created"])
    except ValueError:
        raise CalibrationError(
            "created",
            source,
            f"expected an ISO 8601 date (2025-01-31 or 2025-01-31T12:00:00), got {d['created']!r}",
        ) from None

    scalars = {k: _ranged(d[k], k, source, lo, hi, what) for k, (lo, hi, what) in _RANGES.items()}
    # A stop must be realisable inside the request clamp, or the clamp would silently weaken it.
    for k in ("pause_decel_mps2", "disable_decel_mps2", "safe_stop_decel_mps2"):
        if scalars[k] > -scalars["accel_min_mps2"]:
            raise CalibrationError(
                k, source, f"{scalars[k]!r} exceeds -accel_min_mps2 = {-scalars['accel_min_mps2']!r}"
            )

    throttle_map = _throttle_map(d["throttle_map"], source)
    brake_map = _brake_map(d["brake_map"], source)
    coast_map = _coast_map(d["coast_map"], source)
    # The brake map must realise the strongest request the clamp lets through, beyond coasting.
    if brake_map.decel_mps2[-1] < -scalars["accel_min_mps2"]:
        raise CalibrationError(
            f"brake_map.decel_mps2[{len(brake_map.decel_mps2) - 1}]",
            source,
            f"the map must reach -accel_min_mps2 = {-scalars['accel_min_mps2']!r} m/s^2, "
            f"ends at {brake_map.decel_mps2[-1]!r}",
        )
    return Calibration(
        format=d["format"],
        version=version,
        vehicle=d["vehicle"],
        created=d["created"],
        throttle_map=throttle_map,
        brake_map=brake_map,
        coast_map=coast_map,
        **scalars,
    )


def _throttle_map(m: Any, source: str) -> ThrottleMap:
    _check_keys(m, "throttle_map", _MAP_KEYS["throttle_map"], source)
    speed = _vector(m["speed_mps"], "throttle_map.speed_mps", source, 0.0, 100.0, "m/s")
    accel = _vector(m["accel_mps2"], "throttle_map.accel_mps2", source, -10.0, 10.0, "m/s^2")
    _monotone(speed, "throttle_map.speed_mps", source, strict=True, increasing=True)
    _monotone(accel, "throttle_map.accel_mps2", source, strict=True, increasing=True)
    rows = m["pct"]
    if not isinstance(rows, list) or len(rows) != len(speed):
        n = len(rows) if isinstance(rows, list) else type(rows).__name__
        raise CalibrationError(
            "throttle_map.pct", source, f"expected {len(speed)} rows (one per speed_mps), got {n}"
        )
    pct: list[tuple[float, ...]] = []
    for i, row in enumerate(rows):
        path = f"throttle_map.pct[{i}]"
        if not isinstance(row, list) or len(row) != len(accel):
            n = len(row) if isinstance(row, list) else type(row).__name__
            raise CalibrationError(
                path, source, f"expected {len(accel)} values (one per accel_mps2), got {n}"
            )
        r = tuple(_number(v, f"{path}[{j}]", source) for j, v in enumerate(row))
        for j, v in enumerate(r):
            if not 0.0 <= v <= THROTTLE_PCT_MAX:
                raise CalibrationError(f"{path}[{j}]", source, f"{v!r} out of range: expected 0 .. 100 %")
        # More throttle for more acceleration, or the loop's sign flips inside the map.
        _monotone(r, path, source, strict=False, increasing=True)
        pct.append(r)
    return ThrottleMap(speed, accel, tuple(pct))


def _brake_map(m: Any, source: str) -> BrakeMap:
    _check_keys(m, "brake_map", _MAP_KEYS["brake_map"], source)
    decel = _vector(m["decel_mps2"], "brake_map.decel_mps2", source, 0.0, 15.0, "m/s^2")
    bar = _vector(m["bar"], "brake_map.bar", source, 0.0, BRAKE_BAR_MAX, "bar")
    if len(bar) != len(decel):
        raise CalibrationError(
            "brake_map.bar", source, f"expected {len(decel)} values (one per decel_mps2), got {len(bar)}"
        )
    if decel[0] != 0.0:
        raise CalibrationError(
            "brake_map.decel_mps2[0]", source, f"expected 0.0 (coasting), got {decel[0]!r}"
        )
    _monotone(decel, "brake_map.decel_mps2", source, strict=True, increasing=True)
    _monotone(bar, "brake_map.bar", source, strict=False, increasing=True)
    if bar[-1] <= bar[0]:
        raise CalibrationError("brake_map.bar", source, "expected pressure to rise with deceleration")
    return BrakeMap(decel, bar)


def _coast_map(m: Any, source: str) -> CoastMap:
    _check_keys(m, "coast_map", _MAP_KEYS["coast_map"], source)
    speed = _vector(m["speed_mps"], "coast_map.speed_mps", source, 0.0, 100.0, "m/s")
    accel = _vector(m["accel_mps2"], "coast_map.accel_mps2", source, -5.0, 0.0, "m/s^2")
    if len(accel) != len(speed):
        raise CalibrationError(
            "coast_map.accel_mps2",
            source,
            f"expected {len(speed)} values (one per speed_mps), got {len(accel)}",
        )
    _monotone(speed, "coast_map.speed_mps", source, strict=True, increasing=True)
    # Drag only grows with speed: a rising coast curve is an identification error.
    _monotone(accel, "coast_map.accel_mps2", source, strict=False, increasing=False)
    return CoastMap(speed, accel)


def calibration_to_dict(cal: Calibration) -> dict[str, Any]:
    """The JSON document of a calibration (without "crc32"); `calibration_from_dict` inverts it."""
    out: dict[str, Any] = {}
    for f in fields(cal):
        v = getattr(cal, f.name)
        if isinstance(v, ThrottleMap):
            v = {
                "speed_mps": list(v.speed_mps),
                "accel_mps2": list(v.accel_mps2),
                "pct": [list(r) for r in v.pct],
            }
        elif isinstance(v, BrakeMap):
            v = {"decel_mps2": list(v.decel_mps2), "bar": list(v.bar)}
        elif isinstance(v, CoastMap):
            v = {"speed_mps": list(v.speed_mps), "accel_mps2": list(v.accel_mps2)}
        out[f.name] = v
    return out


def _canonical(d: dict[str, Any]) -> bytes:
    # allow_nan only so that a hand-made file with NaN reaches validation, which names the field.
    return json.dumps(d, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=True).encode()


def _crc32(d: dict[str, Any]) -> int:
    return zlib.crc32(_canonical(d)) & 0xFFFFFFFF


def dumps_calibration(cal: Calibration, *, indent: int | None = None) -> bytes:
    """Canonical JSON of the calibration with its "crc32" (indent only for files humans read;
    the CRC does not depend on it)."""
    d = calibration_to_dict(cal)
    d["crc32"] = _crc32(d)
    if indent is None:
        return _canonical(d)
    text = json.dumps(d, sort_keys=True, indent=indent, ensure_ascii=True)
    # One line per innermost array of numbers (a map row), not one line per number.
    text = _NUMBER_ARRAY.sub(lambda m: "[" + ", ".join(x.strip() for x in m.group(1).split(",")) + "]", text)
    return (text + "\n").encode()


def _no_duplicates(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    d: dict[str, Any] = {}
    for k, v in pairs:
        if k in d:
            raise ValueError(f"duplicate key {k!r}")
        d[k] = v
    return d


def loads_calibration(data: bytes, source: str) -> Calibration:
    """Parse, check "format" and "crc32", then validate. Bad JSON names the line and column."""
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise CalibrationError("", source, f"not UTF-8 text (byte {e.start})") from None
    try:
        d = json.loads(text, object_pairs_hook=_no_duplicates)
    except json.JSONDecodeError as e:
        raise CalibrationError(
            "", source, f"invalid JSON at line {e.lineno} column {e.colno}: {e.msg}"
        ) from None
    except ValueError as e:  # a duplicate key
        raise CalibrationError("", source, f"invalid calibration JSON: {e}") from None
    if not isinstance(d, dict):
        raise CalibrationError("", source, f"expected a JSON object, got {type(d).__name__}")
    if d.get("format") != FORMAT:
        raise CalibrationError("format", source, f"expected {FORMAT!r}, got {d.get('format')!r}")
    if "crc32" not in d:
        raise CalibrationError("crc32", source, "missing")
    crc = d.pop("crc32")
    if isinstance(crc, bool) or not isinstance(crc, int) or not 0 <= crc <= 0xFFFFFFFF:
        raise CalibrationError("crc32", source, f"expected an unsigned 32-bit integer, got {crc!r}")
    actual = _crc32(d)
    if crc != actual:
        raise CalibrationError(
            "crc32",
            source,
            f"mismatch: file says {crc:#010x}, content gives {actual:#010x} (edited or corrupt)",
        )
    return calibration_from_dict(d, source)


def load_calibration(path: str | os.PathLike[str]) -> Calibration:
    """Read and check a calibration file (OSError if it cannot be read)."""
    with open(path, "rb") as f:
        data = f.read()
    return loads_calibration(data, os.fspath(path))


@functools.cache
def default_calibration() -> Calibration:
    """The packaged Passat calibration (ecu/calibrations/passat.json), also inside the zipapp."""
    res = resources.files("bywire.ecu").joinpath("calibrations", "passat.json")
    return loads_calibration(res.read_bytes(), "bywire.ecu/calibrations/passat.json")
