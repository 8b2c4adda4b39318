"""DriveRecovery (seed 000 Sec. 8: "Most states implement a recovery state that is activated whenever
the car makes no progress at all for a certain amount of time").

Entered after no progress in Drive for `DRIVE_NO_PROGRESS_S` while no traffic near us moves: stand
for `RECOVERY_SETTLE_S`, then if anything stands in our lane within `RECOVERY_LEAP_M` (AnnieWAY code's
"frog mode" distance) declare the road blocked there and Replan; else creep on along the lane with
caution (a row queued at an intersection is no blockade: there we only wait). `RECOVERY_SUCCESS_M` of
headway returns to DriveOnLane; `RECOVERY_NO_PROGRESS_S` without progress hands over to the
GlobalRecovery.
"""

from __future__ import annotations

from .. import rules
from ..context import BehaviourContext
from ..hsm import NoProgress, State, Transition
from ..recovery.common import mark_blocked_at
from .common import queued

__all__ = ["drive_recovery_state"]


def _recovery_entry(ctx: BehaviourContext) -> None:
    ctx.family_anchor_odometer_m = ctx.odometer_m


def _recovered(ctx: BehaviourContext) -> bool:
    return ctx.odometer_m - ctx.family_anchor_odometer_m >= rules.RECOVERY_SUCCESS_M


def _obstacle_at_leap(ctx: BehaviourContext) -> bool:
    if ctx.time_in("DriveRecovery") < rules.RECOVERY_SETTLE_S or ctx.lead is None:
        return False
    # a jam at an intersection is no blockade: there we wait (and hand over to the global recovery)
    return ctx.lead.rear_s_m - ctx.ego_front_s_m < rules.RECOVERY_LEAP_M and not queued(ctx, ctx.lead)


def _mark_leap(ctx: BehaviourContext) -> None:
    lead = ctx.lead
    assert lead is not None
    mark_blocked_at(ctx, max(lead.rear_s_m, ctx.ego_s_m), f"recovery: {lead.obj.object_id} in our lane")


def _drive_recovery(ctx: BehaviourContext) -> None:
    if ctx.time_in("DriveRecovery") < rules.RECOVERY_SETTLE_S:
        ctx.hold("drive recovery: looking")
        return
    ctx.cap(rules.RECOVERY_CREEP_SPEED_MPS, "recovery creep")
    ctx.say("drive recovery: creeping on along the lane")


def drive_recovery_state() -> State[BehaviourContext]:
    return State(
        "DriveRecovery",
        doc="no progress: look, then declare a blockade or creep on",
        entry=_recovery_entry,
        activity=_drive_recovery,
        no_progress=NoProgress(rules.RECOVERY_NO_PROGRESS_S, "GlobalRecovery"),
        transitions=(
            Transition(
                "Replan",
                _obstacle_at_leap,
                f"obstacle within {rules.RECOVERY_LEAP_M:g} m",
                _mark_leap,
            ),
            Transition("DriveOnLane", _recovered, f"{rules.RECOVERY_SUCCESS_M:g} m of headway"),
        ),
    )
