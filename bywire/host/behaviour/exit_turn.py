"""Exits no car can steer, planned on their own lanes (seed 000 Sec. 10: the navigation module where
the lane graph's geometry fails).

An RNDF exit joins two waypoints; where they lie so close that no curve between them stays under the
car's full lock, the road graph keeps the least bad one (`roadnet.curves.drivable_connector`) and a car
that follows it swings wide (the DARPA sample's 3.2.13 -> 1.2.5 asks for a 3 m radius; the Passat turns
4.6 m at full lock). Such an exit (peak curvature above the graph's `exit_max_curvature_1pm`) is
planned by the path planner instead, as AnnieWAY planned what the graph could not give:

- the map: the route's own lanes and the exit at their widths, and the intersection's room the car may
  use for the turn (every exit out of the lane it leaves and into the lane it enters), by
  `roadnet.road_area.RoadArea.of_paths`, the edge taken `path_planning.ROAD_EDGE_SLACK_M` out; and what
  stands on them;
- from our rear axle where we stand at the exit's start (the stop line) to the route `GOAL_AFTER_M`
  past the exit's end, begun and ended forward, and on along the route; a second move (a short reverse)
  where one forward sweep does not fit;
- asked for `PLAN_AHEAD_M` before the exit, driven from its start: each leg's points carry their route
  arc length (`Leg.base_s`), so the route's guards (the intersection left behind, the checkpoints) see
  us where we are; a leg before the last ends in a stop, the last hands back to the route at the goal.

`steer_exit` is called by the states that drive the route through an exit (DriveOnLane,
IntersectionDriveInside, IntersectionPrioDriveInside) at the end of their activity; the Intersection
family asks for the plan (`plan_exit_ahead`) while we approach, stop and wait. Where the planner
finds nothing, the exit is driven on the graph's curve as before, and the reason is said.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bywire.host.roadnet.graph import Edge, EdgeKind
from bywire.host.roadnet.road_area import RoadArea

from . import rules
from .context import BehaviourContext
from .manoeuvre import Leg
from .path_planning import legs_of, make_request, planner_of, road_map

__all__ = ["ExitTurn", "plan_exit_ahead", "steer_exit", "unsteerable"]

PLAN_AHEAD_M = 40.0
GOAL_AFTER_M = 8.0
MAP_MARGIN_M = 12.0  # around the start and the goal
LANES_AROUND_M = 20.0  # the route's lanes this far before the start and past the goal are on the map
THEN_M = 15.0  # the route after the goal, appended to the last leg
EXIT_REVERSE_FACTOR = 1.5
START_WINDOW_M = 1.0  # the moves begin with the rear axle this close to their start
_KEY = "exit_turn"


@dataclass
class ExitTurn:
    """One unsteerable exit of the route: its plan and how far it has been driven."""

    edge: Edge
    start_s_m: float  # route arc length of our rear axle where the legs begin
    goal_s_m: float  # and where they hand back to the route
    ticket: int | None = None
    legs: tuple[Leg, ...] = ()
    goal_leg_s_m: float = math.inf  # the goal's arc length on the last leg
    driving: bool = False


def unsteerable(ctx: BehaviourContext, edge: Edge) -> bool:
    """An exit whose curve stays tighter than the car's full lock (see the module docstring)."""
    limit = ctx.graph.params.exit_max_curvature_1pm
    if edge.kind != EdgeKind.EXIT or limit is None or len(edge.path) < 2:
        return False
    return float(np.max(np.abs(edge.path.curvature_1pm))) > limit + 1e-6


def _next_unsteerable(ctx: BehaviourContext) -> ExitTurn | None:
    view = ctx.view
    i = view.edge_index_at(ctx.ego_s_m)
    while i < len(view.edges) and float(view.edge_start[i]) <= ctx.ego_front_s_m + PLAN_AHEAD_M:
        edge = view.edges[i]
        if float(view.edge_start[i]) >= ctx.ego_front_s_m - 1.0 and unsteerable(ctx, edge):
            start = float(view.edge_start[i]) - ctx.params.rear_axle_to_front_m
            goal = min(float(view.edge_end[i]) + GOAL_AFTER_M, view.length_m)
            return ExitTurn(edge, start, goal)
        i += 1
    return None


def _request(ctx: BehaviourContext, turn: ExitTurn) -> None:
    view = ctx.view
    start = view.point_at(turn.start_s_m)
    goal = view.point_at(turn.goal_s_m)
    i0 = view.edge_index_at(turn.start_s_m - LANES_AROUND_M)
    i1 = view.edge_index_at(turn.goal_s_m + LANES_AROUND_M)
    edges = list(view.edges[i0 : i1 + 1])
    # the intersection's room: every exit from our lane's end and into the target lane's start
    edges += [e for e in ctx.graph.out_edges(turn.edge.start) if e.kind == EdgeKind.EXIT]
    edges += [e for e in ctx.graph.in_edges(turn.edge.end) if e.kind == EdgeKind.EXIT]
    own = RoadArea.of_paths([(e.path, e.lane_width_m) for e in edges])
    lo = (min(start[0], goal[0]) - MAP_MARGIN_M, min(start[1], goal[1]) - MAP_MARGIN_M)
    hi = (max(start[0], goal[0]) + MAP_MARGIN_M, max(start[1], goal[1]) + MAP_MARGIN_M)
    s_then = np.linspace(turn.goal_s_m, min(turn.goal_s_m + THEN_M, view.length_m), 31)
    then = tuple(np.array(c) for c in zip(*(view.point_at(float(s)) for s in s_then), strict=True))
    # from where the legs will begin (the stop line), not from where we are now
    request = make_request(
        ctx, road_map(ctx, own, lo, hi), goal, (then[0], then[1], then[2]), fine=True,
        reverse_factor=EXIT_REVERSE_FACTOR, directions=(1.0, 1.0), start=start,
    )  # fmt: skip
    turn.ticket = planner_of(ctx).submit(request)


def _on_route(ctx: BehaviourContext, turn: ExitTurn, legs: tuple[Leg, ...]) -> tuple[Leg, ...]:
    """The legs with the route arc length of each point (`Leg.base_s`)."""
    view = ctx.view
    out: list[Leg] = []
    hint = turn.start_s_m
    for leg in legs:
        base = np.empty(leg.s.size)
        for k in range(leg.s.size):
            base[k], _, _ = view.locate(float(leg.x[k]), float(leg.y[k]), hint, 10.0, 20.0)
            hint = base[k]
        out.append(Leg(leg.x, leg.y, leg.heading, leg.kappa, leg.s, leg.direction, leg.end_s_m, base))
    return tuple(out)


def _poll(ctx: BehaviourContext, turn: ExitTurn) -> None:
    if turn.ticket is None:
        return
    reply = planner_of(ctx).poll(turn.ticket)
    if reply is None:
        return
    turn.ticket = None
    planned = legs_of(reply)
    where = f"exit {turn.edge.start} -> {turn.edge.end}"
    if isinstance(planned, str):
        ctx.say(f"{where} is tighter than full lock; {planned}: on the graph's curve")
        return
    turn.legs = _on_route(ctx, turn, planned.legs)
    gx, gy, _ = ctx.view.point_at(turn.goal_s_m)
    turn.goal_leg_s_m = turn.legs[-1].locate_anywhere(gx, gy)
    ctx.say(f"{where} is tighter than full lock: planned in {len(turn.legs)} moves")


def plan_exit_ahead(ctx: BehaviourContext) -> ExitTurn | None:
    """Ask for the plan of the route's next unsteerable exit within `PLAN_AHEAD_M`, and take it when it
    comes; the turn being planned or driven, None if there is none."""
    if ctx.route is None:
        return None
    turn = ctx.manoeuvre_data.get(_KEY)
    if not isinstance(turn, ExitTurn):
        if ctx.legs or not ctx.on_route:
            return None  # another manoeuvre's legs are being driven
        found = _next_unsteerable(ctx)
        if found is None:
            return None
        ctx.manoeuvre_data[_KEY] = turn = found
        _request(ctx, turn)
    _poll(ctx, turn)
    return turn


def steer_exit(ctx: BehaviourContext) -> None:
    """Plan the route's next unsteerable exit ahead of time and drive its legs (see the module docstring)."""
    turn = plan_exit_ahead(ctx)
    if turn is None:
        return
    if not turn.driving:
        at_start = turn.start_s_m - START_WINDOW_M <= ctx.ego_s_m <= turn.start_s_m + START_WINDOW_M
        if turn.legs and at_start and not ctx.plan.stops and not ctx.plan.hold:
            turn.driving = True
            ctx.begin_legs(turn.legs)
        elif ctx.ego_s_m > turn.start_s_m + START_WINDOW_M:
            # past the start without moves (none found, or found too late: a worker's plan on wall
            # time): this exit is driven on the graph's curve
            if turn.legs:
                ctx.say(f"exit {turn.edge.start} -> {turn.edge.end}: its moves came too late, on the curve")
            del ctx.manoeuvre_data[_KEY]
            return
        else:
            return
    _drive(ctx, turn)


def _stops_on_leg(leg: Leg, route_stops: list[tuple[float, str]]) -> list[tuple[float, str]]:
    """The state's stops (route arc lengths: a lead car, a stop line ahead) moved onto the leg where it
    runs along the route forward; on a leg that does not (a reverse move) they wait for the next leg."""
    base = leg.base_s
    if not route_stops or base is None or leg.direction != 1 or not bool(np.all(np.diff(base) > 0.0)):
        return []
    return [(float(np.interp(s, base, leg.s, right=leg.s[-1] + s - base[-1])), why) for s, why in route_stops]


def _drive(ctx: BehaviourContext, turn: ExitTurn) -> None:
    if not ctx.legs:
        del ctx.manoeuvre_data[_KEY]  # a state took the legs away (a recovery): the route again
        return
    route_stops = list(ctx.plan.stops)  # the state's, in route arc length
    ctx.plan.stops = []
    leg = ctx.legs[ctx.leg_index]
    last = ctx.leg_index == len(ctx.legs) - 1
    if last and ctx.leg_s_m >= turn.goal_leg_s_m:
        ctx.plan.stops = route_stops
        ctx.end_legs()  # at the goal, on the route's own lane: its tracking takes over
        del ctx.manoeuvre_data[_KEY]
        return
    if not last:
        ctx.drive_to_cusp("exit turn: end of a move")
        leg = ctx.legs[ctx.leg_index]
    ctx.plan.stops += _stops_on_leg(leg, route_stops)
    if leg.direction == -1:
        ctx.cap(rules.SPOT_SPEED_MPS, "exit turn: reversing")
    ctx.cap_for_steering()
    ctx.plan.leg = leg
    ctx.plan.leg_s_m = ctx.leg_s_m
    ctx.say(f"exit turn: move {ctx.leg_index + 1} of {len(ctx.legs)}")
