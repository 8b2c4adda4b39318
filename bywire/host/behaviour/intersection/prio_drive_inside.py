"""IntersectionPrioDriveInside (seed 000 Sec. 9.3 case b, Fig. 15): drive through on the priority road.

On entry the go is latched (we are in motion: the MTC's reduced requirements from now on). We stop
again in IntersectionPrioStop "If a priority vehicle is perceived shortly after driving inside the
intersection (point of no return has not been passed yet) and the MTC turns out negative": turning
left, with room to stop at `PRIO_STOP_DECEL_MPS2` before the oncoming lane.
"""

from __future__ import annotations

from .. import rules
from ..context import BehaviourContext
from ..exit_turn import steer_exit
from ..hsm import State, Transition
from ..precedence import Turn
from .common import manager, mtc_free

__all__ = ["intersection_prio_drive_inside_state"]


def _can_still_stop(ctx: BehaviourContext) -> bool:
    stop_front = manager(ctx).oncoming_stop_front_s()
    if stop_front is None:
        return False
    room = stop_front - ctx.ego_front_s_m
    return room > 0.0 and ctx.speed_mps**2 / (2.0 * rules.PRIO_STOP_DECEL_MPS2) <= room


def _prio_must_stop(ctx: BehaviourContext) -> bool:
    mgr = manager(ctx)
    return mgr.crossing.turn == Turn.LEFT and _can_still_stop(ctx) and not mtc_free(ctx)


def _prio_inside_entry(ctx: BehaviourContext) -> None:
    manager(ctx).go_latched = True  # we are in motion: the MTC's reduced requirements from now on


def _prio_drive_inside(ctx: BehaviourContext) -> None:
    _prio_drive_inside_here(ctx)
    steer_exit(ctx)  # an exit ahead tighter than full lock: its planned moves


def _prio_drive_inside_here(ctx: BehaviourContext) -> None:
    ctx.cap(rules.INTERSECTION_SPEED_MPS, "through the intersection")
    ctx.say("driving through the intersection on the priority road")


def intersection_prio_drive_inside_state() -> State[BehaviourContext]:
    return State(
        "IntersectionPrioDriveInside",
        doc="drive through on the priority road",
        entry=_prio_inside_entry,
        activity=_prio_drive_inside,
        transitions=(
            Transition(
                "IntersectionPrioStop",
                _prio_must_stop,
                "priority vehicle, MTC negative, point of no return not passed",
            ),
        ),
    )
