"""The Zone state itself (seed 000 Secs. 8, 10): the navigator's life, what holds in every substate, and
the substates.

On entry a `ZoneNavigator` is made for the route's zone piece; every cycle the leg being driven is
followed at the zone speed; a planned leg before the last is driven to a stop at its end (a cusp) and
the next one begun; reversing is at spot speed; slower where the path's curvature jumps
(`BehaviourContext.cap_for_steering`); never past the plan's end. Seed 000 Sec. 10's replanning: the
next `BLOCK_CHECK_M` of the leg is checked against what stands every cycle, and a blocked section
there plans the way to the target again at once; stopped short of a planned leg's end for
`ZONE_REPLAN_STALL_S` (what the check cannot see), too. The family leaves to Drive once the rear axle
is past the perimeter exit (route tracking resumes there) and to ZoneRecovery after
`ZONE_NO_PROGRESS_S` without progress.
"""

from __future__ import annotations

import math

from .. import rules
from ..context import BehaviourContext
from ..hsm import NoProgress, State, Transition
from ..path_planning import blocked_ahead
from .approach import zone_approach_state
from .enter import zone_enter_state
from .leave import zone_leave_state
from .navigator import ZoneNavigator, ZoneTarget, zone_speed
from .park import zone_park_state
from .recovery import zone_recovery_state

__all__ = ["zone_family"]

BLOCK_CHECK_M = 12.0  # about two car lengths: what the car needs to stop at zone speed, and some
BLOCK_CHECK_STEP_M = 0.5


def _enter(ctx: BehaviourContext) -> None:
    ctx.manoeuvre_data["zone"] = ZoneNavigator(ctx)


def _exit(ctx: BehaviourContext) -> None:
    nav = ctx.manoeuvre_data.pop("zone", None)
    ctx.end_legs()
    target = nav.target if isinstance(nav, ZoneNavigator) else None
    if target is not None and target.kind == "exit":  # route tracking resumes at the perimeter exit
        ego = ctx.situation.ego
        s, lateral, _ = ctx.view.locate(ego.x_m, ego.y_m, target.exit_route_s_m, 1.0, 10.0)
        # never back inside the zone's piece of the route: Drive would see the zone ahead and come back
        ctx.ego_s_m, ctx.ego_lateral_m = max(s, target.exit_route_s_m), lateral


def _left_zone(ctx: BehaviourContext) -> bool:
    nav = ctx.manoeuvre_data.get("zone")
    if not isinstance(nav, ZoneNavigator) or not ctx.legs:
        return False
    target = nav.target
    return (
        target is not None
        and target.kind == "exit"
        and nav.on_final_leg(ctx)
        and ctx.legs[ctx.leg_index].direction == 1
        and ctx.leg_s_m >= nav.exit_s_m
        and _past_gate(ctx, nav, target)
    )


def _past_gate(ctx: BehaviourContext, nav: ZoneNavigator, target: ZoneTarget) -> bool:
    """Our rear axle is past the perimeter exit along the exit edge (a planned path that runs near the
    perimeter point before it leaves, as at the DARPA sample's 14.0.5, must not end the zone early)."""
    px, py = nav.graph.vertex_xy(target.point)
    edge = target.exit_edge
    if edge is None or len(edge.path) < 2:
        return True
    h = float(edge.path.heading_rad[0])
    ego = ctx.situation.ego
    return (ego.x_m - px) * math.cos(h) + (ego.y_m - py) * math.sin(h) >= 0.0


def _follow(ctx: BehaviourContext) -> None:
    nav = ctx.manoeuvre_data.get("zone")
    if ctx.legs and isinstance(nav, ZoneNavigator) and nav.planned and ctx.leg_index < nav.final_leg:
        ctx.drive_to_cusp("zone: end of a planned leg")
    if (
        ctx.legs
        and isinstance(nav, ZoneNavigator)
        and nav.planned
        and ctx.legs[ctx.leg_index].direction == -1
    ):
        ctx.cap(rules.SPOT_SPEED_MPS, "zone: reversing")
    if ctx.legs and isinstance(nav, ZoneNavigator) and nav.planned:
        # never past the planned path's end, whatever the substate makes of it (the spot's own stop and
        # the exit's hand-over to Drive both come before it)
        if nav.on_final_leg(ctx):
            ctx.stop_rear_at(ctx.legs[-1].end_s_m, "zone: end of the plan")
        if nav.replanning and nav.pending is not None:
            legs = nav.poll_legs(ctx)  # the legs being driven stay until the new ones are there
            if legs:
                ctx.begin_legs(legs)
                ctx.say("zone: replanned around what stands on the path")
        elif not _replan_when_blocked(ctx, nav):
            _replan_when_stalled(ctx, nav)
    if ctx.legs:
        ctx.plan.leg = ctx.legs[ctx.leg_index]
        ctx.plan.leg_s_m = ctx.leg_s_m
        ctx.plan.profile = False
        ctx.cap_for_steering()
    ctx.cap(zone_speed(ctx), "zone speed")


def _replan_when_blocked(ctx: BehaviourContext, nav: ZoneNavigator) -> bool:
    """Every cycle the next `BLOCK_CHECK_M` of the leg being driven is checked against what stands now
    (`path_planning.blocked_ahead`): a blocked section plans the way to the target again from here at
    once (not after stalling in front of it). At most once per `ZONE_REPLAN_STALL_S`. True when a
    replan was asked for."""
    if nav.target is None or (
        nav.blocked_replan_s is not None and ctx.t_s - nav.blocked_replan_s < rules.ZONE_REPLAN_STALL_S
    ):
        return False
    if not blocked_ahead(ctx, BLOCK_CHECK_M, BLOCK_CHECK_STEP_M):
        return False
    nav.blocked_replan_s = ctx.t_s
    nav.request_legs(ctx, back_out=False)
    legs = nav.poll_legs(ctx)
    if legs:
        ctx.begin_legs(legs)
    ctx.say("zone: the plan is blocked ahead by what stands there now: replanning")
    return True


def _replan_when_stalled(ctx: BehaviourContext, nav: ZoneNavigator) -> None:
    """Stopped short of a planned leg's end for `ZONE_REPLAN_STALL_S` (something stands on the path that
    was not on the map it was planned on: on LIDAR, a part of a parked car seen only now): plan again
    from here to the same target, on today's map."""
    leg = ctx.legs[ctx.leg_index]
    short = ctx.leg_s_m < leg.end_s_m - rules.KTURN_SWITCH_DISTANCE_M
    if not (ctx.stopped and short) or nav.target is None:
        nav.stalled_since_s = None
        return
    if nav.stalled_since_s is None:
        nav.stalled_since_s = ctx.t_s
        return
    if ctx.t_s - nav.stalled_since_s < rules.ZONE_REPLAN_STALL_S:
        return
    nav.stalled_since_s = None
    nav.request_legs(ctx, back_out=False)
    legs = nav.poll_legs(ctx)
    if legs:
        ctx.begin_legs(legs)
        ctx.say("zone: replanned around what stands on the path")


def zone_family() -> State[BehaviourContext]:
    return State(
        "Zone",
        doc="zones and parking (Sec. 10: hybrid A* on the zone's obstacle map)",
        initial="ZoneApproach",
        entry=_enter,
        exit=_exit,
        activity=_follow,
        no_progress=NoProgress(rules.ZONE_NO_PROGRESS_S, "ZoneRecovery"),
        transitions=(Transition("Drive", _left_zone, "past the perimeter exit"),),
        children=(
            zone_approach_state(),
            zone_enter_state(),
            zone_park_state(),
            zone_leave_state(),
            zone_recovery_state(),
        ),
    )
