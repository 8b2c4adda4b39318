"""GlobalRecovery's last resort (seed 000 Sec. 8 "navigate back on track", Sec. 10): off every lane, the
path planner drives the car back onto the nearest one over whatever is free.

The goal: the nearest lane within `SEARCH_M` (`LaneIndex.match` without a heading: the lane's own
direction is the one to join it in), `JOIN_AHEAD_M` on from the foot point, heading along the lane. The
map: `MAP_HALF_M` around the car and the goal, everything free but what stands (the objects, the
occupancy grid's cells: "drive anywhere free"); the plan ends driving forward. Each leg ends in a stop;
after the last, the global recovery replans from where the car stands (it is on a lane now). Where the
planner finds nothing, the car holds and the global recovery tries again at its interval.
"""

from __future__ import annotations

from .. import rules
from ..context import BehaviourContext
from ..path_planning import blank_map, legs_of, make_request, obstacles_on, planner_of

__all__ = ["BackToRoad", "drive_back", "forget", "request_back"]

SEARCH_M = 40.0
JOIN_AHEAD_M = 6.0
MAP_HALF_M = 15.0  # beyond the box around the car and the goal
_KEY = "back_to_road"


class BackToRoad:
    """The plan asked for (`ticket`), then the legs being driven."""

    def __init__(self, ticket: int) -> None:
        self.ticket: int | None = ticket
        self.failed = ""


def request_back(ctx: BehaviourContext) -> bool:
    """Ask for the way back onto the nearest lane; False when no lane is near enough."""
    ego = ctx.situation.ego
    match = ctx.lane_index.match(ego.x_m, ego.y_m, None, max_distance_m=SEARCH_M)
    if match is None:
        return False
    path = match.edge.path
    p = path.point_at(min(match.s_m + JOIN_AHEAD_M, path.length_m))
    goal = (p.x_m, p.y_m, p.heading_rad)
    lo = (min(ego.x_m, goal[0]) - MAP_HALF_M, min(ego.y_m, goal[1]) - MAP_HALF_M)
    hi = (max(ego.x_m, goal[0]) + MAP_HALF_M, max(ego.y_m, goal[1]) + MAP_HALF_M)
    grid = obstacles_on(ctx, blank_map(lo, hi))
    request = make_request(ctx, grid, goal, fine=True, reverse_factor=1.5, directions=(0.0, 1.0))
    ctx.manoeuvre_data[_KEY] = BackToRoad(planner_of(ctx).submit(request))
    ctx.say(f"global recovery: planning back onto {match.edge.start} -> {match.edge.end}")
    return True


def drive_back(ctx: BehaviourContext) -> str:
    """Drive the way back: "planning", "driving", "done" (on the lane: replan now) or "none" (no plan,
    or none asked for)."""
    back = ctx.manoeuvre_data.get(_KEY)
    if not isinstance(back, BackToRoad):
        return "none"
    if back.ticket is not None:
        reply = planner_of(ctx).poll(back.ticket)
        if reply is None:
            ctx.hold("global recovery: planning back onto the road")
            return "planning"
        back.ticket = None
        planned = legs_of(reply)
        if isinstance(planned, str):
            del ctx.manoeuvre_data[_KEY]
            ctx.say(f"global recovery: no way back onto the road ({planned})")
            return "none"
        ctx.begin_legs(planned.legs)
    if not ctx.legs:
        del ctx.manoeuvre_data[_KEY]
        return "none"
    if ctx.leg_done():
        if ctx.leg_index + 1 >= len(ctx.legs):
            ctx.end_legs()
            del ctx.manoeuvre_data[_KEY]
            return "done"
        ctx.select_leg(ctx.leg_index + 1)
    leg = ctx.legs[ctx.leg_index]
    ctx.plan.leg, ctx.plan.leg_s_m = leg, ctx.leg_s_m
    ctx.stop_rear_at(leg.end_s_m, "global recovery: end of a move back onto the road")
    ctx.cap(rules.RECOVERY_CREEP_SPEED_MPS * 2.0, "global recovery: back onto the road")
    ctx.cap_for_steering()
    gear = "forward" if leg.direction == 1 else "backward"
    ctx.say(f"global recovery: back onto the road, move {ctx.leg_index + 1} of {len(ctx.legs)} ({gear})")
    return "driving"


def forget(ctx: BehaviourContext) -> None:
    """Drop the way back (the global recovery is left or entered anew)."""
    if ctx.manoeuvre_data.pop(_KEY, None) is not None:
        ctx.end_legs()
