"""The map's offset from the lane markings (seed 000 section 6) as a module of the urban host: each new
revolution into the marker map (`perception.lane_offset.LaneOffsetEstimator`), measured against the map
lane the car is on (the road network's lane index: the lane nearest our pose, in its own direction),
filtered, and out on `/urban/lane_offset` as the correction of our position to the map.

The estimator gives the lateral offset o of the real lane from the map's (left > 0). A map that is off by
a survey's error is off by a translation, so the correction is the vector o * n (n the map lane's left
normal where it was measured; none below `MIN_CORRECTION_M`): the behaviour and the controller subtract
it from our pose, and the behaviour from the perceived objects' positions (both are measured in the
position fix's frame), and the whole map then lies where the road is, through intersections as well.

Where the markings are expected is read off the map at the car's foot point, as the paper projects "the
lane markings specified in the RNDF": on each side of the lane, midway to the centre of a lane beside it
(parallel or not, its centre half a width to one and a half widths across) and that lane's far edge, or,
with no lane beside, the lane's own edge. An RNDF's lane centres lie farther apart than its lane width
in places (the DARPA sample's first segment: up to 4.8 m for 12 ft lanes), and abutting lanes of that
width put the shared line 0.6 m off where it is: the car drove its first 90 s 0.5 m beside its lane.

Where it measures: on a lane (not an exit or a zone), the car moving (`MIN_SPEED_MPS`) along it
(`MAX_HEADING_ERROR_RAD`), `SETTLE_M` or more after it came onto that lane from another. The map lane
handed to the estimator is the lane's whole curve around the car, not the edge to the next waypoint:
near a waypoint in a curve that edge's chord came from the 15 m behind the car alone (13.1's 25 m curve
on the DARPA sample: read 0.7-1.0 m on every lap). It reads the road network from the host's resources:
it runs in the host process.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from bywire.host.lateral import VehiclePose
from bywire.host.modules.estimation.lidar_perception import MAX_POSE_AGE_S, SENSOR_FORWARD_M, scan_of
from bywire.host.modules.module_params import number, refuse_unknown
from bywire.host.modules.perception_messages import (
    LANE_OFFSET,
    PERCEPTION_SCAN,
    LaneOffsetEstimate,
    PerceptionScan,
)
from bywire.host.modules.planning.urban_behaviour import extrapolate
from bywire.host.modules.urban_messages import URBAN_POSE, UrbanPose
from bywire.host.perception.lane_markers import warm_up
from bywire.host.perception.lane_offset import LaneOffsetEstimator
from bywire.host.roadnet.graph import DEFAULT_LANE_WIDTH_M, EdgeKind
from bywire.host.runtime.module import Module, ModuleContext

# Smaller offsets are the map's drawing (its waypoints' kinks, the paint's width), not its error: a
# survey's error that matters is a metre (seed 000 Sec. 6); the map is trusted within this.
MIN_CORRECTION_M = 0.3
# A lane beside ours has its centre this many of our lane widths across (as the simulated road's paint
# finds its neighbours, hil/lidar/road_marks.py) and runs within this angle of ours, either way.
BESIDE_LANE_WIDTHS = (0.5, 1.5)
BESIDE_MAX_ANGLE_RAD = math.radians(30.0)
MIN_SPEED_MPS = 1.0  # standing, the same markings would be counted again and again
# The paper's "predicted and estimated lane boundaries are close to parallel": measured only while the car
# drives along its lane. Across it (a K-turn in a dead end, a turn-around) the markings seen are the
# lane's end and the far kerb at a slant, and a few such frames restarted the filter on a 1.3 m offset.
MAX_HEADING_ERROR_RAD = math.radians(10.0)
# After a turn onto another lane the marker map still holds the road just left (it accumulates paint with
# the car's motion over its 40 m image), and its lines vote at a slant: on the DARPA sample, past the exit
# 1.2.6 -> 4.1.1, five such frames restarted the filter on a 1.4 m offset. Measured again once the car has
# driven this far along the new lane.
SETTLE_M = 20.0
# The map lane handed to the estimator, around the car's foot point, from the lane's whole curve (an
# edge ends at the next waypoint, and its chord then missed the curve ahead: 13.1 on the DARPA sample).
BEHIND_M, AHEAD_M = 20.0, 40.0


class LaneOffsetModule(Module):
    """Lane markings -> the correction of our pose to the map (see the module docstring)."""

    def __init__(self, lane_index: Any, params: Mapping[str, Any] | None = None) -> None:
        params = dict(params or {})
        self.lane_index = lane_index
        kind = "lane_offset"
        refuse_unknown(kind, params, ("sensor_forward_m", "min_correction_m"))
        forward = number(kind, params, "sensor_forward_m", SENSOR_FORWARD_M, -10.0, 10.0)
        self.min_correction_m = number(kind, params, "min_correction_m", MIN_CORRECTION_M, 0.0, 10.0)
        self.estimator = LaneOffsetEstimator(sensor_offset_m=(forward, 0.0))
        self._stamp_s = math.nan
        self._normal = (0.0, 0.0)
        self._lane: Any = None  # the map lane measured against, and where the car came onto it
        self._lane_since = (math.inf, math.inf)
        self._last = LaneOffsetEstimate(0.0, False, math.nan, 0.0, math.inf, False, 0.0, 0.0, 0.0)

    def _map_lane(self, x: float, y: float, h: float) -> tuple[np.ndarray, float, tuple[float, ...]] | None:
        """The centreline (driving order), width and expected markings (`expected_markings`) of the map
        lane the car is on, or None (also while the car has driven less than `SETTLE_M` along it since it
        came onto it)."""
        match = self.lane_index.match(x, y, h, max_heading_error_rad=MAX_HEADING_ERROR_RAD)
        if match is None or match.edge.kind != EdgeKind.LANE:
            return None
        if match.edge.lane != self._lane:
            # the first lane is measured at once (nothing of another road is in the marker map yet)
            since = (x, y) if self._lane is not None else (math.inf, math.inf)
            self._lane, self._lane_since = match.edge.lane, since
        if math.hypot(x - self._lane_since[0], y - self._lane_since[1]) < SETTLE_M:
            return None
        graph = self.lane_index.graph
        path = graph.lane_path(match.edge.lane)
        s_lane = graph.lane_s(match.edge.start) + match.s_m
        s = np.unique(np.clip(np.arange(s_lane - BEHIND_M, s_lane + AHEAD_M, 1.0), 0.0, path.length_m))
        if len(s) < 2:
            return None
        px, py, _, _ = path.sample(s)
        width = float(match.edge.lane_width_m or DEFAULT_LANE_WIDTH_M)
        return (
            np.column_stack((px, py)),
            width,
            expected_markings(self.lane_index, match.edge, match.s_m, width),
        )

    def start(self, ctx: ModuleContext) -> None:
        warm_up()  # the marker features' compiled kernels, before the first release

    def step(self, ctx: ModuleContext) -> None:
        now = ctx.now_s
        scan: PerceptionScan | None = ctx.latest(PERCEPTION_SCAN)
        pose: UrbanPose | None = ctx.latest(URBAN_POSE)
        if (
            scan is not None
            and scan.valid
            and not scan.stamp_s <= self._stamp_s
            and pose is not None
            and pose.valid
            and abs(scan.stamp_s - pose.stamp_s) <= MAX_POSE_AGE_S
            and abs(pose.speed_mps) >= MIN_SPEED_MPS
        ):
            self._stamp_s = scan.stamp_s
            self._measure(now, scan, pose)
        last = self._last
        ctx.publish(
            LANE_OFFSET,
            LaneOffsetEstimate(now, last.valid, last.stamp_s, last.offset_m, last.sigma_m, last.measured,
                               last.east_m, last.north_m, last.estimate_m),
        )  # fmt: skip

    def _measure(self, now: float, scan: PerceptionScan, pose: UrbanPose) -> None:
        x, y, h = extrapolate(pose, scan.stamp_s - pose.stamp_s)
        if pose.speed_mps < 0.0:
            h += math.pi  # backwards: the lane we are on runs the other way round our heading
        lane = self._map_lane(x, y, h)
        s = scan_of(scan)
        if lane is None:
            # not on a lane: the markings still go into the map (the car moves), nothing is measured
            self.estimator.markers.update(s, VehiclePose(x, y, h))
            est = self.estimator.filter.update(None, scan.stamp_s)
        else:
            centreline, width, markings = lane
            est = self.estimator.update(s, VehiclePose(x, y, h), centreline, width, markings_m=markings)
            d = centreline[-1] - centreline[0]
            norm = float(np.hypot(d[0], d[1]))
            if est.accepted and norm > 0.0:
                self._normal = (-float(d[1]) / norm, float(d[0]) / norm)
        nx, ny = self._normal
        applied = est.offset_m if abs(est.offset_m) >= self.min_correction_m else 0.0
        self._last = LaneOffsetEstimate(now, est.valid, est.stamp_s, applied, est.sigma_m, est.accepted,
                                        applied * nx, applied * ny, est.offset_m)  # fmt: skip


def expected_markings(lane_index: Any, edge: Any, s_m: float, width_m: float) -> tuple[float, ...]:
    """Where the map puts the markings at arc length `s_m` of lane `edge`, in metres left of its centre
    (see the module docstring), sorted."""
    foot = edge.path.point_at(s_m)
    nx, ny = -math.sin(foot.heading_rad), math.cos(foot.heading_rad)
    lo, hi = BESIDE_LANE_WIDTHS[0] * width_m, BESIDE_LANE_WIDTHS[1] * width_m
    nearest: dict[float, tuple[float, float]] = {}  # side -> (centre across, that lane's width)
    for cand in lane_index.candidates(foot.x_m, foot.y_m, None, max_distance_m=hi):
        other = cand.edge
        if other.kind != EdgeKind.LANE or other.lane == edge.lane:
            continue
        p = other.path.point_at(cand.s_m)
        if abs(math.cos(p.heading_rad - foot.heading_rad)) < math.cos(BESIDE_MAX_ANGLE_RAD):
            continue
        across = nx * (p.x_m - foot.x_m) + ny * (p.y_m - foot.y_m)
        side = math.copysign(1.0, across)
        if lo <= abs(across) <= hi and (side not in nearest or abs(across) < abs(nearest[side][0])):
            nearest[side] = (across, float(other.lane_width_m or DEFAULT_LANE_WIDTH_M))
    out: list[float] = []
    for side in (1.0, -1.0):
        if side in nearest:
            across, other_width = nearest[side]
            out += [0.5 * across, across + side * 0.5 * other_width]
        else:
            out.append(side * 0.5 * width_m)
    return tuple(sorted(out))


__all__ = ["LaneOffsetModule", "expected_markings"]
