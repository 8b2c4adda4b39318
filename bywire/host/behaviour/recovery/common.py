"""What Replan, GlobalRecovery and the families share (seed 000 Sec. 8): getting a route from here, and
reporting a blockade.

`replan_from_here` is the one way back onto a route, shared by Replan and GlobalRecovery: match the rear
axle to the lane graph (`LaneIndex.match`, as `MissionPlanner.replan_from_pose` does), and

- on a lane edge that is blocked (the blockade is between us and the waypoint ahead), or just before
  one with no other way on from the waypoint ahead (no exit, no U-turn edge there: a one-way street):
  we cannot drive on and cannot plan from behind us without reversing to it, so we turn around where
  we are: "kturn" (the
  Drive family's DriveKTurn onto the opposite lane alongside, or where our segment has none, onto the
  nearest lane of another that runs back alongside us: a street drawn as two one-way segments has no
  U-turn edge; then Replan again from there);
- otherwise plan from the waypoint ahead (`MissionPlanner.replan(edge.end, next checkpoint)`) and put
  the edge we are on in front as the route's lead-in: "drive";
- off every lane (in a zone, on a parking lot), or blocked without a lane to turn onto: "failed". The
  global recovery then holds and tries again every `rules.GLOBAL_REPLAN_INTERVAL_S`; bringing the car
  back onto a lane from anywhere is the path planner's (`back_to_road`, Sec. 10's hybrid A*).

A plan that found a checkpoint unreachable with the blockades known has forgotten them all (the
planner's rule, as AnnieWAY's): the command's requests say so, and name checkpoints that stayed
unreachable (they are skipped).
"""

from __future__ import annotations

from bywire.host.roadnet.graph import Edge, EdgeKind

from .. import rules
from ..context import BehaviourContext
from ..lanes import adjacent_left_lane, opposite_lane_nearby
from ..route_view import RouteView
from ..situation import RequestKind

__all__ = ["mark_blocked_at", "replan_from_here"]


def mark_blocked_at(ctx: BehaviourContext, route_s_m: float, why: str) -> None:
    """Mark the route edge at `route_s_m` blocked in the graph and tell the mission layer."""
    view = ctx.view
    if not view.edges:
        return
    edge = view.edges[view.edge_index_at(route_s_m)]
    ctx.graph.block_edge(edge.start, edge.end)
    ctx.request(RequestKind.EDGE_BLOCKED, f"{edge.start} -> {edge.end} blocked: {why}", edge)
    ctx.replan_why = f"blocked: {why}"


def _no_way_on(ctx: BehaviourContext, edge: Edge) -> bool:
    """Every edge out of the waypoint ahead is blocked (and none is a U-turn, which is never blocked):
    a route from there would run into the blockade, be found impossible, forget it (the planner's rule)
    and lead straight back to it."""
    outs = ctx.graph.out_edges(edge.end)
    return bool(outs) and all(e.blocked for e in outs)


def replan_from_here(ctx: BehaviourContext) -> str:
    """Get a route from where we are (see the module docstring): "drive", "kturn" or "failed"."""
    ego = ctx.situation.ego
    match = ctx.lane_index.match(ego.x_m, ego.y_m, ego.heading_rad)
    if match is None:
        ctx.say("replan: we are on no lane of the network")
        return "failed"
    edge = match.edge
    dead_end = _no_way_on(ctx, edge)
    if edge.blocked or dead_end:
        where = f"{edge.start} -> {edge.end}" + (" and every way on from its end" if dead_end else "")
        side = None
        if edge.kind == EdgeKind.LANE and edge.lane is not None:
            side = adjacent_left_lane(ctx.graph, edge.lane, ego.x_m, ego.y_m, ego.heading_rad)
            if side is not None and not side.opposite:
                side = None
        if side is None:  # no U-turn edge: a lane of another segment running back alongside
            reach = rules.TURNAROUND_SEARCH_M
            side = opposite_lane_nearby(ctx.graph, ego.x_m, ego.y_m, ego.heading_rad, reach)
        if side is not None:
            ctx.kturn_target = side
            ctx.say(f"replan: {where} is blocked, turning around onto lane {side.lane}")
            return "kturn"
        ctx.say(f"replan: {where} is blocked and there is no lane to turn onto")
        return "failed"
    n_targets = len(ctx.planner.targets)
    first = min(ctx.next_checkpoint, n_targets)
    route = ctx.planner.replan(edge.end, first)
    ctx.route = RouteView(ctx.graph, route, ctx.imap, lead_in=edge)
    ctx.ego_s_m = match.s_m  # on the lead-in edge, which starts the new route
    ctx.ego_lateral_m = match.lateral_offset_m
    ctx.on_route = True
    ctx.retrack()  # this cycle's guards see us, and the objects, on the new route
    ctx.request(
        RequestKind.REPLAN, f"route from {edge.end} (on {edge.start} -> {edge.end}): {ctx.replan_why}"
    )
    if route.blockades_forgotten:
        ctx.request(
            RequestKind.BLOCKADES_FORGOTTEN,
            f"a checkpoint was unreachable with the blockades known: forgot {route.forgotten_blockades}",
        )
    for leg in route.legs:
        if not leg.reached:
            ctx.request(RequestKind.CHECKPOINT_UNREACHABLE, f"checkpoint {leg.checkpoint} cannot be reached")
    return "drive"
