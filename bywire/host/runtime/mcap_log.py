"""Recording the object store's topics and the CAN buses to MCAP, and reading recordings back.

Issue 3: every topic and every bus frame of a run goes into one MCAP file that standard tools
(Foxglove) open, the file stays readable when the host crashes, and a recording can be decoded back
into the same Python objects for `bywire log info|plot|replay`.

Encoding. Messages are JSON (message encoding "json"), described by a JSON Schema per type (schema
encoding "jsonschema"), generated from the dataclass fields; the schema name is the type's stable
name (`register_type(cls, name=...)`, else `module.QualName`). Supported field types: float, int,
bool, str, bytes (base64 string), `X | None`, enums (IntEnum / int-valued Enum -> integer with the
member names as Foxglove enum constants, IntFlag -> integer, other Enum -> its str or float value),
homogeneous tuples and lists of those (`tuple[X, ...]`, `tuple[X, X]`, `list[X]`), nested dataclasses
and numpy arrays as `{"dtype": "<f8", "shape": [...], "data": base64 of the C-order bytes}` (exact,
NaN payloads included; Foxglove shows these as opaque byte arrays). Nested sequences and
heterogeneous tuples are refused: Foxglove's JSON Schema parser cannot show arrays of arrays, so
use a tuple of a small dataclass or a numpy array.

The schemas are written for Foxglove's parser, which accepts exactly one `type` per field: an
Optional field carries its inner type's schema (null in the data means None), and a float field
says "number" although it may hold one of the strings below.

Non-finite floats: JSON has no NaN, so NaN, +inf and -inf are written as the strings "NaN",
"Infinity" and "-Infinity" (JavaScript's spellings). Every finite float is written with Python's
shortest round-trip repr, so decoding gives back bit-identical floats (replay compares exactly);
null stays reserved for None, so NaN and None remain distinct. Foxglove plots such a sample as a
gap, which is what a NaN is.

Time. log_time = publish_time = round(t_s * 1e9) ns, t_s being the object's own time on the run's
clock: simulated seconds in SIL, CLOCK_MONOTONIC in HIL, so not an epoch time (Foxglove shows it as
a date near 1970). Times that do not fit MCAP's unsigned nanoseconds (negative, non-finite) are
written as 0; the exact `t_s` is in the message either way. A CAN frame's log time is its
`timestamp` (python-can stamps frames with `time.time()`, an epoch time: pass `t_s=` to
`record_frame` to put frames on the run's clock, e.g. with `protocol.timebase.rx_time_s`).

Crash survival. The recorder writes through to the file descriptor (no user-space buffer), and
closes a chunk when it exceeds `chunk_size` bytes or when its first message is `flush_interval_s`
old (checked on every record, and every `flush_interval_s / 2` by a background thread that writes
chunks older than that). A process killed with SIGKILL therefore leaves a file holding every
message recorded more than `flush_interval_s` (plus thread scheduling latency) before the kill;
only the open chunk is lost. The data survives a process crash, not a
power loss (no fsync before `close()`). The reader here (not `mcap.reader.make_reader`, which needs
the footer of a closed file) reads such a file up to its last complete record.

Reading is for untrusted input: a log never names Python code to import; schema names are looked
up in the registry filled by `register_type`, and unknown types come back as dicts. The recorder
writes CRCs over every chunk, over the whole data section and over the summary, so damage is found
wherever it is: damaged files (bytes flipped, garbage, a closed file cut inside) raise `LogError`
naming the file, the byte offset and what failed; a damaged summary behind an intact data section
only marks the file as not complete. A file that merely ends early (a crash: no footer) yields
what it holds and reports itself as not complete.
"""

from __future__ import annotations

import base64
import binascii
import contextlib
import dataclasses
import enum
import io
import json
import math
import os
import re
import struct
import threading
import time
import types
import typing
import zlib
from collections.abc import Callable, Collection, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO, TypeVar, overload

import can
import numpy as np
from mcap.writer import CompressionType, Writer

import bywire

T = TypeVar("T")

MCAP_MAGIC = b"\x89MCAP0\r\n"
MESSAGE_ENCODING = "json"
SCHEMA_ENCODING = "jsonschema"
CAN_TOPIC_PREFIX = "/can/"
CAN_FRAME_SCHEMA = "bywire.CanFrame"
DEFAULT_CHUNK_SIZE = 256 * 1024  # bytes before compression; a chunk this big is written at once
DEFAULT_FLUSH_INTERVAL_S = 0.25  # the most a crash can lose (see the module docstring)

_JSON_TO_NONFINITE = {"NaN": math.nan, "Infinity": math.inf, "-Infinity": -math.inf}
_MAX_NS = 2**64 - 1
_NUMPY_DTYPE = re.compile(r"[<>|][biufc]\d{1,2}")
_MAX_NDIM = 32
# allow_nan=False: a non-finite float that slipped past the codecs must fail, not write bad JSON.
_JSON = json.JSONEncoder(separators=(",", ":"), allow_nan=False)


class LogError(ValueError):
    """A recording that cannot be written or read as asked: names the file and what failed."""

    def __init__(self, path: str | os.PathLike[str], problem: str) -> None:
        super().__init__(f"{os.fspath(path)}: {problem}")
        self.path = os.fspath(path)
        self.problem = problem


class _FieldError(Exception):
    """A value that does not fit its field; containers prepend their field names on the way up."""

    def __init__(self, problem: str) -> None:
        super().__init__(problem)
        self.problem = problem
        self.where: list[str] = []

    def at(self, name: str) -> _FieldError:
        self.where.insert(0, name)
        return self

    def describe(self, root: str) -> str:
        path = root
        for part in self.where:
            path += part if part.startswith("[") else f".{part}"
        return f"{path}: {self.problem}"


# -- codecs: one (schema, encode, decode) per Python type, built once from the type hints -----------------


@dataclass(frozen=True)
class _Codec:
    schema: dict[str, Any]
    item_schema: dict[str, Any]  # the schema as an array item: Foxglove takes less there
    encode: Callable[[Any], Any]
    decode: Callable[[Any], Any]


def _encode_float(v: Any) -> Any:
    # float(): float subclasses (np.float64) and numpy scalars become plain floats for the JSON encoder.
    if isinstance(v, float | int | np.integer | np.floating) and not isinstance(v, bool | np.bool_):
        f = float(v)
    else:
        raise _FieldError(f"expected a number, got {type(v).__name__}")
    if math.isfinite(f):
        return f
    return "NaN" if f != f else ("Infinity" if f > 0 else "-Infinity")


def _decode_float(v: Any) -> float:
    if isinstance(v, float):
        return v
    if isinstance(v, int) and not isinstance(v, bool):
        return float(v)
    if isinstance(v, str) and v in _JSON_TO_NONFINITE:
        return _JSON_TO_NONFINITE[v]
    raise _FieldError(f"expected a number, got {_json_kind(v)}")


def _encode_int(v: Any) -> int:
    if isinstance(v, int | np.integer) and not isinstance(v, bool | np.bool_):
        return int(v)
    raise _FieldError(f"expected an integer, got {type(v).__name__}")


def _decode_int(v: Any) -> int:
    if isinstance(v, int) and not isinstance(v, bool):
        return v
    raise _FieldError(f"expected an integer, got {_json_kind(v)}")


def _encode_bool(v: Any) -> bool:
    if isinstance(v, bool | np.bool_):
        return bool(v)
    raise _FieldError(f"expected a bool, got {type(v).__name__}")


def _decode_bool(v: Any) -> bool:
    if isinstance(v, bool):
        return v
    raise _FieldError(f"expected a bool, got {_json_kind(v)}")


def _encode_str(v: Any) -> str:
    if isinstance(v, str):
        return v
    raise _FieldError(f"expected a str, got {type(v).__name__}")


def _decode_str(v: Any) -> str:
    if isinstance(v, str):
        return v
    raise _FieldError(f"expected a string, got {_json_kind(v)}")


def _encode_bytes(v: Any) -> str:
    if isinstance(v, bytes | bytearray | memoryview):
        return base64.b64encode(v).decode("ascii")
    raise _FieldError(f"expected bytes, got {type(v).__name__}")


def _decode_bytes(v: Any) -> bytes:
    if not isinstance(v, str):
        raise _FieldError(f"expected a base64 string, got {_json_kind(v)}")
    try:
        return base64.b64decode(v.encode("ascii"), validate=True)
    except (binascii.Error, UnicodeEncodeError) as exc:
        raise _FieldError(f"not valid base64 ({exc})") from exc


def _encode_ndarray(v: Any) -> dict[str, Any]:
    if not isinstance(v, np.ndarray):
        raise _FieldError(f"expected a numpy array, got {type(v).__name__}")
    if v.dtype.kind not in "biufc" or v.dtype.fields is not None:
        raise _FieldError(f"numpy arrays of dtype {v.dtype} cannot be recorded (numbers and bools only)")
    return {
        "dtype": v.dtype.str,
        "shape": list(v.shape),
        "data": base64.b64encode(np.ascontiguousarray(v).tobytes()).decode("ascii"),
    }


def _decode_ndarray(v: Any) -> np.ndarray:
    if not isinstance(v, dict) or set(v) != {"dtype", "shape", "data"}:
        raise _FieldError("expected an array object with exactly dtype, shape and data")
    dtype_str, shape, data = v["dtype"], v["shape"], _decode_bytes(v["data"])
    if not isinstance(dtype_str, str) or not _NUMPY_DTYPE.fullmatch(dtype_str):
        raise _FieldError(f"numpy dtype {dtype_str!r} is not a plain number or bool type")
    try:
        dtype = np.dtype(dtype_str)
    except (TypeError, ValueError) as exc:
        raise _FieldError(f"numpy dtype {dtype_str!r}: {exc}") from exc
    if (
        not isinstance(shape, list)
        or len(shape) > _MAX_NDIM
        or not all(isinstance(n, int) and not isinstance(n, bool) and n >= 0 for n in shape)
    ):
        raise _FieldError(f"array shape must be a list of at most {_MAX_NDIM} sizes >= 0, got {shape!r}")
    count = math.prod(shape)
    if count * dtype.itemsize != len(data):
        raise _FieldError(
            f"array of shape {shape}, dtype {dtype_str} needs {count * dtype.itemsize} bytes, has {len(data)}"
        )
    # Read-only, backed by the decoded bytes: recorded objects are immutable.
    return np.frombuffer(data, dtype=dtype, count=count).reshape(shape)


def _json_kind(v: Any) -> str:
    if v is None:
        return "null"
    return {bool: "a bool", int: "an integer", float: "a number", str: "a string", list: "an array"}.get(
        type(v), "an object" if isinstance(v, dict) else type(v).__name__
    )


_SCALARS: dict[type, tuple[dict[str, Any], Callable[[Any], Any], Callable[[Any], Any]]] = {
    float: ({"type": "number"}, _encode_float, _decode_float),
    int: ({"type": "integer"}, _encode_int, _decode_int),
    bool: ({"type": "boolean"}, _encode_bool, _decode_bool),
    str: ({"type": "string"}, _encode_str, _decode_str),
}

_SUPPORTED = (
    "float, int, bool, str, bytes, X | None, enums, tuple[X, ...], list[X], dataclasses and numpy arrays"
)

_codecs: dict[Any, _Codec] = {}
_codecs_lock = threading.RLock()


def _codec(tp: Any, building: tuple[type, ...] = ()) -> _Codec:
    with _codecs_lock:
        known = _codecs.get(tp)
        if known is not None:
            return known
        codec = _build_codec(tp, building)
        with contextlib.suppress(TypeError):  # an unhashable annotation: built again next time
            _codecs[tp] = codec
        return codec


def _build_codec(tp: Any, building: tuple[type, ...]) -> _Codec:
    if tp in _SCALARS:
        schema, enc, dec = _SCALARS[tp]
        return _Codec(schema, schema, enc, dec)
    if tp is bytes:
        return _Codec(
            {"type": "string", "contentEncoding": "base64"},
            {"type": "string", "description": "base64"},
            _encode_bytes,
            _decode_bytes,
        )
    if tp is np.ndarray or typing.get_origin(tp) is np.ndarray:
        schema = {
            "type": "object",
            "description": "numpy array: data is the base64 of the C-order bytes of dtype and shape",
            "properties": {
                "dtype": {"type": "string"},
                "shape": {"type": "array", "items": {"type": "integer"}},
                "data": {"type": "string", "contentEncoding": "base64"},
            },
            "required": ["dtype", "shape", "data"],
        }
        return _Codec(schema, schema, _encode_ndarray, _decode_ndarray)
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        return _enum_codec(tp)
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        return _dataclass_codec(tp, building)
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        inner = [a for a in args if a is not type(None)]
        if len(inner) == 1 and len(args) == 2:
            return _optional_codec(_codec(inner[0], building))
        raise _FieldError(f"type {_type_name(tp)} is not supported: of unions only X | None is")
    if origin in (tuple, list, Sequence):
        return _sequence_codec(tp, origin, args, building)
    raise _FieldError(f"type {_type_name(tp)} is not supported (supported: {_SUPPORTED})")


def _type_name(tp: Any) -> str:
    return tp.__name__ if isinstance(tp, type) else repr(tp).replace("typing.", "")


def _optional_codec(inner: _Codec) -> _Codec:
    def enc(v: Any) -> Any:
        return None if v is None else inner.encode(v)

    def dec(v: Any) -> Any:
        return None if v is None else inner.decode(v)

    return _Codec(inner.schema, inner.item_schema, enc, dec)


def _sequence_codec(tp: Any, origin: Any, args: tuple[Any, ...], building: tuple[type, ...]) -> _Codec:
    if origin is tuple and len(args) == 2 and args[1] is Ellipsis:
        item_type, length = args[0], None
    elif origin is tuple and args and Ellipsis not in args:
        if any(a != args[0] for a in args):
            raise _FieldError(
                f"type {_type_name(tp)} is not supported: tuples must hold one type (use a dataclass)"
            )
        item_type, length = args[0], len(args)
    elif origin is not tuple and len(args) == 1:
        item_type, length = args[0], None
    else:
        raise _FieldError(f"type {_type_name(tp)} is not supported: name the item type (tuple[float, ...])")
    item_origin = typing.get_origin(item_type)
    if item_origin in (tuple, list, Sequence):
        raise _FieldError(
            f"type {_type_name(tp)} is not supported: Foxglove cannot show arrays of arrays "
            "(use a tuple of a dataclass or a numpy array)"
        )
    item = _codec(item_type, building)
    schema: dict[str, Any] = {"type": "array", "items": item.item_schema}
    if length is not None:
        schema["minItems"] = schema["maxItems"] = length
    make: Callable[[Any], Any] = list if origin is list else tuple
    kind = "list" if origin is list else "tuple"

    def enc(v: Any) -> list[Any]:
        if not isinstance(v, tuple | list):
            raise _FieldError(f"expected a {kind}, got {type(v).__name__}")
        if length is not None and len(v) != length:
            raise _FieldError(f"expected {length} items, got {len(v)}")
        out = []
        for i, x in enumerate(v):
            try:
                out.append(item.encode(x))
            except _FieldError as exc:
                raise exc.at(f"[{i}]") from None
        return out

    def dec(v: Any) -> Any:
        if not isinstance(v, list):
            raise _FieldError(f"expected an array, got {_json_kind(v)}")
        if length is not None and len(v) != length:
            raise _FieldError(f"expected {length} items, got {len(v)}")
        out = []
        for i, x in enumerate(v):
            try:
                out.append(item.decode(x))
            except _FieldError as exc:
                raise exc.at(f"[{i}]") from None
        return make(out)

    return _Codec(schema, schema, enc, dec)


def _enum_codec(cls: type[enum.Enum]) -> _Codec:
    members = list(cls)
    if issubclass(cls, enum.Flag):
        if not issubclass(cls, int):
            raise _FieldError(f"enum {cls.__name__}: only IntFlag flags are supported")
        names = ", ".join(f"{m.name}={int(m)}" for m in members)
        schema: dict[str, Any] = {"type": "integer", "description": f"{cls.__name__} flags: {names}"}
        item_schema = schema
        value_kind: type = int
    else:
        kinds = {type(int(m.value)) if isinstance(m.value, int) else type(m.value) for m in members}
        if len(kinds) != 1 or not kinds <= {int, str, float}:
            raise _FieldError(f"enum {cls.__name__}: values must all be int, all str or all float")
        value_kind = kinds.pop()
        values = [int(m.value) if value_kind is int else m.value for m in members]
        if value_kind is float and not all(math.isfinite(x) for x in values):
            raise _FieldError(f"enum {cls.__name__}: float values must be finite")
        if value_kind is int:
            # Foxglove shows a oneOf of numeric consts as named constants of the field.
            schema = {
                "type": "integer",
                "oneOf": [{"title": m.name, "const": x} for m, x in zip(members, values, strict=True)],
            }
            item_schema = {"type": "integer"}
        else:
            schema = {"type": "string" if value_kind is str else "number", "enum": values}
            item_schema = {"type": schema["type"]}

    def enc(v: Any) -> Any:
        try:
            member = v if isinstance(v, cls) else cls(v)
        except (ValueError, TypeError) as exc:
            raise _FieldError(f"{v!r} is not a {cls.__name__}") from exc
        return int(member.value) if value_kind is int else member.value

    def dec(v: Any) -> Any:
        if isinstance(v, bool) or not isinstance(v, value_kind):
            raise _FieldError(f"expected a {cls.__name__} value, got {_json_kind(v)}")
        try:
            return cls(v)
        except ValueError as exc:
            raise _FieldError(f"{v!r} is not a {cls.__name__}") from exc

    return _Codec(schema, item_schema, enc, dec)


def _dataclass_codec(cls: type, building: tuple[type, ...]) -> _Codec:
    if cls in building:
        raise _FieldError(f"{cls.__name__} contains itself: recursive types are not supported")
    try:
        hints = typing.get_type_hints(cls)
    except Exception as exc:  # NameError, TypeError...: whatever the annotations make of it
        raise _FieldError(f"cannot resolve the annotations of {cls.__qualname__}: {exc}") from exc
    fields = [f for f in dataclasses.fields(cls) if f.init]  # init=False fields are derived: not stored
    codecs: list[tuple[str, _Codec]] = []
    for f in fields:
        try:
            codecs.append((f.name, _codec(hints[f.name], (*building, cls))))
        except _FieldError as exc:
            raise exc.at(f.name) from None
    required = [
        f.name
        for f in fields
        if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    ]
    schema: dict[str, Any] = {
        "title": schema_name_of(cls),
        "type": "object",
        "properties": {name: c.schema for name, c in codecs},
        "required": [name for name, c in codecs if name in required and not _is_optional(hints[name])],
        "additionalProperties": False,
    }
    names = {name for name, _ in codecs}
    missing_ok = {name for name, _ in codecs if name not in required}

    def enc(v: Any) -> dict[str, Any]:
        if type(v) is not cls:
            raise _FieldError(f"expected a {cls.__name__}, got {type(v).__name__}")
        out = {}
        for name, c in codecs:
            try:
                out[name] = c.encode(getattr(v, name))
            except _FieldError as exc:
                raise exc.at(name) from None
        return out

    def dec(v: Any) -> Any:
        if not isinstance(v, dict):
            raise _FieldError(f"expected an object for {cls.__name__}, got {_json_kind(v)}")
        unknown = v.keys() - names
        if unknown:
            raise _FieldError(
                f"fields {sorted(unknown)} are not in {cls.__name__} (recorded with another version of it?)"
            )
        kwargs = {}
        for name, c in codecs:
            if name in v:
                try:
                    kwargs[name] = c.decode(v[name])
                except _FieldError as exc:
                    raise exc.at(name) from None
            elif name not in missing_ok:
                raise _FieldError(f"field {name!r} of {cls.__name__} is missing")
        try:
            return cls(**kwargs)
        except Exception as exc:  # the class's own checks (__post_init__) refusing recorded values
            raise _FieldError(f"{cls.__name__} refused the recorded values: {exc}") from exc

    return _Codec(schema, schema, enc, dec)


def _is_optional(tp: Any) -> bool:
    return typing.get_origin(tp) in (typing.Union, types.UnionType) and type(None) in typing.get_args(tp)


# -- the type registry ----------------------------------------------------------------------------------

_names_by_type: dict[type, str] = {}
_types_by_name: dict[str, type] = {}


@overload
def register_type(cls: type[T], *, name: str | None = None) -> type[T]: ...
@overload
def register_type(cls: None = None, *, name: str | None = None) -> Callable[[type[T]], type[T]]: ...


def register_type(cls: type[T] | None = None, *, name: str | None = None) -> Any:
    """Make a dataclass decodable from recordings, under `name` (default `module.QualName`).

    Use as `register_type(cls)`, `@register_type` or `@register_type(name="bywire.Pose")`. The
    name is the MCAP schema name: keep it stable when moving the class, or old recordings decode
    as dicts. Checks that every field type can be encoded (LogError naming the field if not).
    """

    def register(klass: type[T]) -> type[T]:
        if not isinstance(klass, type) or not dataclasses.is_dataclass(klass):
            raise LogError("<registry>", f"only dataclasses can be registered, got {klass!r}")
        with _codecs_lock:
            schema_name = name or _names_by_type.get(klass) or f"{klass.__module__}.{klass.__qualname__}"
            holder = _types_by_name.get(schema_name)
            if holder is not None and holder is not klass:
                raise LogError(
                    "<registry>",
                    f"schema name {schema_name!r} is taken by {holder.__module__}.{holder.__qualname__}",
                )
            old = _names_by_type.get(klass)
            if old is not None and old != schema_name:
                raise LogError("<registry>", f"{klass.__qualname__} is already registered as {old!r}")
            _names_by_type[klass] = schema_name
            _types_by_name[schema_name] = klass
            _codecs.pop(klass, None)  # its schema title may have changed with the name
            try:
                _codec(klass)
            except _FieldError as exc:
                del _names_by_type[klass], _types_by_name[schema_name]
                raise LogError("<registry>", exc.describe(klass.__qualname__)) from None
        return klass

    return register if cls is None else register(cls)


def registered_types() -> dict[str, type]:
    """Schema name -> class, for everything `register_type` has seen."""
    with _codecs_lock:
        return dict(_types_by_name)


def schema_name_of(cls: type) -> str:
    """The MCAP schema name of a dataclass: its registered name, else `module.QualName`."""
    return _names_by_type.get(cls) or f"{cls.__module__}.{cls.__qualname__}"


def json_schema(cls: type) -> dict[str, Any]:
    """The JSON Schema of a dataclass as written into recordings (LogError if a field cannot be encoded)."""
    if not isinstance(cls, type) or not dataclasses.is_dataclass(cls):
        raise LogError("<schema>", f"only dataclasses have a schema, got {cls!r}")
    try:
        schema = dict(_codec(cls).schema)
    except _FieldError as exc:
        raise LogError("<schema>", exc.describe(cls.__qualname__)) from None
    schema["$comment"] = (
        "bywire recording: non-finite floats are the strings NaN, Infinity, -Infinity; null is None"
    )
    return schema


def schema_bytes(cls: type) -> bytes:
    return json.dumps(json_schema(cls), separators=(",", ":"), sort_keys=True).encode()


def encode_object(obj: object) -> bytes:
    """The JSON message of one dataclass instance (LogError naming the field that cannot be encoded)."""
    cls = type(obj)
    if not dataclasses.is_dataclass(cls):
        raise LogError("<encode>", f"only dataclass instances can be recorded, got {cls.__name__}")
    try:
        payload = _codec(cls).encode(obj)
    except _FieldError as exc:
        raise LogError("<encode>", exc.describe(cls.__qualname__)) from None
    return _JSON.encode(payload).encode()


def decode_object(cls: type[T], data: bytes | dict[str, Any]) -> T:
    """Decode one JSON message (bytes or already parsed) into `cls` (LogError naming the field)."""
    try:
        raw = json.loads(data) if isinstance(data, bytes | bytearray) else data
        return typing.cast(T, _codec(cls).decode(raw))
    except _FieldError as exc:
        raise LogError("<decode>", exc.describe(cls.__qualname__)) from None
    except (ValueError, RecursionError) as exc:
        raise LogError("<decode>", f"not JSON: {exc}") from None


def time_ns(t_s: float) -> int:
    """MCAP nanoseconds for a time in seconds; 0 for what MCAP cannot hold (negative, non-finite)."""
    if not math.isfinite(t_s) or t_s <= 0.0:
        return 0
    ns = t_s * 1e9
    return _MAX_NS if ns >= _MAX_NS else round(ns)


# -- CAN frames --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class CanFrame:
    """A CAN frame as recorded on `/can/<bus>`: python-can's fields; `data` as integers so Foxglove
    can plot single bytes (`/can/vehicle.data[2]`)."""

    timestamp: float
    arbitration_id: int
    is_extended_id: bool
    is_remote_frame: bool
    is_error_frame: bool
    is_fd: bool
    bitrate_switch: bool
    error_state_indicator: bool
    is_rx: bool
    dlc: int
    data: tuple[int, ...]

    @classmethod
    def from_message(cls, msg: can.Message, t_s: float | None = None) -> CanFrame:
        return cls(
            timestamp=float(msg.timestamp if t_s is None else t_s),
            arbitration_id=int(msg.arbitration_id),
            is_extended_id=bool(msg.is_extended_id),
            is_remote_frame=bool(msg.is_remote_frame),
            is_error_frame=bool(msg.is_error_frame),
            is_fd=bool(msg.is_fd),
            bitrate_switch=bool(msg.bitrate_switch),
            error_state_indicator=bool(msg.error_state_indicator),
            is_rx=bool(msg.is_rx),
            dlc=int(msg.dlc),
            data=tuple(msg.data),
        )

    def to_message(self, channel: str | None = None) -> can.Message:
        if not 0 <= self.arbitration_id < 2**29:
            raise ValueError(f"arbitration id {self.arbitration_id} is outside 0..2^29-1")
        if not 0 <= self.dlc <= 64 or len(self.data) > 64 or not all(0 <= b <= 255 for b in self.data):
            raise ValueError(f"dlc {self.dlc} / data {self.data!r} is not a CAN payload")
        return can.Message(
            timestamp=self.timestamp,
            arbitration_id=self.arbitration_id,
            is_extended_id=self.is_extended_id,
            is_remote_frame=self.is_remote_frame,
            is_error_frame=self.is_error_frame,
            channel=channel,
            dlc=self.dlc,
            data=bytes(self.data),
            is_fd=self.is_fd,
            is_rx=self.is_rx,
            bitrate_switch=self.bitrate_switch,
            error_state_indicator=self.error_state_indicator,
        )


register_type(CanFrame, name=CAN_FRAME_SCHEMA)


# -- writing ------------------------------------------------------------------------------------------------


class _WriteThrough:
    """A file the MCAP writer can use that hands every write to the kernel at once.

    mcap's Writer wraps raw files in a BufferedWriter; this object is not a RawIOBase, so it is used
    as is, and what the writer has written survives the death of the process.
    """

    def __init__(self, path: Path) -> None:
        self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        self._pos = 0

    def write(self, data: bytes | bytearray | memoryview) -> int:
        view = memoryview(data)
        while view:
            n = os.write(self._fd, view)
            view = view[n:]
            self._pos += n
        return len(data)

    def tell(self) -> int:
        return self._pos

    def flush(self) -> None:
        pass  # nothing buffered here

    def close(self, sync: bool = True) -> None:
        if self._fd >= 0:
            try:
                if sync:
                    os.fsync(self._fd)
            finally:
                os.close(self._fd)
                self._fd = -1


class McapRecorder:
    """Records store objects (`record`, usable as `store.add_tap(rec.record)`) and CAN frames
    (`record_frame`) into one MCAP file; thread-safe; `close()` writes the summary and footer.

    See the module docstring for the encoding, the time base and what a crash can lose.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        chunk_size: int = DEFAULT_CHUNK_SIZE,
        flush_interval_s: float = DEFAULT_FLUSH_INTERVAL_S,
        compression: str = "zstd",
    ) -> None:
        if chunk_size < 1:
            raise ValueError(f"chunk_size must be at least 1 byte, not {chunk_size}")
        if not flush_interval_s > 0:
            raise ValueError(f"flush_interval_s must be > 0, not {flush_interval_s}")
        kinds = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
        if compression not in kinds:
            raise ValueError(f"compression must be one of {sorted(kinds)}, not {compression!r}")
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.flush_interval_s = flush_interval_s
        self._lock = threading.Lock()
        try:
            self._stream = _WriteThrough(self.path)
        except OSError as exc:
            raise LogError(self.path, f"cannot create the recording: {exc.strerror or exc}") from None
        self._writer = Writer(
            typing.cast(BinaryIO, self._stream),
            chunk_size=chunk_size,
            compression=kinds[compression],
            enable_data_crcs=True,  # a CRC over the whole data section, in DataEnd: damage anywhere shows
        )
        self._writer.start(profile="", library=f"bywire {bywire.__version__}")
        self._writer.add_metadata(
            "bywire",
            {
                "log_time": "t_s * 1e9 on the run's clock (simulated in SIL, CLOCK_MONOTONIC in HIL)",
                "nonfinite_floats": "strings NaN, Infinity, -Infinity",
            },
        )
        self._schemas: dict[str, int] = {}  # schema name -> id
        self._channels: dict[str, tuple[int, type]] = {}  # topic -> (channel id, type)
        self._sequence: dict[int, int] = {}
        self._pending_since: float | None = None  # monotonic time of the oldest unwritten message
        self._error: BaseException | None = None
        self._closed = False
        self.messages = 0
        self._stop = threading.Event()
        self._flusher = threading.Thread(target=self._flush_loop, name="mcap-flush", daemon=True)
        self._flusher.start()

    def record(self, topic: str, obj: object) -> None:
        """Record a dataclass instance with a `t_s` on `topic` (log time from `t_s`)."""
        t_s = getattr(obj, "t_s", None)
        if isinstance(t_s, bool) or not isinstance(t_s, int | float):
            raise LogError(self.path, f"topic {topic!r}: {type(obj).__name__} has no float t_s to time it")
        self._record(topic, obj, time_ns(float(t_s)))

    def record_frame(self, bus: str, msg: can.Message, t_s: float | None = None) -> None:
        """Record a CAN frame on `/can/<bus>`; log time = `t_s` if given, else the frame's timestamp."""
        frame = CanFrame.from_message(msg, t_s)
        self._record(CAN_TOPIC_PREFIX + bus, frame, time_ns(frame.timestamp))

    def _record(self, topic: str, obj: object, log_time_ns: int) -> None:
        cls = type(obj)
        try:
            payload = encode_object(obj)
        except LogError as exc:
            raise LogError(self.path, f"topic {topic!r}: {exc.problem}") from None
        with self._lock:
            self._check_open()
            channel = self._channels.get(topic)
            if channel is None:
                channel = self._channels[topic] = (self._register(topic, cls), cls)
            elif channel[1] is not cls:
                raise LogError(
                    self.path, f"topic {topic!r} carries {channel[1].__name__}, not {cls.__name__}"
                )
            channel_id = channel[0]
            seq = self._sequence[channel_id] = self._sequence.get(channel_id, 0) + 1
            now_s = time.monotonic()
            try:
                self._writer.add_message(
                    channel_id=channel_id,
                    log_time=log_time_ns,
                    data=payload,
                    publish_time=log_time_ns,
                    sequence=seq & 0xFFFFFFFF,
                )
                self.messages += 1
                if self._pending_since is None:
                    self._pending_since = now_s
                elif now_s - self._pending_since >= self.flush_interval_s:
                    self._flush_locked()
            except OSError as exc:
                self._error = exc
                raise LogError(self.path, f"writing failed: {exc}") from exc

    def _register(self, topic: str, cls: type) -> int:
        name = schema_name_of(cls)
        schema_id = self._schemas.get(name)
        if schema_id is None:
            schema_id = self._schemas[name] = self._writer.register_schema(
                name=name, encoding=SCHEMA_ENCODING, data=schema_bytes(cls)
            )
        return self._writer.register_channel(
            topic=topic, message_encoding=MESSAGE_ENCODING, schema_id=schema_id
        )

    def _check_open(self) -> None:
        if self._closed:
            raise LogError(self.path, "the recording is closed")
        if self._error is not None:
            raise LogError(self.path, f"writing failed earlier: {self._error}")

    def _flush_locked(self) -> None:
        self._writer.flush()  # closes the open chunk; _WriteThrough has no buffer of its own
        self._pending_since = None

    def _flush_loop(self) -> None:
        # Waking every half interval and writing chunks at least half an interval old bounds the age
        # of an unwritten message by one interval even when nothing else is recorded.
        half_s = self.flush_interval_s / 2
        while not self._stop.wait(half_s):
            with self._lock:
                if self._closed or self._error is not None:
                    return
                if self._pending_since is not None and time.monotonic() - self._pending_since >= half_s:
                    try:
                        self._flush_locked()
                    except OSError as exc:
                        self._error = exc  # reported by the next record() or close()
                        return

    def flush(self) -> None:
        """Write the open chunk now."""
        with self._lock:
            self._check_open()
            self._flush_locked()

    def close(self) -> None:
        """Write the summary and footer and close the file (idempotent)."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._stop.set()
            try:
                if self._error is None:
                    self._writer.finish()
            except OSError as exc:
                self._error = exc
            finally:
                self._stream.close(sync=self._error is None)
        if threading.current_thread() is not self._flusher:
            self._flusher.join()
        if self._error is not None:
            raise LogError(self.path, f"writing failed: {self._error}")

    def __enter__(self) -> McapRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# -- reading ------------------------------------------------------------------------------------------------

_OP_HEADER, _OP_FOOTER, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06
_OP_DATA_END = 0x0F


class _Short(Exception):
    """A record's content is shorter than its fields say."""


class _Cursor:
    __slots__ = ("buf", "end", "pos")

    def __init__(self, buf: bytes, pos: int = 0, end: int | None = None) -> None:
        self.buf = buf
        self.pos = pos
        self.end = len(buf) if end is None else end

    def take(self, n: int) -> bytes:
        if n > self.end - self.pos:
            raise _Short(f"needs {n} bytes, {self.end - self.pos} left")
        out = self.buf[self.pos : self.pos + n]
        self.pos += n
        return out

    def u16(self) -> int:
        return int(struct.unpack("<H", self.take(2))[0])

    def u32(self) -> int:
        return int(struct.unpack("<I", self.take(4))[0])

    def u64(self) -> int:
        return int(struct.unpack("<Q", self.take(8))[0])

    def string(self) -> str:
        return self.take(self.u32()).decode("utf-8")


@dataclass(frozen=True)
class SchemaInfo:
    name: str
    encoding: str
    data: bytes


@dataclass(frozen=True)
class ChannelInfo:
    topic: str
    message_encoding: str
    schema: SchemaInfo | None


@dataclass(frozen=True)
class RawMessage:
    """One message as stored: its channel's topic and schema, times and undecoded payload."""

    channel: ChannelInfo
    sequence: int
    log_time_ns: int
    publish_time_ns: int
    data: bytes

    @property
    def topic(self) -> str:
        return self.channel.topic


class McapLogReader:
    """One pass over an MCAP file, tolerant of a missing end (a crash) and strict about damage.

    `messages()` yields the messages in file order; afterwards `complete` says whether the file was
    closed cleanly (footer and closing magic present, data section and summary CRCs right) and
    `end_note` how it ended; `channels` holds every channel seen. Damage to what messages are made
    of (a chunk, a schema, a channel) raises LogError naming the file, the byte offset and the
    problem (so does a data section whose CRC fails); damage only to the summary after a verified
    data section is noted in `damage` and leaves `complete` False, since every message is intact.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = os.fspath(path)
        self.complete = False
        self.end_note = "not read yet"
        self.channels: dict[int, ChannelInfo] = {}
        self.message_count = 0
        self.damage: str | None = None  # damage found outside the messages (they have their own CRC)
        self._schemas: dict[int, SchemaInfo] = {}

    def _fail(self, offset: int, problem: str) -> LogError:
        return LogError(self.path, f"byte {offset}: {problem}")

    def messages(self, topics: Collection[str] | None = None) -> Iterator[RawMessage]:
        try:
            f = open(self.path, "rb")  # noqa: SIM115 (closed in the finally below; this is a generator)
        except OSError as exc:
            raise LogError(self.path, f"cannot open: {exc.strerror or exc}") from None
        try:
            yield from self._read(f, None if topics is None else frozenset(topics))
        except OSError as exc:
            raise LogError(self.path, f"reading failed: {exc}") from None
        finally:
            f.close()

    def _read(self, f: BinaryIO, topics: frozenset[str] | None) -> Iterator[RawMessage]:
        size = os.fstat(f.fileno()).st_size
        magic = f.read(len(MCAP_MAGIC))
        if len(magic) < len(MCAP_MAGIC):
            what = "empty file" if not magic else f"only {len(magic)} bytes"
            raise LogError(self.path, f"{what}: not an MCAP recording (no header)")
        if magic != MCAP_MAGIC:
            raise LogError(self.path, f"not an MCAP file (starts with {magic!r})")
        # A file that ends with a footer and the magic was closed: anything that looks cut short
        # inside it is damage, not a crash.
        closed = False
        if size >= 2 * len(MCAP_MAGIC) + 9 + 20:
            f.seek(size - len(MCAP_MAGIC) - 9 - 20)
            end = f.read(9 + 20 + len(MCAP_MAGIC))
            closed = end[:9] == struct.pack("<BQ", _OP_FOOTER, 20) and end[-len(MCAP_MAGIC) :] == MCAP_MAGIC
            f.seek(len(MCAP_MAGIC))
        offset = len(MCAP_MAGIC)
        # CRCs of the data section (up to the DataEnd record) and of the summary (after it), as
        # written into DataEnd and the footer: damage outside the chunks (which have their own CRC)
        # is found too. None for the summary until DataEnd has been read.
        data_crc = zlib.crc32(magic)
        summary_crc: int | None = None
        while True:
            head = f.read(9)
            if len(head) < 9:
                self.end_note = (
                    f"ends at byte {offset} without a footer (not closed: the recorder crashed or was killed)"
                    if not head
                    else f"ends inside a record header at byte {offset} (not closed: crash?)"
                )
                return
            opcode, length = struct.unpack("<BQ", head)
            if closed and (opcode == 0 or length > size - offset - 9):
                raise self._fail(
                    offset, f"record {opcode:#04x} of {length} bytes runs past the end of this closed file"
                )
            if opcode == 0:
                # Not a valid opcode: zeros where a record should start are a file system's unwritten tail.
                self.end_note = f"zero bytes from byte {offset} on (an unfinished write)"
                return
            if length > size - offset - 9:
                self.end_note = (
                    f"the record at byte {offset} ends past the end of the file ({size} bytes): "
                    "cut short (not closed: crash?)"
                )
                return
            body = f.read(length)
            if len(body) < length:  # the file shrank while being read
                self.end_note = f"the record at byte {offset} was cut short while reading"
                return
            try:
                if opcode == _OP_FOOTER:
                    self._footer(f, offset, head, _Cursor(body), summary_crc)
                    return
                if summary_crc is not None:
                    # The summary only repeats schemas and channels and indexes what came before.
                    summary_crc = zlib.crc32(body, zlib.crc32(head, summary_crc))
                elif opcode == _OP_DATA_END:
                    expected = _Cursor(body).u32()
                    if expected not in (0, data_crc):
                        raise self._fail(
                            offset,
                            "the data section's CRC does not match: the file is damaged (the messages "
                            "read passed their chunk's CRC, but others may be missing)",
                        )
                    summary_crc = 0
                else:
                    data_crc = zlib.crc32(body, zlib.crc32(head, data_crc))
                    if opcode == _OP_CHUNK:
                        yield from self._chunk(body, offset, topics)
                    else:
                        msg = self._record(opcode, _Cursor(body), offset)
                        if msg is not None and (topics is None or msg.topic in topics):
                            yield msg
            except _Short as exc:
                raise self._fail(offset, f"record {opcode:#04x} is damaged: {exc}") from None
            except UnicodeDecodeError:
                raise self._fail(offset, f"record {opcode:#04x} is damaged: a name is not UTF-8") from None
            offset += 9 + length

    def _damaged(self, note: str) -> None:
        """Damage after the data section (summary, footer): every message was read intact, so noted."""
        self.damage = note if self.damage is None else f"{self.damage}; {note}"

    def _footer(self, f: BinaryIO, offset: int, head: bytes, cur: _Cursor, summary_crc: int | None) -> None:
        cur.u64(), cur.u64()  # summary start, summary offset start
        expected = cur.u32()
        if (
            summary_crc is not None
            and expected != 0
            and zlib.crc32(cur.buf[:16], zlib.crc32(head, summary_crc)) != expected
        ):
            self._damaged(f"the summary's CRC does not match (footer at byte {offset})")
        tail = f.read(len(MCAP_MAGIC))
        if len(tail) < len(MCAP_MAGIC):
            self.end_note = "the closing magic after the footer is cut short (crash while closing?)"
            return
        if tail != MCAP_MAGIC:
            self._damaged(f"the footer is not followed by the MCAP magic ({tail!r})")
        if self.damage is None:
            self.complete = True
            self.end_note = "closed cleanly (summary and footer present)"
        else:
            self.end_note = f"closed, but damaged after the messages (all of them intact): {self.damage}"

    def _record(self, opcode: int, cur: _Cursor, offset: int) -> RawMessage | None:
        if opcode == _OP_SCHEMA:
            schema_id = cur.u16()
            schema = SchemaInfo(cur.string(), cur.string(), cur.take(cur.u32()))
            if schema_id == 0:
                raise self._fail(offset, "a schema with id 0 (reserved for 'no schema')")
            known = self._schemas.setdefault(schema_id, schema)
            if known != schema:
                raise self._fail(offset, f"schema {schema_id} is defined twice, differently")
        elif opcode == _OP_CHANNEL:
            channel_id, schema_id = cur.u16(), cur.u16()
            topic, encoding = cur.string(), cur.string()
            meta = _Cursor(cur.buf, cur.pos, cur.end)
            meta_length = meta.u32()
            if meta_length > meta.end - meta.pos:
                raise _Short("channel metadata runs past the record")
            meta.end = meta.pos + meta_length
            while meta.pos < meta.end:
                meta.string(), meta.string()
            if schema_id != 0 and schema_id not in self._schemas:
                raise self._fail(offset, f"channel {topic!r} refers to schema {schema_id}, never defined")
            channel = ChannelInfo(topic, encoding, self._schemas.get(schema_id))
            known_channel = self.channels.setdefault(channel_id, channel)
            if known_channel != channel:
                raise self._fail(offset, f"channel {channel_id} is defined twice, differently")
        elif opcode == _OP_MESSAGE:
            channel_id, sequence, log_time, publish_time = struct.unpack("<HIQQ", cur.take(22))
            info = self.channels.get(channel_id)
            if info is None:
                raise self._fail(offset, f"a message on channel {channel_id}, which was never defined")
            self.message_count += 1
            return RawMessage(info, sequence, log_time, publish_time, cur.buf[cur.pos : cur.end])
        # Header, indexes, statistics, metadata, attachments, data end: nothing we need.
        return None

    def _chunk(self, body: bytes, offset: int, topics: frozenset[str] | None) -> Iterator[RawMessage]:
        cur = _Cursor(body)
        cur.u64(), cur.u64()  # message start/end time
        uncompressed_size, crc = cur.u64(), cur.u32()
        compression = cur.string()
        records = cur.take(cur.u64())
        data = self._decompress(compression, records, uncompressed_size, offset)
        if crc != 0 and zlib.crc32(data) != crc:
            raise self._fail(offset, "chunk CRC mismatch: the file is damaged")
        inner = _Cursor(data)
        while inner.pos < inner.end:
            start = inner.pos
            opcode, length = struct.unpack("<BQ", inner.take(9))
            if length > inner.end - inner.pos:
                raise self._fail(offset, f"chunk record at +{start} runs past the chunk")
            rec = _Cursor(inner.buf, inner.pos, inner.pos + length)
            inner.pos += length
            if opcode in (_OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE):
                msg = self._record(opcode, rec, offset)
                if msg is not None and (topics is None or msg.topic in topics):
                    yield msg

    def _decompress(self, compression: str, data: bytes, size: int, offset: int) -> bytes:
        try:
            if compression == "":
                out = data
            elif compression == "zstd":
                import zstandard

                pieces, total = [], 0
                for piece in zstandard.ZstdDecompressor().read_to_iter(io.BytesIO(data), write_size=1 << 16):
                    total += len(piece)
                    if total > size:
                        break  # more than announced: a damaged chunk (or a bomb), stop inflating
                    pieces.append(piece)
                out = b"".join(pieces)
            elif compression == "lz4":
                import lz4.frame

                out = lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=size + 1)
            else:
                raise self._fail(offset, f"chunk compression {compression!r} is not one this reader knows")
        except LogError:
            raise
        except Exception as exc:  # zstd/lz4 errors have their own types: all mean a damaged chunk here
            raise self._fail(offset, f"chunk does not decompress ({compression}): {exc}") from None
        if len(out) != size:
            raise self._fail(
                offset, f"chunk decompresses to {len(out)}{'+' if len(out) > size else ''} bytes, not {size}"
            )
        return out


# -- decoding messages -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class LogEntry:
    """One decoded message: `obj` is an instance of the registered type named by the schema, else a
    dict (non-finite floats restored where the file's schema says number); `raw` is the JSON as stored."""

    topic: str
    log_time_ns: int
    obj: Any
    raw: dict[str, Any]
    schema_name: str = ""

    @property
    def t_s(self) -> float:
        return self.log_time_ns * 1e-9


def _restore_nonfinite(value: Any, schema: Any, depth: int = 0) -> Any:
    if depth > 64 or not isinstance(schema, dict):
        return value
    kind = schema.get("type")
    if kind == "number" and isinstance(value, str):
        return _JSON_TO_NONFINITE.get(value, value)
    if kind == "object" and isinstance(value, dict):
        props = schema.get("properties")
        if isinstance(props, dict):
            return {k: _restore_nonfinite(v, props.get(k), depth + 1) for k, v in value.items()}
    if kind == "array" and isinstance(value, list):
        return [_restore_nonfinite(v, schema.get("items"), depth + 1) for v in value]
    return value


class _Decoder:
    def __init__(self, path: str) -> None:
        self.path = path
        self._file_schemas: dict[SchemaInfo, Any] = {}

    def decode(self, raw_msg: RawMessage) -> LogEntry:
        info = raw_msg.channel
        where = f"topic {info.topic!r}, message at {raw_msg.log_time_ns * 1e-9:.9f} s"
        if info.message_encoding != MESSAGE_ENCODING:
            raise LogError(self.path, f"{where}: message encoding {info.message_encoding!r} is not JSON")
        try:
            raw = json.loads(raw_msg.data)
        except (ValueError, RecursionError) as exc:
            raise LogError(self.path, f"{where}: not JSON ({str(exc)[:80]})") from None
        if not isinstance(raw, dict):
            raise LogError(self.path, f"{where}: expected a JSON object, got {_json_kind(raw)}")
        name = info.schema.name if info.schema is not None else ""
        cls = _types_by_name.get(name)
        if cls is None:
            obj: Any = _restore_nonfinite(raw, self._file_schema(info.schema))
        else:
            try:
                obj = _codec(cls).decode(raw)
            except _FieldError as exc:
                raise LogError(self.path, f"{where}: {exc.describe(cls.__qualname__)}") from None
            except RecursionError:
                raise LogError(self.path, f"{where}: nested too deeply") from None
        return LogEntry(info.topic, raw_msg.log_time_ns, obj, raw, name)

    def _file_schema(self, schema: SchemaInfo | None) -> Any:
        if schema is None or schema.encoding != SCHEMA_ENCODING:
            return None
        if schema not in self._file_schemas:
            try:
                self._file_schemas[schema] = json.loads(schema.data)
            except (ValueError, RecursionError):
                self._file_schemas[schema] = None  # an unreadable schema: leave the values as stored
        return self._file_schemas[schema]


def read_objects(path: str | os.PathLike[str], topics: Collection[str] | None = None) -> Iterator[LogEntry]:
    """The messages of a recording (optionally only `topics`), decoded, in file order.

    A crash-truncated file yields what it holds; a damaged one raises LogError.
    """
    reader = McapLogReader(path)
    decoder = _Decoder(reader.path)
    for raw_msg in reader.messages(topics):
        yield decoder.decode(raw_msg)


def read_frames(path: str | os.PathLike[str], bus: str | None = None) -> Iterator[can.Message]:
    """The CAN frames of a recording (all buses, or `bus`), as python-can messages with `channel` = bus."""
    reader = McapLogReader(path)
    decoder = _Decoder(reader.path)
    for raw_msg in reader.messages():
        topic = raw_msg.topic
        if not topic.startswith(CAN_TOPIC_PREFIX) or (bus is not None and topic != CAN_TOPIC_PREFIX + bus):
            continue
        entry = decoder.decode(raw_msg)
        if not isinstance(entry.obj, CanFrame):
            raise LogError(reader.path, f"topic {topic!r} has schema {entry.schema_name!r}, not CAN frames")
        try:
            yield entry.obj.to_message(channel=topic[len(CAN_TOPIC_PREFIX) :])
        except ValueError as exc:
            raise LogError(reader.path, f"topic {topic!r} at {entry.t_s:.9f} s: {exc}") from None
