"""What several Drive states read (seed 000 Sec. 8; DARPA rules 1.7): the still lead, a queue at an
intersection, the passing plan and the blockade ahead.

- `queued`: rules 1.7, still vehicles in a row up to the next intersection on our route are queued
  there (not passed, not a blockade);
- `pass_plan` (`PassPlan`): how we would pass the still lead on the lane to our left, or None when we
  may not or cannot (DriveOnLane's guard into PassObstacle, PassObstacle's plan; see `pass_obstacle`);
- `road_blocked` / `mark_blockade`: the road ahead is blocked (a report by perception, or a still
  obstacle that cannot be passed; see `on_lane`), and marking it for Replan; `report_key`, the key a
  perception report is acted on once under.
"""

from __future__ import annotations

from bywire.host.roadnet.graph import EdgeKind
from bywire.host.roadnet.ids import LaneId

from .. import rules
from ..context import BehaviourContext
from ..lanes import adjacent_left_lane
from ..recovery.common import mark_blocked_at
from ..route_view import PathObject
from ..situation import BlockedRoad

__all__ = [
    "LANE_CHANGE_KINDS",
    "PassPlan",
    "mark_blockade",
    "pass_plan",
    "queued",
    "report_key",
    "road_blocked",
]

LANE_CHANGE_KINDS = frozenset({EdgeKind.LANE_CHANGE})


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
    """How we would pass `obstacle` on the lane to our left (see `pass_obstacle`). Route arc
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


def road_blocked(ctx: BehaviourContext) -> bool:
    return _blockade(ctx) is not None


def report_key(b: BlockedRoad) -> tuple[object, ...]:
    return (b.edge,) if b.edge is not None else (round(b.x_m, 1), round(b.y_m, 1))


def mark_blockade(ctx: BehaviourContext) -> None:
    found = _blockade(ctx)
    if found is not None:
        mark_blocked_at(ctx, found[0], found[1])
    # perception's reports count once each: a report that stays is not a new blockade every cycle
    ctx.reports_handled |= {report_key(b) for b in ctx.situation.blocked}
