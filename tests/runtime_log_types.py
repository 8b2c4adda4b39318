"""Store object types for the MCAP recording tests, importable by a recorder subprocess too.

Registered under fixed schema names so a recording made by another process decodes into them.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

import numpy as np

from bywire.host.runtime.log_schema import register_type


class Mode(enum.IntEnum):
    OFF = 0
    ARMED = 1
    ACTIVE = 2


class Faults(enum.IntFlag):
    NONE = 0
    WATCHDOG = 1
    CRC = 2
    STALE = 4


class Source(enum.Enum):
    GPS = "gps"
    ODOMETRY = "odometry"


@register_type(name="test.Point")
@dataclass(frozen=True, slots=True)
class Point:
    x_m: float
    y_m: float


@register_type(name="test.Pose")
@dataclass(frozen=True, slots=True)
class Pose:
    t_s: float
    x_m: float
    v_mps: float = 0.0
    source: Source = Source.GPS


@register_type(name="test.Status")
@dataclass(frozen=True)
class Status:
    """Every supported field kind at once."""

    t_s: float
    mode: Mode
    faults: Faults
    speed_mps: float
    gap_m: float | None
    counter: int
    engaged: bool
    note: str
    blob: bytes
    path: tuple[Point, ...]
    corner: tuple[float, float]
    modes: list[Mode]
    samples: np.ndarray = field(compare=False)  # arrays do not compare with ==: the tests compare them
    lead: Point | None = None


@register_type(name="test.Tick")
@dataclass(frozen=True, slots=True)
class Tick:
    """The crash test's object: a sequence number and the wall (monotonic) time it was recorded at."""

    t_s: float
    seq: int
    wall_s: float
