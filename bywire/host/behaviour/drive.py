"""The Drive family: DriveOnLane, LaneChange, PassObstacle, DriveKTurn, DriveRecovery (seed 000 Sec. 8).

Sec. 8: "The state Drive comprises all regular driving maneuvers on normal roads. It has several
substates that cover different situations, such as following the course of a lane (DriveOnLane),
making a k-turn (DriveKTurn), or changing the lane (LaneChange)." Passing a stopped or parked car is
ours to add (AnnieWAY's published code has it as `StDrivePassObstacle`), with its lane change out and
back. Every state below has the same shape: a doc line, its entry/exit, its activity (what it plans
each cycle) and its transitions, the guards named for what they test and labelled with the rule.

DriveOnLane follows the route stub at the profile speed (MDF limits, curves), behind the lead vehicle
(the following controller keeps DARPA's distance, Sec. 11.2.1), and stops 7.5 m behind a stopped lead
(rules 5.2: 5-10 m). It leaves, in this order of precedence, for

1. Replan - the road is blocked: perception reports it for an edge (or a point) ahead of us (each
   report acted on once, until it is withdrawn), or an obstacle in our lane within `BLOCKADE_RANGE_M`
   has stood still for the `BLOCKADE_STILL_S` (AnnieWAY code: 10 s) we have stood behind it, cannot
   be passed, and is not queued at an intersection. The edge it stands on is marked blocked;
2. (the family, from any substate: MissionComplete once the last checkpoint is reached and we stand,
   Replan when we are off the route by more than `OFF_TRACK_M` outside a manoeuvre)
3. Intersection - the next intersection is within `INTERSECTION_APPROACH_TRIGGER_M` (55 m);
4. Zone - the next zone entry is within `ZONE_APPROACH_TRIGGER_M`;
5. DriveKTurn - the route's next piece is a U-turn (K-turn) and we stand at its start;
6. LaneChange - the route's next lane change starts within `LANE_CHANGE_TRIGGER_M`;
7. PassObstacle - a vehicle in our lane has stood still for the `PASS_STILL_S` (AnnieWAY code: 5 s)
   we have stood behind it (5-10 m back), it is not queued at an intersection (rules 1.7: a row of
   still vehicles up to a stop line, `QUEUE_GAP_M` apart at most), there is a lane to our left
   alongside with no still obstacle in the stretch we need (`PASSING_SEPARATION_M` before and after
   it), and the route runs on along our lane for the whole manoeuvre and `PASS_NO_INTERSECTION_M`
   more. (Passing on the right is not done.)

LaneChange: the moving-traffic check on the target lane (Fig. 13 c, `MtcSituation.LANE_CHANGE`) with the
merge point half way along the lane-change edge; refused, we stop where the change begins and wait.
Once our front bumper is past that point we are committed (the MTC's hysteresis taken to its end).

PassObstacle (Fig. 13 d): PassObstacleWait stands behind the obstacle until the MTC approves the
passing lane (`MtcSituation.PASSING` with oncoming traffic, `LANE_CHANGE` on a lane of our direction),
then PassObstacleOut / PassObstacleBy / PassObstacleBack drive `manoeuvre.shifted_leg`: out over
`PASS_SHIFT_LENGTH_M`, alongside until the rear axle is `PASSING_SEPARATION_M` past the obstacle's
front, back over `PASS_SHIFT_LENGTH_M` (35 m from the stop: rules 5.2 asks for 40 m at most). Should
the obstacle drive off while we wait, we follow it instead.

DriveKTurn: `manoeuvre.kturn_legs` onto the opposite lane on our left, forward, backward, forward,
each leg ending in a stop at `KTURN_SPEED_MPS`; then Replan from the new pose.

DriveRecovery (no progress in Drive for `DRIVE_NO_PROGRESS_S` while no traffic near us moves): stand
for `RECOVERY_SETTLE_S`, then if anything stands in our lane within `RECOVERY_LEAP_M` (AnnieWAY code's
"frog mode" distance) declare the road blocked there and Replan; else creep on along the lane with
caution (a row queued at an intersection is no blockade: there we only wait). `RECOVERY_SUCCESS_M` of
headway returns to DriveOnLane; `RECOVERY_NO_PROGRESS_S` without progress hands over to the
GlobalRecovery.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from bywire.host.roadnet.graph import EdgeKind
from bywire.host.roadnet.ids import LaneId

from . import rules
from .context import BehaviourContext
from .hsm import NoProgress, State, Transition
from .lanes import adjacent_left_lane, lane_vehicles
from .manoeuvre import Leg, kturn_legs, shifted_leg
from .mtc import moving_traffic_check
from .recovery import mark_blocked_at, mission_done
from .route_view import PathObject
from .situation import BlockedRoad

__all__ = ["LaneChangePlan", "PassPlan", "drive_family", "pass_plan", "queued", "report_key"]

_ZONE_KINDS = frozenset({EdgeKind.ZONE})
_UTURN = frozenset({EdgeKind.UTURN})
_LANE_CHANGE = frozenset({EdgeKind.LANE_CHANGE})


# ------------------------------------------------------------------------------------------- shared facts


def _half_width(ctx: BehaviourContext) -> float:
    return 0.5 * ctx.params.vehicle_width_m


def _still_lead(ctx: BehaviourContext, still_s: float) -> PathObject | None:
    """The lead, if it is an obstacle in our lane that has stood still for the `still_s` we have stood
    stopped behind it (counted from when we stopped there: it may have come to rest long before)."""
    lead = ctx.lead
    if lead is None or ctx.stood_behind_s(lead.obj.object_id) < still_s:
        return None
    return lead


def queued(ctx: BehaviourContext, obstacle: PathObject) -> bool:
    """rules 1.7: still vehicles in a row up to the next intersection on our route are queued there."""
    ev = next((e for e in ctx.view.intersections if e.s_m >= obstacle.rear_s_m), None)
    if ev is None:
        return False
    front = obstacle.front_s_m
    row = sorted(
        (
            p
            for p in ctx.route_objects
            if p.in_corridor and p.s_m > obstacle.s_m and p.obj.speed_mps < rules.STILL_SPEED_MPS
        ),
        key=lambda p: p.s_m,
    )
    for p in row:
        if p.rear_s_m - front > rules.QUEUE_GAP_M:
            break
        front = max(front, p.front_s_m)
    return ev.s_m - front < rules.QUEUE_GAP_M


class PassPlan:
    """How we would pass `obstacle` on the lane to our left (see the module docstring). Route arc
    lengths of the rear axle: out from `out_start` to `out_end`, back from `back_start` to `back_end`;
    the MTC's merge point `mp` is the middle of the stretch of the passing lane we use."""

    def __init__(
        self, ctx: BehaviourContext, obstacle: PathObject, offset_m: float, opposite: bool, lane: LaneId
    ) -> None:
        self.obstacle_id = obstacle.obj.object_id
        self.offset_m = offset_m
        self.opposite = opposite
        self.lane = lane
        self.out_start_s_m = ctx.ego_s_m
        self.out_end_s_m = self.out_start_s_m + rules.PASS_SHIFT_LENGTH_M
        self.back_start_s_m = max(obstacle.front_s_m + rules.PASSING_SEPARATION_M, self.out_end_s_m)
        self.back_end_s_m = self.back_start_s_m + rules.PASS_SHIFT_LENGTH_M
        self.mp_s_m = 0.5 * (self.out_start_s_m + self.back_end_s_m)
        self.mp_lane_s_m = 0.0  # the merge point in the passing lane's arc length (set on entry)


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


def pass_plan(ctx: BehaviourContext) -> PassPlan | None:
    """The passing manoeuvre around the lead, or None when we may not or cannot pass it."""
    if ctx.route is None or not ctx.on_route:
        return None
    lead = _still_lead(ctx, rules.PASS_STILL_S)
    if lead is None or queued(ctx, lead):
        return None
    view = ctx.view
    edge = ctx.current_edge()
    if edge is None or edge.kind != EdgeKind.LANE or edge.lane is None:
        return None
    lane = edge.lane
    x, y, h = view.point_at(lead.s_m)
    side = adjacent_left_lane(ctx.graph, lane, x, y, h)
    if side is None:
        return None
    plan = PassPlan(ctx, lead, side.offset_m, side.opposite, side.lane)
    end = plan.back_end_s_m
    # the route runs on along our own lane through the whole manoeuvre, and no intersection is near
    i0, i1 = view.edge_index_at(ctx.ego_s_m), view.edge_index_at(end)
    if end >= view.length_m or any(
        e.kind != EdgeKind.LANE or e.lane != lane for e in view.edges[i0 : i1 + 1]
    ):
        return None
    ev = view.next_intersection(ctx.ego_s_m)
    if ev is not None and ev.s_m < end + rules.PASS_NO_INTERSECTION_M:
        return None
    piece = view.next_piece(ctx.ego_s_m)
    if piece is not None and piece.start_s_m < end + rules.PASS_NO_INTERSECTION_M:
        return None
    # no still obstacle in the stretch of the passing lane we use
    reach = _half_width(ctx) + rules.LATERAL_CLEARANCE_M
    for p in ctx.route_objects:
        if p.obj.object_id == lead.obj.object_id or p.obj.speed_mps >= rules.STILL_SPEED_MPS:
            continue
        across = 0.5 * p.obj.width_m
        stretch = lead.rear_s_m - rules.PASSING_SEPARATION_M < p.s_m < end + rules.PASSING_SEPARATION_M
        if stretch and abs(p.lateral_m - plan.offset_m) - across < reach:
            return None
    return plan


def _blockade(ctx: BehaviourContext) -> tuple[float, str] | None:
    """Where the road ahead is blocked (route arc length) and why, or None."""
    if ctx.route is None or not ctx.on_route:
        return None
    view = ctx.view
    here = view.edge_index_at(ctx.ego_s_m)
    for b in ctx.situation.blocked:
        if report_key(b) in ctx.reports_handled:
            continue  # acted upon already (and perhaps forgotten by the planner): not again
        if b.edge is not None:
            ahead = [i for i in view.edge_positions.get(b.edge, ()) if i >= here]
            if ahead:
                where = max(float(view.edge_start[ahead[0]]), ctx.ego_s_m)
                return where, f"reported at {b.edge[0]} -> {b.edge[1]} {b.detail}".strip()
        else:
            s, lateral, _ = view.locate(b.x_m, b.y_m, ctx.ego_s_m, 0.0, rules.LEAD_HORIZON_M)
            if s > ctx.ego_s_m and abs(lateral) < view.lane_width_at(s):
                return s, f"reported at ({b.x_m:.1f}, {b.y_m:.1f}) {b.detail}".strip()
    lead = _still_lead(ctx, rules.BLOCKADE_STILL_S)
    if lead is None or lead.rear_s_m - ctx.ego_front_s_m > rules.BLOCKADE_RANGE_M or queued(ctx, lead):
        return None
    if pass_plan(ctx) is not None:
        return None
    return max(
        lead.rear_s_m, ctx.ego_s_m
    ), f"{lead.obj.object_id} still for {rules.BLOCKADE_STILL_S:g} s, no way past"


def _road_blocked(ctx: BehaviourContext) -> bool:
    return _blockade(ctx) is not None


def report_key(b: BlockedRoad) -> tuple[object, ...]:
    return (b.edge,) if b.edge is not None else (round(b.x_m, 1), round(b.y_m, 1))


def _mark_blockade(ctx: BehaviourContext) -> None:
    found = _blockade(ctx)
    if found is not None:
        mark_blocked_at(ctx, found[0], found[1])
    # perception's reports count once each: a report that stays is not a new blockade every cycle
    ctx.reports_handled |= {report_key(b) for b in ctx.situation.blocked}


def _off_track(ctx: BehaviourContext) -> bool:
    return ctx.on_route and not ctx.legs and abs(ctx.ego_lateral_m) > rules.OFF_TRACK_M


def _set_off_track(ctx: BehaviourContext) -> None:
    ctx.replan_why = f"off the route by {abs(ctx.ego_lateral_m):.1f} m"


# ------------------------------------------------------------------------------------------- DriveOnLane


def intersection_near(ctx: BehaviourContext) -> bool:
    if ctx.route is None or not ctx.on_route:
        return False
    ev = ctx.view.next_intersection(ctx.ego_s_m)
    return ev is not None and ev.s_m - ctx.ego_front_s_m <= rules.INTERSECTION_APPROACH_TRIGGER_M


def _zone_near(ctx: BehaviourContext) -> bool:
    if ctx.route is None or not ctx.on_route:
        return False
    piece = ctx.view.next_piece(ctx.ego_s_m, _ZONE_KINDS)
    return piece is not None and piece.start_s_m - ctx.ego_front_s_m <= rules.ZONE_APPROACH_TRIGGER_M


def _kturn_piece_start(ctx: BehaviourContext) -> float | None:
    piece = ctx.view.next_piece(ctx.ego_s_m, _UTURN) if ctx.route is not None else None
    if (
        piece is None
        or piece.start_s_m - ctx.ego_front_s_m > rules.KTURN_TRIGGER_M + ctx.params.stub_length_m
    ):
        return None
    return piece.start_s_m


def _at_kturn(ctx: BehaviourContext) -> bool:
    start = _kturn_piece_start(ctx)
    if start is None or not ctx.stopped or abs(start - ctx.ego_front_s_m) > rules.STOP_LINE_TOLERANCE_M:
        return False
    edge = ctx.current_edge()
    x, y, h = ctx.view.point_at(ctx.ego_s_m)
    if edge is None or edge.lane is None:
        return False
    side = adjacent_left_lane(ctx.graph, edge.lane, x, y, h)
    if side is None or not side.opposite:
        return False
    ctx.kturn_offset_m = side.offset_m
    return True


def _lane_change_near(ctx: BehaviourContext) -> bool:
    if ctx.route is None or not ctx.on_route:
        return False
    piece = ctx.view.next_piece(ctx.ego_s_m, _LANE_CHANGE)
    return piece is not None and piece.start_s_m - ctx.ego_front_s_m <= rules.LANE_CHANGE_TRIGGER_M


def _can_pass(ctx: BehaviourContext) -> bool:
    return pass_plan(ctx) is not None


def _drive_on_lane(ctx: BehaviourContext) -> None:
    start = _kturn_piece_start(ctx)
    if start is not None:
        ctx.stop_front_at(start, "K-turn ahead")
        ctx.say("following the lane to the K-turn")
        return
    lead = ctx.lead
    if lead is not None and lead.obj.speed_mps < rules.STILL_SPEED_MPS and ctx.stopped:
        still = ctx.stood_behind_s(lead.obj.object_id)
        ctx.say(f"stopped behind still {lead.obj.object_id} for {still:.0f} s")
    elif lead is not None:
        ctx.say(f"following {lead.obj.object_id}")
    else:
        ctx.say("following the lane")


# ------------------------------------------------------------------------------------------- LaneChange


def _lane_change_entry(ctx: BehaviourContext) -> None:
    view = ctx.view
    piece = view.next_piece(ctx.ego_s_m, _LANE_CHANGE)
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


# ------------------------------------------------------------------------------------------- PassObstacle


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


# ------------------------------------------------------------------------------------------- DriveKTurn


def _kturn_entry(ctx: BehaviourContext) -> None:
    ego = ctx.situation.ego
    offset = ctx.kturn_offset_m
    if offset is None:
        edge = ctx.current_edge()
        side = None
        if edge is not None and edge.lane is not None:
            side = adjacent_left_lane(ctx.graph, edge.lane, ego.x_m, ego.y_m, ego.heading_rad)
        # no opposite lane found alongside: turn on the spot's widest circle (one forward half circle)
        offset = side.offset_m if side is not None else 2.0 * ctx.params.kturn_radius_m
    legs = kturn_legs(ego.x_m, ego.y_m, ego.heading_rad, offset, ctx.params.kturn_radius_m)
    ctx.begin_legs(legs)
    ctx.replan_why = "after the K-turn"


def _kturn_exit(ctx: BehaviourContext) -> None:
    ctx.end_legs()
    ctx.kturn_offset_m = None


def _leg_done(ctx: BehaviourContext) -> bool:
    if not ctx.legs:
        return True
    leg = ctx.legs[ctx.leg_index]
    return ctx.leg_s_m >= leg.end_s_m - rules.KTURN_SWITCH_DISTANCE_M and ctx.stopped


def _more_legs(ctx: BehaviourContext) -> bool:
    return _leg_done(ctx) and ctx.leg_index + 1 < len(ctx.legs)


def _last_leg_done(ctx: BehaviourContext) -> bool:
    return _leg_done(ctx) and ctx.leg_index + 1 >= len(ctx.legs)


def _next_leg(ctx: BehaviourContext) -> None:
    ctx.select_leg(ctx.leg_index + 1)


def _kturn_activity(ctx: BehaviourContext) -> None:
    if not ctx.legs:
        ctx.hold("K-turn: no legs")
        return
    leg: Leg = ctx.legs[ctx.leg_index]
    ctx.plan.leg = leg
    ctx.plan.leg_s_m = ctx.leg_s_m
    ctx.cap(rules.KTURN_SPEED_MPS, "K-turn speed")
    ctx.stop_rear_at(leg.end_s_m, "end of the K-turn leg")
    gear = "forward" if leg.direction == 1 else "backward"
    ctx.say(f"K-turn leg {ctx.leg_index + 1} of {len(ctx.legs)} ({gear})")


# ------------------------------------------------------------------------------------------- DriveRecovery


def _recovery_entry(ctx: BehaviourContext) -> None:
    ctx.family_anchor_odometer_m = ctx.odometer_m


def _recovered(ctx: BehaviourContext) -> bool:
    return ctx.odometer_m - ctx.family_anchor_odometer_m >= rules.RECOVERY_SUCCESS_M


def _obstacle_at_leap(ctx: BehaviourContext) -> bool:
    if ctx.time_in("DriveRecovery") < rules.RECOVERY_SETTLE_S or ctx.lead is None:
        return False
    # a jam at an intersection is no blockade: there we wait (and hand over to the global recovery)
    return ctx.lead.rear_s_m - ctx.ego_front_s_m < rules.RECOVERY_LEAP_M and not queued(ctx, ctx.lead)


def _mark_leap(ctx: BehaviourContext) -> None:
    lead = ctx.lead
    assert lead is not None
    mark_blocked_at(ctx, max(lead.rear_s_m, ctx.ego_s_m), f"recovery: {lead.obj.object_id} in our lane")


def _drive_recovery(ctx: BehaviourContext) -> None:
    if ctx.time_in("DriveRecovery") < rules.RECOVERY_SETTLE_S:
        ctx.hold("drive recovery: looking")
        return
    ctx.cap(rules.RECOVERY_CREEP_SPEED_MPS, "recovery creep")
    ctx.say("drive recovery: creeping on along the lane")


# ------------------------------------------------------------------------------------------- the family


def _traffic_moving(ctx: BehaviourContext) -> bool:
    return ctx.traffic_moving()


def drive_family() -> State[BehaviourContext]:
    leaving = (
        Transition(
            "Replan", _road_blocked, "road blocked ahead (still obstacle, no way past)", _mark_blockade
        ),
        Transition(
            "Intersection",
            intersection_near,
            f"intersection within {rules.INTERSECTION_APPROACH_TRIGGER_M:g} m",
        ),
        Transition("Zone", _zone_near, f"zone entry within {rules.ZONE_APPROACH_TRIGGER_M:g} m"),
    )
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
            State(
                "DriveOnLane",
                doc="follow the lane (and the lead vehicle)",
                activity=_drive_on_lane,
                transitions=(
                    *leaving,
                    Transition("DriveKTurn", _at_kturn, "at the start of a U-turn"),
                    Transition(
                        "LaneChange",
                        _lane_change_near,
                        f"lane change within {rules.LANE_CHANGE_TRIGGER_M:g} m",
                    ),
                    Transition(
                        "PassObstacle",
                        _can_pass,
                        f"lead still for {rules.PASS_STILL_S:g} s, lane to the left free",
                    ),
                ),
            ),
            State(
                "LaneChange",
                doc="change into the adjacent lane when the MTC finds a gap (Fig. 13 c)",
                entry=_lane_change_entry,
                activity=_lane_change,
                transitions=(
                    Transition("Replan", _road_blocked, "road blocked ahead", _mark_blockade),
                    Transition("DriveOnLane", _lane_change_done, "in the target lane"),
                ),
            ),
            State(
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
                            Transition(
                                "DriveOnLane", lambda c: _pass_phase(c, "back_end_s_m"), "back in our lane"
                            ),
                        ),
                    ),
                ),
            ),
            State(
                "DriveKTurn",
                doc="turn around onto the opposite lane: forward, backward, forward",
                initial="DriveKTurnForward",
                entry=_kturn_entry,
                exit=_kturn_exit,
                activity=_kturn_activity,
                children=(
                    State(
                        "DriveKTurnForward",
                        doc="first leg, forward, full left",
                        transitions=(
                            Transition("DriveKTurnBackward", _more_legs, "leg done", _next_leg),
                            Transition("Replan", _last_leg_done, "turned around"),
                        ),
                    ),
                    State(
                        "DriveKTurnBackward",
                        doc="second leg, backward, full right",
                        transitions=(Transition("DriveKTurnFinish", _more_legs, "leg done", _next_leg),),
                    ),
                    State(
                        "DriveKTurnFinish",
                        doc="third leg, forward, full left into the opposite lane",
                        transitions=(Transition("Replan", _last_leg_done, "turned around"),),
                    ),
                ),
            ),
            State(
                "DriveRecovery",
                doc="no progress: look, then declare a blockade or creep on",
                entry=_recovery_entry,
                activity=_drive_recovery,
                no_progress=NoProgress(rules.RECOVERY_NO_PROGRESS_S, "GlobalRecovery"),
                transitions=(
                    Transition(
                        "Replan",
                        _obstacle_at_leap,
                        f"obstacle within {rules.RECOVERY_LEAP_M:g} m",
                        _mark_leap,
                    ),
                    Transition("DriveOnLane", _recovered, f"{rules.RECOVERY_SUCCESS_M:g} m of headway"),
                ),
            ),
        ),
    )
