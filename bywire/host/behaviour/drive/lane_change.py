"""LaneChange (seed 000 Sec. 8, Fig. 13 c): into the adjacent lane when the moving-traffic check (Sec. 9)
finds a gap.

The moving-traffic check on the target lane (Fig. 13 c, `MtcSituation.LANE_CHANGE`) with the
merge point half way along the lane-change edge; refused, we stop where the change begins and wait.
Once our front bumper is past that point we are committed (the MTC's hysteresis taken to its end).
"""

from __future__ import annotations

from dataclasses import dataclass

from bywire.host.roadnet.ids import LaneId

from .. import rules
from ..context import BehaviourContext
from ..hsm import State, Transition
from ..lanes import lane_vehicles
from ..mtc import moving_traffic_check
from .common import LANE_CHANGE_KINDS, mark_blockade, road_blocked

__all__ = ["LaneChangePlan", "lane_change_state"]


@dataclass
class LaneChangePlan:
    """The lane change ahead: its edge's span on the route, the MTC's merge point half way along it (in
    route and target-lane arc length), and whether we are committed (front bumper past its start)."""

    start_s_m: float
    end_s_m: float
    mp_s_m: float
    target: LaneId | None
    mp_lane_s_m: float
    committed: bool = False


def _lane_change_entry(ctx: BehaviourContext) -> None:
    view = ctx.view
    piece = view.next_piece(ctx.ego_s_m, LANE_CHANGE_KINDS)
    assert piece is not None
    edge = view.edges[piece.first]
    mid = 0.5 * (piece.start_s_m + piece.end_s_m)
    x, y, _ = view.point_at(mid)
    target = edge.lane
    mp_lane_s = 0.0
    if target is not None:
        path = ctx.graph.lane_path(target)
        if path is not None:
            mp_lane_s = path.project(x, y).s_m
    ctx.manoeuvre_data["lane_change"] = LaneChangePlan(piece.start_s_m, piece.end_s_m, mid, target, mp_lane_s)


def _lane_change_plan(ctx: BehaviourContext) -> LaneChangePlan:
    plan = ctx.manoeuvre_data["lane_change"]
    assert isinstance(plan, LaneChangePlan)
    return plan


def _lane_change_done(ctx: BehaviourContext) -> bool:
    return ctx.ego_s_m >= _lane_change_plan(ctx).end_s_m


def _lane_change(ctx: BehaviourContext) -> None:
    plan = _lane_change_plan(ctx)
    if plan.committed or plan.target is None:
        ctx.say(f"changing lanes into {plan.target}")
        return
    limit = ctx.view.v_cap[ctx.view.window(ctx.ego_s_m, ctx.ego_s_m + 1.0)].min()
    v_d = max(float(limit), 1.0)  # the lane's speed (the MTC's v_d must be > 0)
    params = rules.mtc_params(rules.MtcSituation.LANE_CHANGE).with_desired_speed(v_d)
    vehicles = lane_vehicles(
        ctx.graph,
        ctx.situation.objects,
        plan.target,
        plan.mp_lane_s_m,
        plan.mp_s_m - ctx.ego_front_s_m,
        params,
        rules.MTC_APPROACH_HORIZON_M,
    )
    result = moving_traffic_check(ctx.speed_mps, vehicles, params)
    ctx.plan.mtc = result
    if result.free and ctx.ego_front_s_m >= plan.start_s_m:
        plan.committed = True  # the MTC's hysteresis taken to its end: no turning back half way
    if result.free:
        ctx.say(f"lane change into {plan.target}: the gap is free")
    else:
        ctx.stop_front_at(plan.start_s_m, "lane change refused")
        blocking = "; ".join(r.describe() for r in result.blocking)
        ctx.say(f"lane change into {plan.target} waits: {blocking}")


def lane_change_state() -> State[BehaviourContext]:
    return State(
        "LaneChange",
        doc="change into the adjacent lane when the MTC finds a gap (Fig. 13 c)",
        entry=_lane_change_entry,
        activity=_lane_change,
        transitions=(
            Transition("Replan", road_blocked, "road blocked ahead", mark_blockade),
            Transition("DriveOnLane", _lane_change_done, "in the target lane"),
        ),
    )
