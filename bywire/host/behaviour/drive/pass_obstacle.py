"""PassObstacle and its substates (seed 000 Sec. 8, Fig. 13 d; the MTC of Sec. 9): pass a stopped or
parked vehicle through the lane to our left.

PassObstacleWait stands behind the obstacle until the MTC approves the
passing lane (`MtcSituation.PASSING` with oncoming traffic, `LANE_CHANGE` on a lane of our direction),
then PassObstacleOut / PassObstacleBy / PassObstacleBack drive `manoeuvre.shifted_leg`: out over
`PASS_SHIFT_LENGTH_M`, alongside until the rear axle is `PASSING_SEPARATION_M` past the obstacle's
front, back over `PASS_SHIFT_LENGTH_M` (35 m from the stop: rules 5.2 asks for 40 m at most). Should
the obstacle drive off while we wait, we follow it instead. Whether we may pass, and the plan of the
manoeuvre, is `common.pass_plan`.
"""

from __future__ import annotations

from collections.abc import Callable

from .. import rules
from ..context import BehaviourContext
from ..hsm import State, Transition
from ..lanes import lane_vehicles
from ..manoeuvre import shifted_leg
from ..mtc import moving_traffic_check
from .common import PassPlan, pass_plan

__all__ = ["pass_obstacle_state"]


def _pass_entry(ctx: BehaviourContext) -> None:
    plan = pass_plan(ctx)
    assert plan is not None
    view = ctx.view
    w = view.window(plan.out_start_s_m - 3.0, plan.back_end_s_m + 10.0)
    leg = shifted_leg(
        view.x[w],
        view.y[w],
        view.heading[w],
        view.s[w],
        plan.offset_m,
        plan.out_start_s_m,
        plan.back_start_s_m,
        rules.PASS_SHIFT_LENGTH_M,
    )
    mx, my, _ = view.point_at(plan.mp_s_m)
    lane_path = ctx.graph.lane_path(plan.lane)
    plan.mp_lane_s_m = lane_path.project(mx, my).s_m if lane_path is not None else 0.0
    ctx.manoeuvre_data["pass"] = plan
    ctx.begin_legs((leg,))


def _pass_exit(ctx: BehaviourContext) -> None:
    ctx.end_legs()
    ctx.manoeuvre_data.pop("pass", None)


def _pass_plan_of(ctx: BehaviourContext) -> PassPlan:
    plan = ctx.manoeuvre_data["pass"]
    assert isinstance(plan, PassPlan)
    return plan


def _pass_activity(ctx: BehaviourContext) -> None:
    ctx.plan.leg = ctx.legs[0] if ctx.legs else None
    ctx.plan.leg_s_m = ctx.leg_s_m
    ctx.cap(rules.PASS_SPEED_MPS, "passing speed")


def _passing_mtc(ctx: BehaviourContext) -> bool:
    plan = _pass_plan_of(ctx)
    situation = rules.MtcSituation.PASSING if plan.opposite else rules.MtcSituation.LANE_CHANGE
    params = rules.mtc_params(situation).with_desired_speed(rules.PASS_SPEED_MPS)
    vehicles = lane_vehicles(
        ctx.graph,
        ctx.situation.objects,
        plan.lane,
        plan.mp_lane_s_m,
        plan.mp_s_m - ctx.ego_front_s_m,
        params,
        rules.MTC_APPROACH_HORIZON_M,
        frozenset({plan.obstacle_id}),
    )
    result = moving_traffic_check(ctx.speed_mps, vehicles, params)
    ctx.plan.mtc = result
    return result.free


def _pass_wait(ctx: BehaviourContext) -> None:
    ctx.hold("waiting for a gap to pass")
    free = _passing_mtc(ctx)
    plan = _pass_plan_of(ctx)
    ctx.say(f"passing {plan.obstacle_id}: {'gap free' if free else 'oncoming traffic'}")


def _pass_go(ctx: BehaviourContext) -> bool:
    return _passing_mtc(ctx)


def _obstacle_moved(ctx: BehaviourContext) -> bool:
    plan = ctx.manoeuvre_data.get("pass")
    return isinstance(plan, PassPlan) and ctx.stillness.still_for(plan.obstacle_id, ctx.t_s) == 0.0


def _pass_phase(ctx: BehaviourContext, attr: str) -> bool:
    plan = ctx.manoeuvre_data.get("pass")
    return isinstance(plan, PassPlan) and ctx.ego_s_m >= float(getattr(plan, attr))


def _say_pass(what: str) -> Callable[[BehaviourContext], None]:
    def activity(ctx: BehaviourContext) -> None:
        plan = _pass_plan_of(ctx)
        ctx.plan.drive_off_accel_mps2 = rules.mtc_params(rules.MtcSituation.PASSING).accel_sat_mps2
        ctx.say(f"{what} {plan.obstacle_id}")

    return activity


def pass_obstacle_state() -> State[BehaviourContext]:
    return State(
        "PassObstacle",
        doc="pass a stopped or parked vehicle through the lane to the left (Fig. 13 d)",
        initial="PassObstacleWait",
        entry=_pass_entry,
        exit=_pass_exit,
        activity=_pass_activity,
        children=(
            State(
                "PassObstacleWait",
                doc="stand behind it until the MTC approves the passing lane",
                activity=_pass_wait,
                transitions=(
                    Transition("DriveOnLane", _obstacle_moved, "it drove off"),
                    Transition("PassObstacleOut", _pass_go, "MTC: the passing lane is free"),
                ),
            ),
            State(
                "PassObstacleOut",
                doc="lane change out",
                activity=_say_pass("pulling out to pass"),
                transitions=(
                    Transition(
                        "PassObstacleBy",
                        lambda c: _pass_phase(c, "out_end_s_m"),
                        "in the passing lane",
                    ),
                ),
            ),
            State(
                "PassObstacleBy",
                doc="drive by it",
                activity=_say_pass("passing"),
                transitions=(
                    Transition(
                        "PassObstacleBack",
                        lambda c: _pass_phase(c, "back_start_s_m"),
                        f"{rules.PASSING_SEPARATION_M:g} m past it",
                    ),
                ),
            ),
            State(
                "PassObstacleBack",
                doc="lane change back in",
                activity=_say_pass("returning in front of"),
                transitions=(
                    Transition("DriveOnLane", lambda c: _pass_phase(c, "back_end_s_m"), "back in our lane"),
                ),
            ),
        ),
    )
