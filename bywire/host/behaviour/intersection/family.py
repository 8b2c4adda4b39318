"""The Intersection state itself (seed 000 Sec. 9.3, Fig. 15): the intersection manager's life, what holds
in every substate, and the substates.

On entry the crossing's `IntersectionManager` is made for the next intersection on the route, it sees
every cycle's objects, and goes on exit. The family leaves to Drive once our rear axle is past the end
of the crossing edge (MissionComplete when the last checkpoint is reached), and to IntersectionRecovery
after `INTERSECTION_NO_PROGRESS_S` without progress while no vehicle at the intersection moves.
"""

from __future__ import annotations

from .. import rules
from ..context import BehaviourContext
from ..exit_turn import plan_exit_ahead
from ..hsm import NoProgress, State, Transition
from ..intersection_manager import IntersectionManager
from ..recovery.mission_complete import mission_done
from .approach import intersection_approach_state
from .common import manager
from .drive_inside import intersection_drive_inside_state
from .prio_drive_inside import intersection_prio_drive_inside_state
from .prio_stop import intersection_prio_stop_state
from .queue import intersection_queue_state
from .recovery import intersection_recovery_state
from .stop import intersection_stop_state
from .wait import intersection_wait_state

__all__ = ["intersection_family"]


def _enter(ctx: BehaviourContext) -> None:
    event = ctx.view.next_intersection(ctx.ego_s_m)
    assert event is not None
    ctx.intersection = IntersectionManager(ctx.graph, ctx.view, event, ctx.crossing_cache)
    ctx.intersection.update(ctx.t_s, ctx.situation.objects)


def _exit(ctx: BehaviourContext) -> None:
    ctx.intersection = None


def _update(ctx: BehaviourContext) -> None:
    manager(ctx).update(ctx.t_s, ctx.situation.objects)
    plan_exit_ahead(ctx)  # planned while we approach, stop and wait: driven once we go


def _left(ctx: BehaviourContext) -> bool:
    return (
        ctx.intersection is not None and ctx.on_route and ctx.ego_s_m >= ctx.intersection.event.exit_end_s_m
    )


def _moving_here(ctx: BehaviourContext) -> bool:
    return ctx.intersection is not None and ctx.intersection.traffic_moving


def intersection_family() -> State[BehaviourContext]:
    return State(
        "Intersection",
        doc="all behaviour at intersections (Sec. 9.3, Fig. 15)",
        initial="IntersectionApproach",
        entry=_enter,
        exit=_exit,
        activity=_update,
        no_progress=NoProgress(rules.INTERSECTION_NO_PROGRESS_S, "IntersectionRecovery", _moving_here),
        transitions=(
            Transition("MissionComplete", mission_done, "last checkpoint reached"),
            Transition("Drive", _left, "left the intersection"),
        ),
        children=(
            intersection_approach_state(),
            intersection_queue_state(),
            intersection_stop_state(),
            intersection_wait_state(),
            intersection_drive_inside_state(),
            intersection_prio_drive_inside_state(),
            intersection_prio_stop_state(),
            intersection_recovery_state(),
        ),
    )
