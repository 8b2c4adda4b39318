"""The K-turn planned on the road (seed 000 Sec. 10: "the navigation module [...] also used for
U-turns and K-turns"): DriveKTurn's legs from the path planner, within the road and around what stands
on it.

- Onto which lane: the one DriveOnLane (a U-turn the RNDF asks for) or Replan (a blockade) chose; else
  the opposite lane of our segment on our left (`lanes.adjacent_left_lane`); else the nearest lane of
  any segment within `rules.TURNAROUND_SEARCH_M` that runs the other way alongside us
  (`lanes.opposite_lane_nearby`: a street drawn as two one-way segments has no U-turn edge, and
  turning onto it is the way out).
- The goal: the rear axle on that lane's centre line `GOAL_AHEAD_M` on from the point alongside us,
  heading along it.
- The map: the road (`roadnet.road_area`: lanes and exits at their RNDF widths, the band between the
  lanes of a street, zones) within `MAP_HALF_M` of the start and goal, everything else an obstacle, and
  what stands on it (`path_planning.obstacles_on`: the barrier of a blockade, parked cars). The road's
  edge is taken `path_planning.ROAD_EDGE_SLACK_M` outside the lanes' painted edge: the planner's margin
  (0.3 m) is for what stands; against the edge the car keeps 0.1 m inside the lane line, 0.4 m off a
  curb (which stands 0.3 m outside it). A full margin inside the line turns a three-point turn in a
  9 m street into a five-point one.
- The search: as for a zone, but reversing costs what driving forward does (a K-turn reverses by
  design), begun and ended forward (a first leg backward, or a last, costs a change of direction), with
  the finer search graph as a last try (a street little wider than the car is long
  takes many short legs).

Where the planner finds nothing (or there is no lane to turn onto), the caller keeps the geometric
three-point turn of before (`manoeuvre.kturn_legs`), which does not look at the road's edges.
"""

from __future__ import annotations

import math

from bywire.host.navigation.grid_map import GridMap

from .. import rules
from ..context import BehaviourContext
from ..lanes import AdjacentLane, adjacent_left_lane, opposite_lane_nearby
from ..path_planning import PlanRequest, Pose, make_request, road_map

__all__ = ["turn_map", "turn_request", "turn_target"]

GOAL_AHEAD_M = 2.0
MAP_HALF_M = 22.0
TURN_REVERSE_FACTOR = 1.0


def turn_target(ctx: BehaviourContext) -> AdjacentLane | None:
    """The lane to turn onto (see the module docstring), None if there is none."""
    if ctx.kturn_target is not None:
        return ctx.kturn_target
    ego = ctx.situation.ego
    edge = ctx.current_edge()
    if edge is not None and edge.lane is not None:
        side = adjacent_left_lane(ctx.graph, edge.lane, ego.x_m, ego.y_m, ego.heading_rad)
        if side is not None and side.opposite:
            return side
    return opposite_lane_nearby(ctx.graph, ego.x_m, ego.y_m, ego.heading_rad, rules.TURNAROUND_SEARCH_M)


def turn_goal(ctx: BehaviourContext, target: AdjacentLane) -> Pose | None:
    """Our rear axle's pose on the target lane at the end of the turn."""
    path = ctx.graph.lane_path(target.lane)
    if path is None:
        return None
    s = min(target.lane_s_m + GOAL_AHEAD_M, path.length_m)
    p = path.point_at(s)
    return p.x_m, p.y_m, p.heading_rad


def turn_map(ctx: BehaviourContext, start: Pose, goal: Pose) -> GridMap:
    """The road around `start` and `goal` with what stands on it (see the module docstring)."""
    mx, my = 0.5 * (start[0] + goal[0]), 0.5 * (start[1] + goal[1])
    lo, hi = (mx - MAP_HALF_M, my - MAP_HALF_M), (mx + MAP_HALF_M, my + MAP_HALF_M)
    return road_map(ctx, ctx.road_area, lo, hi)


def turn_request(
    ctx: BehaviourContext, target: AdjacentLane, begin_forward: bool = True
) -> PlanRequest | None:
    """The planner's request for the turn onto `target` from where we stand (None: no goal on it); begun
    driving forward (as we came along the lane) unless `begin_forward` is False (the rest of a turn)."""
    goal = turn_goal(ctx, target)
    if goal is None:
        return None
    ego = ctx.situation.ego
    start = (ego.x_m, ego.y_m, ego.heading_rad)
    if math.hypot(goal[0] - start[0], goal[1] - start[1]) > MAP_HALF_M:
        return None
    grid = turn_map(ctx, start, goal)
    # ended driving forward: we go on along the other lane
    begin = 1.0 if begin_forward else 0.0
    return make_request(
        ctx, grid, goal, fine=True, reverse_factor=TURN_REVERSE_FACTOR, directions=(begin, 1.0)
    )
