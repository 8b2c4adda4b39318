"""What Replan, GlobalRecovery and the families share (seed 000 Sec. 8): getting a route from here, and
reporting a blockade.

`replan_from_here` is the one way back onto a route, shared by Replan and GlobalRecovery: match the rear
axle to the lane graph (`LaneIndex.match`, as `MissionPlanner.replan_from_pose` does), and

- on a lane edge that is blocked (the blockade is between us and the waypoint ahead): we cannot drive on
  and cannot plan from behind us without reversing to it, so we turn around where we are: "kturn" (the
  Drive family's DriveKTurn onto the opposite lane alongside; then Replan again from there);
- otherwise plan from the waypoint ahead (`MissionPlanner.replan(edge.end, next checkpoint)`) and put
  the edge we are on in front as the route's lead-in: "drive";
- off every lane (in a zone, on a parking lot), or blocked without an opposite lane: "failed". The
  global recovery then holds and tries again every `rules.GLOBAL_REPLAN_INTERVAL_S`; bringing the car
  back onto a lane from anywhere is the zone planner's job (Sec. 10, hybrid A*), which comes later.

A plan that found a checkpoint unreachable with the blockades known has forgotten them all (the
planner's rule, as AnnieWAY's): the command's requests say so, and name checkpoints that stayed
unreachable (they are skipped).
"""

from __future__ import annotations

from bywire.host.roadnet.graph import EdgeKind

from ..context import BehaviourContext
from ..lanes import adjacent_left_lane
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


def replan_from_here(ctx: BehaviourContext) -> str:
    """Get a route from where we are (see the module docstring): "drive", "kturn" or "failed"."""
    ego = ctx.situation.ego
    match = ctx.lane_index.match(ego.x_m, ego.y_m, ego.heading_rad)
    if match is None:
        ctx.say("replan: we are on no lane of the network (waiting for zone navigation)")
        return "failed"
    edge = match.edge
    if edge.blocked:
        if edge.kind == EdgeKind.LANE and edge.lane is not None:
            side = adjacent_left_lane(ctx.graph, edge.lane, ego.x_m, ego.y_m, ego.heading_rad)
            if side is not None and side.opposite:
                ctx.kturn_offset_m = side.offset_m
                ctx.say(
                    f"replan: {edge.start} -> {edge.end} is blocked, turning around onto lane {side.lane}"
                )
                return "kturn"
        ctx.say(f"replan: {edge.start} -> {edge.end} is blocked and there is no lane to turn onto")
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
