"""Strict readers for our configuration files (scenarios, host configurations, calibrations).

A typo in a safety-relevant file that silently does nothing is worse than no file: every reader
refuses unknown keys, wrong types and impossible values with the file and the path of the bad field
(`grade.yaml: faults[1].at_s: expected a number >= 0, got 'soon'`), and where the file is YAML, its
line too (`grade.yaml:14: faults[1].at_s: ...`, `yaml_line`), as compilers and linters name a place.
"""

from __future__ import annotations

import re
from typing import Any, Self


class SchemaError(ValueError):
    """A file that cannot be used, with the file and the path of the bad field."""

    def __init__(self, source: str, path: str, message: str) -> None:
        super().__init__(f"{source}: {path}: {message}" if path else f"{source}: {message}")
        self.source = source
        self.path = path
        self.message = message
        self.line: int | None = None

    def at_line(self, line: int | None) -> Self:
        """This error told at `line` (1-based) of its file: `file:line: path: what`."""
        if line is not None:
            self.line = line
            where = f"{self.source}:{line}"
            field = f"{self.path}: " if self.path else ""
            self.args = (f"{where}: {field}{self.message}",)
        return self


_PATH_PART = re.compile(r"\[(\d+)\]|([^.\[\]]+)")


def yaml_line(text: str, path: str) -> int | None:
    """The line (1-based) where the field `path` (`faults[1].at_s`, as `Reader` names it) stands in
    the YAML document `text`: its deepest part that is there; None for no part or no valid YAML.
    Read from the node tree, so that the data the readers see stays plain dicts and lists."""
    import yaml

    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError:
        return None
    line = None
    for index, key in _PATH_PART.findall(path):
        if key and isinstance(node, yaml.MappingNode):
            found = next((kv for kv in node.value if getattr(kv[0], "value", None) == key), None)
            if found is None:
                break
            line, node = found[0].start_mark.line + 1, found[1]
        elif index and isinstance(node, yaml.SequenceNode) and int(index) < len(node.value):
            node = node.value[int(index)]
            line = node.start_mark.line + 1
        else:
            break
    return line


class Reader:
    """Typed access to one mapping of a file, remembering where it is for error messages.

    Subclasses set `error_type` to their own `SchemaError` subclass.
    """

    error_type: type[SchemaError] = SchemaError

    def __init__(self, data: Any, source: str, path: str) -> None:
        if not isinstance(data, dict):
            raise self.error_type(source, path, f"expected a mapping, got {type(data).__name__}")
        self.data = data
        self.source = source
        self.path = path
        self.used: set[str] = set()

    def _p(self, key: str) -> str:
        return f"{self.path}.{key}" if self.path else key

    def error(self, key: str, message: str) -> SchemaError:
        return self.error_type(self.source, self._p(key), message)

    def has(self, key: str) -> bool:
        return key in self.data

    def raw(self, key: str, default: Any = None) -> Any:
        self.used.add(key)
        return self.data.get(key, default)

    def number(
        self, key: str, default: float | None = None, lo: float | None = None, hi: float | None = None
    ) -> float:
        self.used.add(key)
        if key not in self.data:
            if default is None:
                raise self.error(key, "required number is missing")
            return default
        value = self.data[key]
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.error(key, f"expected a number, got {value!r}")
        value = float(value)
        if value != value:
            raise self.error(key, "expected a number, got NaN")
        if lo is not None and value < lo:
            raise self.error(key, f"expected a number >= {lo}, got {value}")
        if hi is not None and value > hi:
            raise self.error(key, f"expected a number <= {hi}, got {value}")
        return value

    def opt_number(self, key: str, lo: float | None = None, hi: float | None = None) -> float | None:
        if key not in self.data or self.data[key] is None:
            self.used.add(key)
            return None
        return self.number(key, lo=lo, hi=hi)

    def string(self, key: str, default: str | None = None, choices: tuple[str, ...] | None = None) -> str:
        self.used.add(key)
        if key not in self.data:
            if default is None:
                raise self.error(key, "required string is missing")
            return default
        value = self.data[key]
        if not isinstance(value, str):
            raise self.error(key, f"expected a string, got {value!r}")
        if choices is not None and value not in choices:
            raise self.error(key, f"expected one of {', '.join(choices)}, got {value!r}")
        return value

    def boolean(self, key: str, default: bool) -> bool:
        self.used.add(key)
        value = self.data.get(key, default)
        if not isinstance(value, bool):
            raise self.error(key, f"expected true or false, got {value!r}")
        return value

    def sub(self, key: str) -> Self:
        self.used.add(key)
        return type(self)(self.data.get(key) or {}, self.source, self._p(key))

    def profile(self, key: str) -> tuple[tuple[float, float], ...]:
        """A piecewise profile: a list of [t_s, value] pairs with increasing t_s."""
        self.used.add(key)
        value = self.data.get(key)
        if value is None:
            return ()
        if isinstance(value, int | float) and not isinstance(value, bool):
            return ((0.0, float(value)),)
        if not isinstance(value, list):
            raise self.error(key, f"expected a list of [t_s, value] pairs or a number, got {value!r}")
        points: list[tuple[float, float]] = []
        for i, item in enumerate(value):
            ok = (
                isinstance(item, list | tuple)
                and len(item) == 2
                and all(isinstance(v, int | float) and not isinstance(v, bool) for v in item)
            )
            if not ok:
                raise self.error(f"{key}[{i}]", f"expected [t_s, value], got {item!r}")
            if points and item[0] <= points[-1][0]:
                raise self.error(f"{key}[{i}]", f"times must increase, {item[0]} after {points[-1][0]}")
            points.append((float(item[0]), float(item[1])))
        return tuple(points)

    def finish(self) -> None:
        unknown = sorted(set(self.data) - self.used)
        if unknown:
            raise self.error(unknown[0], "unknown key (a typo?)")
