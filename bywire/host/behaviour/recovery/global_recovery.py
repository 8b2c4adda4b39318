"""GlobalRecovery (seed 000 Sec. 8): "If all situation-dependent recovery handling fails, a global
recovery state is invoked to navigate back on track".

Hold, and after `RECOVERY_SETTLE_S` try `replan_from_here` (`common`) every `GLOBAL_REPLAN_INTERVAL_S`
until it gives a route (Drive) or a turn (DriveKTurn). Off every lane, the path planner drives the car
back onto the nearest one over whatever is free (`back_to_road`), and the replan follows at once. Its
own timer is its retry interval: it has no recovery above it.
"""

from __future__ import annotations

from .. import rules
from ..context import BehaviourContext
from ..hsm import State, Transition
from .back_to_road import drive_back, forget, request_back
from .common import replan_from_here

__all__ = ["global_recovery_state"]


def _global_entry(ctx: BehaviourContext) -> None:
    forget(ctx)
    ctx.replan_outcome = None
    ctx.manoeuvre_data["global_last_try_s"] = None
    ctx.legs = ()
    ctx.replan_why = ctx.replan_why or "global recovery"


def _global_activity(ctx: BehaviourContext) -> None:
    back = drive_back(ctx)
    if back in ("planning", "driving"):
        return
    if back == "done":
        ctx.replan_outcome = replan_from_here(ctx)
        return
    ctx.hold("global recovery: getting back on track")
    if ctx.time_in("GlobalRecovery") < rules.RECOVERY_SETTLE_S:
        return
    last = ctx.manoeuvre_data.get("global_last_try_s")
    if isinstance(last, float) and ctx.t_s - last < rules.GLOBAL_REPLAN_INTERVAL_S:
        return
    ctx.manoeuvre_data["global_last_try_s"] = ctx.t_s
    ctx.replan_outcome = replan_from_here(ctx)
    ego = ctx.situation.ego
    if ctx.replan_outcome == "failed" and ctx.lane_index.match(ego.x_m, ego.y_m, ego.heading_rad) is None:
        request_back(ctx)  # off every lane: the planner's way back onto the nearest


def global_recovery_state() -> State[BehaviourContext]:
    return State(
        "GlobalRecovery",
        doc="hold, then replan from the current pose every GLOBAL_REPLAN_INTERVAL_S (Sec. 8)",
        entry=_global_entry,
        exit=forget,
        activity=_global_activity,
        transitions=(
            Transition(
                "DriveKTurn", lambda c: c.replan_outcome == "kturn", "blocked where we are: turn around"
            ),
            Transition("Drive", lambda c: c.replan_outcome == "drive", "back on a route"),
        ),
    )
