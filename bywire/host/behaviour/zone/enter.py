"""ZoneEnter (seed 000 Secs. 8, 10): to the next target, a spot's alignment point and entry, or the exit.

On entry the navigator's legs to the target are begun; ZonePark once the front bumper is at the
spot.
"""

from __future__ import annotations

from ..context import BehaviourContext
from ..hsm import State, Transition
from .navigator import front_in_spot, navigator, take_planned_legs

__all__ = ["zone_enter_state"]


def _enter_entry(ctx: BehaviourContext) -> None:
    navigator(ctx).request_legs(ctx)
    take_planned_legs(ctx)


def _enter_activity(ctx: BehaviourContext) -> None:
    if take_planned_legs(ctx):
        return
    target = navigator(ctx).target
    what = "the exit" if target is None or target.kind == "exit" else f"spot {target.point.lane_id}"
    how = "planned path" if navigator(ctx).planned else "stand-in straight lines"
    ctx.say(f"zone: driving to {what} ({how})")


def zone_enter_state() -> State[BehaviourContext]:
    return State(
        "ZoneEnter",
        doc="to the spot (or straight to the exit)",
        entry=_enter_entry,
        activity=_enter_activity,
        transitions=(Transition("ZonePark", front_in_spot, "front bumper at the spot"),),
    )
