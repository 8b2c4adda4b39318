"""ZoneApproach (seed 000 Sec. 8, the Zone family's entry state): on the road, up to `ZONE_HANDOVER_M`
before the perimeter entry, slowing to the zone speed.
"""

from __future__ import annotations

from .. import rules
from ..context import BehaviourContext
from ..hsm import State, Transition
from .navigator import navigator, zone_speed

__all__ = ["zone_approach_state"]


def _at_perimeter(ctx: BehaviourContext) -> bool:
    return ctx.on_route and ctx.ego_front_s_m >= navigator(ctx).entry_s_m - rules.ZONE_HANDOVER_M


def _approach(ctx: BehaviourContext) -> None:
    ctx.cap(zone_speed(ctx), "zone ahead")
    ctx.say("approaching the zone")


def zone_approach_state() -> State[BehaviourContext]:
    return State(
        "ZoneApproach",
        doc="to the perimeter entry at zone speed",
        activity=_approach,
        transitions=(Transition("ZoneEnter", _at_perimeter, "at the perimeter entry"),),
    )
