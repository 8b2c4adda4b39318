"""RNDF identifiers: ``M.N`` (lane, spot, perimeter ``M.0``) and ``M.N.P`` (waypoint, spot/perimeter point).

The DARPA format (2006, sec. 2.3) names everything by position: waypoint ``17.2.5`` is the fifth point of
lane 2 of segment 17; ``14.0.3`` is perimeter point 3 of zone 14 (the perimeter is "lane" 0); ``14.2.1``
is the first waypoint of spot 2 of zone 14.  These classes keep the numbers as integers so that ids sort
and compare numerically ("1.10" after "1.9") and hash cheaply as graph vertices.
"""

from __future__ import annotations

import re
from typing import NamedTuple

_LANE_RE = re.compile(r"(\d{1,9})\.(\d{1,9})")
_WAYPOINT_RE = re.compile(r"(\d{1,9})\.(\d{1,9})\.(\d{1,9})")


class LaneId(NamedTuple):
    """``M.N``: lane N of segment M, spot N of zone M, or the perimeter ``M.0`` of zone M."""

    segment: int
    lane: int

    def __str__(self) -> str:
        return f"{self.segment}.{self.lane}"

    @classmethod
    def parse(cls, text: str) -> LaneId:
        """``"17.2"`` -> LaneId(17, 2); ValueError for anything else (leading/trailing text included)."""
        m = _LANE_RE.fullmatch(text)
        if m is None:
            raise ValueError(f"expected a lane id M.N, found {text!r}")
        return cls(int(m.group(1)), int(m.group(2)))

    def waypoint(self, number: int) -> WaypointId:
        return WaypointId(self.segment, self.lane, number)


class WaypointId(NamedTuple):
    """``M.N.P``: waypoint P of lane (or spot, or perimeter when N == 0) M.N."""

    segment: int
    lane: int
    number: int  # P: the point's number in its lane (perimeter, spot)

    def __str__(self) -> str:
        return f"{self.segment}.{self.lane}.{self.number}"

    @classmethod
    def parse(cls, text: str) -> WaypointId:
        """``"17.2.5"`` -> WaypointId(17, 2, 5); ValueError for anything else."""
        m = _WAYPOINT_RE.fullmatch(text)
        if m is None:
            raise ValueError(f"expected a waypoint id M.N.P, found {text!r}")
        return cls(int(m.group(1)), int(m.group(2)), int(m.group(3)))

    @property
    def lane_id(self) -> LaneId:
        return LaneId(self.segment, self.lane)

    @property
    def is_perimeter(self) -> bool:
        return self.lane == 0
