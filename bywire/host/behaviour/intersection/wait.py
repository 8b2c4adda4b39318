"""IntersectionWait (seed 000 Sec. 9.3, Fig. 15): at the stop line, precedence and the MTC.

On entry we arrive at the line (the manager's four-way-stop precedence counts from then). We go on to
IntersectionDriveInside "As soon as these vehicles have passed the intersection and the MTC turns out
positive for all visible priority vehicles", after `INTERSECTION_MIN_WAIT_S` at the least, and latch
the go (the MTC's hysteresis once we set off).
"""

from __future__ import annotations

from .. import rules
from ..context import BehaviourContext
from ..hsm import State, Transition
from .common import latch_go, manager, mtc_free

__all__ = ["intersection_wait_state"]


def _arrive(ctx: BehaviourContext) -> None:
    manager(ctx).arrive(ctx.t_s)


def _our_turn(ctx: BehaviourContext) -> bool:
    mgr = manager(ctx)
    return (
        ctx.time_in("IntersectionWait") >= rules.INTERSECTION_MIN_WAIT_S
        and mgr.may_go_by_precedence
        and mtc_free(ctx)
    )


def _wait(ctx: BehaviourContext) -> None:
    mgr = manager(ctx)
    ctx.hold("waiting at the stop line")
    if ctx.plan.mtc is None:
        ctx.plan.mtc = mgr.mtc(ctx.speed_mps, ctx.ego_front_s_m)
    parts = []
    if mgr.decision is not None:
        parts.append(mgr.decision.reason)
    if ctx.plan.mtc is not None and not ctx.plan.mtc.free:
        parts.append("MTC: " + "; ".join(r.describe() for r in ctx.plan.mtc.blocking))
    ctx.say("waiting: " + (" / ".join(parts) if parts else "minimum stop"))


def intersection_wait_state() -> State[BehaviourContext]:
    return State(
        "IntersectionWait",
        doc="precedence (four-way stop) and MTC for priority vehicles",
        entry=_arrive,
        activity=_wait,
        transitions=(
            Transition(
                "IntersectionDriveInside",
                _our_turn,
                "those with precedence have passed and the MTC is positive",
                latch_go,
            ),
        ),
    )
