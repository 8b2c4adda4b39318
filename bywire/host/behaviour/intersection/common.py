"""What several Intersection states read (seed 000 Sec. 9.3): the crossing's manager, the distance from
our front bumper to the stop line, whether a vehicle stands between us and the line, the moving-traffic
check (Sec. 9.1) as the manager computes it, and the go latch (the MTC's hysteresis once we set off).
"""

from __future__ import annotations

from ..context import BehaviourContext
from ..intersection_manager import IntersectionManager

__all__ = ["front_to_line", "latch_go", "manager", "mtc_free", "someone_before_line"]


def manager(ctx: BehaviourContext) -> IntersectionManager:
    assert ctx.intersection is not None
    return ctx.intersection


def front_to_line(ctx: BehaviourContext) -> float:
    return manager(ctx).event.s_m - ctx.ego_front_s_m


def someone_before_line(ctx: BehaviourContext) -> bool:
    lead = ctx.lead
    return lead is not None and lead.rear_s_m < manager(ctx).event.s_m


def mtc_free(ctx: BehaviourContext) -> bool:
    result = manager(ctx).mtc(ctx.speed_mps, ctx.ego_front_s_m)
    ctx.plan.mtc = result
    return result.free


def latch_go(ctx: BehaviourContext) -> None:
    manager(ctx).go_latched = True
