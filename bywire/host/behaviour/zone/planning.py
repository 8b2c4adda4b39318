"""The Zone states' paths from the zone planner (seed 000 Sec. 10: "These states control invocation of
the navigation module described in Section 10"), `host.navigation`'s hybrid A*.

The obstacle map of a zone (`zone_map`): a grid of `ZONE_CELL_M` over the perimeter's bounding box and
`MAP_PAD_M` around it; outside the perimeter polygon is an obstacle (the car stays in the zone), except
within `GATE_OPEN_M` of the perimeter points where lanes enter and leave (the car's tail is still on the
road at the entry, its nose already on it at the exit); every standing object of the world model is a
box on it (parked cars, a wall: on perfect perception the simulator's objects, on LIDAR the tracks), and
on LIDAR every obstacle cell of the perception's occupancy grid is too (the wall no track holds, the
whole seen outline of a parked car). Our own place is never an obstacle.

`plan_legs` plans from our rear-axle pose to a goal pose on that map (margin `ZONE_MARGIN_M`, tried
again at `ZONE_MARGIN_TIGHT_M` when our own pose is inside the wider one, as between two parked cars),
smooths the path (`navigation.smoothing`) and cuts it into `Leg`s at its cusps, each driven to a stop.
Where no path is found it says why and the caller keeps the stand-in's straight lines.

Deviation: the paper plans in the navigation module's own process while the car stands; this planner
runs inside the behaviour's cycle (a plan takes 0.1-0.5 s on this machine: SIL only waits for it; on a
car the behaviour would miss its deadline while it plans).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bywire.host.navigation.cspace import Footprint, build_cspace
from bywire.host.navigation.grid_map import GridMap
from bywire.host.navigation.hybrid_astar import PlannerParams, plan
from bywire.host.navigation.smoothing import smooth_path, split_at_cusps
from bywire.host.roadnet.ids import WaypointId

from .. import rules
from ..context import BehaviourContext
from ..manoeuvre import Leg, path_leg
from ..situation import Direction

__all__ = ["PlannedLegs", "goal_in_spot", "plan_legs", "zone_map"]

ZONE_CELL_M = 0.2
MAP_PAD_M = 14.0
GATE_OPEN_M = 12.0  # the car's length, rules.ZONE_HANDOVER_M and the margin before the entry
ZONE_MARGIN_M = 0.3
ZONE_MARGIN_TIGHT_M = 0.1
# a metre backwards costs this many forwards: a driver backs out of a spot and turns, and does not
# reverse the length of the lot because that is a few metres shorter
ZONE_REVERSE_FACTOR = 2.5
PASSAT_WIDTH_M = 1.82
PASSAT_LENGTH_M = 4.77

Pose = tuple[float, float, float]


@dataclass(frozen=True)
class PlannedLegs:
    legs: tuple[Leg, ...]
    length_m: float
    direction_changes: int
    plan_ms: float


def _inside(poly: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Even-odd point-in-polygon test, vectorised over the points."""
    inside = np.zeros(x.shape, dtype=bool)
    n = poly.shape[0]
    for i in range(n):
        x0, y0 = poly[i]
        x1, y1 = poly[(i + 1) % n]
        crosses = (y0 > y) != (y1 > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            x_at = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
        inside ^= crosses & (x < x_at)
    return inside


def zone_map(ctx: BehaviourContext, zone_id: int) -> GridMap:
    """The zone's obstacle map now (see the module docstring)."""
    zone = ctx.graph.network.zone(zone_id)
    pts = zone.perimeter.points
    poly = np.array([ctx.graph.vertex_xy(p.id) for p in pts])
    lo = poly.min(axis=0) - MAP_PAD_M
    hi = poly.max(axis=0) + MAP_PAD_M
    cols = math.ceil((hi[0] - lo[0]) / ZONE_CELL_M)
    rows = math.ceil((hi[1] - lo[1]) / ZONE_CELL_M)
    grid = GridMap(np.zeros((rows, cols), dtype=bool), ZONE_CELL_M, (float(lo[0]), float(lo[1])))
    rr, cc = np.mgrid[0:rows, 0:cols]
    cx, cy = grid.centre_of(rr, cc)
    blocked = ~_inside(poly, cx, cy)
    gates = {ex.exit for ex in zone.perimeter.exits} | {
        ex.entry for ex in ctx.graph.network.exits() if ex.entry.segment == zone_id
    }
    for g in gates:
        gx, gy = ctx.graph.vertex_xy(g)
        blocked &= np.hypot(cx - gx, cy - gy) > GATE_OPEN_M
    boxes = [
        (o.x_m, o.y_m, o.heading_rad, o.length_m, o.width_m)
        for o in ctx.situation.objects
        if abs(o.speed_mps) < 1.0  # what stands is the map; what moves is the tracker's business
    ]
    cells = ctx.situation.obstacle_cells
    if cells is not None and len(cells):
        # the perception grid's obstacle cells, each a square of its size (LIDAR: the wall, the whole
        # seen outline of a parked car); boxes of the same cells' tracks add nothing but do no harm
        boxes += [
            (float(cx), float(cy), 0.0, float(sz), float(sz)) for cx, cy, sz in cells if _near(grid, cx, cy)
        ]
    out = GridMap(blocked, ZONE_CELL_M, grid.origin_xy_m).with_boxes(boxes)
    # our own place is no obstacle (a stray return under the car, a track of our own shadow)
    ego = ctx.situation.ego
    own = GridMap(np.zeros_like(out.occupied), ZONE_CELL_M, out.origin_xy_m).with_boxes(
        [_own_box(ctx, ego.x_m, ego.y_m, ego.heading_rad)]
    )
    return GridMap(out.occupied & ~own.occupied | (blocked & own.occupied), ZONE_CELL_M, out.origin_xy_m)


def _near(grid: GridMap, x: float, y: float) -> bool:
    w, h = grid.size_m
    ox, oy = grid.origin_xy_m
    return ox <= x <= ox + w and oy <= y <= oy + h


def _own_box(
    ctx: BehaviourContext, x: float, y: float, heading: float
) -> tuple[float, float, float, float, float]:
    """Our car's box (rear axle pose), grown by the planner's tight margin."""
    front = ctx.params.rear_axle_to_front_m
    rear = PASSAT_LENGTH_M - front
    shift = 0.5 * (front - rear)
    grow = 2.0 * ZONE_MARGIN_TIGHT_M
    return (x + shift * math.cos(heading), y + shift * math.sin(heading), heading, PASSAT_LENGTH_M + grow,
            PASSAT_WIDTH_M + grow)  # fmt: skip


def goal_in_spot(ctx: BehaviourContext, first: WaypointId, checkpoint: WaypointId) -> Pose:
    """Our rear-axle pose with the front bumper on the spot's checkpoint, facing into the spot."""
    (x1, y1), (x2, y2) = ctx.graph.vertex_xy(first), ctx.graph.vertex_xy(checkpoint)
    heading = math.atan2(y2 - y1, x2 - x1)
    back = ctx.params.rear_axle_to_front_m
    return x2 - back * math.cos(heading), y2 - back * math.sin(heading), heading


def _footprint(ctx: BehaviourContext) -> Footprint:
    front = ctx.params.rear_axle_to_front_m
    return Footprint(front_m=front, rear_m=PASSAT_LENGTH_M - front, width_m=PASSAT_WIDTH_M)


def plan_legs(
    ctx: BehaviourContext,
    zone_id: int,
    goal: Pose,
    then: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    back_out_m: float = 0.0,
) -> PlannedLegs | str:
    """Legs from our pose to `goal` through the zone, or why there are none. `then` (x, y, heading
    arrays from the goal on, forward): driven on after the goal without a stop (the exit edge).
    `back_out_m` > 0: first straight back that far (out of a parking spot: DARPA rules 5.2 have the car
    reverse out of it), then the planned path from there."""
    ego = ctx.situation.ego
    start = (ego.x_m, ego.y_m, ego.heading_rad)
    first: list[Leg] = []
    if back_out_m > 0.0:
        c, s = math.cos(start[2]), math.sin(start[2])
        n = max(2, math.ceil(back_out_m / 0.25) + 1)
        d = np.linspace(0.0, back_out_m, n)
        bx, by, bh = start[0] - d * c, start[1] - d * s, np.full(n, start[2])
        cs = build_cspace(zone_map(ctx, zone_id), _footprint(ctx), margin_m=ZONE_MARGIN_TIGHT_M)
        if not cs.collides(bx, by, bh).any():
            first.append(path_leg(bx, by, bh, -1))
            start = (float(bx[-1]), float(by[-1]), start[2])
    grid = zone_map(ctx, zone_id)
    params = PlannerParams(turn_radius_m=rules.KTURN_RADIUS_M, reverse_factor=ZONE_REVERSE_FACTOR)
    reason = ""
    for margin in (ZONE_MARGIN_M, ZONE_MARGIN_TIGHT_M):
        cs = build_cspace(grid, _footprint(ctx), margin_m=margin)
        result = plan(cs, start, goal, params)
        if result.found and first and result.length_m < 1e-6:
            return PlannedLegs(tuple(first), back_out_m, 0, result.plan_ms)
        if result.found:
            poses, dirs, _ = smooth_path(cs, result.poses, result.directions, params.turn_radius_m)
            stretches: list[tuple[np.ndarray, Direction]] = [
                (poses[i0 : i1 + 1], 1 if dirs[i1] > 0 else -1) for i0, i1 in split_at_cusps(dirs)
            ]
            if then is not None:
                more = np.column_stack(then)
                if stretches[-1][1] == 1:
                    stretches[-1] = (np.vstack((stretches[-1][0], more[1:])), 1)
                else:
                    stretches.append((more, 1))
            legs = first + [path_leg(part[:, 0], part[:, 1], part[:, 2], d) for part, d in stretches]
            changes = result.direction_changes + (1 if first and stretches[0][1] == 1 else 0)
            return PlannedLegs(
                tuple(legs), result.length_m + (back_out_m if first else 0.0), changes, result.plan_ms
            )
        reason = result.reason
    return f"zone planner: {reason}"
