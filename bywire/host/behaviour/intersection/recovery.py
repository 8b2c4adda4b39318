"""IntersectionRecovery (seed 000 Sec. 8: "Most states implement a recovery state that is activated
whenever the car makes no progress at all for a certain amount of time"), for Sec. 9.3's intersections.

Entered after `INTERSECTION_NO_PROGRESS_S` without progress while no vehicle at the intersection moves:
stand for `RECOVERY_SETTLE_S`, then proceed through the box with caution at walking pace;
`RECOVERY_NO_PROGRESS_S` more without progress and the GlobalRecovery takes over.
"""

from __future__ import annotations

from .. import rules
from ..context import BehaviourContext
from ..hsm import NoProgress, State

__all__ = ["intersection_recovery_state"]


def _recovery(ctx: BehaviourContext) -> None:
    if ctx.time_in("IntersectionRecovery") < rules.RECOVERY_SETTLE_S:
        ctx.hold("intersection recovery: looking")
        return
    ctx.cap(rules.RECOVERY_CREEP_SPEED_MPS, "recovery creep")
    ctx.say("intersection recovery: proceeding through with caution")


def intersection_recovery_state() -> State[BehaviourContext]:
    return State(
        "IntersectionRecovery",
        doc="no progress: proceed through with caution",
        activity=_recovery,
        no_progress=NoProgress(rules.RECOVERY_NO_PROGRESS_S, "GlobalRecovery"),
    )
