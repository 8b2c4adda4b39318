"""The Drive state itself (seed 000 Sec. 8, Fig. 11): what holds in all its substates, and the substates.

From any substate Drive leaves for MissionComplete once the last checkpoint is reached and we stand, and
for Replan when we are off the route by more than `OFF_TRACK_M` outside a manoeuvre; without progress
for `DRIVE_NO_PROGRESS_S` while no traffic near us moves, it enters DriveRecovery. Its substates:
DriveOnLane (the initial one), LaneChange, PassObstacle, DriveKTurn and DriveRecovery.
"""

from __future__ import annotations

from .. import rules
from ..context import BehaviourContext
from ..hsm import NoProgress, State, Transition
from ..recovery.mission_complete import mission_done
from .kturn import drive_kturn_state
from .lane_change import lane_change_state
from .on_lane import drive_on_lane_state
from .pass_obstacle import pass_obstacle_state
from .recovery import drive_recovery_state

__all__ = ["drive_family"]


def _off_track(ctx: BehaviourContext) -> bool:
    return ctx.on_route and not ctx.legs and abs(ctx.ego_lateral_m) > rules.OFF_TRACK_M


def _set_off_track(ctx: BehaviourContext) -> None:
    ctx.replan_why = f"off the route by {abs(ctx.ego_lateral_m):.1f} m"


def _traffic_moving(ctx: BehaviourContext) -> bool:
    return ctx.traffic_moving()


def drive_family() -> State[BehaviourContext]:
    return State(
        "Drive",
        doc="regular driving on roads (Sec. 8)",
        initial="DriveOnLane",
        no_progress=NoProgress(rules.DRIVE_NO_PROGRESS_S, "DriveRecovery", _traffic_moving),
        transitions=(
            Transition("MissionComplete", mission_done, "last checkpoint reached"),
            Transition("Replan", _off_track, f"off the route by > {rules.OFF_TRACK_M:g} m", _set_off_track),
        ),
        children=(
            drive_on_lane_state(),
            lane_change_state(),
            pass_obstacle_state(),
            drive_kturn_state(),
            drive_recovery_state(),
        ),
    )
