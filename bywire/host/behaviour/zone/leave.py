"""ZoneLeave (seed 000 Secs. 8, 10; DARPA rules 5.2 "and reverse out of"): the planner's legs out of the
spot and on to the next target (ZonePark at the next spot); with the stand-in, reverse out to the
spot's alignment point, then on.
"""

from __future__ import annotations

from .. import rules
from ..context import BehaviourContext
from ..hsm import State, Transition
from .navigator import front_in_spot, navigator, take_planned_legs, zone_speed

__all__ = ["zone_leave_state"]


def _leave_entry(ctx: BehaviourContext) -> None:
    navigator(ctx).request_legs(ctx)
    take_planned_legs(ctx)


def _leave_activity(ctx: BehaviourContext) -> None:
    nav = navigator(ctx)
    if take_planned_legs(ctx):
        return
    if nav.planned:  # the planner's legs reverse out and go on; the Zone family drives them
        target = nav.target
        ctx.say(
            "zone: out of the spot, to "
            + ("the exit" if target is None or target.kind == "exit" else "the next spot")
        )
        return
    if ctx.legs and ctx.legs[ctx.leg_index].direction == -1:
        leg = ctx.legs[ctx.leg_index]
        if not ctx.leg_done():
            ctx.cap(min(rules.SPOT_SPEED_MPS, zone_speed(ctx)), "reversing out")
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


def zone_leave_state() -> State[BehaviourContext]:
    return State(
        "ZoneLeave",
        doc="reverse out of the spot, on to the next target",
        entry=_leave_entry,
        activity=_leave_activity,
        transitions=(Transition("ZonePark", front_in_spot, "front bumper at the next spot"),),
    )
