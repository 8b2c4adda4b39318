"""ZoneRecovery (seed 000 Sec. 8: "Most states implement a recovery state that is activated whenever the
car makes no progress at all for a certain amount of time"), for the zones of Sec. 10.

Entered after `ZONE_NO_PROGRESS_S` without progress: stand for `RECOVERY_SETTLE_S`, then a fresh
straight line to the target at walking pace; `RECOVERY_SUCCESS_M` of headway returns to ZoneEnter,
`RECOVERY_NO_PROGRESS_S` more without progress and the GlobalRecovery takes over.
"""

from __future__ import annotations

from .. import rules
from ..context import BehaviourContext
from ..hsm import NoProgress, State, Transition
from .navigator import navigator

__all__ = ["zone_recovery_state"]


def _recovery_entry(ctx: BehaviourContext) -> None:
    ctx.family_anchor_odometer_m = ctx.odometer_m
    ctx.end_legs()


def _recovery(ctx: BehaviourContext) -> None:
    if ctx.time_in("ZoneRecovery") < rules.RECOVERY_SETTLE_S:
        ctx.hold("zone recovery: looking")
        return
    if not ctx.legs:
        ego = ctx.situation.ego
        leg = navigator(ctx).forward_leg(ego.x_m, ego.y_m)
        if leg is None:
            ctx.hold("zone recovery: no target")
            return
        ctx.begin_legs((leg,))
        ctx.plan.leg, ctx.plan.leg_s_m = leg, ctx.leg_s_m
    ctx.cap(rules.RECOVERY_CREEP_SPEED_MPS, "recovery creep")
    ctx.say("zone recovery: a fresh line to the target")


def _recovered(ctx: BehaviourContext) -> bool:
    return ctx.odometer_m - ctx.family_anchor_odometer_m >= rules.RECOVERY_SUCCESS_M


def zone_recovery_state() -> State[BehaviourContext]:
    return State(
        "ZoneRecovery",
        doc="no progress: a fresh straight line to the target",
        entry=_recovery_entry,
        activity=_recovery,
        no_progress=NoProgress(rules.RECOVERY_NO_PROGRESS_S, "GlobalRecovery"),
        transitions=(Transition("ZoneEnter", _recovered, f"{rules.RECOVERY_SUCCESS_M:g} m of headway"),),
    )
