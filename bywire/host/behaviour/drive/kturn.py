"""DriveKTurn and its legs (seed 000 Sec. 8: "making a k-turn (DriveKTurn)"; Sec. 10: planned on the
obstacle map).

On entry the turn is asked of the path planner on the road (`turnaround`): onto the lane chosen, within
the lanes' widths, around what stands there; DriveKTurnPlanning holds the car until the legs are there.
Where the planner finds none, the geometric three-point turn of `manoeuvre.kturn_legs` onto the opposite
lane on our left (forward, backward, forward), which does not look at the road's edges, and the reason
is said. Each leg ends in a stop at `KTURN_SPEED_MPS` (the gear changes there); DriveKTurnForward and
DriveKTurnBackward drive the legs before the last, DriveKTurnFinish the last; then Replan from the new
pose. A planned turn is checked every cycle against what stands now (`path_planning.blocked_ahead`,
the next `BLOCK_CHECK_M` of the leg): a blocked section stops the car and plans the rest of the turn
again from where it stands (DriveKTurnPlanning), at most once per `rules.ZONE_REPLAN_STALL_S`.
Entered from DriveOnLane at the start of the route's U-turn, or from Replan and GlobalRecovery
when the road is blocked where we are.
"""

from __future__ import annotations

from .. import rules
from ..context import BehaviourContext
from ..hsm import State, Transition
from ..lanes import AdjacentLane, adjacent_left_lane
from ..manoeuvre import Leg, kturn_legs
from ..path_planning import blocked_ahead, legs_of, planner_of
from .turnaround import turn_request, turn_target

__all__ = ["drive_kturn_state"]

_TICKET = "kturn_ticket"
_BLOCKED_AT = "kturn_blocked_at_s"
BLOCK_CHECK_M = 6.0  # a K-turn's legs are short: past the cusp's stop and the car's length


def _geometric_legs(ctx: BehaviourContext) -> tuple[Leg, ...]:
    ego = ctx.situation.ego
    target = ctx.kturn_target
    if target is None:
        edge = ctx.current_edge()
        if edge is not None and edge.lane is not None:
            target = adjacent_left_lane(ctx.graph, edge.lane, ego.x_m, ego.y_m, ego.heading_rad)
    # no lane found alongside: turn on the spot's widest circle (one forward half circle)
    offset = target.offset_m if target is not None else 2.0 * ctx.params.kturn_radius_m
    return kturn_legs(ego.x_m, ego.y_m, ego.heading_rad, offset, ctx.params.kturn_radius_m)


def _kturn_entry(ctx: BehaviourContext) -> None:
    ctx.replan_why = "after the K-turn"
    ctx.legs = ()
    ctx.manoeuvre_data.pop(_TICKET, None)
    ctx.manoeuvre_data.pop(_BLOCKED_AT, None)
    target = turn_target(ctx)
    if _ask_for_the_turn(ctx, target, True, "no lane to plan the turn onto"):
        ctx.kturn_target = target


def _ask_for_the_turn(
    ctx: BehaviourContext, target: AdjacentLane | None, begin_forward: bool, none: str
) -> bool:
    """Ask the planner for the turn onto `target` from where we stand (True); where no request can be
    made, begin the geometric three-point turn and say why (`none`)."""
    request = None if target is None else turn_request(ctx, target, begin_forward)
    if request is None:
        ctx.say(f"K-turn: {none}: the three-point turn")
        ctx.begin_legs(_geometric_legs(ctx))
        return False
    ctx.manoeuvre_data[_TICKET] = planner_of(ctx).submit(request)
    return True


def _kturn_exit(ctx: BehaviourContext) -> None:
    ctx.end_legs()
    ctx.kturn_target = None
    ctx.manoeuvre_data.pop(_TICKET, None)
    ctx.manoeuvre_data.pop(_BLOCKED_AT, None)


def _planned_turn_blocked(ctx: BehaviourContext) -> bool:
    """The planner's turn (not the geometric fallback, which has no target to plan to again) is blocked
    ahead by what stands now, and it was not replanned within `rules.ZONE_REPLAN_STALL_S`."""
    if not ctx.legs or ctx.kturn_target is None:
        return False
    last = ctx.manoeuvre_data.get(_BLOCKED_AT)
    if isinstance(last, float) and ctx.t_s - last < rules.ZONE_REPLAN_STALL_S:
        return False
    return blocked_ahead(ctx, BLOCK_CHECK_M)


def _replan_turn(ctx: BehaviourContext) -> None:
    """The rest of the turn planned again from here; the car holds until it comes (DriveKTurnPlanning),
    and turns the geometric way if none does."""
    ctx.manoeuvre_data[_BLOCKED_AT] = ctx.t_s
    ctx.legs, ctx.leg_index = (), 0
    if _ask_for_the_turn(ctx, ctx.kturn_target, False, "blocked, and no plan can be asked from here"):
        ctx.say("K-turn: the turn is blocked ahead by what stands there now: replanning from here")


def _take_plan(ctx: BehaviourContext) -> None:
    """Begin the planner's legs once they are there (the geometric turn where it found none)."""
    ticket = ctx.manoeuvre_data.get(_TICKET)
    if not isinstance(ticket, int):
        return
    reply = planner_of(ctx).poll(ticket)
    if reply is None:
        return
    del ctx.manoeuvre_data[_TICKET]
    planned = legs_of(reply)
    if isinstance(planned, str):
        ctx.say(f"K-turn: {planned}: the three-point turn")
        ctx.begin_legs(_geometric_legs(ctx))
        return
    ctx.say(f"K-turn planned: {len(planned.legs)} legs, {planned.length_m:.1f} m")
    ctx.begin_legs(planned.legs)


def _next_is(ctx: BehaviourContext, which: str) -> bool:
    """The leg after this one is the last ("last"), or one before it driven forward / backward."""
    nxt = ctx.leg_index + 1
    if nxt >= len(ctx.legs):
        return False
    if which == "last":
        return nxt == len(ctx.legs) - 1
    return nxt < len(ctx.legs) - 1 and ctx.legs[nxt].direction == (1 if which == "forward" else -1)


def _first_is(ctx: BehaviourContext, which: str) -> bool:
    """The legs are there and the first is the last ("last"), or one driven forward / backward."""
    if not ctx.legs or ctx.leg_index != 0:
        return False
    if which == "last":
        return len(ctx.legs) == 1
    return len(ctx.legs) > 1 and ctx.legs[0].direction == (1 if which == "forward" else -1)


def _last_leg_done(ctx: BehaviourContext) -> bool:
    return ctx.leg_done() and ctx.leg_index + 1 >= len(ctx.legs)


def _next_leg(ctx: BehaviourContext) -> None:
    ctx.select_leg(ctx.leg_index + 1)


def _kturn_activity(ctx: BehaviourContext) -> None:
    if not ctx.legs:
        _take_plan(ctx)
    if not ctx.legs:
        ctx.hold("K-turn: planning")
        return
    leg: Leg = ctx.legs[ctx.leg_index]
    ctx.plan.leg = leg
    ctx.plan.leg_s_m = ctx.leg_s_m
    ctx.cap(rules.KTURN_SPEED_MPS, "K-turn speed")
    ctx.cap_for_steering()
    ctx.stop_rear_at(leg.end_s_m, "end of the K-turn leg")
    gear = "forward" if leg.direction == 1 else "backward"
    ctx.say(f"K-turn leg {ctx.leg_index + 1} of {len(ctx.legs)} ({gear})")


def _done_then_last(ctx: BehaviourContext) -> bool:
    return ctx.leg_done() and _next_is(ctx, "last")


def _done_then_backward(ctx: BehaviourContext) -> bool:
    return ctx.leg_done() and _next_is(ctx, "backward")


def _done_then_forward(ctx: BehaviourContext) -> bool:
    return ctx.leg_done() and _next_is(ctx, "forward")


# where a leg before the last leads when it is done: to the state of the leg after it (the planner's
# legs alternate at the cusps; a leg in the same direction again re-enters its state)
_BLOCKED = Transition("DriveKTurnPlanning", _planned_turn_blocked, "blocked ahead: replan", _replan_turn)
_LEG_DONE = (
    _BLOCKED,
    Transition("DriveKTurnFinish", _done_then_last, "leg done, the last next", _next_leg),
    Transition("DriveKTurnBackward", _done_then_backward, "leg done, backward next", _next_leg),
    Transition("DriveKTurnForward", _done_then_forward, "leg done, forward next", _next_leg),
)


def drive_kturn_state() -> State[BehaviourContext]:
    return State(
        "DriveKTurn",
        doc="turn around onto the opposite lane: the planner's legs on the road (else a three-point turn)",
        initial="DriveKTurnPlanning",
        entry=_kturn_entry,
        exit=_kturn_exit,
        activity=_kturn_activity,
        children=(
            State(
                "DriveKTurnPlanning",
                doc="hold while the path planner plans the turn on the road",
                transitions=(
                    Transition("DriveKTurnFinish", lambda c: _first_is(c, "last"), "one leg"),
                    Transition("DriveKTurnForward", lambda c: _first_is(c, "forward"), "forward first"),
                    Transition("DriveKTurnBackward", lambda c: _first_is(c, "backward"), "backward first"),
                ),
            ),
            State(
                "DriveKTurnForward",
                doc="a leg before the last, forward",
                transitions=_LEG_DONE,
            ),
            State(
                "DriveKTurnBackward",
                doc="a leg before the last, backward",
                transitions=_LEG_DONE,
            ),
            State(
                "DriveKTurnFinish",
                doc="the last leg, into the lane",
                transitions=(_BLOCKED, Transition("Replan", _last_leg_done, "turned around")),
            ),
        ),
    )
