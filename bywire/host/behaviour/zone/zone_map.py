"""The obstacle map of a zone (seed 000 Sec. 10) and the pose that parks us in a spot.

`zone_map`: a grid of `path_planning.ZONE_CELL_M` over the perimeter's bounding box and `MAP_PAD_M`
around it; outside the perimeter polygon is an obstacle (the car stays in the zone), except the road
within `GATE_OPEN_M` of the perimeter points where lanes enter and leave (the car's tail is still on
the lane or exit at the entry, its nose already on it at the exit: `roadnet.road_area`, its edge taken
`path_planning.ROAD_EDGE_SLACK_M` out as for a K-turn); what stands in it is put on by
`path_planning.obstacles_on`. (Opening everything near a gate let the path cut the corner between the
road and the perimeter: 2 m off the road at the DARPA sample's zone 14.)
"""

from __future__ import annotations

import math

import numpy as np

from bywire.host.navigation.grid_map import GridMap
from bywire.host.roadnet.ids import WaypointId
from bywire.host.roadnet.road_area import polygon_contains

from ..context import BehaviourContext
from ..path_planning import ROAD_EDGE_SLACK_M, Pose, blank_map, obstacles_on

__all__ = ["goal_in_spot", "zone_map"]

MAP_PAD_M = 14.0
GATE_OPEN_M = 12.0  # the car's length, rules.ZONE_HANDOVER_M and the margin before the entry


def zone_map(ctx: BehaviourContext, zone_id: int) -> GridMap:
    """The zone's obstacle map now (see the module docstring)."""
    zone = ctx.graph.network.zone(zone_id)
    poly = np.array([ctx.graph.vertex_xy(p.id) for p in zone.perimeter.points])
    lo = poly.min(axis=0) - MAP_PAD_M
    hi = poly.max(axis=0) + MAP_PAD_M
    grid = blank_map((float(lo[0]), float(lo[1])), (float(hi[0]), float(hi[1])))
    cx, cy = grid.cell_centres()
    blocked = ~polygon_contains(poly, cx, cy)
    gates = {ex.exit for ex in zone.perimeter.exits} | {
        ex.entry for ex in ctx.graph.network.exits() if ex.entry.segment == zone_id
    }
    near_gate = np.zeros_like(blocked)
    for g in gates:
        gx, gy = ctx.graph.vertex_xy(g)
        near_gate |= np.hypot(cx - gx, cy - gy) <= GATE_OPEN_M
    if near_gate.any():
        road = ctx.road_area.excess_m(cx[near_gate], cy[near_gate]) <= ROAD_EDGE_SLACK_M
        open_ = np.zeros_like(blocked)
        open_[near_gate] = road
        blocked &= ~open_
    return obstacles_on(ctx, GridMap(blocked, grid.resolution_m, grid.origin_xy_m))


def goal_in_spot(ctx: BehaviourContext, first: WaypointId, checkpoint: WaypointId) -> Pose:
    """Our rear-axle pose with the front bumper on the spot's checkpoint, facing into the spot."""
    (x1, y1), (x2, y2) = ctx.graph.vertex_xy(first), ctx.graph.vertex_xy(checkpoint)
    heading = math.atan2(y2 - y1, x2 - x1)
    back = ctx.params.rear_axle_to_front_m
    return x2 - back * math.cos(heading), y2 - back * math.sin(heading), heading
