"""DriveOnLane (seed 000 Sec. 8): follow the lane and the lead vehicle, and the transitions out of it.

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
"""

from __future__ import annotations

from bywire.host.roadnet.graph import EdgeKind

from .. import rules
from ..context import BehaviourContext
from ..exit_turn import steer_exit
from ..hsm import State, Transition
from ..lanes import adjacent_left_lane
from .common import LANE_CHANGE_KINDS, mark_blockade, pass_plan, road_blocked

__all__ = ["drive_on_lane_state", "intersection_near"]

_ZONE_KINDS = frozenset({EdgeKind.ZONE})
_UTURN = frozenset({EdgeKind.UTURN})


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
    ctx.kturn_target = side
    return True


def _lane_change_near(ctx: BehaviourContext) -> bool:
    if ctx.route is None or not ctx.on_route:
        return False
    piece = ctx.view.next_piece(ctx.ego_s_m, LANE_CHANGE_KINDS)
    return piece is not None and piece.start_s_m - ctx.ego_front_s_m <= rules.LANE_CHANGE_TRIGGER_M


def _can_pass(ctx: BehaviourContext) -> bool:
    return pass_plan(ctx) is not None


def _drive_on_lane(ctx: BehaviourContext) -> None:
    _drive_on_lane_here(ctx)
    steer_exit(ctx)  # an exit ahead tighter than full lock: its planned moves


def _drive_on_lane_here(ctx: BehaviourContext) -> None:
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


def drive_on_lane_state() -> State[BehaviourContext]:
    return State(
        "DriveOnLane",
        doc="follow the lane (and the lead vehicle)",
        activity=_drive_on_lane,
        transitions=(
            Transition(
                "Replan", road_blocked, "road blocked ahead (still obstacle, no way past)", mark_blockade
            ),
            Transition(
                "Intersection",
                intersection_near,
                f"intersection within {rules.INTERSECTION_APPROACH_TRIGGER_M:g} m",
            ),
            Transition("Zone", _zone_near, f"zone entry within {rules.ZONE_APPROACH_TRIGGER_M:g} m"),
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
    )
