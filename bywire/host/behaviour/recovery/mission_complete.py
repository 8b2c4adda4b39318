"""MissionComplete (seed 000 Sec. 8): stopped at the last checkpoint (the MDF's finish), and the guard
`mission_done` by which the Drive and Intersection families end there.
"""

from __future__ import annotations

from ..context import BehaviourContext
from ..hsm import State

__all__ = ["mission_complete_state", "mission_done"]


def _complete_activity(ctx: BehaviourContext) -> None:
    ctx.hold(f"mission complete: checkpoints {', '.join(map(str, ctx.reached))} reached")


def mission_complete_state() -> State[BehaviourContext]:
    return State(
        "MissionComplete",
        doc="stopped at the last checkpoint (the MDF's finish)",
        activity=_complete_activity,
    )


def mission_done(ctx: BehaviourContext) -> bool:
    """Every reachable checkpoint of the route passed and we stand still (at the last one)."""
    return ctx.route is not None and not ctx.pending_marks() and ctx.stopped
