"""The Zone family: ZoneApproach, ZoneEnter, ZonePark, ZoneLeave, ZoneRecovery (seed 000 Secs. 8, 10).

Sec. 8: "The navigation in unstructured environments and parking maneuvers is controlled by the state
Zone and its substates. These states control invocation of the navigation module described in Section
10." That module (hybrid A* on the obstacle map with Voronoi and RTR heuristics) comes later. Until then
the path inside a zone is a **simple stand-in**: straight lines (`manoeuvre.polyline_leg`) from where we
are to a point `ZONE_SPOT_ALIGN_M` before the spot on its axis, into the spot to its checkpoint, back
out along the axis to that point, and from there straight to the perimeter exit and on along the exit
edge. It sees no obstacles but those on its lines (which stop it, as on a lane) and plans around none;
a parking lot with cars in the way will leave it to ZoneRecovery and then the GlobalRecovery.

The route's zone piece (`Route.drive_pieces`: ZONE, PARK, UNPARK edges between an exit into the
perimeter and one out of it) gives the targets in order: each parking spot (its first waypoint, and
the checkpoint at its second), then the perimeter exit.

- ZoneApproach: on the road, up to the perimeter entry, slowing to the zone speed.
- ZoneEnter: to the next target (a spot's alignment point and entry, or the exit).
- ZonePark: into the spot (front bumper to the checkpoint, rules 5.2: "pull forward into [...]
  specified parking spot") and stand `ZONE_PARK_DWELL_S`: the checkpoint is reached.
- ZoneLeave: reverse out to the alignment point ("and reverse out of"), then on to the next target.
- The family leaves to Drive once the rear axle is past the perimeter exit (route tracking resumes
  there) and to ZoneRecovery after `ZONE_NO_PROGRESS_S` without progress: a fresh straight line to
  the target at walking pace; `RECOVERY_NO_PROGRESS_S` more and the GlobalRecovery takes over.

Speeds: the MDF's zone limit, at most `ZONE_SPEED_MAX_MPS`; into and out of the spot `SPOT_SPEED_MPS`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bywire.host.roadnet.graph import Edge, EdgeKind
from bywire.host.roadnet.ids import WaypointId

from . import rules
from .context import BehaviourContext
from .hsm import NoProgress, State, Transition
from .manoeuvre import Leg, polyline_leg

__all__ = ["ZoneNavigator", "ZoneTarget", "zone_family"]

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

    def back_out_leg(self, x_m: float, y_m: float) -> Leg | None:
        """Reverse from (x, y) to the alignment point of the spot just left (the previous target)."""
        if self.index == 0 or self.targets[self.index - 1].kind != "spot":
            return None
        return polyline_leg([(x_m, y_m), self.align_point(self.targets[self.index - 1])], -1)


def _nav(ctx: BehaviourContext) -> ZoneNavigator:
    nav = ctx.manoeuvre_data.get("zone")
    assert isinstance(nav, ZoneNavigator)
    return nav


def _zone_speed(ctx: BehaviourContext) -> float:
    view = ctx.view
    limits = [
        e.speed_max_mps
        for e in view.edges
        if e.kind in (EdgeKind.ZONE, EdgeKind.PARK) and e.speed_max_mps is not None
    ]
    return min([rules.ZONE_SPEED_MAX_MPS, *limits])


# ------------------------------------------------------------------------------------------- the family


def _enter(ctx: BehaviourContext) -> None:
    ctx.manoeuvre_data["zone"] = ZoneNavigator(ctx)


def _exit(ctx: BehaviourContext) -> None:
    nav = ctx.manoeuvre_data.pop("zone", None)
    ctx.end_legs()
    target = nav.target if isinstance(nav, ZoneNavigator) else None
    if target is not None and target.kind == "exit":  # route tracking resumes at the perimeter exit
        ego = ctx.situation.ego
        s, lateral, _ = ctx.view.locate(ego.x_m, ego.y_m, target.exit_route_s_m, 1.0, 10.0)
        ctx.ego_s_m, ctx.ego_lateral_m = s, lateral


def _left_zone(ctx: BehaviourContext) -> bool:
    nav = ctx.manoeuvre_data.get("zone")
    if not isinstance(nav, ZoneNavigator) or not ctx.legs:
        return False
    target = nav.target
    return (
        target is not None
        and target.kind == "exit"
        and ctx.legs[ctx.leg_index].direction == 1
        and ctx.leg_s_m >= nav.exit_s_m
    )


def _follow(ctx: BehaviourContext) -> None:
    if ctx.legs:
        ctx.plan.leg = ctx.legs[ctx.leg_index]
        ctx.plan.leg_s_m = ctx.leg_s_m
        ctx.plan.profile = False
    ctx.cap(_zone_speed(ctx), "zone speed")


# ------------------------------------------------------------------------------------------- substates


def _at_perimeter(ctx: BehaviourContext) -> bool:
    return ctx.on_route and ctx.ego_front_s_m >= _nav(ctx).entry_s_m


def _approach(ctx: BehaviourContext) -> None:
    ctx.cap(_zone_speed(ctx), "zone ahead")
    ctx.say("approaching the zone")


def _enter_entry(ctx: BehaviourContext) -> None:
    ego = ctx.situation.ego
    leg = _nav(ctx).forward_leg(ego.x_m, ego.y_m)
    if leg is not None:
        ctx.begin_legs((leg,))


def _enter_activity(ctx: BehaviourContext) -> None:
    target = _nav(ctx).target
    what = "the exit" if target is None or target.kind == "exit" else f"spot {target.point.lane_id}"
    ctx.say(f"zone: driving to {what} (stand-in straight lines)")


def _front_in_spot(ctx: BehaviourContext) -> bool:
    nav = _nav(ctx)
    target = nav.target
    return (
        target is not None
        and target.kind == "spot"
        and bool(ctx.legs)
        and ctx.legs[ctx.leg_index].direction == 1
        and ctx.leg_s_m + ctx.params.rear_axle_to_front_m >= nav.wp1_s_m
    )


def _park_activity(ctx: BehaviourContext) -> None:
    nav = _nav(ctx)
    ctx.cap(min(rules.SPOT_SPEED_MPS, _zone_speed(ctx)), "in the spot")
    ctx.stop_front_at(nav.wp2_s_m, "parking spot checkpoint")
    front = ctx.leg_s_m + ctx.params.rear_axle_to_front_m
    at_spot = abs(front - nav.wp2_s_m) <= rules.STOP_LINE_TOLERANCE_M
    if ctx.stopped and at_spot:
        if nav.parked_since_s is None:
            nav.parked_since_s = ctx.t_s
    else:
        nav.parked_since_s = None
    ctx.say("parking")


def _parked(ctx: BehaviourContext) -> bool:
    nav = _nav(ctx)
    return nav.parked_since_s is not None and ctx.t_s - nav.parked_since_s >= rules.ZONE_PARK_DWELL_S


def _reach_spot(ctx: BehaviourContext) -> None:
    nav = _nav(ctx)
    for mark in ctx.pending_marks():
        if mark.spot:
            ctx.reach(mark)
        break
    nav.index += 1
    nav.parked_since_s = None


def _parked_final(ctx: BehaviourContext) -> bool:
    if not _parked(ctx):
        return False
    pending = ctx.pending_marks()
    return len(pending) == 1 and pending[0].spot


def _finish_in_spot(ctx: BehaviourContext) -> None:
    _reach_spot(ctx)


def _leave_entry(ctx: BehaviourContext) -> None:
    ego = ctx.situation.ego
    leg = _nav(ctx).back_out_leg(ego.x_m, ego.y_m)
    if leg is not None:
        ctx.begin_legs((leg,))


def _leave_activity(ctx: BehaviourContext) -> None:
    nav = _nav(ctx)
    if ctx.legs and ctx.legs[ctx.leg_index].direction == -1:
        leg = ctx.legs[ctx.leg_index]
        done = ctx.leg_s_m >= leg.end_s_m - rules.KTURN_SWITCH_DISTANCE_M and ctx.stopped
        if not done:
            ctx.cap(min(rules.SPOT_SPEED_MPS, _zone_speed(ctx)), "reversing out")
            ctx.stop_rear_at(leg.end_s_m, "out of the spot")
            ctx.plan.leg, ctx.plan.leg_s_m = leg, ctx.leg_s_m
            ctx.say("zone: reversing out of the spot")
            return
        ego = ctx.situation.ego
        forward = nav.forward_leg(ego.x_m, ego.y_m)
        if forward is None:
            ctx.end_legs()
            ctx.hold("zone: no target left")
            return
        ctx.begin_legs((forward,))
        ctx.plan.leg, ctx.plan.leg_s_m = forward, ctx.leg_s_m
    target = nav.target
    ctx.say("zone: on to " + ("the exit" if target is None or target.kind == "exit" else "the next spot"))


def _recovery_entry(ctx: BehaviourContext) -> None:
    ctx.family_anchor_odometer_m = ctx.odometer_m
    ctx.end_legs()


def _recovery(ctx: BehaviourContext) -> None:
    if ctx.time_in("ZoneRecovery") < rules.RECOVERY_SETTLE_S:
        ctx.hold("zone recovery: looking")
        return
    if not ctx.legs:
        ego = ctx.situation.ego
        leg = _nav(ctx).forward_leg(ego.x_m, ego.y_m)
        if leg is None:
            ctx.hold("zone recovery: no target")
            return
        ctx.begin_legs((leg,))
        ctx.plan.leg, ctx.plan.leg_s_m = leg, ctx.leg_s_m
    ctx.cap(rules.RECOVERY_CREEP_SPEED_MPS, "recovery creep")
    ctx.say("zone recovery: a fresh line to the target")


def _recovered(ctx: BehaviourContext) -> bool:
    return ctx.odometer_m - ctx.family_anchor_odometer_m >= rules.RECOVERY_SUCCESS_M


def zone_family() -> State[BehaviourContext]:
    return State(
        "Zone",
        doc="zones and parking (Sec. 10; stand-in straight-line navigation)",
        initial="ZoneApproach",
        entry=_enter,
        exit=_exit,
        activity=_follow,
        no_progress=NoProgress(rules.ZONE_NO_PROGRESS_S, "ZoneRecovery"),
        transitions=(Transition("Drive", _left_zone, "past the perimeter exit"),),
        children=(
            State(
                "ZoneApproach",
                doc="to the perimeter entry at zone speed",
                activity=_approach,
                transitions=(Transition("ZoneEnter", _at_perimeter, "at the perimeter entry"),),
            ),
            State(
                "ZoneEnter",
                doc="to the spot (or straight to the exit)",
                entry=_enter_entry,
                activity=_enter_activity,
                transitions=(Transition("ZonePark", _front_in_spot, "front bumper at the spot"),),
            ),
            State(
                "ZonePark",
                doc="pull into the spot, stand at its checkpoint",
                activity=_park_activity,
                transitions=(
                    Transition(
                        "MissionComplete", _parked_final, "parked at the last checkpoint", _finish_in_spot
                    ),
                    Transition(
                        "ZoneLeave",
                        _parked,
                        f"stood {rules.ZONE_PARK_DWELL_S:g} s at the checkpoint",
                        _reach_spot,
                    ),
                ),
            ),
            State(
                "ZoneLeave",
                doc="reverse out of the spot, on to the next target",
                entry=_leave_entry,
                activity=_leave_activity,
                transitions=(Transition("ZonePark", _front_in_spot, "front bumper at the next spot"),),
            ),
            State(
                "ZoneRecovery",
                doc="no progress: a fresh straight line to the target",
                entry=_recovery_entry,
                activity=_recovery,
                no_progress=NoProgress(rules.RECOVERY_NO_PROGRESS_S, "GlobalRecovery"),
                transitions=(
                    Transition("ZoneEnter", _recovered, f"{rules.RECOVERY_SUCCESS_M:g} m of headway"),
                ),
            ),
        ),
    )
