"""Lane facts the Drive family needs: the lane beside us, where an object is along a lane, lane MTC.

`adjacent_left_lane` finds the lane to our left in the same segment (the one we pass on, or K-turn
into) by projecting our position onto each of the segment's other lanes: a lane in our direction lies
left when we are right of it; an opposite lane lies left when we are left of it (its left is our
right). It counts when its centre line is 1 m to 2.2 lane widths away (as the road graph's adjacency,
host/roadnet/graph.py) and runs within 30 deg of parallel (or anti-parallel). `opposite_lane_nearby`
looks further, for a turn-around where the segment has no such lane: the nearest lane of *any*
segment to our left that runs the other way alongside us (a street drawn as two one-way segments).

`lane_vehicles` turns the objects matched to a lane (their `LaneRef`, seed 000 Sec. 8) into the MTC's
`ConflictVehicle`s for one merge point given in that lane's coordinate (its arc length): d_B = MP -
B's front bumper, each vehicle driving along its lane (Sec. 9.1 assumptions 1 and 2).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

from bywire.host.roadnet.graph import DEFAULT_LANE_WIDTH_M, EdgeKind, RoadGraph
from bywire.host.roadnet.ids import LaneId

from .mtc import ConflictVehicle
from .rules import MtcParams
from .situation import TrackedObject

__all__ = ["AdjacentLane", "adjacent_left_lane", "lane_position", "lane_vehicles", "opposite_lane_nearby"]

_PARALLEL_RAD = math.radians(30.0)


@dataclass(frozen=True)
class AdjacentLane:
    lane: LaneId
    offset_m: float  # its centre line, this far to our left (> 0)
    opposite: bool  # it runs the other way
    lane_s_m: float  # our position's foot on it, in its arc length


def adjacent_left_lane(
    graph: RoadGraph, lane: LaneId, x_m: float, y_m: float, heading_rad: float
) -> AdjacentLane | None:
    """The nearest lane of `lane`'s segment to the left of the pose (None if there is none)."""
    try:
        segment = graph.network.segment(lane.segment)
    except KeyError:
        return None
    width = graph.network.lane(lane).width_m or DEFAULT_LANE_WIDTH_M
    best: AdjacentLane | None = None
    for other in segment.lanes:
        if other.id == lane:
            continue
        path = graph.lane_path(other.id)
        if path is None:
            continue
        proj = path.project(x_m, y_m, heading_rad=heading_rad)
        if not (0.0 < proj.s_m < path.length_m):
            continue  # not alongside this lane
        err = abs(proj.heading_error_rad)
        if err < _PARALLEL_RAD:
            offset, opposite = -proj.lateral_offset_m, False
        elif err > math.pi - _PARALLEL_RAD:
            offset, opposite = proj.lateral_offset_m, True
        else:
            continue
        max_gap = 2.2 * max(width, other.width_m or DEFAULT_LANE_WIDTH_M)
        if 1.0 <= offset <= max_gap and (best is None or offset < best.offset_m):
            best = AdjacentLane(other.id, offset, opposite, proj.s_m)
    return best


def opposite_lane_nearby(
    graph: RoadGraph, x_m: float, y_m: float, heading_rad: float, max_offset_m: float
) -> AdjacentLane | None:
    """The nearest lane of any segment that runs the other way alongside us, its centre line 1 m to
    `max_offset_m` to our left (None if there is none)."""
    best: AdjacentLane | None = None
    for seg in graph.network.segments:
        for other in seg.lanes:
            path = graph.lane_path(other.id)
            if path is None:
                continue
            proj = path.project(x_m, y_m, heading_rad=heading_rad)
            if not (0.0 < proj.s_m < path.length_m) or abs(proj.heading_error_rad) < math.pi - _PARALLEL_RAD:
                continue
            offset = proj.lateral_offset_m
            if 1.0 <= offset <= max_offset_m and (best is None or offset < best.offset_m):
                best = AdjacentLane(other.id, offset, True, proj.s_m)
    return best


def lane_position(graph: RoadGraph, obj: TrackedObject) -> tuple[LaneId, float] | None:
    """(lane, arc length of the object's centre along it) from its lane match on a LANE edge."""
    ref = obj.lane
    if ref is None or not graph.has_edge(*ref.edge):
        return None
    edge = graph.edge(*ref.edge)
    if edge.kind != EdgeKind.LANE or edge.lane is None:
        return None
    try:
        return edge.lane, graph.lane_s(edge.start) + ref.s_m
    except KeyError:
        return None


def lane_vehicles(
    graph: RoadGraph,
    objects: Iterable[TrackedObject],
    lane: LaneId,
    mp_lane_s_m: float,
    own_dist_to_mp_m: float,
    params: MtcParams,
    horizon_m: float,
    exclude: frozenset[str] = frozenset(),
) -> list[ConflictVehicle]:
    """Conflict vehicles on `lane` for a merge point at lane arc length `mp_lane_s_m` (see docstring)."""
    out = []
    for obj in objects:
        if obj.object_id in exclude:
            continue
        pos = lane_position(graph, obj)
        if pos is None or pos[0] != lane:
            continue
        d_b = mp_lane_s_m - (pos[1] + 0.5 * obj.length_m)
        if abs(d_b) > horizon_m:
            continue
        out.append(ConflictVehicle(d_b, obj.speed_mps, own_dist_to_mp_m, obj.object_id, params))
    return out
