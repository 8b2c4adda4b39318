"""The zone navigation (seed 000 Sec. 10): `ZoneNavigator`, and what the Zone states read of it.

To each target the path planner's legs (`path_planning`, hybrid A* on the zone's obstacle map,
`zone_map`): into a spot with the front bumper on its checkpoint, out of it and on to the next, to the
perimeter exit and on along the exit edge. Where the planner finds no path, the stand-in of before it:

Straight lines (`manoeuvre.polyline_leg`) from where we are to a point `ZONE_SPOT_ALIGN_M` before the
spot on its axis, into the spot to its checkpoint, back out along the axis to that point, and from there
straight to the perimeter exit and on along the exit edge. The route's zone piece (`Route.drive_pieces`:
ZONE, PARK, UNPARK edges between an exit into the perimeter and one out of it) gives the targets in
order: each parking spot (its first waypoint, and the checkpoint at its second), then the perimeter
exit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bywire.host.roadnet.graph import Edge, EdgeKind
from bywire.host.roadnet.ids import WaypointId

from .. import rules
from ..context import BehaviourContext
from ..manoeuvre import Leg, polyline_leg
from ..path_planning import PlannedLegs, legs_of, make_request, planner_of
from .zone_map import goal_in_spot, zone_map

__all__ = ["ZoneNavigator", "ZoneTarget", "front_in_spot", "navigator", "take_planned_legs", "zone_speed"]

_ZONE = frozenset({EdgeKind.ZONE})
_EXIT_SAMPLE_M = 0.5


@dataclass(frozen=True)
class ZoneTarget:
    kind: str  # "spot" or "exit"
    point: WaypointId  # spot: its first waypoint; exit: the perimeter point
    spot_end: WaypointId | None = None  # spot: its second waypoint (the checkpoint)
    exit_edge: Edge | None = None  # exit: the route's edge out of the zone
    exit_route_s_m: float = 0.0  # exit: arc length of the perimeter point along the route


class ZoneNavigator:
    """The stand-in zone navigation for one pass through a zone (see the module docstring)."""

    def __init__(self, ctx: BehaviourContext) -> None:
        view = ctx.view
        piece = view.next_piece(ctx.ego_s_m, _ZONE)
        assert piece is not None
        self.graph = ctx.graph
        self.entry_s_m = piece.start_s_m
        edges = view.edges
        targets: list[ZoneTarget] = []
        for i in range(piece.first, piece.last + 1):
            e = edges[i]
            if e.kind == EdgeKind.PARK:
                targets.append(ZoneTarget("spot", e.start, e.end))
        last = edges[piece.last]
        if last.end.is_perimeter:
            exit_edge = edges[piece.last + 1] if piece.last + 1 < len(edges) else None
            targets.append(ZoneTarget("exit", last.end, None, exit_edge, piece.end_s_m))
        self.targets = tuple(targets)
        self.zone_id = edges[piece.first].start.segment  # the piece starts on the zone's perimeter
        self.planned = False  # the legs being driven are the planner's (else the stand-in's)
        self.final_leg = 0  # the leg that reaches the target
        self.last_plan: PlannedLegs | str | None = None
        self.stalled_since_s: float | None = None  # stopped short of a planned leg's end since
        self.blocked_replan_s: float | None = None  # when a blocked section ahead last asked for a replan
        self.pending: int | None = None  # the zone planner's ticket of the plan asked for
        self.replanning = False  # the plan asked for replaces legs being driven
        self.index = 0
        self.parked_since_s: float | None = None
        self.wp1_s_m = math.inf  # on the current forward leg
        self.wp2_s_m = math.inf
        self.exit_s_m = math.inf

    @property
    def target(self) -> ZoneTarget | None:
        return self.targets[self.index] if self.index < len(self.targets) else None

    def _xy(self, v: WaypointId) -> tuple[float, float]:
        return self.graph.vertex_xy(v)

    def align_point(self, target: ZoneTarget) -> tuple[float, float]:
        assert target.spot_end is not None
        (x1, y1), (x2, y2) = self._xy(target.point), self._xy(target.spot_end)
        d = math.hypot(x2 - x1, y2 - y1) or 1.0
        return x1 - rules.ZONE_SPOT_ALIGN_M * (x2 - x1) / d, y1 - rules.ZONE_SPOT_ALIGN_M * (y2 - y1) / d

    def forward_leg(self, x_m: float, y_m: float) -> Leg | None:
        """From (x, y) to the current target (see the module docstring); None when none is left."""
        target = self.target
        if target is None:
            return None
        points: list[tuple[float, float]] = [(x_m, y_m)]
        if target.kind == "spot":
            assert target.spot_end is not None
            points += [self.align_point(target), self._xy(target.point), self._xy(target.spot_end)]
        else:
            points.append(self._xy(target.point))
            if target.exit_edge is not None and len(target.exit_edge.path) > 1:
                p = target.exit_edge.path
                s = np.arange(_EXIT_SAMPLE_M, p.length_m, _EXIT_SAMPLE_M)
                ex, ey, _, _ = p.sample(s)
                points += list(zip(ex.tolist(), ey.tolist(), strict=True))
                points.append((float(p.x_m[-1]), float(p.y_m[-1])))
        leg = polyline_leg(points, 1)
        if target.kind == "spot":
            assert target.spot_end is not None
            x1, y1 = self._xy(target.point)
            self.wp1_s_m = leg.locate_anywhere(x1, y1)
            self.wp2_s_m = leg.end_s_m
            self.exit_s_m = math.inf
        else:
            px, py = self._xy(target.point)
            self.exit_s_m = leg.locate_anywhere(px, py)
            self.wp1_s_m = self.wp2_s_m = math.inf
        return leg

    def request_legs(self, ctx: BehaviourContext, back_out: bool = True) -> None:
        """Ask the zone planner for the legs from our pose to the current target: into a spot, front
        bumper at its checkpoint, or to the perimeter exit and on along the exit edge (straight back out
        of the spot just left first, unless `back_out` is False: a replan). `poll_legs` gives them."""
        target = self.target
        if target is None:
            return
        ego = ctx.situation.ego
        then = None
        forward_via = None
        if target.kind == "spot":
            # forward in (rules 5.2 "pull forward into"): where the plan to the parked pose arrives
            # reversing, the plan goes instead to where a straight run along the spot's axis begins (the
            # front bumper ZONE_SPOT_STRAIGHT_M short of the spot) and on along it without a stop
            assert target.spot_end is not None
            gx, gy, gh = goal_in_spot(ctx, target.point, target.spot_end)
            (x1, y1), (x2, y2) = self._xy(target.point), self._xy(target.spot_end)
            run = math.hypot(x2 - x1, y2 - y1) + rules.ZONE_SPOT_STRAIGHT_M
            d = np.linspace(-run, 0.0, max(2, math.ceil(run / _EXIT_SAMPLE_M) + 1))
            run_in = (gx + d * math.cos(gh), gy + d * math.sin(gh), np.full(d.size, gh))
            goal = (gx, gy, gh)
            forward_via = ((float(run_in[0][0]), float(run_in[1][0]), gh), run_in)
        else:
            px, py = self._xy(target.point)
            heading = math.atan2(py - ego.y_m, px - ego.x_m)
            if target.exit_edge is not None and len(target.exit_edge.path) > 1:
                p = target.exit_edge.path
                heading = float(p.heading_rad[0])
                s = np.arange(0.0, p.length_m, _EXIT_SAMPLE_M)
                ex, ey, eh, _ = p.sample(np.append(s, p.length_m))
                then = (ex, ey, eh)
            goal = (px, py, heading)
        back_out_m = 0.0
        if back_out and self.index > 0 and self.targets[self.index - 1].kind == "spot":
            left = self.targets[self.index - 1]
            assert left.spot_end is not None
            (x1, y1), (x2, y2) = self._xy(left.point), self._xy(left.spot_end)
            back_out_m = math.hypot(x2 - x1, y2 - y1) + rules.ZONE_BACK_OUT_MARGIN_M  # front clear of it
        self.replanning = not back_out and self.planned
        request = make_request(ctx, zone_map(ctx, self.zone_id), goal, then, back_out_m, forward_via)
        self.pending = planner_of(ctx).submit(request)

    def poll_legs(self, ctx: BehaviourContext) -> tuple[Leg, ...] | None:
        """The requested legs once the planner has them (None: still planning). Where it found none, the
        stand-in's straight lines (reversing out of the spot just left first), and the reason is said; a
        replan that finds none gives no legs (the ones being driven stay)."""
        if self.pending is None:
            return None
        reply = planner_of(ctx).poll(self.pending)
        if reply is None:
            return None
        self.pending = None
        planned = legs_of(reply)
        target = self.target
        if target is None:
            return ()
        ego = ctx.situation.ego
        self.last_plan = planned
        if isinstance(planned, str):
            if self.replanning:
                ctx.say(planned)
                return ()  # a replan that finds nothing keeps the legs being driven
            self.planned = False
            ctx.say(planned)
            back = self.back_out_leg(ego.x_m, ego.y_m)
            if back is not None:
                self.final_leg = 1
                forward = self.forward_leg(*back.point_at(back.end_s_m)[:2])
                return (back,) if forward is None else (back, forward)
            forward = self.forward_leg(ego.x_m, ego.y_m)
            self.final_leg = 0
            return () if forward is None else (forward,)
        self.planned = True
        legs = planned.legs
        self.final_leg = len(legs) - 1
        final = legs[-1]
        if target.kind == "spot":
            assert target.spot_end is not None
            x1, y1 = self._xy(target.point)
            self.wp1_s_m = final.locate_anywhere(x1, y1)
            self.wp2_s_m = final.end_s_m + ctx.params.rear_axle_to_front_m
            self.exit_s_m = math.inf
        else:
            px, py = self._xy(target.point)
            self.exit_s_m = final.locate_anywhere(px, py)
            self.wp1_s_m = self.wp2_s_m = math.inf
        return legs

    def on_final_leg(self, ctx: BehaviourContext) -> bool:
        return bool(ctx.legs) and ctx.leg_index >= min(self.final_leg, len(ctx.legs) - 1)

    def back_out_leg(self, x_m: float, y_m: float) -> Leg | None:
        """Reverse from (x, y) to the alignment point of the spot just left (the previous target)."""
        if self.index == 0 or self.targets[self.index - 1].kind != "spot":
            return None
        return polyline_leg([(x_m, y_m), self.align_point(self.targets[self.index - 1])], -1)


def take_planned_legs(ctx: BehaviourContext) -> bool:
    """Begin the legs the planner has just given; True while still waiting for them (the car holds)."""
    nav = navigator(ctx)
    if nav.pending is None:
        return False
    legs = nav.poll_legs(ctx)
    if legs is None:
        ctx.hold("zone: planning")
        return True
    if legs:
        ctx.begin_legs(legs)
        ctx.plan.leg, ctx.plan.leg_s_m = ctx.legs[0], ctx.leg_s_m  # this cycle already drives the new legs
    return False


def navigator(ctx: BehaviourContext) -> ZoneNavigator:
    nav = ctx.manoeuvre_data.get("zone")
    assert isinstance(nav, ZoneNavigator)
    return nav


def zone_speed(ctx: BehaviourContext) -> float:
    view = ctx.view
    limits = [
        e.speed_max_mps
        for e in view.edges
        if e.kind in (EdgeKind.ZONE, EdgeKind.PARK) and e.speed_max_mps is not None
    ]
    return min([rules.ZONE_SPEED_MAX_MPS, *limits])


def front_in_spot(ctx: BehaviourContext) -> bool:
    nav = navigator(ctx)
    target = nav.target
    return (
        target is not None
        and target.kind == "spot"
        and bool(ctx.legs)
        and nav.on_final_leg(ctx)
        and ctx.legs[ctx.leg_index].direction == 1
        and ctx.leg_s_m + ctx.params.rear_axle_to_front_m >= nav.wp1_s_m
    )
