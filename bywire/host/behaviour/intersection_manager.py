"""One crossing of an intersection: who waits where, who has the right of way, may we go (Sec. 9.3).

AnnieWAY kept "a manager object per concern" (`aw_IntersectionManager.cpp`); this is ours. The
`Intersection` state family makes one when it is entered and drops it when it is left.

Geometry of the crossing (`crossing_geometry`, computed once per route crossing and cached): our path
through the intersection is the route from 10 m before the approach waypoint to 25 m past the crossing
edge. For every other lane that touches the intersection (Sec. 9.1 assumption 2: "the other traffic
participants stay in the middle of the road") the candidate ways of a vehicle on it are the lane itself
through the intersection and each exit leaving from it; a candidate conflicts with us where its centre
line first comes within `rules.CONFLICT_DISTANCE_M` of ours: that point is the merge point MP of
Fig. 14, with its arc length on our route and in the lane's coordinate (the lane's arc length, through
an exit: that of the exit's start plus the arc length along the exit). Our own approach lane is left
out (vehicles on it are leads or followers: the following controller's business). Where a vehicle's
way is unknown, every candidate counts (conservative: it may take any exit).

Each cycle (`update`): objects seen stopped at another stop line (front bumper within `STOP_LINE_ZONE_M`
before / `STOP_LINE_PAST_M` past it, within 2 m of the lane, heading within 45 deg) are the waiting
vehicles of `IntersectionPrecedence` with the time we first saw them stopped there as their arrival; a
vehicle whose track ends at a stop line still waits there for `REACQUIRE_S`, and a new track that appears
at that line within it (moving or not) is that vehicle, which keeps its arrival (a LIDAR tracker loses a
waiting car when another drives between us and it, and finds it again under a new id, often as it starts
its turn: hidden is not gone); one that pulls away stays at its line until it is past that zone, by when
its centre is in the box (so it never drops out of the queue between line and box); objects with their
centre inside the box are in the box (both at once counts as in the box, precedence.py's rule). `mtc()`
runs the moving-traffic check for the vehicles on lanes with the right of way over our turn
(`precedence.right_of_way`, cases a-c), each with the situation's parameter set: d_B = MP (lane
coordinate) - B's front bumper, d_A = MP (route) - our front bumper; conflicts whose window we have left
(d_A < -D_A2) are dropped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from bywire.host.roadnet.graph import EdgeKind, RoadGraph
from bywire.host.roadnet.ids import LaneId, WaypointId
from bywire.host.roadnet.path import wrap_angle

from . import rules
from .mtc import ConflictVehicle, MtcResult, moving_traffic_check
from .precedence import (
    Approach,
    ApproachingVehicle,
    IntersectionPrecedence,
    PrecedenceDecision,
    Side,
    StopLine,
    Turn,
    WaitingVehicle,
    relative_side,
    right_of_way,
)
from .situation import EdgeKey, TrackedObject

if TYPE_CHECKING:
    from .route_view import IntersectionEvent, RouteView

__all__ = ["Conflict", "Crossing", "IntersectionManager", "crossing_geometry"]

_SIDE_TO_APPROACH: dict[Side, Approach] = {
    "right": Approach.FROM_RIGHT,
    "left": Approach.FROM_LEFT,
    "opposite": Approach.ONCOMING,
    "same": Approach.SAME_DIRECTION,
}
# A turn of less than 30 deg through the intersection is "straight" (ours: RNDF exits that go straight
# on bend by a few degrees where lanes are offset).
_STRAIGHT_MAX_RAD = math.radians(30.0)
# A track lost at a stop line and one found there this soon after are one car (see the docstring): a
# car passing between us and it hides it for a second or two at urban speeds.
REACQUIRE_S = 3.0
_OWN_BACK_M = 10.0  # our path through the crossing starts this far before the approach waypoint
_OWN_ON_M = 25.0  # ... and runs on this far past the crossing edge
_LANE_BACK_M = 20.0  # a lane's own way through the intersection: from this far before its touch point
_LANE_ON_M = 40.0  # ... to this far past it


@dataclass(frozen=True)
class Conflict:
    """A merge point MP between our crossing and one way of a vehicle on `lane` (Fig. 14)."""

    lane: LaneId
    branch: EdgeKey | None  # the exit it takes; None: on along its lane
    own_offset_m: float  # MP on our route, from the approach waypoint
    lane_s_m: float  # MP in the lane's coordinate
    side: Side  # where the lane comes from, seen from our approach
    priority: bool  # no stop sign on that lane here


@dataclass(frozen=True)
class Crossing:
    turn: Turn
    own_priority: bool
    conflicts: tuple[Conflict, ...]
    stop_lines: tuple[StopLine, ...]


def _turn(heading_in: float, heading_out: float) -> Turn:
    delta = wrap_angle(heading_out - heading_in)
    if delta > _STRAIGHT_MAX_RAD:
        return Turn.LEFT
    if delta < -_STRAIGHT_MAX_RAD:
        return Turn.RIGHT
    return Turn.STRAIGHT


def _first_close(own_xy: np.ndarray, cand_xy: np.ndarray, threshold_m: float) -> tuple[int, int] | None:
    """First row of `own_xy` within `threshold_m` of any point of `cand_xy`, and that nearest point."""
    if own_xy.shape[0] == 0 or cand_xy.shape[0] == 0:
        return None
    d2 = ((own_xy[:, None, :] - cand_xy[None, :, :]) ** 2).sum(axis=2)
    rows = np.flatnonzero((d2 < threshold_m * threshold_m).any(axis=1))
    if rows.size == 0:
        return None
    i = int(rows[0])
    return i, int(np.argmin(d2[i]))


def _first_conflict(
    own_xy: np.ndarray, cand_xy: np.ndarray, threshold_m: float, step: int = 4
) -> tuple[int, int] | None:
    """Exactly `_first_close`, about `step`² cheaper: every `step`-th sample of both finds the rows of
    ours that may be close (within the threshold plus the samples skipped on either side), and only
    those rows are compared with every sample of the other."""
    if own_xy.shape[0] < 2 * step or cand_xy.shape[0] < 2 * step:
        return _first_close(own_xy, cand_xy, threshold_m)
    spacing = float(np.max(np.hypot(*np.diff(own_xy, axis=0).T))) + float(
        np.max(np.hypot(*np.diff(cand_xy, axis=0).T))
    )
    reach = threshold_m + 0.5 * step * spacing
    coarse_own, coarse_cand = own_xy[::step], cand_xy[::step]
    d2 = ((coarse_own[:, None, :] - coarse_cand[None, :, :]) ** 2).sum(axis=2)
    near = np.flatnonzero((d2 < reach * reach).any(axis=1))
    if near.size == 0:
        return None
    rows = np.unique(np.clip((near[:, None] * step + np.arange(-step, step + 1)[None, :]).ravel(), 0, None))
    rows = rows[rows < own_xy.shape[0]]
    hit = _first_close(own_xy[rows], cand_xy, threshold_m)
    return None if hit is None else (int(rows[hit[0]]), hit[1])


def crossing_geometry(graph: RoadGraph, view: RouteView, event: IntersectionEvent) -> Crossing:
    """The static geometry of our crossing at `event` (see the module docstring)."""
    info = event.info
    w = view.window(event.s_m - _OWN_BACK_M, event.exit_end_s_m + _OWN_ON_M)
    own_xy = np.column_stack((view.x[w], view.y[w]))
    own_s = view.s[w]
    pose_in = graph.vertex_pose(event.approach)
    heading_in = pose_in.heading_rad if pose_in is not None else view.point_at(event.s_m)[2]
    turn = _turn(heading_in, view.point_at(event.exit_end_s_m)[2])
    own_lane = event.approach.lane_id
    touching = info.approaches + info.entries
    conflicts: list[Conflict] = []
    for lane in info.lanes:
        if lane == own_lane:
            continue
        lane_path = graph.lane_path(lane)
        if lane_path is None:
            continue
        touches = [v for v in touching if v.lane_id == lane]
        first = graph.vertex_pose(touches[0])
        if first is None:
            continue
        side = relative_side(heading_in, first.heading_rad)
        priority = not any(graph.is_stop(v) for v in touches if v in info.approaches)
        s_touch = [graph.lane_s(v) for v in touches]
        lo = max(min(s_touch) - _LANE_BACK_M, 0.0)
        hi = min(max(s_touch) + _LANE_ON_M, lane_path.length_m)
        cands: list[tuple[EdgeKey | None, np.ndarray, np.ndarray]] = []
        if hi > lo:
            ls = np.arange(lo, hi, 0.5)
            lx, ly, _, _ = lane_path.sample(ls)
            cands.append((None, np.column_stack((lx, ly)), ls))
        for e in info.exits:
            if e.start.lane_id == lane and len(e.path) > 1:
                p = e.path
                cands.append((e.key, np.column_stack((p.x_m, p.y_m)), graph.lane_s(e.start) + p.s_m))
        for branch, cxy, cs in cands:
            hit = _first_conflict(own_xy, cxy, rules.CONFLICT_DISTANCE_M)
            if hit is None:
                continue
            i, j = hit
            conflicts.append(
                Conflict(lane, branch, float(own_s[i]) - event.s_m, float(cs[j]), side, priority)
            )
    stop_lines = []
    for v in info.stops:
        pose = graph.vertex_pose(v)
        if pose is not None:
            stop_lines.append(StopLine(str(v), pose.heading_rad))
    own_priority = not event.stop
    return Crossing(turn, own_priority, tuple(conflicts), tuple(stop_lines))


@dataclass(frozen=True)
class _LanePosition:
    lane: LaneId
    lane_s_m: float  # the object's centre in the lane coordinate
    branch: EdgeKey | None


class IntersectionManager:
    """One crossing (see the module docstring). Times are the behaviour's clock, seconds."""

    def __init__(
        self,
        graph: RoadGraph,
        view: RouteView,
        event: IntersectionEvent,
        cache: dict[tuple[object, ...], Crossing] | None = None,
    ) -> None:
        self.graph = graph
        self.event = event
        key = (
            event.approach,
            tuple(
                e.key
                for e in view.edges[event.crossing : view.edge_index_at(event.exit_end_s_m + _OWN_ON_M) + 1]
            ),
            round(event.exit_end_s_m - event.s_m, 3),
        )
        crossing = None if cache is None else cache.get(key)
        if crossing is None:
            crossing = crossing_geometry(graph, view, event)
            if cache is not None:
                cache[key] = crossing
        self.crossing = crossing
        own_line = str(event.approach)
        self.precedence: IntersectionPrecedence | None = None
        if event.stop and any(line.line_id == own_line for line in crossing.stop_lines):
            self.precedence = IntersectionPrecedence(crossing.stop_lines, own_line)
        self._line_pose = {
            line.line_id: (graph.vertex_xy(WaypointId.parse(line.line_id)), line.approach_heading_rad)
            for line in crossing.stop_lines
        }
        self._first_seen: dict[tuple[str, str], float] = {}
        # per stop line: (arrival, when lost) of a waiting vehicle whose track ended there (see update)
        self._lost_at_line: dict[str, tuple[float, float, str]] = {}
        self._conflicts_by_lane: dict[LaneId, list[Conflict]] = {}
        for c in crossing.conflicts:
            self._conflicts_by_lane.setdefault(c.lane, []).append(c)
        self._row_cache: dict[tuple[Side, bool], str | None] = {}
        self.go_latched = False  # the MTC's hysteresis: we set ourselves in motion on a go
        self.waiting: tuple[WaitingVehicle, ...] = ()
        self.in_box: tuple[str, ...] = ()
        self.decision: PrecedenceDecision | None = None
        self.traffic_moving = False
        self._positions: list[tuple[TrackedObject, _LanePosition]] = []
        self._last_t = -math.inf

    # ------------------------------------------------------------------------------- per cycle

    def update(self, t_s: float, objects: tuple[TrackedObject, ...]) -> None:
        """Classify the objects and feed the precedence manager (once per cycle, monotonic time)."""
        if t_s == self._last_t:
            return
        self._last_t = t_s
        info = self.event.info
        waiting: list[WaitingVehicle] = []
        positions: list[tuple[TrackedObject, _LanePosition]] = []
        cx, cy = (
            info.hull_xy.mean(axis=0) if info.hull_xy.shape[0] else self.graph.vertex_xy(self.event.approach)
        )
        moving = False
        at_line = [(obj, self._at_line(obj)) for obj in objects]
        seen = {(obj.object_id, line) for obj, line in at_line if line is not None}
        box = [obj.object_id for obj in objects if info.in_box(obj.x_m, obj.y_m)]
        # tracks that left their line this cycle other than into the box: lost there (before new tracks
        # at that line are given their arrival, which may be the lost one's)
        for (oid, lid), arrived in self._first_seen.items():
            if (oid, lid) not in seen and oid not in box:
                self._lost_at_line[lid] = (arrived, t_s, oid)
        for obj, line in at_line:
            if line is not None:
                key = (obj.object_id, line)
                if key not in self._first_seen:
                    lost = self._lost_at_line.pop(line, None)
                    # a new track where one was lost a moment ago: the same car, seen again
                    if lost is not None and t_s - lost[1] <= REACQUIRE_S:
                        self._first_seen[key] = lost[0]
                self._first_seen.setdefault(key, t_s)
        # One car waits at a line's front: two tracks there are one car's fragments (a car half hidden
        # is segmented in two) or a car that replaced one lost there; the line's earliest arrival stands.
        first_at: dict[str, float] = {}
        for (oid, lid), arrived in self._first_seen.items():
            if (oid, lid) in seen:
                first_at[lid] = min(arrived, first_at.get(lid, arrived))
        for obj, line in at_line:
            if line is not None:
                self._first_seen[(obj.object_id, line)] = first_at[line]
                waiting.append(WaitingVehicle(obj.object_id, line, first_at[line]))
            pos = self._lane_position(obj)
            if pos is not None:
                positions.append((obj, pos))
            if (
                obj.speed_mps > rules.STILL_SPEED_MPS
                and math.hypot(obj.x_m - cx, obj.y_m - cy) < rules.TRAFFIC_NEAR_M
            ):
                moving = True
        self._first_seen = {k: v for k, v in self._first_seen.items() if k in seen}
        # A waiting car whose track was lost still waits until REACQUIRE_S has passed: hidden is not gone.
        taken = {line for _, line in seen}
        self._lost_at_line = {k: v for k, v in self._lost_at_line.items() if t_s - v[1] <= REACQUIRE_S}
        for line, (arrived, _, oid) in self._lost_at_line.items():
            if oid in box:
                continue
            if line not in taken:
                waiting.append(WaitingVehicle(oid, line, arrived))
            elif arrived < first_at[line]:
                # lost while another track at its line, arrived later, went on: that one is this car
                for key in [k for k in self._first_seen if k[1] == line]:
                    self._first_seen[key] = arrived
                waiting = [
                    WaitingVehicle(w.vehicle_id, w.stop_line_id, arrived) if w.stop_line_id == line else w
                    for w in waiting
                ]
        self.waiting = tuple(waiting)
        self.in_box = tuple(box)
        self._positions = positions
        self.traffic_moving = moving
        if self.precedence is not None:
            self.decision = self.precedence.update(t_s, self.waiting, self.in_box)

    def arrive(self, t_s: float) -> None:
        """We stopped at our stop line (IntersectionWait's entry)."""
        if self.precedence is not None and self.precedence.own_arrived_s is None:
            self.precedence.arrive(t_s)
            self.decision = self.precedence.update(t_s, self.waiting, self.in_box)

    def _reacquiring(self, line_id: str) -> bool:
        """A waiting vehicle's track was lost at this line a moment ago (its new track may be moving:
        the car started its turn while it was hidden)."""
        lost = self._lost_at_line.get(line_id)
        return lost is not None and self._last_t - lost[1] <= REACQUIRE_S

    def _at_line(self, obj: TrackedObject) -> str | None:
        """The stop line `obj` waits at: stopped there, or registered there and not yet in the box."""
        for line_id, ((lx, ly), heading) in self._line_pose.items():
            if (
                obj.speed_mps > rules.STOPPED_SPEED_MPS
                and (obj.object_id, line_id) not in self._first_seen
                and not self._reacquiring(line_id)
            ):
                continue
            c, s = math.cos(heading), math.sin(heading)
            along = (obj.x_m - lx) * c + (obj.y_m - ly) * s
            across = -(obj.x_m - lx) * s + (obj.y_m - ly) * c
            front_before = -(along + 0.5 * obj.length_m)
            if (
                -rules.STOP_LINE_PAST_M <= front_before <= rules.STOP_LINE_ZONE_M
                and abs(across) < rules.STOP_LINE_LATERAL_M
                and abs(wrap_angle(obj.heading_rad - heading)) < rules.STOP_LINE_HEADING_RAD
            ):
                return line_id
        return None

    def _lane_position(self, obj: TrackedObject) -> _LanePosition | None:
        ref = obj.lane
        if ref is None or not self.graph.has_edge(*ref.edge):
            return None
        edge = self.graph.edge(*ref.edge)
        if edge.kind == EdgeKind.LANE and edge.lane is not None and edge.lane in self._conflicts_by_lane:
            try:
                return _LanePosition(edge.lane, self.graph.lane_s(edge.start) + ref.s_m, None)
            except KeyError:
                return None
        if edge.kind == EdgeKind.EXIT and edge.start.lane_id in self._conflicts_by_lane:
            try:
                return _LanePosition(edge.start.lane_id, self.graph.lane_s(edge.start) + ref.s_m, edge.key)
            except KeyError:
                return None
        return None

    # ------------------------------------------------------------------------------- decisions

    def _situation_for(self, side: Side, priority: bool) -> str | None:
        key = (side, priority)
        if key not in self._row_cache:
            av = ApproachingVehicle("b", _SIDE_TO_APPROACH[side], priority)
            row = right_of_way(self.crossing.turn, self.crossing.own_priority, [av])
            self._row_cache[key] = row.yield_to[0].situation if row.yield_to else None
        return self._row_cache[key]

    def conflict_vehicles(self, own_front_s_m: float) -> list[ConflictVehicle]:
        """The MTC's view of every vehicle with the right of way over us, one entry per merge point."""
        out: list[ConflictVehicle] = []
        for obj, pos in self._positions:
            for c in self._conflicts_by_lane.get(pos.lane, ()):
                if pos.branch is not None and c.branch != pos.branch:
                    continue
                if pos.branch is None and c.branch is not None:
                    branch_s = self.graph.lane_s(c.branch[0])
                    if branch_s < pos.lane_s_m - 0.5 * obj.length_m:
                        continue  # that exit leaves from behind the vehicle
                situation = self._situation_for(c.side, c.priority)
                if situation is None:
                    continue
                params = rules.mtc_params(situation)
                d_b = c.lane_s_m - (pos.lane_s_m + 0.5 * obj.length_m)
                d_a = self.event.s_m + c.own_offset_m - own_front_s_m
                if d_b > rules.MTC_APPROACH_HORIZON_M or d_b < -rules.MTC_APPROACH_HORIZON_M:
                    continue
                if d_a < -params.d_a2_m:
                    continue  # we have left this conflict's window
                branch = "lane" if c.branch is None else f"{c.branch[0]}>{c.branch[1]}"
                out.append(ConflictVehicle(d_b, obj.speed_mps, d_a, f"{obj.object_id}@{branch}", params))
        return out

    def mtc(self, own_speed_mps: float, own_front_s_m: float) -> MtcResult:
        """The moving-traffic check now (eq. 17 over all priority vehicles), with our hysteresis."""
        vehicles = self.conflict_vehicles(own_front_s_m)
        return moving_traffic_check(
            max(own_speed_mps, 0.0),
            vehicles,
            rules.mtc_params(rules.MtcSituation.INTERSECTION_CROSSING),
            in_motion=self.go_latched,
        )

    def oncoming_stop_front_s(self) -> float | None:
        """Where our front bumper stops before the opposing lane for a left turn (IntersectionPrioStop)."""
        d_a1 = rules.mtc_params(rules.MtcSituation.INTERSECTION_LEFT_TURN).d_a1_m
        points = [
            self.event.s_m + c.own_offset_m - d_a1
            for c in self.crossing.conflicts
            if c.side == "opposite" and c.priority
        ]
        return min(points) if points else None

    @property
    def may_go_by_precedence(self) -> bool:
        """Precedence says go (True where no precedence applies: priority road, or no stop lines)."""
        return self.precedence is None or (self.decision is not None and self.decision.may_go)
