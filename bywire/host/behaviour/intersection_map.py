"""Intersections of a road graph: which exits, stop lines and lanes make up one (seed 000 Secs. 8, 9.3).

The 2006 RNDF has no intersection objects (the later "RNDF 1.1" names some, for traffic lights); an
intersection is where lanes are joined by exits. So an `IntersectionInfo` is a connected component of
the lane-to-lane EXIT edges (their start and end waypoints, joined through shared waypoints and through
waypoints closer than `MERGE_RADIUS_M`: the two turns of an L corner share none), plus any stop
waypoint on its own (a stop sign without exits is an intersection of one approach). Exits into and
out of zones are the zone's business (the zone/ family), not an intersection's.

Per intersection: the approach waypoints (where exits leave, with the approach heading of their lane),
the entry waypoints (where exits arrive), the stop lines among the approaches, the lanes that touch it
(through an approach or an entry: also a priority road that passes straight through with exits only
arriving on it), and the box: the convex hull of approach and entry waypoints. A vehicle waiting at a
stop line has its centre ~2.4 m behind the line, outside the hull; one that has started across is
inside it.

An intersection "matters" to the behaviour (`is_real`) when it has a stop line or more than one
approach: a lone exit joining two road segments end to end is driven as a lane.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from bywire.host.roadnet.graph import Edge, EdgeKind, RoadGraph
from bywire.host.roadnet.ids import LaneId, WaypointId

__all__ = ["IntersectionInfo", "IntersectionMap", "convex_hull", "inside_convex"]

FloatArray = npt.NDArray[np.float64]

# Ours: the lane ends of one intersection lie a lane width or two apart (4-8 m), consecutive
# intersections are a block apart (50 m and more).
MERGE_RADIUS_M = 12.0


@dataclass(frozen=True, eq=False)
class IntersectionInfo:
    index: int
    approaches: tuple[WaypointId, ...]  # lane waypoints exits leave from (sorted)
    entries: tuple[WaypointId, ...]  # lane waypoints exits arrive at (sorted)
    stops: tuple[WaypointId, ...]  # approaches with a stop sign
    exits: tuple[Edge, ...]
    lanes: tuple[LaneId, ...]  # lanes through an approach or an entry (sorted)
    hull_xy: FloatArray = field(repr=False)  # (k, 2) counter-clockwise, or (0, 2) without a box

    @property
    def is_real(self) -> bool:
        return bool(self.stops) or len(self.approaches) > 1

    def in_box(self, x_m: float, y_m: float) -> bool:
        return inside_convex(self.hull_xy, x_m, y_m)


def convex_hull(points: FloatArray) -> FloatArray:
    """Andrew's monotone chain: the hull counter-clockwise without collinear points ((0, 2) if < 3)."""
    pts = sorted({(float(x), float(y)) for x, y in points})
    if len(pts) < 3:
        return np.zeros((0, 2))

    def cross(o: tuple[float, float], a: tuple[float, float], b: tuple[float, float]) -> float:
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower: list[tuple[float, float]] = []
    for p in pts:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], p) <= 0.0:
            lower.pop()
        lower.append(p)
    upper: list[tuple[float, float]] = []
    for p in reversed(pts):
        while len(upper) >= 2 and cross(upper[-2], upper[-1], p) <= 0.0:
            upper.pop()
        upper.append(p)
    hull = lower[:-1] + upper[:-1]
    return np.array(hull) if len(hull) >= 3 else np.zeros((0, 2))


def inside_convex(hull: FloatArray, x_m: float, y_m: float) -> bool:
    """Strictly inside a counter-clockwise convex polygon (False for an empty one)."""
    n = hull.shape[0]
    if n < 3:
        return False
    for i in range(n):
        ax, ay = hull[i]
        bx, by = hull[(i + 1) % n]
        if (bx - ax) * (y_m - ay) - (by - ay) * (x_m - ax) <= 0.0:
            return False
    return True


class IntersectionMap:
    """All intersections of a graph, built once; `at(v)` finds the one a waypoint belongs to."""

    def __init__(self, graph: RoadGraph) -> None:
        self.graph = graph
        parent: dict[WaypointId, WaypointId] = {}

        def find(v: WaypointId) -> WaypointId:
            root = v
            while parent[root] != root:
                root = parent[root]
            while parent[v] != root:
                parent[v], v = root, parent[v]
            return root

        exits = sorted(
            (
                e
                for e in graph.edges(EdgeKind.EXIT)
                if not e.start.is_perimeter and not e.end.is_perimeter and e.start != e.end
            ),
            key=lambda e: e.key,
        )
        for e in exits:
            for v in e.key:
                parent.setdefault(v, v)
            ra, rb = find(e.start), find(e.end)
            if ra != rb:
                parent[max(ra, rb)] = min(ra, rb)
        stops = sorted(v for v in graph.vertices() if graph.is_stop(v))
        for v in stops:
            parent.setdefault(v, v)
        # RNDF exits of one intersection need not share waypoints (an L corner's two turns do not):
        # waypoints of different exits this close together are one intersection.
        members = sorted(parent)
        if len(members) > 1:
            xy = np.array([graph.vertex_xy(v) for v in members], dtype=np.float64)
            for i, j in sorted(cKDTree(xy).query_pairs(MERGE_RADIUS_M)):
                ra, rb = find(members[i]), find(members[j])
                if ra != rb:
                    parent[max(ra, rb)] = min(ra, rb)
        groups: dict[WaypointId, list[WaypointId]] = {}
        for v in sorted(parent):
            groups.setdefault(find(v), []).append(v)
        exits_of: dict[WaypointId, list[Edge]] = {}
        for e in exits:
            exits_of.setdefault(find(e.start), []).append(e)

        self.intersections: list[IntersectionInfo] = []
        self._of: dict[WaypointId, IntersectionInfo] = {}
        for root in sorted(groups):
            members = groups[root]
            its_exits = tuple(exits_of.get(root, ()))
            approaches = tuple(
                sorted({e.start for e in its_exits} | {v for v in members if graph.is_stop(v)})
            )
            entries = tuple(sorted({e.end for e in its_exits}))
            lanes = tuple(sorted({v.lane_id for v in approaches + entries}))
            xy = np.array([graph.vertex_xy(v) for v in approaches + entries], dtype=np.float64)
            info = IntersectionInfo(
                index=len(self.intersections),
                approaches=approaches,
                entries=entries,
                stops=tuple(v for v in approaches if graph.is_stop(v)),
                exits=its_exits,
                lanes=lanes,
                hull_xy=convex_hull(xy.reshape(-1, 2)),
            )
            self.intersections.append(info)
            for v in members:
                self._of[v] = info

    def at(self, v: WaypointId) -> IntersectionInfo | None:
        """The intersection waypoint `v` is an approach, entry or stop line of (None: not part of one)."""
        return self._of.get(v)
