"""IntersectionStop (seed 000 Sec. 9.3 case a, Fig. 15): stop at the stop line of a stop road.

"AnnieWAY stops at the stop line and changes into the state IntersectionWait". Stop-line accuracy: the
front bumper is stopped on the line (the longitudinal stopping and position controllers aim there,
Sec. 11.2.2); IntersectionWait begins once we stand with the front bumper no more than
`STOP_LINE_TOLERANCE_M` before it (rules 5.2: within 1 m).
"""

from __future__ import annotations

from .. import rules
from ..context import BehaviourContext
from ..hsm import State, Transition
from .common import front_to_line, manager

__all__ = ["intersection_stop_state"]


def _stopped_at_line(ctx: BehaviourContext) -> bool:
    return ctx.stopped and front_to_line(ctx) <= rules.STOP_LINE_TOLERANCE_M


def _stop(ctx: BehaviourContext) -> None:
    ctx.stop_front_at(manager(ctx).event.s_m, "stop line")
    ctx.say(f"stopping at the stop line, {front_to_line(ctx):.1f} m ahead")


def intersection_stop_state() -> State[BehaviourContext]:
    return State(
        "IntersectionStop",
        doc="stop at the stop line",
        activity=_stop,
        transitions=(
            Transition(
                "IntersectionWait",
                _stopped_at_line,
                f"stopped, front within {rules.STOP_LINE_TOLERANCE_M:g} m of the line",
            ),
        ),
    )
