"""Roads as lanes: `Lane` = an id and a `host.roadnet.path.Path` (arc length, point_at, project).

Here a road from a scenario's `RoadSpec`: straight, or a constant-curvature arc (gently curved,
|radius| >= 200 m), `lanes` lanes side by side, lane 0 on the right, lane k offset k lane widths to the
left. The road starts at the origin of the local plane (`host.geo.LocalFrame` at the road's geodetic
origin), so the plant's GPS emulator and the host's lane map share one frame. The urban world
(`hil.world.urban`) uses the same `Path` type directly, as the edges of its `RoadGraph`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bywire.hil.world.spec import RoadSpec
from bywire.host.geo import LocalFrame
from bywire.host.roadnet.path import Path

SAMPLE_M = 1.0  # lane sampling; Path interpolates linearly between samples


@dataclass(frozen=True)
class Lane:
    lane_id: int
    path: Path

    @property
    def length_m(self) -> float:
        return self.path.length_m


@dataclass(frozen=True)
class Pose2D:
    x_m: float
    y_m: float
    heading_rad: float


class Road:
    """A set of lanes on the local plane with the geodetic origin of that plane."""

    def __init__(self, spec: RoadSpec) -> None:
        self.spec = spec
        self.frame = LocalFrame(spec.origin_lat_deg, spec.origin_lon_deg)
        self.lanes: dict[int, Lane] = {k: Lane(k, _lane_path(spec, k)) for k in range(spec.lanes)}
        self._straight = spec.radius_m is None
        h0 = math.radians(spec.heading_deg)
        self._c, self._s = math.cos(h0), math.sin(h0)

    def lane(self, lane_id: int) -> Lane:
        try:
            return self.lanes[lane_id]
        except KeyError:
            raise KeyError(f"no lane {lane_id} (lanes: {sorted(self.lanes)})") from None

    def pose_at(self, lane_id: int, s_m: float, lateral_m: float = 0.0) -> Pose2D:
        """Pose on `lane_id` at arc length s (straight past the ends), shifted `lateral_m` to the left."""
        if self._straight:
            w = lane_id * self.spec.lane_width_m + lateral_m
            return Pose2D(
                s_m * self._c - w * self._s, s_m * self._s + w * self._c, math.radians(self.spec.heading_deg)
            )
        path = self.lane(lane_id).path
        length = path.length_m
        p = path.point_at(min(max(s_m, 0.0), length))
        extra = s_m - length if s_m > length else min(s_m, 0.0)
        x = p.x_m + extra * math.cos(p.heading_rad) - lateral_m * math.sin(p.heading_rad)
        y = p.y_m + extra * math.sin(p.heading_rad) + lateral_m * math.cos(p.heading_rad)
        return Pose2D(x, y, p.heading_rad)

    def locate(self, x_m: float, y_m: float, hint_s: float | None = None) -> tuple[int, float, float]:
        """(lane id, arc length on it, lateral offset from its centre, left > 0) of the nearest lane."""
        if self._straight:
            along = x_m * self._c + y_m * self._s
            left = -x_m * self._s + y_m * self._c
            w = self.spec.lane_width_m
            k = min(max(round(left / w), 0), self.spec.lanes - 1)
            return k, along, left - k * w
        best: tuple[int, float, float] | None = None
        for lane in self.lanes.values():
            proj = lane.path.project(x_m, y_m, hint_s)
            if best is None or abs(proj.lateral_offset_m) < abs(best[2]):
                best = (lane.lane_id, proj.s_m, proj.lateral_offset_m)
        assert best is not None
        return best


def _lane_path(spec: RoadSpec, k: int) -> Path:
    h0 = math.radians(spec.heading_deg)
    offset = k * spec.lane_width_m
    n = max(2, math.ceil(spec.length_m / SAMPLE_M) + 1)
    if spec.radius_m is None:
        s = np.linspace(0.0, spec.length_m, n)
        x = s * math.cos(h0) - offset * math.sin(h0)
        y = s * math.sin(h0) + offset * math.cos(h0)
        return Path(x, y, np.full(n, h0), np.zeros(n))
    # Arc of the reference lane (lane 0), centre to the left for radius > 0; lane k is the parallel arc
    # k widths to the left, radius R - k w, same angle swept (so its arc length differs slightly).
    radius = spec.radius_m
    cx, cy = -radius * math.sin(h0), radius * math.cos(h0)
    sweep = spec.length_m / radius
    ang = np.linspace(0.0, sweep, n)
    r_k = radius - offset
    phi = h0 - math.pi / 2.0 + ang  # angle from the centre to the lane point
    x = cx + r_k * np.cos(phi)
    y = cy + r_k * np.sin(phi)
    heading = h0 + ang
    return Path(x, y, heading, np.full(n, 1.0 / r_k))


__all__ = ["Lane", "Pose2D", "Road"]
