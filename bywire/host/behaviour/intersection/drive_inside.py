"""IntersectionDriveInside (seed 000 Sec. 9.3, Fig. 15): drive through after the go.

After a go we command the MTC's drive-off (`a_sat`, Sec. 9.1 assumption 3) and drive through at
`INTERSECTION_SPEED_MPS`, the manoeuvre speed v_d the check assumed. While still at the line, an MTC
that turns negative (in motion, with the reduced requirements) stops us there again. The family leaves
to Drive once we are through.
"""

from __future__ import annotations

from .. import rules
from ..context import BehaviourContext
from ..exit_turn import steer_exit
from ..hsm import State
from .common import front_to_line, manager

__all__ = ["intersection_drive_inside_state"]


def _drive_inside(ctx: BehaviourContext) -> None:
    _drive_inside_here(ctx)
    steer_exit(ctx)  # an exit ahead tighter than full lock: its planned moves


def _drive_inside_here(ctx: BehaviourContext) -> None:
    mgr = manager(ctx)
    ctx.cap(rules.INTERSECTION_SPEED_MPS, "through the intersection")
    result = mgr.mtc(ctx.speed_mps, ctx.ego_front_s_m)
    ctx.plan.mtc = result
    at_line = front_to_line(ctx) > -rules.STOP_LINE_TOLERANCE_M
    if not result.free and mgr.event.stop and at_line:
        ctx.stop_front_at(mgr.event.s_m, "MTC turned negative at the line")
        ctx.say("holding at the line: " + "; ".join(r.describe() for r in result.blocking))
        return
    ctx.plan.drive_off_accel_mps2 = rules.mtc_params(rules.MtcSituation.INTERSECTION_CROSSING).accel_sat_mps2
    with_caution = mgr.decision is not None and mgr.decision.with_caution
    ctx.say("driving through the intersection" + (" with caution (stuck vehicles)" if with_caution else ""))


def intersection_drive_inside_state() -> State[BehaviourContext]:
    return State(
        "IntersectionDriveInside",
        doc="drive through, merging per the MTC's safety parameters",
        activity=_drive_inside,
    )
