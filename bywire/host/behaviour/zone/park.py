"""ZonePark (seed 000 Secs. 8, 10; DARPA rules 5.2): into the spot and stand at its checkpoint.

Into the spot (front bumper to the checkpoint, rules 5.2: "pull forward into [...] specified parking
spot") at `SPOT_SPEED_MPS`, and stand `ZONE_PARK_DWELL_S`: the checkpoint is reached. Then
MissionComplete if it was the last one, else ZoneLeave.
"""

from __future__ import annotations

from .. import rules
from ..context import BehaviourContext
from ..hsm import State, Transition
from .navigator import navigator, zone_speed

__all__ = ["zone_park_state"]


def _park_activity(ctx: BehaviourContext) -> None:
    nav = navigator(ctx)
    ctx.cap(min(rules.SPOT_SPEED_MPS, zone_speed(ctx)), "in the spot")
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
    nav = navigator(ctx)
    return nav.parked_since_s is not None and ctx.t_s - nav.parked_since_s >= rules.ZONE_PARK_DWELL_S


def _reach_spot(ctx: BehaviourContext) -> None:
    nav = navigator(ctx)
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


def zone_park_state() -> State[BehaviourContext]:
    return State(
        "ZonePark",
        doc="pull into the spot, stand at its checkpoint",
        activity=_park_activity,
        transitions=(
            Transition("MissionComplete", _parked_final, "parked at the last checkpoint", _finish_in_spot),
            Transition(
                "ZoneLeave",
                _parked,
                f"stood {rules.ZONE_PARK_DWELL_S:g} s at the checkpoint",
                _reach_spot,
            ),
        ),
    )
