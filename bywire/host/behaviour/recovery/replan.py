"""Replan (seed 000 Sec. 8): "reactivates the mission planning module" from where we are.

On entry `replan_from_here` (`common`) gets a route from the current pose; the state holds while it
does and leaves by its outcome: DriveKTurn when we are blocked where we stand and can turn around,
Drive on a new route, GlobalRecovery when there is no route from here.
"""

from __future__ import annotations

from ..context import BehaviourContext
from ..hsm import State, Transition
from .common import replan_from_here

__all__ = ["replan_state"]


def _replan_entry(ctx: BehaviourContext) -> None:
    ctx.replan_outcome = replan_from_here(ctx)


def _replan_activity(ctx: BehaviourContext) -> None:
    ctx.hold(f"replanning ({ctx.replan_why})")


def replan_state() -> State[BehaviourContext]:
    return State(
        "Replan",
        doc="reactivate mission planning from the current pose (Sec. 8)",
        entry=_replan_entry,
        activity=_replan_activity,
        transitions=(
            Transition(
                "DriveKTurn", lambda c: c.replan_outcome == "kturn", "blocked where we are: turn around"
            ),
            Transition("Drive", lambda c: c.replan_outcome == "drive", "new route"),
            Transition("GlobalRecovery", lambda c: c.replan_outcome == "failed", "no route from here"),
        ),
    )
