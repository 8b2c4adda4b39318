"""IntersectionPrioStop (seed 000 Sec. 9.3 case c, Fig. 15): yield before the left turn on a priority road.

On entry the go latch is released. We stop before the oncoming lane and "wait until the MTC confirms
that no danger comes from priority vehicles anymore, and turn left" (IntersectionPrioDriveInside, the
go latched again).
"""

from __future__ import annotations

from .. import rules
from ..context import BehaviourContext
from ..hsm import State, Transition
from .common import latch_go, manager, mtc_free

__all__ = ["intersection_prio_stop_state"]


def _prio_stop_entry(ctx: BehaviourContext) -> None:
    manager(ctx).go_latched = False


def _prio_stop(ctx: BehaviourContext) -> None:
    mgr = manager(ctx)
    stop_front = mgr.oncoming_stop_front_s()
    if stop_front is not None:
        ctx.stop_front_at(stop_front, "yield to oncoming traffic")
    ctx.cap(rules.INTERSECTION_SPEED_MPS, "left turn")
    if ctx.plan.mtc is None:
        ctx.plan.mtc = mgr.mtc(ctx.speed_mps, ctx.ego_front_s_m)
    blocking = "; ".join(r.describe() for r in ctx.plan.mtc.blocking)
    ctx.say("yielding before the left turn" + (f": {blocking}" if blocking else ""))


def intersection_prio_stop_state() -> State[BehaviourContext]:
    return State(
        "IntersectionPrioStop",
        doc="stop before the opposing lane until the MTC approves the left turn",
        entry=_prio_stop_entry,
        activity=_prio_stop,
        transitions=(Transition("IntersectionPrioDriveInside", mtc_free, "MTC positive", latch_go),),
    )
