"""IntersectionQueue (seed 000 Sec. 9.3, Fig. 15): behind another vehicle before the intersection.

Entered when "another traffic participant is perceived on the same lane between AnnieWAY and the
intersection"; we stay behind it (on a stop road never past the line) "until the other vehicle has
passed the intersection and the lane is free", then approach again.
"""

from __future__ import annotations

from ..context import BehaviourContext
from ..hsm import State, Transition
from .common import manager, someone_before_line

__all__ = ["intersection_queue_state"]


def _lane_free(ctx: BehaviourContext) -> bool:
    return not someone_before_line(ctx)


def _queue(ctx: BehaviourContext) -> None:
    mgr = manager(ctx)
    if mgr.event.stop:
        ctx.stop_front_at(mgr.event.s_m, "stop line")
    lead = ctx.lead
    ctx.say(f"queueing behind {lead.obj.object_id}" if lead is not None else "queueing")


def intersection_queue_state() -> State[BehaviourContext]:
    return State(
        "IntersectionQueue",
        doc="behind another vehicle before the intersection",
        activity=_queue,
        transitions=(Transition("IntersectionApproach", _lane_free, "the lane to the intersection is free"),),
    )
