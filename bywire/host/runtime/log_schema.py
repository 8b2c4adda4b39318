"""The message schema of recordings and of the live view: the registry that message dataclasses
register with, and the one JSON encoding of their instances.

Seed 000 section 3: the runtime's data are time-stamped objects that can be logged and replayed
(DESIGN.md section 1); STYLE "schema first": a message type is a dataclass defined once, and this
module turns it into a JSON Schema and its instances into JSON and back. A message type depends on
this module only, never on a file format: the MCAP recorder (`mcap_recorder`), the MCAP reader
(`mcap_reader`) and the Foxglove live view (`live_view`) all encode through it.

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

The schemas are written for Foxglove's parser, which accepts exactly one `type` per field, and every
message is valid JSON (RFC 8259) that validates against its own schema (a JSON Schema validator, e.g.
`jsonschema`, accepts every message of a recorded run). What JSON cannot spell is written so:

- NaN in a float field is the field left out: float fields are not `required`, and a float field
  that is absent reads back as NaN. Foxglove plots the missing sample as a gap, which is what a
  NaN is.
- None in an `X | None` field is the field left out too; the field's schema says so with the
  annotation `"default": null` (which is also how a reader tells an optional float from a float).
- NaN where no field can be left out (an item of `tuple[float, ...]`, or a `float | None` field,
  where leaving out means None) is null. JSON offers nothing else; a strict validator refuses a
  null there, so the types we record keep NaN out of float arrays and have no `float | None`
  fields (what the recorded-run tests check). Arrays of `X | None` are refused: their null would
  have no single type for Foxglove.
- +inf and -inf are the numbers 1e999 and -1e999: valid JSON numbers (RFC 8259 sec. 6 lets a
  parser choose its range) that Python's json and JavaScript's JSON.parse, hence Foxglove, read as
  +-Infinity.

Every finite float is written with Python's shortest round-trip repr, so decoding gives back
bit-identical floats (replay compares exactly). Recordings written before this convention (NaN,
Infinity and -Infinity as strings; None as null) still decode: a reader is given the schema the
file holds (`decode_message`) and follows what its writer meant, also for fields the writer did
not know yet (they take their class default).

Time. A message's time is its object's own `t_s` on the run's clock; `time_ns` gives the unsigned
nanoseconds that MCAP and Foxglove count in (0 for what they cannot hold).

Decoding is for untrusted input: a recording never names Python code to import; schema names are
looked up in the registry filled by `register_type` (`decode_message`), and unknown types come
back as dicts.
"""

from __future__ import annotations

import base64
import binascii
import contextlib
import dataclasses
import enum
import json
import math
import os
import re
import threading
import types
import typing
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar, overload

import numpy as np

T = TypeVar("T")

MESSAGE_ENCODING = "json"
SCHEMA_ENCODING = "jsonschema"

_JSON_TO_NONFINITE = {"NaN": math.nan, "Infinity": math.inf, "-Infinity": -math.inf}
_MAX_NS = 2**64 - 1
_NUMPY_DTYPE = re.compile(r"[<>|][biufc]\d{1,2}")
_MAX_NDIM = 32
# allow_nan=False: a non-finite float that slipped past the codecs must fail, not write bad JSON.
_JSON = json.JSONEncoder(separators=(",", ":"), allow_nan=False)
_PLUS_INFINITY, _MINUS_INFINITY = "1e999", "-1e999"

NONFINITE_CONVENTION = (
    "bywire recording: a float field left out is NaN; a field with default null left out is None; "
    "NaN in an array or in an optional float is null; +-infinity is 1e999 / -1e999"
)


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
    """How one Python type is written: its schema, and its encoder and decoder.

    `decode(value, writer)` gets the schema the writer of the value used, as the file holds it (None:
    written by this code). A dataclass field whose value `left_out(value)` says is written by
    leaving the field out, and an absent field reads back as `absent()`.
    """

    schema: dict[str, Any]
    item_schema: dict[str, Any]  # the schema as an array item: Foxglove takes less there
    encode: Callable[[Any], Any]
    decode: Callable[[Any, Any], Any]
    left_out: Callable[[Any], bool] | None = None
    absent: Callable[[], Any] | None = None


def _plain(decode: Callable[[Any], Any]) -> Callable[[Any, Any], Any]:
    """A decoder that reads the same whatever the writer's schema."""
    return lambda v, _writer: decode(v)


def _is_nan(v: Any) -> bool:
    return isinstance(v, float | np.floating) and v != v


def _encode_float(v: Any) -> float | None:
    """A float as JSON: null for NaN (only where its field cannot be left out), +-inf as is (the
    serializer writes them +-1e999)."""
    # float(): float subclasses (np.float64) and numpy scalars become plain floats for the JSON encoder.
    if isinstance(v, float | int | np.integer | np.floating) and not isinstance(v, bool | np.bool_):
        f = float(v)
    else:
        raise _FieldError(f"expected a number, got {type(v).__name__}")
    return None if f != f else f


def _decode_float(v: Any) -> float:
    if isinstance(v, float):
        return v
    if isinstance(v, int) and not isinstance(v, bool):
        return float(v)
    if v is None:
        return math.nan
    if isinstance(v, str) and v in _JSON_TO_NONFINITE:  # recordings of the older convention
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
    if tp is float:
        number: dict[str, Any] = {"type": "number"}
        return _Codec(number, number, _encode_float, _plain(_decode_float), _is_nan, lambda: math.nan)
    if tp in _SCALARS:
        scalar, enc, dec = _SCALARS[tp]
        return _Codec(scalar, scalar, enc, _plain(dec))
    if tp is bytes:
        return _Codec(
            {"type": "string", "contentEncoding": "base64"},
            {"type": "string", "description": "base64"},
            _encode_bytes,
            _plain(_decode_bytes),
        )
    if tp is np.ndarray or typing.get_origin(tp) is np.ndarray:
        schema: dict[str, Any] = {
            "type": "object",
            "description": "numpy array: data is the base64 of the C-order bytes of dtype and shape",
            "properties": {
                "dtype": {"type": "string"},
                "shape": {"type": "array", "items": {"type": "integer"}},
                "data": {"type": "string", "contentEncoding": "base64"},
            },
            "required": ["dtype", "shape", "data"],
        }
        return _Codec(schema, schema, _encode_ndarray, _plain(_decode_ndarray))
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        return _enum_codec(tp)
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        return _dataclass_codec(tp, building)
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        inner = [a for a in args if a is not type(None)]
        if len(inner) == 1 and len(args) == 2:
            return _optional_codec(_codec(inner[0], building), inner[0] is float)
        raise _FieldError(f"type {_type_name(tp)} is not supported: of unions only X | None is")
    if origin in (tuple, list, Sequence):
        return _sequence_codec(tp, origin, args, building)
    raise _FieldError(f"type {_type_name(tp)} is not supported (supported: {_SUPPORTED})")


def _type_name(tp: Any) -> str:
    return tp.__name__ if isinstance(tp, type) else repr(tp).replace("typing.", "")


def _optional_codec(inner: _Codec, holds_float: bool) -> _Codec:
    """`X | None`: None is the field left out, and `"default": null` in the schema says so. In a
    `float | None` field NaN is null; in recordings of the older convention (no default in the
    writer's schema) null was None."""

    def enc(v: Any) -> Any:
        return None if v is None else inner.encode(v)

    def dec(v: Any, writer: Any) -> Any:
        if v is None:
            new_convention = not isinstance(writer, dict) or "default" in writer
            return math.nan if holds_float and new_convention else None
        return inner.decode(v, writer)

    schema = {**inner.schema, "default": None}
    return _Codec(schema, inner.item_schema, enc, dec, lambda v: v is None, lambda: None)


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
    if item_origin in (typing.Union, types.UnionType):
        raise _FieldError(
            f"type {_type_name(tp)} is not supported: an item that may be None would be null, "
            "which no single item type of a JSON Schema admits (use a dataclass with an optional field)"
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

    def dec(v: Any, writer: Any) -> Any:
        if not isinstance(v, list):
            raise _FieldError(f"expected an array, got {_json_kind(v)}")
        if length is not None and len(v) != length:
            raise _FieldError(f"expected {length} items, got {len(v)}")
        item_writer = writer.get("items") if isinstance(writer, dict) else None
        out = []
        for i, x in enumerate(v):
            try:
                out.append(item.decode(x, item_writer))
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

    return _Codec(schema, item_schema, enc, _plain(dec))


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
        "required": [name for name, c in codecs if name in required and c.left_out is None],
        "additionalProperties": False,
    }
    names = {name for name, _ in codecs}
    missing_ok = {name for name, _ in codecs if name not in required}  # they have a default
    retired = _retired_by_type.get(cls, frozenset())

    def enc(v: Any) -> dict[str, Any]:
        if type(v) is not cls:
            raise _FieldError(f"expected a {cls.__name__}, got {type(v).__name__}")
        out = {}
        for name, c in codecs:
            value = getattr(v, name)
            if c.left_out is not None and c.left_out(value):
                continue
            try:
                out[name] = c.encode(value)
            except _FieldError as exc:
                raise exc.at(name) from None
        return out

    def dec(v: Any, writer: Any) -> Any:
        if not isinstance(v, dict):
            raise _FieldError(f"expected an object for {cls.__name__}, got {_json_kind(v)}")
        unknown = v.keys() - names - retired
        if unknown:
            raise _FieldError(
                f"fields {sorted(unknown)} are not in {cls.__name__} (recorded with another version of it?)"
            )
        written = writer.get("properties") if isinstance(writer, dict) else None
        if not isinstance(written, dict):
            written = None  # written by this code (or an unreadable schema): every field was known
        kwargs = {}
        for name, c in codecs:
            if name in v:
                try:
                    kwargs[name] = c.decode(v[name], None if written is None else written.get(name))
                except _FieldError as exc:
                    raise exc.at(name) from None
            elif name in missing_ok and written is not None and name not in written:
                pass  # a field its writer did not know yet: the class default
            elif c.absent is not None:
                kwargs[name] = c.absent()  # left out: NaN, None
            elif name not in missing_ok:
                raise _FieldError(f"field {name!r} of {cls.__name__} is missing")
        try:
            return cls(**kwargs)
        except Exception as exc:  # the class's own checks (__post_init__) refusing recorded values
            raise _FieldError(f"{cls.__name__} refused the recorded values: {exc}") from exc

    return _Codec(schema, schema, enc, dec)


# -- the type registry ----------------------------------------------------------------------------------

_names_by_type: dict[type, str] = {}
_types_by_name: dict[str, type] = {}
_retired_by_type: dict[type, frozenset[str]] = {}  # fields older versions recorded, ignored when read


@overload
def register_type(cls: type[T], *, name: str | None = None, retired: tuple[str, ...] = ()) -> type[T]: ...
@overload
def register_type(
    cls: None = None, *, name: str | None = None, retired: tuple[str, ...] = ()
) -> Callable[[type[T]], type[T]]: ...


def register_type(
    cls: type[T] | None = None, *, name: str | None = None, retired: tuple[str, ...] = ()
) -> Any:
    """Make a dataclass decodable from recordings, under `name` (default `module.QualName`).

    Use as `register_type(cls)`, `@register_type` or `@register_type(name="bywire.Pose")`. The
    name is the MCAP schema name: keep it stable when moving the class, or old recordings decode
    as dicts. `retired`: fields an older version of the class had; recordings that carry them still
    decode (the value is dropped). Checks that every field type can be encoded (LogError naming the
    field if not).
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
            _retired_by_type[klass] = frozenset(retired)
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
    schema["$comment"] = NONFINITE_CONVENTION
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
    try:
        return _JSON.encode(payload).encode()
    except ValueError:  # an infinity (NaN never gets here): the rare case, written by hand
        return _json_with_infinities(payload).encode()


def _json_with_infinities(value: Any) -> str:
    """What `_JSON` writes, with +-inf as the numbers +-1e999 (finite floats by the same repr)."""
    if isinstance(value, float):
        if math.isinf(value):
            return _PLUS_INFINITY if value > 0 else _MINUS_INFINITY
        return _JSON.encode(value)
    if isinstance(value, dict):
        items = (f"{_JSON.encode(k)}:{_json_with_infinities(v)}" for k, v in value.items())
        return "{" + ",".join(items) + "}"
    if isinstance(value, list):
        return "[" + ",".join(_json_with_infinities(v) for v in value) + "]"
    return _JSON.encode(value)


def decode_object(cls: type[T], data: bytes | dict[str, Any]) -> T:
    """Decode one JSON message (bytes or already parsed) into `cls` (LogError naming the field)."""
    try:
        raw = json.loads(data) if isinstance(data, bytes | bytearray) else data
        return typing.cast(T, _codec(cls).decode(raw, None))
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


def object_time_ns(obj: object, where: str | os.PathLike[str], topic: str) -> int:
    """The log time of an object from its `t_s` (what the recorder and the live view stamp); LogError
    naming `where` and the topic when it has none."""
    t_s = getattr(obj, "t_s", None)
    if isinstance(t_s, bool) or not isinstance(t_s, int | float):
        raise LogError(where, f"topic {topic!r}: {type(obj).__name__} has no float t_s to time it")
    return time_ns(float(t_s))


# -- decoding recorded messages ------------------------------------------------------------------------


def decode_message(
    schema_name: str, data: bytes, file_schema: Callable[[], Any]
) -> tuple[Any, dict[str, Any]]:
    """Decode one recorded JSON message whose schema is named `schema_name`: (object, JSON as stored).

    The object is an instance of the type registered under that name, else the stored dict with what
    JSON cannot spell restored where `file_schema()` (the message's JSON Schema as the file holds it,
    parsed, or None) says number: a number field left out or null is NaN, a field with default null
    left out is None. The file's schema also tells the registered types which convention and which
    fields the writer knew. LogError("<decode>", the problem) if the message is not JSON, not an
    object, or does not fit its registered type.
    """
    try:
        raw = json.loads(data)
    except (ValueError, RecursionError) as exc:
        raise LogError("<decode>", f"not JSON ({str(exc)[:80]})") from None
    if not isinstance(raw, dict):
        raise LogError("<decode>", f"expected a JSON object, got {_json_kind(raw)}")
    cls = _types_by_name.get(schema_name)
    if cls is None:
        return _restore_nonfinite(raw, file_schema()), raw
    try:
        return _codec(cls).decode(raw, file_schema()), raw
    except _FieldError as exc:
        raise LogError("<decode>", exc.describe(cls.__qualname__)) from None
    except RecursionError:
        raise LogError("<decode>", "nested too deeply") from None


def _restore_nonfinite(value: Any, schema: Any, depth: int = 0, in_array: bool = False) -> Any:
    if depth > 64 or not isinstance(schema, dict):
        return value
    kind = schema.get("type")
    if kind == "number":
        if isinstance(value, str):  # the older convention's strings
            return _JSON_TO_NONFINITE.get(value, value)
        if value is None and (in_array or "default" in schema):
            return math.nan  # an optional float without a default is the older convention's None
        return value
    if kind == "object" and isinstance(value, dict):
        props = schema.get("properties")
        if isinstance(props, dict):
            out = {k: _restore_nonfinite(v, props.get(k), depth + 1) for k, v in value.items()}
            for k, prop in props.items():
                if k in out or not isinstance(prop, dict):
                    continue
                if "default" in prop:
                    out[k] = prop["default"]
                elif prop.get("type") == "number":
                    out[k] = math.nan
            return out
    if kind == "array" and isinstance(value, list):
        return [_restore_nonfinite(v, schema.get("items"), depth + 1, in_array=True) for v in value]
    return value
