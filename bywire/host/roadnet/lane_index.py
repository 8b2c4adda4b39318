"""Which lane is an object on? (seed 000 sec. 8: "Dynamic objects recognized by the perception module are
matched to the most probable edge of the geometrical graph representation, based on their position and
orientation.")

`LaneIndex` keeps one kd-tree over the samples of every LANE and EXIT edge (exits are the lanes through
intersections, where the role of an object matters most).  A query takes the edges with a sample within
reach, projects the position onto each, and scores each candidate by the negative log-likelihood of a
Gaussian in the lateral offset and the heading error:

    score = (d / sigma_d)^2 + (dpsi / sigma_psi)^2

with d the distance to the foot point and dpsi the heading error (left out without a heading).  The most
probable edge has the lowest score.  sigma_d = 1 m (half a lane: a car 1.8 m off the centre line is on
the line between two lanes) and sigma_psi = 20 deg (cars change lanes at a few degrees; 20 deg already
says "turning"), parameters of `LaneIndex`.  Candidates farther than `max_distance_m` or with a heading
error beyond `max_heading_error_rad` are no match: an oncoming car is not in our lane however close.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .graph import Edge, EdgeKind, RoadGraph

LATERAL_SIGMA_M = 1.0
HEADING_SIGMA_RAD = math.radians(20.0)
MAX_DISTANCE_M = 5.0
MAX_HEADING_ERROR_RAD = math.radians(60.0)


@dataclass(frozen=True)
class LaneMatch:
    """An edge an object may be on: arc length along the edge, signed offset (left > 0), heading error
    (object minus lane, NaN without a heading), distance to the foot point and the score (lower wins)."""

    edge: Edge
    s_m: float
    lateral_offset_m: float
    heading_error_rad: float
    distance_m: float
    score: float


class LaneIndex:
    def __init__(
        self,
        graph: RoadGraph,
        kinds: Iterable[EdgeKind] = (EdgeKind.LANE, EdgeKind.EXIT),
        lateral_sigma_m: float = LATERAL_SIGMA_M,
        heading_sigma_rad: float = HEADING_SIGMA_RAD,
    ) -> None:
        self.graph = graph
        self.lateral_sigma_m = lateral_sigma_m
        self.heading_sigma_rad = heading_sigma_rad
        self.edges: list[Edge] = [e for e in graph.edges(tuple(kinds)) if len(e.path) > 1]
        xy = [e.path.xy for e in self.edges]
        owner = [np.full(len(e.path), i, dtype=np.intp) for i, e in enumerate(self.edges)]
        s = [e.path.s_m for e in self.edges]
        if not self.edges:
            self._tree = None
            return
        self._xy = np.concatenate(xy)
        self._owner = np.concatenate(owner)
        self._s = np.concatenate(s)
        self._tree = cKDTree(self._xy)
        # a sample within reach of the foot point lies at most half a sample spacing farther than it
        self._reach_slack_m = max(float(np.max(np.diff(p.s_m))) for p in (e.path for e in self.edges)) / 2.0

    def candidates(
        self,
        x_m: float,
        y_m: float,
        heading_rad: float | None = None,
        max_distance_m: float = MAX_DISTANCE_M,
        max_heading_error_rad: float = MAX_HEADING_ERROR_RAD,
    ) -> list[LaneMatch]:
        """Every edge within `max_distance_m` (and heading error), best first."""
        if self._tree is None:
            return []
        hits = self._tree.query_ball_point((x_m, y_m), max_distance_m + self._reach_slack_m)
        if not hits:
            return []
        hits_arr = np.asarray(hits, dtype=np.intp)
        out: list[LaneMatch] = []
        for i in np.unique(self._owner[hits_arr]):
            edge = self.edges[int(i)]
            mine = hits_arr[self._owner[hits_arr] == i]
            near = mine[np.argmin(np.hypot(self._xy[mine, 0] - x_m, self._xy[mine, 1] - y_m))]
            proj = edge.path.project(x_m, y_m, hint_s=float(self._s[near]), heading_rad=heading_rad)
            foot = edge.path.point_at(proj.s_m)
            distance = math.hypot(x_m - foot.x_m, y_m - foot.y_m)
            if distance > max_distance_m:
                continue
            score = (distance / self.lateral_sigma_m) ** 2
            if heading_rad is not None:
                if abs(proj.heading_error_rad) > max_heading_error_rad:
                    continue
                score += (proj.heading_error_rad / self.heading_sigma_rad) ** 2
            out.append(
                LaneMatch(edge, proj.s_m, proj.lateral_offset_m, proj.heading_error_rad, distance, score)
            )
        out.sort(key=lambda m: (m.score, m.edge.kind != EdgeKind.LANE))
        return out

    def match(
        self,
        x_m: float,
        y_m: float,
        heading_rad: float | None = None,
        max_distance_m: float = MAX_DISTANCE_M,
        max_heading_error_rad: float = MAX_HEADING_ERROR_RAD,
    ) -> LaneMatch | None:
        """The most probable edge for an object at (x, y) heading `heading_rad`, or None."""
        found = self.candidates(x_m, y_m, heading_rad, max_distance_m, max_heading_error_rad)
        return found[0] if found else None
