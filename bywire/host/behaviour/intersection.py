"""The Intersection family: the sub-machine of seed 000 Fig. 15 (Sec. 9.3), and IntersectionRecovery.

Fig. 15 itself is not in our text of the paper; its transitions are the ones Sec. 9.3 describes, and
no others (each is quoted at its guard below):

    IntersectionApproach -> IntersectionQueue           "another traffic participant is perceived on the
                                                          same lane between AnnieWAY and the intersection"
    IntersectionQueue    -> IntersectionApproach        "until the other vehicle has passed the
                                                          intersection and the lane is free"
    IntersectionApproach -> IntersectionStop            (a) "if AnnieWAY is on a stop road"
    IntersectionApproach -> IntersectionPrioDriveInside (b) "on a priority road and no other vehicle has
                                                          the right-of-way"
    IntersectionApproach -> IntersectionPrioStop        (c) "on a priority road but needs to yield the
                                                          right-of-way to priority vehicles [...] before it
                                                          may turn left"
    IntersectionStop     -> IntersectionWait            "AnnieWAY stops at the stop line and changes into
                                                          the state IntersectionWait"
    IntersectionWait     -> IntersectionDriveInside     "As soon as these vehicles have passed the
                                                          intersection and the MTC turns out positive for
                                                          all visible priority vehicles"
    IntersectionPrioDriveInside -> IntersectionPrioStop "If a priority vehicle is perceived shortly after
                                                          driving inside the intersection (point of no
                                                          return has not been passed yet) and the MTC
                                                          turns out negative"
    IntersectionPrioStop -> IntersectionPrioDriveInside "waits until the MTC confirms that no danger comes
                                                          from priority vehicles anymore, and turns left"

The family leaves to Drive once our rear axle is past the end of the crossing edge, and to
IntersectionRecovery after `INTERSECTION_NO_PROGRESS_S` without progress while no vehicle at the
intersection moves (a recovery that proceeds through the box with caution at walking pace;
`RECOVERY_NO_PROGRESS_S` more without progress and the GlobalRecovery takes over).

Who may go is decided by the crossing's `IntersectionManager`: precedence at four-way stops
(`IntersectionPrecedence`: every vehicle that stopped before us goes first, in its order, each with its
own bounded turn - the n x 10 s of Sec. 12 done right) and the MTC for priority traffic (`right_of_way`
cases a-c), with the MTC's hysteresis once we set off. After a go we command the MTC's drive-off
(`a_sat`, Sec. 9.1 assumption 3) and drive through at `INTERSECTION_SPEED_MPS`, the manoeuvre speed v_d
the check assumed. While still at the line in IntersectionDriveInside, an MTC that turns negative (in
motion, with the reduced requirements) stops us there again.

Stop-line accuracy: IntersectionStop stops the front bumper on the line (the longitudinal stopping and
position controllers aim there, Sec. 11.2.2); IntersectionWait begins once we stand with the front
bumper no more than `STOP_LINE_TOLERANCE_M` before it (rules 5.2: within 1 m).
"""

from __future__ import annotations

from . import rules
from .context import BehaviourContext
from .hsm import NoProgress, State, Transition
from .intersection_manager import IntersectionManager
from .precedence import Turn
from .recovery.mission_complete import mission_done

__all__ = ["intersection_family"]


def _mgr(ctx: BehaviourContext) -> IntersectionManager:
    assert ctx.intersection is not None
    return ctx.intersection


# ------------------------------------------------------------------------------------------- the family


def _enter(ctx: BehaviourContext) -> None:
    event = ctx.view.next_intersection(ctx.ego_s_m)
    assert event is not None
    ctx.intersection = IntersectionManager(ctx.graph, ctx.view, event, ctx.crossing_cache)
    ctx.intersection.update(ctx.t_s, ctx.situation.objects)


def _exit(ctx: BehaviourContext) -> None:
    ctx.intersection = None


def _update(ctx: BehaviourContext) -> None:
    _mgr(ctx).update(ctx.t_s, ctx.situation.objects)


def _left(ctx: BehaviourContext) -> bool:
    return (
        ctx.intersection is not None and ctx.on_route and ctx.ego_s_m >= ctx.intersection.event.exit_end_s_m
    )


def _moving_here(ctx: BehaviourContext) -> bool:
    return ctx.intersection is not None and ctx.intersection.traffic_moving


def _front_to_line(ctx: BehaviourContext) -> float:
    return _mgr(ctx).event.s_m - ctx.ego_front_s_m


def _someone_before_line(ctx: BehaviourContext) -> bool:
    lead = ctx.lead
    return lead is not None and lead.rear_s_m < _mgr(ctx).event.s_m


def _near_decision(ctx: BehaviourContext) -> bool:
    return _front_to_line(ctx) <= rules.INTERSECTION_DECISION_M


def _mtc_free(ctx: BehaviourContext) -> bool:
    result = _mgr(ctx).mtc(ctx.speed_mps, ctx.ego_front_s_m)
    ctx.plan.mtc = result
    return result.free


# ------------------------------------------------------------------------------------------- Approach


def _stop_road(ctx: BehaviourContext) -> bool:
    return _mgr(ctx).event.stop


def _prio_yield(ctx: BehaviourContext) -> bool:
    """Case c: priority road, left turn, the MTC refuses (someone oncoming has the right of way)."""
    mgr = _mgr(ctx)
    return (
        not mgr.event.stop and _near_decision(ctx) and mgr.crossing.turn == Turn.LEFT and not _mtc_free(ctx)
    )


def _prio_go(ctx: BehaviourContext) -> bool:
    """Case b: priority road and nobody has the right of way over us (the MTC approves all of them)."""
    mgr = _mgr(ctx)
    return not mgr.event.stop and _near_decision(ctx) and _mtc_free(ctx)


def _approach(ctx: BehaviourContext) -> None:
    mgr = _mgr(ctx)
    if mgr.event.stop:
        ctx.stop_front_at(mgr.event.s_m, "stop line")
    ctx.say(f"approaching the intersection at {mgr.event.approach} ({mgr.crossing.turn.value})")


# ------------------------------------------------------------------------------------------- Queue


def _lane_free(ctx: BehaviourContext) -> bool:
    return not _someone_before_line(ctx)


def _queue(ctx: BehaviourContext) -> None:
    mgr = _mgr(ctx)
    if mgr.event.stop:
        ctx.stop_front_at(mgr.event.s_m, "stop line")
    lead = ctx.lead
    ctx.say(f"queueing behind {lead.obj.object_id}" if lead is not None else "queueing")


# ------------------------------------------------------------------------------------------- Stop / Wait


def _stopped_at_line(ctx: BehaviourContext) -> bool:
    return ctx.stopped and _front_to_line(ctx) <= rules.STOP_LINE_TOLERANCE_M


def _stop(ctx: BehaviourContext) -> None:
    ctx.stop_front_at(_mgr(ctx).event.s_m, "stop line")
    ctx.say(f"stopping at the stop line, {_front_to_line(ctx):.1f} m ahead")


def _arrive(ctx: BehaviourContext) -> None:
    _mgr(ctx).arrive(ctx.t_s)


def _our_turn(ctx: BehaviourContext) -> bool:
    mgr = _mgr(ctx)
    return (
        ctx.time_in("IntersectionWait") >= rules.INTERSECTION_MIN_WAIT_S
        and mgr.may_go_by_precedence
        and _mtc_free(ctx)
    )


def _latch_go(ctx: BehaviourContext) -> None:
    _mgr(ctx).go_latched = True


def _wait(ctx: BehaviourContext) -> None:
    mgr = _mgr(ctx)
    ctx.hold("waiting at the stop line")
    if ctx.plan.mtc is None:
        ctx.plan.mtc = mgr.mtc(ctx.speed_mps, ctx.ego_front_s_m)
    parts = []
    if mgr.decision is not None:
        parts.append(mgr.decision.reason)
    if ctx.plan.mtc is not None and not ctx.plan.mtc.free:
        parts.append("MTC: " + "; ".join(r.describe() for r in ctx.plan.mtc.blocking))
    ctx.say("waiting: " + (" / ".join(parts) if parts else "minimum stop"))


# ------------------------------------------------------------------------------------------- DriveInside


def _drive_inside(ctx: BehaviourContext) -> None:
    mgr = _mgr(ctx)
    ctx.cap(rules.INTERSECTION_SPEED_MPS, "through the intersection")
    result = mgr.mtc(ctx.speed_mps, ctx.ego_front_s_m)
    ctx.plan.mtc = result
    at_line = _front_to_line(ctx) > -rules.STOP_LINE_TOLERANCE_M
    if not result.free and mgr.event.stop and at_line:
        ctx.stop_front_at(mgr.event.s_m, "MTC turned negative at the line")
        ctx.say("holding at the line: " + "; ".join(r.describe() for r in result.blocking))
        return
    ctx.plan.drive_off_accel_mps2 = rules.mtc_params(rules.MtcSituation.INTERSECTION_CROSSING).accel_sat_mps2
    with_caution = mgr.decision is not None and mgr.decision.with_caution
    ctx.say("driving through the intersection" + (" with caution (stuck vehicles)" if with_caution else ""))


# ------------------------------------------------------------------------------------------- priority road


def _can_still_stop(ctx: BehaviourContext) -> bool:
    stop_front = _mgr(ctx).oncoming_stop_front_s()
    if stop_front is None:
        return False
    room = stop_front - ctx.ego_front_s_m
    return room > 0.0 and ctx.speed_mps**2 / (2.0 * rules.PRIO_STOP_DECEL_MPS2) <= room


def _prio_must_stop(ctx: BehaviourContext) -> bool:
    mgr = _mgr(ctx)
    return mgr.crossing.turn == Turn.LEFT and _can_still_stop(ctx) and not _mtc_free(ctx)


def _prio_inside_entry(ctx: BehaviourContext) -> None:
    _mgr(ctx).go_latched = True  # we are in motion: the MTC's reduced requirements from now on


def _prio_drive_inside(ctx: BehaviourContext) -> None:
    ctx.cap(rules.INTERSECTION_SPEED_MPS, "through the intersection")
    ctx.say("driving through the intersection on the priority road")


def _prio_stop_entry(ctx: BehaviourContext) -> None:
    _mgr(ctx).go_latched = False


def _prio_stop(ctx: BehaviourContext) -> None:
    mgr = _mgr(ctx)
    stop_front = mgr.oncoming_stop_front_s()
    if stop_front is not None:
        ctx.stop_front_at(stop_front, "yield to oncoming traffic")
    ctx.cap(rules.INTERSECTION_SPEED_MPS, "left turn")
    if ctx.plan.mtc is None:
        ctx.plan.mtc = mgr.mtc(ctx.speed_mps, ctx.ego_front_s_m)
    blocking = "; ".join(r.describe() for r in ctx.plan.mtc.blocking)
    ctx.say("yielding before the left turn" + (f": {blocking}" if blocking else ""))


# ------------------------------------------------------------------------------------------- recovery


def _recovery(ctx: BehaviourContext) -> None:
    if ctx.time_in("IntersectionRecovery") < rules.RECOVERY_SETTLE_S:
        ctx.hold("intersection recovery: looking")
        return
    ctx.cap(rules.RECOVERY_CREEP_SPEED_MPS, "recovery creep")
    ctx.say("intersection recovery: proceeding through with caution")


def intersection_family() -> State[BehaviourContext]:
    decide = f"within {rules.INTERSECTION_DECISION_M:g} m"
    return State(
        "Intersection",
        doc="all behaviour at intersections (Sec. 9.3, Fig. 15)",
        initial="IntersectionApproach",
        entry=_enter,
        exit=_exit,
        activity=_update,
        no_progress=NoProgress(rules.INTERSECTION_NO_PROGRESS_S, "IntersectionRecovery", _moving_here),
        transitions=(
            Transition("MissionComplete", mission_done, "last checkpoint reached"),
            Transition("Drive", _left, "left the intersection"),
        ),
        children=(
            State(
                "IntersectionApproach",
                doc="entry state: approach until the decision",
                activity=_approach,
                transitions=(
                    Transition(
                        "IntersectionQueue", _someone_before_line, "vehicle between us and the intersection"
                    ),
                    Transition("IntersectionStop", _stop_road, "(a) stop road"),
                    Transition(
                        "IntersectionPrioStop",
                        _prio_yield,
                        f"(c) priority road, left turn, MTC negative, {decide}",
                    ),
                    Transition(
                        "IntersectionPrioDriveInside", _prio_go, f"(b) priority road, MTC positive, {decide}"
                    ),
                ),
            ),
            State(
                "IntersectionQueue",
                doc="behind another vehicle before the intersection",
                activity=_queue,
                transitions=(
                    Transition("IntersectionApproach", _lane_free, "the lane to the intersection is free"),
                ),
            ),
            State(
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
            ),
            State(
                "IntersectionWait",
                doc="precedence (four-way stop) and MTC for priority vehicles",
                entry=_arrive,
                activity=_wait,
                transitions=(
                    Transition(
                        "IntersectionDriveInside",
                        _our_turn,
                        "those with precedence have passed and the MTC is positive",
                        _latch_go,
                    ),
                ),
            ),
            State(
                "IntersectionDriveInside",
                doc="drive through, merging per the MTC's safety parameters",
                activity=_drive_inside,
            ),
            State(
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
            ),
            State(
                "IntersectionPrioStop",
                doc="stop before the opposing lane until the MTC approves the left turn",
                entry=_prio_stop_entry,
                activity=_prio_stop,
                transitions=(
                    Transition("IntersectionPrioDriveInside", _mtc_free, "MTC positive", _latch_go),
                ),
            ),
            State(
                "IntersectionRecovery",
                doc="no progress: proceed through with caution",
                activity=_recovery,
                no_progress=NoProgress(rules.RECOVERY_NO_PROGRESS_S, "GlobalRecovery"),
            ),
        ),
    )
