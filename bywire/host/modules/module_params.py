"""A module's `params:` from a host configuration, read so that a misspelt key or a value out of range
is refused where it is written.

The configuration loader checks every module's params when it loads the file (`ModuleKind.check_params`),
so the error names the file and the module (`modules[3].params: lidar_perception: unknown params
['join_distanse_m'] ...`). Read only at the module's start, the same mistake would raise in every
restart until the module's failure policy stopped the host.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Mapping
from typing import Any


def refuse_unknown(kind: str, params: Mapping[str, Any], known: Iterable[str]) -> None:
    """ValueError naming the keys of `params` that are not in `known`, and those that are."""
    known = set(known)
    extra = sorted(set(params) - known)
    if extra:
        raise ValueError(f"{kind}: unknown params {extra} (known: {', '.join(sorted(known)) or 'none'})")


def number(
    kind: str,
    params: Mapping[str, Any],
    key: str,
    default: float,
    lo: float = -math.inf,
    hi: float = math.inf,
) -> float:
    """`params[key]` (or `default`) as a float, refused unless a finite number in lo..hi."""
    value = params.get(key, default)
    if (
        isinstance(value, bool)
        or not isinstance(value, int | float)
        or not math.isfinite(value)
        or not lo <= value <= hi
    ):
        raise ValueError(f"{kind}: params.{key} must be a number in {lo:g}..{hi:g}, got {value!r}")
    return float(value)


def integer(kind: str, params: Mapping[str, Any], key: str, default: int, lo: int, hi: int) -> int:
    """`params[key]` (or `default`) as an int, refused unless an integer in lo..hi."""
    value = params.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise ValueError(f"{kind}: params.{key} must be an integer in {lo}..{hi}, got {value!r}")
    return value


def station_ids(kind: str, params: Mapping[str, Any], key: str) -> frozenset[int]:
    """A list of V2X station ids (0..2^32-1)."""
    value = params.get(key, ())
    if not isinstance(value, list | tuple) or any(
        isinstance(s, bool) or not isinstance(s, int) or not 0 <= s < 2**32 for s in value
    ):
        raise ValueError(f"{kind}: params.{key} must be a list of station ids (0..2^32-1), got {value!r}")
    return frozenset(value)


def make_dataclass(
    kind: str, cls: type[Any], params: Mapping[str, Any], prefix: str = "", also_known: Iterable[str] = ()
) -> Any:
    """`cls(**params)` with the dataclass's field names (after `prefix`, which the keys carry), a
    number where the field's default is one (or null where its type allows None), and the
    dataclass's own checks; every refusal a ValueError that names the module kind and the key.
    `also_known`: the module's other params, named with these when a key is unknown."""
    fields = {f.name: f for f in dataclasses.fields(cls)}
    refuse_unknown(kind, params, [prefix + name for name in fields] + list(also_known))
    kwargs: dict[str, Any] = {}
    for key, value in params.items():
        name = key[len(prefix) :]
        default: Any = fields[name].default
        nullable = "None" in str(fields[name].type)
        if (
            isinstance(default, int | float)
            and not isinstance(default, bool)
            and not (value is None and nullable)
        ):
            value = number(kind, params, key, float(default))
        kwargs[name] = value
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{kind}: {exc}") from exc
