"""A scenario with some of its fields set to other values: the variations of a campaign, and
`bywire hil run NAME --set PATH=VALUE`, which reproduces one of them alone.

A field is named by the path the scenario's readers use in their errors (`vehicle.v0_mps`,
`faults[0].at_s`, `world.vehicles[0].driver`), so that a campaign's parameter, an error about it and
the command that reruns it all say the same thing. Setting a mapping's key that is not there adds it
(the scenario's parser then judges it, as in a file); a list index must exist; `null` removes a key
(a scenario without its `world.fuzz`). The data is the file's, before parsing: the values are what a
YAML file would hold.
"""

from __future__ import annotations

import copy
import re
from collections.abc import Mapping
from typing import Any

import yaml

_PART = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)|\[(\d+)\]")
_PATH = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(\[\d+\])*(\.[A-Za-z_][A-Za-z0-9_]*(\[\d+\])*)*")


class OverrideError(ValueError):
    """A field path that does not name a place in the scenario (said with the path)."""


def check_path(path: str) -> None:
    """Refuse a malformed field path (`faults[0].at_s` is one, `faults.0` is not)."""
    if not _PATH.fullmatch(path):
        raise OverrideError(f"{path!r} is not a field path (keys joined by '.', list items as [i])")


def _parts(path: str) -> list[str | int]:
    check_path(path)
    return [key if key else int(index) for key, index in _PART.findall(path)]


def apply_overrides(data: Any, overrides: Mapping[str, Any]) -> dict[str, Any]:
    """A copy of the scenario data `data` with each field of `overrides` set (in their order)."""
    if not isinstance(data, dict):
        raise OverrideError(f"a scenario is a mapping, not {type(data).__name__}")
    out: dict[str, Any] = copy.deepcopy(data)
    for path, value in overrides.items():
        parts = _parts(path)
        node: Any = out
        for i, part in enumerate(parts[:-1]):
            where = _join(parts[: i + 1])
            if isinstance(part, int):
                if not isinstance(node, list) or part >= len(node):
                    raise OverrideError(f"{path}: there is no {where} ({_size(node)})")
                node = node[part]
            else:
                if not isinstance(node, dict):
                    raise OverrideError(f"{path}: {_join(parts[:i]) or 'the scenario'} is not a mapping")
                if node.get(part) is None:
                    node[part] = {}  # a section the file leaves out: its defaults, with this field set
                node = node[part]
        last = parts[-1]
        if isinstance(last, int):
            if not isinstance(node, list) or last >= len(node):
                raise OverrideError(f"{path}: there is no {_join(parts)} ({_size(node)})")
            node[last] = copy.deepcopy(value)
        elif not isinstance(node, dict):
            raise OverrideError(f"{path}: {_join(parts[:-1]) or 'the scenario'} is not a mapping")
        elif value is None:
            node.pop(last, None)
        else:
            node[last] = copy.deepcopy(value)
    return out


def _size(node: Any) -> str:
    return f"the list has {len(node)} items" if isinstance(node, list) else "not a list there"


def _join(parts: list[str | int]) -> str:
    text = ""
    for p in parts:
        text += f"[{p}]" if isinstance(p, int) else (f".{p}" if text else p)
    return text


def parse_assignment(text: str) -> tuple[str, Any]:
    """`PATH=VALUE` of the command line: VALUE is YAML (`25`, `[[0, 5.0]]`, `{kind: scripted}`)."""
    path, sep, value = text.partition("=")
    if not sep:
        raise OverrideError(f"{text!r}: expected PATH=VALUE (e.g. vehicle.v0_mps=25)")
    check_path(path.strip())
    try:
        return path.strip(), yaml.safe_load(value)
    except yaml.YAMLError as exc:
        raise OverrideError(f"{text!r}: the value is not YAML: {exc}") from None


def format_assignment(path: str, value: Any) -> str:
    """The `PATH=VALUE` that `parse_assignment` reads back as (path, value): YAML flow style."""
    text = yaml.safe_dump(value, default_flow_style=True, width=10**6).strip()
    if text.endswith("\n..."):
        text = text[: -len("\n...")].strip()
    return f"{path}={text}"


__all__ = ["OverrideError", "apply_overrides", "check_path", "format_assignment", "parse_assignment"]
