"""Errors and warnings of the RNDF / MDF readers.

Every error names the file, the line and what was expected there, as ``file:line: what was expected``;
the three parts are also attributes, so tools can point an editor at the line.  Warnings are for
what real DARPA files do that the 2006 format text does not allow but that loses no information
(header counts that disagree with the body, team-tool headers, missing end markers after a complete
last section); they travel with the parsed result instead of going to a logger, so that a caller
(``bywire rndf check``, a test) decides what to do with them.
"""

from __future__ import annotations

from dataclasses import dataclass


class RoadnetError(ValueError):
    """A road network or mission file that cannot be read: ``path:line: expected``."""

    def __init__(self, path: str, line: int, expected: str) -> None:
        self.path = path
        self.line = line
        self.expected = expected
        super().__init__(f"{path}:{line}: {expected}")

    def __reduce__(self) -> tuple[type[RoadnetError], tuple[str, int, str]]:
        # ValueError pickles with its message only; keep the three attributes across processes.
        return (type(self), (self.path, self.line, self.expected))


class RndfError(RoadnetError):
    """A Route Network Definition File that cannot be read or does not hold together."""


class MdfError(RoadnetError):
    """A Mission Data File that cannot be read, or whose checkpoints are not in its RNDF."""


@dataclass(frozen=True)
class ParseWarning:
    """Something tolerated while reading; ``str()`` gives ``path:line: warning: message``."""

    path: str
    line: int
    message: str

    def __str__(self) -> str:
        return f"{self.path}:{self.line}: warning: {self.message}"
