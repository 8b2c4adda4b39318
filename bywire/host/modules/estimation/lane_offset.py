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
(`MAX_HEADING_ERROR_RAD`), `SETTLE_M` or more after it came onto that lane from another, and only where
the map's lines run parallel to the lane over the +-15 m the measurement's chord spans
(`parallel_markings`, looked at every `STATION_M`):

- no other lane lies within half a width of it: there the map draws two lanes on one, and the simulated
  road paints both lanes' lines (the DARPA sample's 3.1 and 3.2 lie 0.6-1.6 m apart over 60 m: their
  lines were read as a 1.0-1.5 m offset for 6 s, and the car drove 1.47 m beside its lane);
- as many markings are expected all along: a lane beside begins or ends, or its centre crosses
  1.5 widths, where the paint changes from a line midway to the lane's own edges (10.1 beside 10.2 lies
  5.48-5.52 m across);
- every lane within `REACH_LANE_WIDTHS` keeps its distance across within `PARALLEL_TOL_M`: a diverging
  lane's lines smear beside the expected ones or pull the Radon direction off ours (3.1 leaving 3.2 at
  3.7 deg: read 0.7 m).

Elsewhere nothing is measured, and the filter holds what it had (a real RNDF error changes slowly along
a road). The map lane handed to the estimator is the lane's whole curve around the car, not the edge to
the next waypoint: near a waypoint in a curve that edge's chord came from the 15 m behind the car alone
(13.1's 25 m curve: read 0.7-1.0 m on every lap). On the DARPA sample mission's recorded marker images
(the map right: every offset a misreading), 361 of 13 256 frames read more than 0.3 m (86 more than
1 m); with the whole curve, these rules and the estimator's own (no measurement at the angle window's
edge, no restart onto a jump within a lane) 2 do (0.33 m at most), and 28 % of the frames are not
measured. It reads the road network from the host's resources: it runs in the host process.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
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
# The map is compared with the paint only where its lines run parallel to the lane over the measurement's
# chord (`OffsetParams.centreline_window_m`, +-15 m), looked at every `STATION_M`: there the Radon plane
# has one direction and the lines lie where the map says at the car as well.
PARALLEL_WINDOW_M = 15.0
STATION_M = 2.5
# A lane within this many of our widths (centre to centre) paints lines that can vote: its near edge
# within 2.5 widths, where a vote is still matched beyond the farthest expected marking (2 widths).
REACH_LANE_WIDTHS = 3.0
# A lane is abreast of a point where its nearest point lies square to it within this (its samples' chords);
# farther along, that nearest point is the lane's end.
ABREAST_M = 0.5
# A lane that moves across by more than this over the window is not parallel (1 deg over 30 m): its line
# projects to a smear that moves the peak, or pulls the Radon direction off ours.
PARALLEL_TOL_M = 0.5


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
        self._stations: dict[tuple[Any, int], _Station] = {}  # parallel_markings' cache
        self._last = LaneOffsetEstimate(0.0, False, math.nan, 0.0, math.inf, False, 0.0, 0.0, 0.0)

    def _map_lane(self, x: float, y: float, h: float) -> tuple[np.ndarray, float, tuple[float, ...]] | None:
        """The centreline (driving order), width and expected markings (`parallel_markings`) of the map
        lane the car is on, or None: off a lane, where the map's lines are not parallel to it, and while
        the car has driven less than `SETTLE_M` along it since it came onto it."""
        match = self.lane_index.match(x, y, h, max_heading_error_rad=MAX_HEADING_ERROR_RAD)
        if match is None or match.edge.kind != EdgeKind.LANE:
            return None
        if match.edge.lane != self._lane:
            # the first lane is measured at once (nothing of another road is in the marker map yet)
            since = (x, y) if self._lane is not None else (math.inf, math.inf)
            self._lane, self._lane_since = match.edge.lane, since
        if math.hypot(x - self._lane_since[0], y - self._lane_since[1]) < SETTLE_M:
            return None
        width = float(match.edge.lane_width_m or DEFAULT_LANE_WIDTH_M)
        markings = parallel_markings(self.lane_index, match.edge, match.s_m, width, self._stations)
        if markings is None:
            return None
        graph = self.lane_index.graph
        path = graph.lane_path(match.edge.lane)
        s_lane = graph.lane_s(match.edge.start) + match.s_m
        s = np.unique(np.clip(np.arange(s_lane - BEHIND_M, s_lane + AHEAD_M, 1.0), 0.0, path.length_m))
        if len(s) < 2:
            return None
        px, py, _, _ = path.sample(s)
        return np.column_stack((px, py)), width, markings

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
            est = self.estimator.update(
                s, VehiclePose(x, y, h), centreline, width, markings_m=markings, road=self._lane
            )
            d = centreline[-1] - centreline[0]
            norm = float(np.hypot(d[0], d[1]))
            if est.accepted and norm > 0.0:
                self._normal = (-float(d[1]) / norm, float(d[0]) / norm)
        nx, ny = self._normal
        applied = est.offset_m if abs(est.offset_m) >= self.min_correction_m else 0.0
        self._last = LaneOffsetEstimate(now, est.valid, est.stamp_s, applied, est.sigma_m, est.accepted,
                                        applied * nx, applied * ny, est.offset_m)  # fmt: skip


def lanes_beside(
    lane_index: Any, lane: Any, x_m: float, y_m: float, heading_rad: float, reach_m: float
) -> dict[Any, tuple[float, float]]:
    """The other lanes beside the point (x, y) of lane `lane` heading `heading_rad`: lane id -> (its
    centre's distance across, left > 0; its width), for each lane that runs within
    `BESIDE_MAX_ANGLE_RAD` of it either way, whose centre lies within `reach_m`, abreast of the point
    (its nearest point is square to it, not an end of it that lies ahead or behind)."""
    nx, ny = -math.sin(heading_rad), math.cos(heading_rad)
    nearest: dict[Any, Any] = {}  # lane -> its nearest candidate edge
    for cand in lane_index.candidates(x_m, y_m, None, max_distance_m=reach_m):
        other = cand.edge
        if other.kind != EdgeKind.LANE or other.lane == lane:
            continue
        if other.lane not in nearest or cand.distance_m < nearest[other.lane].distance_m:
            nearest[other.lane] = cand
    out: dict[Any, tuple[float, float]] = {}
    for other_lane, cand in nearest.items():
        p = cand.edge.path.point_at(cand.s_m)
        if abs(math.cos(p.heading_rad - heading_rad)) < math.cos(BESIDE_MAX_ANGLE_RAD):
            continue
        dx, dy = p.x_m - x_m, p.y_m - y_m
        if abs(dx * math.cos(p.heading_rad) + dy * math.sin(p.heading_rad)) > ABREAST_M:
            continue  # the lane ends before it comes abreast
        out[other_lane] = (nx * dx + ny * dy, float(cand.edge.lane_width_m or DEFAULT_LANE_WIDTH_M))
    return out


def _markings(beside: Mapping[Any, tuple[float, float]], width_m: float) -> tuple[float, ...]:
    """The expected markings (see `expected_markings`) from the lanes beside (`lanes_beside`)."""
    lo, hi = BESIDE_LANE_WIDTHS[0] * width_m, BESIDE_LANE_WIDTHS[1] * width_m
    nearest: dict[float, tuple[float, float]] = {}  # side -> (centre across, that lane's width)
    for across, other_width in beside.values():
        side = math.copysign(1.0, across)
        if lo <= abs(across) <= hi and (side not in nearest or abs(across) < abs(nearest[side][0])):
            nearest[side] = (across, other_width)
    out: list[float] = []
    for side in (1.0, -1.0):
        if side in nearest:
            across, other_width = nearest[side]
            out += [0.5 * across, across + side * 0.5 * other_width]
        else:
            out.append(side * 0.5 * width_m)
    return tuple(sorted(out))


def expected_markings(lane_index: Any, edge: Any, s_m: float, width_m: float) -> tuple[float, ...]:
    """Where the map puts the markings at arc length `s_m` of lane `edge`, in metres left of its centre
    (see the module docstring), sorted."""
    foot = edge.path.point_at(s_m)
    beside = lanes_beside(
        lane_index, edge.lane, foot.x_m, foot.y_m, foot.heading_rad, BESIDE_LANE_WIDTHS[1] * width_m
    )
    return _markings(beside, width_m)


@dataclass(frozen=True)
class _Station:
    """What the map has beside a station of a lane (`parallel_markings`)."""

    overlapped: bool  # another lane's centre within half a width of it
    markings: int  # how many markings are expected there
    across_m: Mapping[Any, float]  # the lanes within reach: their centres' distance across


def _station(lane_index: Any, lane: Any, s_m: float, width_m: float) -> _Station:
    p = lane_index.graph.lane_path(lane).point_at(s_m)
    beside = lanes_beside(lane_index, lane, p.x_m, p.y_m, p.heading_rad, REACH_LANE_WIDTHS * width_m)
    return _Station(
        any(abs(a) < BESIDE_LANE_WIDTHS[0] * width_m for a, _ in beside.values()),
        len(_markings(beside, width_m)),
        {other: a for other, (a, _) in beside.items()},
    )


def parallel_markings(
    lane_index: Any,
    edge: Any,
    s_m: float,
    width_m: float,
    cache: dict[tuple[Any, int], _Station] | None = None,
) -> tuple[float, ...] | None:
    """`expected_markings` at arc length `s_m` of lane `edge`, or None where the map's lines do not run
    parallel to the lane over +-`PARALLEL_WINDOW_M` along it (see the module docstring): another lane
    within half a width of it (the map draws two lanes on one), expected markings that come or go (a
    lane beside begins, ends, or crosses the band of `BESIDE_LANE_WIDTHS`), or a lane within
    `REACH_LANE_WIDTHS` that moves across by more than `PARALLEL_TOL_M` (it diverges). The stations
    lie every `STATION_M` along the lane from its start; `cache` keeps them (the map does not move)."""
    graph = lane_index.graph
    lane = edge.lane
    length = graph.lane_path(lane).length_m
    s_lane = graph.lane_s(edge.start) + s_m
    first = max(math.ceil((s_lane - PARALLEL_WINDOW_M) / STATION_M), 0)
    last = min(math.floor((s_lane + PARALLEL_WINDOW_M) / STATION_M), math.floor(length / STATION_M))
    counts: set[int] = set()
    across: dict[Any, list[float]] = {}
    for k in range(first, last + 1):
        station = cache.get((lane, k)) if cache is not None else None
        if station is None:
            station = _station(lane_index, lane, k * STATION_M, width_m)
            if cache is not None:
                cache[(lane, k)] = station
        if station.overlapped:
            return None
        counts.add(station.markings)
        for other, a in station.across_m.items():
            across.setdefault(other, []).append(a)
    if len(counts) > 1 or any(max(a) - min(a) > PARALLEL_TOL_M for a in across.values()):
        return None
    return expected_markings(lane_index, edge, s_m, width_m)


__all__ = ["LaneOffsetModule", "expected_markings", "lanes_beside", "parallel_markings"]
