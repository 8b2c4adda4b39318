"""DriveKTurn and its three legs (seed 000 Sec. 8: "making a k-turn (DriveKTurn)").

`manoeuvre.kturn_legs` onto the opposite lane on our left, forward, backward, forward, each leg ending
in a stop at `KTURN_SPEED_MPS`; then Replan from the new pose. Entered from DriveOnLane at the start of
the route's U-turn, or from Replan and GlobalRecovery when the road is blocked where we stand.
"""

from __future__ import annotations

from .. import rules
from ..context import BehaviourContext
from ..hsm import State, Transition
from ..lanes import adjacent_left_lane
from ..manoeuvre import Leg, kturn_legs

__all__ = ["drive_kturn_state"]


def _kturn_entry(ctx: BehaviourContext) -> None:
    ego = ctx.situation.ego
    offset = ctx.kturn_offset_m
    if offset is None:
        edge = ctx.current_edge()
        side = None
        if edge is not None and edge.lane is not None:
            side = adjacent_left_lane(ctx.graph, edge.lane, ego.x_m, ego.y_m, ego.heading_rad)
        # no opposite lane found alongside: turn on the spot's widest circle (one forward half circle)
        offset = side.offset_m if side is not None else 2.0 * ctx.params.kturn_radius_m
    legs = kturn_legs(ego.x_m, ego.y_m, ego.heading_rad, offset, ctx.params.kturn_radius_m)
    ctx.begin_legs(legs)
    ctx.replan_why = "after the K-turn"


def _kturn_exit(ctx: BehaviourContext) -> None:
    ctx.end_legs()
    ctx.kturn_offset_m = None


def _leg_done(ctx: BehaviourContext) -> bool:
    if not ctx.legs:
        return True
    leg = ctx.legs[ctx.leg_index]
    return ctx.leg_s_m >= leg.end_s_m - rules.KTURN_SWITCH_DISTANCE_M and ctx.stopped


def _more_legs(ctx: BehaviourContext) -> bool:
    return _leg_done(ctx) and ctx.leg_index + 1 < len(ctx.legs)


def _last_leg_done(ctx: BehaviourContext) -> bool:
    return _leg_done(ctx) and ctx.leg_index + 1 >= len(ctx.legs)


def _next_leg(ctx: BehaviourContext) -> None:
    ctx.select_leg(ctx.leg_index + 1)


def _kturn_activity(ctx: BehaviourContext) -> None:
    if not ctx.legs:
        ctx.hold("K-turn: no legs")
        return
    leg: Leg = ctx.legs[ctx.leg_index]
    ctx.plan.leg = leg
    ctx.plan.leg_s_m = ctx.leg_s_m
    ctx.cap(rules.KTURN_SPEED_MPS, "K-turn speed")
    ctx.stop_rear_at(leg.end_s_m, "end of the K-turn leg")
    gear = "forward" if leg.direction == 1 else "backward"
    ctx.say(f"K-turn leg {ctx.leg_index + 1} of {len(ctx.legs)} ({gear})")


def drive_kturn_state() -> State[BehaviourContext]:
    return State(
        "DriveKTurn",
        doc="turn around onto the opposite lane: forward, backward, forward",
        initial="DriveKTurnForward",
        entry=_kturn_entry,
        exit=_kturn_exit,
        activity=_kturn_activity,
        children=(
            State(
                "DriveKTurnForward",
                doc="first leg, forward, full left",
                transitions=(
                    Transition("DriveKTurnBackward", _more_legs, "leg done", _next_leg),
                    Transition("Replan", _last_leg_done, "turned around"),
                ),
            ),
            State(
                "DriveKTurnBackward",
                doc="second leg, backward, full right",
                transitions=(Transition("DriveKTurnFinish", _more_legs, "leg done", _next_leg),),
            ),
            State(
                "DriveKTurnFinish",
                doc="third leg, forward, full left into the opposite lane",
                transitions=(Transition("Replan", _last_leg_done, "turned around"),),
            ),
        ),
    )
