"""The manoeuvres' paths from the path planner (seed 000 Sec. 10: the Zone states, K-turns and U-turns
"control invocation of the navigation module"), `host.navigation`'s hybrid A* on an obstacle map.

A map is where the manoeuvre may drive (the zone's perimeter: `zone.zone_map`; the road's lanes:
`drive.turnaround`) with `obstacles_on` it: every standing object of the world model a box (parked
cars, a wall, a barrier: on perfect perception the simulator's objects, on LIDAR the tracks), and on
LIDAR every obstacle cell of the perception's occupancy grid too (the wall no track holds, the whole seen
outline of a parked car). Our own place is never an obstacle.

A plan is a `PlanRequest` (`make_request`: the map, the car, our rear-axle pose, the goal pose) that
`solve` turns into a `PlanReply`: planned (margin `ZONE_MARGIN_M`, again at `ZONE_MARGIN_TIGHT_M` when
our own pose is inside the wider one, as between two parked cars; with `fine` a last try on a finer
search graph, for turns in a street little wider than the car is long), smoothed
(`navigation.smoothing`) and cut at its cusps into stretches, which `legs_of` makes `Leg`s, each driven
to a stop. Where no path is found the reply says why and the caller falls back on its stand-in.

Where it is solved is a `PathPlanner`'s business: `InlinePathPlanner` at once, in the behaviour's cycle
(SIL: the simulated clock waits for it, so runs stay deterministic); on wall time the host's process
worker (`modules.planning.path_planner_process`), as the paper's navigation module ran in a process of
its own: a plan takes 0.1-0.5 s here, and the behaviour holds the car ("zone: planning") and keeps its
rhythm meanwhile.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Generator
from dataclasses import dataclass, replace
from typing import Protocol, cast

import numpy as np

from bywire.host.navigation.cspace import CSpace, Footprint, build_cspace
from bywire.host.navigation.grid_map import GridMap
from bywire.host.navigation.hybrid_astar import PlannerParams, run_to_end, search
from bywire.host.navigation.smoothing import smooth_path, split_at_cusps
from bywire.host.navigation.tentacles import box_points
from bywire.host.roadnet.road_area import RoadArea

from . import rules
from .context import BehaviourContext
from .manoeuvre import Leg, path_leg
from .situation import Direction

__all__ = [
    "ROAD_EDGE_SLACK_M", "InlinePathPlanner", "PathPlanner", "PlanReply", "PlanRequest", "PlannedLegs",
    "blank_map", "blocked_ahead", "footprint", "legs_of", "make_request", "obstacles_on", "planner_of",
    "road_map", "solve", "solve_steps", "standing_points",
]  # fmt: skip

ZONE_CELL_M = 0.2
ZONE_MARGIN_M = 0.3
# a road's edge on a planner's map lies this far outside the lanes' painted edge: the margin is for what
# stands, and against the edge the car keeps 0.1 m inside the line, 0.4 m off a curb (0.3 m outside it)
ROAD_EDGE_SLACK_M = 0.2
ZONE_MARGIN_TIGHT_M = 0.1
# a metre backwards costs this many forwards: a driver backs out of a spot and turns, and does not
# reverse the length of the lot because that is a few metres shorter
ZONE_REVERSE_FACTOR = 2.5
# the inline planner's step: a few milliseconds of compiled search on this machine (0.1-0.2 s in
# Python), well inside the behaviour's hang bound; a plan of a few thousand expansions takes a few cycles
SEARCH_STEP_EXPANSIONS = 500
SEARCH = PlannerParams(turn_radius_m=rules.KTURN_RADIUS_M, reverse_factor=ZONE_REVERSE_FACTOR)
# the finer search graph of `PlanRequest.fine`: 0.5 m arcs and a 0.3 m closed set find the many-point
# turn of an 8 m street the usual one misses (seconds of search: the last resort before a stand-in)
FINE_SEARCH = replace(SEARCH, arc_m=0.5, xy_bin_m=0.3, max_expansions=40_000)

Pose = tuple[float, float, float]


@dataclass(frozen=True)
class PlannedLegs:
    legs: tuple[Leg, ...]
    length_m: float
    direction_changes: int
    plan_ms: float


def blank_map(lo_xy_m: tuple[float, float], hi_xy_m: tuple[float, float]) -> GridMap:
    """An empty grid of `ZONE_CELL_M` cells covering the box from `lo_xy_m` to `hi_xy_m`."""
    cols = math.ceil((hi_xy_m[0] - lo_xy_m[0]) / ZONE_CELL_M)
    rows = math.ceil((hi_xy_m[1] - lo_xy_m[1]) / ZONE_CELL_M)
    return GridMap(np.zeros((rows, cols), dtype=bool), ZONE_CELL_M, (float(lo_xy_m[0]), float(lo_xy_m[1])))


def road_map(ctx: BehaviourContext, area: RoadArea, lo_xy_m: tuple[float, float],
             hi_xy_m: tuple[float, float]) -> GridMap:  # fmt: skip
    """The box from `lo_xy_m` to `hi_xy_m` as a map on which `area` is the road (its edge taken
    `ROAD_EDGE_SLACK_M` out) and everything else an obstacle, with what stands on it (`obstacles_on`)."""
    grid = blank_map(lo_xy_m, hi_xy_m)
    cx, cy = grid.cell_centres()
    off = GridMap(area.excess_m(cx, cy) > ROAD_EDGE_SLACK_M, grid.resolution_m, grid.origin_xy_m)
    return obstacles_on(ctx, off)


def obstacles_on(ctx: BehaviourContext, grid: GridMap) -> GridMap:
    """`grid` (where the manoeuvre may not go) with what stands on it now, our own place left as the grid
    has it (see the module docstring)."""
    blocked = grid.occupied
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
    out = grid.with_boxes(boxes)
    # our own place is no obstacle (a stray return under the car, a track of our own shadow)
    ego = ctx.situation.ego
    own = GridMap(np.zeros_like(out.occupied), ZONE_CELL_M, out.origin_xy_m).with_boxes(
        [_own_box(ctx, ego.x_m, ego.y_m, ego.heading_rad)]
    )
    return GridMap(out.occupied & ~own.occupied | (blocked & own.occupied), ZONE_CELL_M, out.origin_xy_m)


def standing_points(ctx: BehaviourContext) -> np.ndarray:
    """What stands, as points (n, 2): the outlines of the objects slower than `rules.STILL_SPEED_MPS`
    and, on LIDAR, the occupancy grid's obstacle cells (the reactive layer's and the replan check's)."""
    sit = ctx.situation
    pts = [
        box_points(o.x_m, o.y_m, o.heading_rad, o.length_m, o.width_m)
        for o in sit.objects
        if abs(o.speed_mps) < rules.STILL_SPEED_MPS
    ]
    cells = sit.obstacle_cells
    if cells is not None and len(cells):
        pts.append(np.asarray(cells, dtype=float)[:, :2])
    return np.vstack(pts) if pts else np.zeros((0, 2))


def blocked_ahead(ctx: BehaviourContext, distance_m: float, step_m: float = 0.5) -> bool:
    """Whether the next `distance_m` of the leg being driven is blocked by what stands now (Sec. 10's
    replanning check): a pose there whose outline, grown by the tight margin, holds one of the
    `standing_points`. What already touches us where we stand is no new blockade (a stray return, our
    own shadow); what lies beyond `distance_m` is not looked at (the free-section check: it may be gone,
    or be planned around, by the time we get there)."""
    leg = ctx.legs[ctx.leg_index]
    s = np.arange(ctx.leg_s_m, min(ctx.leg_s_m + distance_m, leg.end_s_m), step_m)
    points = standing_points(ctx)
    if s.size < 2 or not points.size:
        return False
    x, y, h = (np.interp(s, leg.s, a) for a in (leg.x, leg.y, leg.heading))
    fp = footprint(ctx)
    grow = ZONE_MARGIN_TIGHT_M
    dx = points[None, :, 0] - x[:, None]
    dy = points[None, :, 1] - y[:, None]
    c, sn = np.cos(h)[:, None], np.sin(h)[:, None]
    along = c * dx + sn * dy
    across = -sn * dx + c * dy
    half = 0.5 * fp.width_m + grow
    inside = (along >= -fp.rear_m - grow) & (along <= fp.front_m + grow) & (np.abs(across) <= half)
    inside[0] = False
    return bool(inside.any())


def _near(grid: GridMap, x: float, y: float) -> bool:
    w, h = grid.size_m
    ox, oy = grid.origin_xy_m
    return ox <= x <= ox + w and oy <= y <= oy + h


def _own_box(
    ctx: BehaviourContext, x: float, y: float, heading: float
) -> tuple[float, float, float, float, float]:
    """Our car's box (rear axle pose), grown by the planner's tight margin."""
    fp = footprint(ctx)
    shift = 0.5 * (fp.front_m - fp.rear_m)
    grow = 2.0 * ZONE_MARGIN_TIGHT_M
    length = fp.front_m + fp.rear_m
    return (x + shift * math.cos(heading), y + shift * math.sin(heading), heading, length + grow,
            fp.width_m + grow)  # fmt: skip


def footprint(ctx: BehaviourContext) -> Footprint:
    """Our car's outline as the behaviour's parameters give it."""
    p = ctx.params
    return Footprint(p.rear_axle_to_front_m, p.vehicle_length_m - p.rear_axle_to_front_m, p.vehicle_width_m)


@dataclass(frozen=True)
class PlanRequest:
    """Everything a plan needs, picklable (a worker process solves it): the map, the car, the poses."""

    occupied: np.ndarray  # bool (rows, cols) of ZONE_CELL_M cells
    origin_xy_m: tuple[float, float]
    footprint: Footprint
    start: Pose
    goal: Pose
    then: tuple[np.ndarray, np.ndarray, np.ndarray] | None  # driven on after the goal (the exit edge)
    back_out_m: float  # first straight back this far (out of a spot), where free
    # where the plan must arrive driving forward (into a spot): if the plan to `goal` arrives reversing,
    # plan instead to this pose and drive `then` from it (a straight run into the spot)
    forward_via: tuple[Pose, tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None
    # where the usual search graph finds nothing: a last try at the tight margin on a finer one (short
    # arcs, a finer closed set: many short legs in a street little wider than the car is long)
    fine: bool = False
    reverse_factor: float = ZONE_REVERSE_FACTOR
    # +1 / -1: the motion at the start and after the goal (`PlannerParams`: the other way costs a change)
    start_direction: float = 0.0
    goal_direction: float = 0.0


@dataclass(frozen=True)
class PlanReply:
    """The plan's stretches (poses N x 3 and a direction each, driving order), or why there are none."""

    stretches: tuple[tuple[np.ndarray, int], ...]
    length_m: float
    direction_changes: int
    plan_ms: float
    reason: str = ""  # empty: found


class PathPlanner(Protocol):
    """Where plans are solved: `submit` a request, `poll` its ticket until it gives the reply."""

    def submit(self, request: PlanRequest) -> int: ...

    def poll(self, ticket: int) -> PlanReply | None: ...


class InlinePathPlanner:
    """Solves each request in the caller's thread, one step of `solve_steps` per `poll` (one map, or
    `SEARCH_STEP_EXPANSIONS` of the search: a few hundred milliseconds at most): the behaviour keeps
    its cycle (and the supervisor's hang bound) however long the search, and in lockstep SIL the reply
    comes after the same number of cycles in every run."""

    def __init__(self) -> None:
        self._steps: dict[int, Generator[object, None, PlanReply]] = {}
        self._next = 0

    def submit(self, request: PlanRequest) -> int:
        ticket, self._next = self._next, self._next + 1
        self._steps[ticket] = solve_steps(request)
        return ticket

    def poll(self, ticket: int) -> PlanReply | None:
        steps = self._steps.get(ticket)
        if steps is None:
            return PlanReply((), 0.0, 0, 0.0, f"zone planner: no request {ticket}")
        try:
            next(steps)
        except StopIteration as done:
            del self._steps[ticket]
            reply: PlanReply = done.value
            return reply
        return None


def planner_of(ctx: BehaviourContext) -> PathPlanner:
    """The behaviour's planner: the one the host gave it, else an `InlinePathPlanner` made now."""
    if ctx.path_planner is None:
        ctx.path_planner = InlinePathPlanner()
    return cast(PathPlanner, ctx.path_planner)


def make_request(
    ctx: BehaviourContext,
    grid: GridMap,
    goal: Pose,
    then: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    back_out_m: float = 0.0,
    forward_via: tuple[Pose, tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None,
    fine: bool = False,
    reverse_factor: float = ZONE_REVERSE_FACTOR,
    directions: tuple[float, float] = (0.0, 0.0),
    start: Pose | None = None,
) -> PlanRequest:
    """The request for a plan from `start` (our pose) to `goal` on `grid` (see `solve`)."""
    if abs(grid.resolution_m - ZONE_CELL_M) > 1e-9:
        raise ValueError(f"path planning: a map of {grid.resolution_m} m cells, not {ZONE_CELL_M} m")
    ego = ctx.situation.ego
    here = start or (ego.x_m, ego.y_m, ego.heading_rad)
    return PlanRequest(
        grid.occupied, grid.origin_xy_m, footprint(ctx), here, goal, then,
        back_out_m, forward_via, fine, reverse_factor, *directions,
    )  # fmt: skip


def solve(req: PlanRequest) -> PlanReply:
    """`solve_steps` to the end (a worker process's call)."""
    return run_to_end(solve_steps(req))


def solve_steps(req: PlanRequest) -> Generator[object, None, PlanReply]:
    """Plan (margin `ZONE_MARGIN_M`, again at `ZONE_MARGIN_TIGHT_M` where our own pose is inside the
    wider one), smooth, cut at the cusps. `back_out_m` > 0: first straight back that far (out of a
    parking spot: DARPA rules 5.2 have the car reverse out of it) where that is free, then the planned
    path from there. `then`: appended to the last stretch if it is forward, else a stretch of its own."""
    grid = GridMap(req.occupied, ZONE_CELL_M, req.origin_xy_m)
    maps: dict[float, CSpace] = {}  # per margin: the back-out check and every goal tried share them
    start = req.start
    first: list[tuple[np.ndarray, int]] = []
    if req.back_out_m > 0.0:
        c, s = math.cos(start[2]), math.sin(start[2])
        n = max(2, math.ceil(req.back_out_m / 0.25) + 1)
        d = np.linspace(0.0, req.back_out_m, n)
        back = np.column_stack((start[0] - d * c, start[1] - d * s, np.full(n, start[2])))
        cs = yield from _cspace(grid, req.footprint, ZONE_MARGIN_TIGHT_M, maps)
        if not cs.collides(back[:, 0], back[:, 1], back[:, 2]).any():
            first.append((back, -1))
            start = (float(back[-1, 0]), float(back[-1, 1]), start[2])
    reply = yield from _plan_to(grid, req, maps, start, first, req.goal, req.then)
    arrives_forward = bool(reply.stretches) and reply.stretches[-1][1] == 1
    if req.forward_via is not None and (reply.reason or (reply.stretches and not arrives_forward)):
        via, run = req.forward_via
        reply = yield from _plan_to(grid, req, maps, start, first, via, run)
    return reply


def _cspace(
    grid: GridMap, footprint: Footprint, margin_m: float, maps: dict[float, CSpace]
) -> Generator[object, None, CSpace]:
    """The configuration space at `margin_m`, built (a step of its own) the first time it is asked for."""
    if margin_m not in maps:
        maps[margin_m] = build_cspace(grid, footprint, margin_m=margin_m)
        yield "map"
    return maps[margin_m]


def _plan_to(
    grid: GridMap,
    req: PlanRequest,
    maps: dict[float, CSpace],
    start: Pose,
    first: list[tuple[np.ndarray, int]],
    goal: Pose,
    then: tuple[np.ndarray, np.ndarray, np.ndarray] | None,
) -> Generator[object, None, PlanReply]:
    """One goal of `solve_steps`: at the wide margin, else the tight one; `first` driven before it."""

    def mine(params: PlannerParams) -> PlannerParams:
        return replace(params, reverse_factor=req.reverse_factor, start_direction=req.start_direction,
                       goal_direction=req.goal_direction)  # fmt: skip

    tries = [(ZONE_MARGIN_M, mine(SEARCH)), (ZONE_MARGIN_TIGHT_M, mine(SEARCH))]
    if req.fine:
        tries.append((ZONE_MARGIN_TIGHT_M, mine(FINE_SEARCH)))
    reason = ""
    for margin, params in tries:
        cs = yield from _cspace(grid, req.footprint, margin, maps)
        result = yield from search(cs, start, goal, params, yield_every=SEARCH_STEP_EXPANSIONS)
        if not result.found:
            reason = result.reason
            continue
        stretches: list[tuple[np.ndarray, int]] = list(first)
        if result.length_m > 1e-6:
            yield "smoothing"
            poses, dirs, _ = smooth_path(cs, result.poses, result.directions, params.turn_radius_m)
            stretches += [(poses[i0 : i1 + 1], 1 if dirs[i1] > 0 else -1) for i0, i1 in split_at_cusps(dirs)]
        if then is not None:
            more = np.column_stack(then)
            if stretches and stretches[-1][1] == 1:
                stretches[-1] = (np.vstack((stretches[-1][0], more[1:])), 1)
            else:
                stretches.append((more, 1))
        signs = [d for _, d in stretches]
        changes = sum(1 for a, b in itertools.pairwise(signs) if a != b)
        length = result.length_m + sum(float(np.hypot(*np.diff(p[:, :2], axis=0).T).sum()) for p, _ in first)
        return PlanReply(tuple(stretches), length, changes, result.plan_ms)
    return PlanReply((), 0.0, 0, 0.0, f"zone planner: {reason}")


def legs_of(reply: PlanReply) -> PlannedLegs | str:
    """The reply's stretches as `Leg`s, or why there are none."""
    if reply.reason or not reply.stretches:
        return reply.reason or "zone planner: an empty plan"
    legs: list[Leg] = []
    for part, d in reply.stretches:
        direction: Direction = 1 if d > 0 else -1
        legs.append(path_leg(part[:, 0], part[:, 1], part[:, 2], direction))
    return PlannedLegs(tuple(legs), reply.length_m, reply.direction_changes, reply.plan_ms)
