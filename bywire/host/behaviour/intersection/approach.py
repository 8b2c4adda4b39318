"""IntersectionApproach (seed 000 Sec. 9.3, Fig. 15): the entry state, up to the decision.

We approach the intersection (on a stop road stopping at the line) and leave, in this order, for

    IntersectionQueue           "another traffic participant is perceived on the same lane between
                                AnnieWAY and the intersection"
    IntersectionStop            (a) "if AnnieWAY is on a stop road"
    IntersectionPrioStop        (c) "on a priority road but needs to yield the right-of-way to priority
                                vehicles [...] before it may turn left"
    IntersectionPrioDriveInside (b) "on a priority road and no other vehicle has the right-of-way"

cases b and c decided within `INTERSECTION_DECISION_M` of the line.
"""

from __future__ import annotations

from .. import rules
from ..context import BehaviourContext
from ..hsm import State, Transition
from ..precedence import Turn
from .common import front_to_line, manager, mtc_free, someone_before_line

__all__ = ["intersection_approach_state"]


def _near_decision(ctx: BehaviourContext) -> bool:
    return front_to_line(ctx) <= rules.INTERSECTION_DECISION_M


def _stop_road(ctx: BehaviourContext) -> bool:
    return manager(ctx).event.stop


def _prio_yield(ctx: BehaviourContext) -> bool:
    """Case c: priority road, left turn, the MTC refuses (someone oncoming has the right of way)."""
    mgr = manager(ctx)
    return not mgr.event.stop and _near_decision(ctx) and mgr.crossing.turn == Turn.LEFT and not mtc_free(ctx)


def _prio_go(ctx: BehaviourContext) -> bool:
    """Case b: priority road and nobody has the right of way over us (the MTC approves all of them)."""
    mgr = manager(ctx)
    return not mgr.event.stop and _near_decision(ctx) and mtc_free(ctx)


def _approach(ctx: BehaviourContext) -> None:
    mgr = manager(ctx)
    if mgr.event.stop:
        ctx.stop_front_at(mgr.event.s_m, "stop line")
    ctx.say(f"approaching the intersection at {mgr.event.approach} ({mgr.crossing.turn.value})")


def intersection_approach_state() -> State[BehaviourContext]:
    decide = f"within {rules.INTERSECTION_DECISION_M:g} m"
    return State(
        "IntersectionApproach",
        doc="entry state: approach until the decision",
        activity=_approach,
        transitions=(
            Transition("IntersectionQueue", someone_before_line, "vehicle between us and the intersection"),
            Transition("IntersectionStop", _stop_road, "(a) stop road"),
            Transition(
                "IntersectionPrioStop",
                _prio_yield,
                f"(c) priority road, left turn, MTC negative, {decide}",
            ),
            Transition("IntersectionPrioDriveInside", _prio_go, f"(b) priority road, MTC positive, {decide}"),
        ),
    )
