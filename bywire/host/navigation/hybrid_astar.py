"""Hybrid A* on the kinematic one-track model (seed 000 Sec. 10.2; Dolgov et al. 2010 for the names).

Nodes are continuous poses (x, y, heading) with a steering index and the direction they were reached
in; the search's closed set is discretised (`xy_bin_m`, the configuration space's heading bins). Edges
are the precomputed `primitives` moved to the node; a successor is kept when every sample along its
edge is free in the `CSpace` table. A cell reached again more cheaply is re-opened (the cheaper node
replaces the old one: Autoware's users asked for exactly this, autoware_universe PR 8068), so the
search's optimum is not lost to the order of expansion.

Edge cost: arc length, times `reverse_factor` backwards, plus `direction_change_m` per change of
direction (also against the motion the car is in at the start and must go on in after the goal, where
`start_direction` / `goal_direction` give them: a K-turn begins and ends driving forward), plus
`steer_change_weight` x |kappa change| x R and `steer_weight` x |kappa| x R x arc (every
term >= the arc length it covers, so the admissible heuristics stay admissible for the cost).

Cost-to-go: the maximum of the Reeds-Shepp length and the obstacle-aware free-space distance
(`heuristics`, Sec. 10.3.3). A node is pushed with the cheap part (the free-space distance and the
straight-line distance) and given the full value when it is popped (lazy evaluation: the Reeds-Shepp
metric is paid for once per expansion, not per successor).

Analytic expansion: from every `shot_every`-th expansion within `shot_range_m` of the goal the shortest
Reeds-Shepp path to the goal is checked against the table, and from every expansion within two turning
radii the `shot_candidates` shortest; the first free one ends the search. This is the only way the
search ends: a path ends exactly on the goal pose, never merely near it (a parking spot has no room for
a tolerance, and the heuristics, which measure to the exact goal, stay admissible for what is searched).
`exhaustive=True` keeps searching until no open node can beat the best complete path (the tests'
reference optimum).

The loop runs compiled (`search_kernel`, numba: ~5 us an expansion, the Reeds-Shepp heuristic its
largest part; the Python loop took ~100 us). The Python loop stays here as the reference
(`compiled=False`): tests/host/navigation/test_search_kernel.py holds the two to the same expansions,
steps and path, every pose to the last bit. `warm_up` compiles the kernels (or loads them from numba's
cache) before a process's first plan. The successor set is built once per parameters
(`build_primitives` keeps it).
"""

from __future__ import annotations

import functools
import heapq
import math
import time
from collections.abc import Generator
from dataclasses import dataclass, field
from typing import TypeVar

import numpy as np

from . import reeds_shepp
from . import search_kernel as _kernel
from .cspace import CSpace, Footprint, build_cspace
from .grid_map import GridMap
from .heuristics import HeuristicField
from .primitives import MotionPrimitives, build_primitives
from .reeds_shepp_kernel import path_collides

__all__ = ["Plan", "PlannerParams", "plan", "run_to_end", "search", "warm_up"]

Pose = tuple[float, float, float]
T = TypeVar("T")


@dataclass(frozen=True)
class PlannerParams:
    turn_radius_m: float = 5.5  # rules.KTURN_RADIUS_M: 26 deg of steer on the Passat, 4 deg below the lock
    arc_m: float = 1.5
    n_steer: int = 5
    xy_bin_m: float = 0.5  # the closed set's cell
    reverse: bool = True
    reverse_factor: float = 1.5
    direction_change_m: float = 3.0
    steer_change_weight: float = 0.5
    steer_weight: float = 0.05
    shot_every: int = 3
    shot_range_m: float = 30.0
    shot_candidates: int = 4
    rs_range_m: float = 20.0
    # w > 1: weighted A*, a path costing at most w times the optimum, found many times faster (Autoware's
    # planner weights its distance heuristic by 2); 1: the optimum of the search graph
    heuristic_weight: float = 1.5
    closed_headings: int = 72  # heading bins of the closed set
    max_expansions: int = 100_000
    sample_step_m: float | None = None  # collision samples along an edge; None: half the map's cell
    # +1 / -1: the motion the car is in at the start (a first edge the other way costs a direction
    # change), and the one it goes on in after the goal (a path arriving the other way costs one); 0: free
    start_direction: float = 0.0
    goal_direction: float = 0.0


@dataclass
class Plan:
    found: bool
    poses: np.ndarray  # (N, 3) x_m, y_m, heading_rad of the rear axle's centre, start to goal
    directions: np.ndarray  # (N,) +1 forward, -1 backward (the motion arriving at each pose)
    cost: float
    length_m: float
    direction_changes: int
    expansions: int
    plan_ms: float
    reason: str = ""
    tree: list[tuple[float, float, float, float]] = field(default_factory=list)  # (x0, y0, x1, y1) edges

    def summary(self) -> dict[str, object]:
        return {
            "found": self.found,
            "length_m": round(self.length_m, 3),
            "direction_changes": self.direction_changes,
            "plan_ms": round(self.plan_ms, 2),
            "expansions": self.expansions,
            "cost": round(self.cost, 3) if math.isfinite(self.cost) else None,
            "reason": self.reason,
        }


class _Nodes:
    """Structure-of-arrays node store (a Python object per node costs more than the search itself)."""

    def __init__(self) -> None:
        self.pose: list[Pose] = []
        self.steer: list[int] = []
        self.dir: list[float] = []
        self.g: list[float] = []
        self.parent: list[int] = []
        self.prim: list[int] = []  # index of the primitive from the parent's steering set
        self.full_h: list[bool] = []

    def add(self, pose: Pose, steer: int, d: float, g: float, parent: int, prim: int) -> int:
        self.pose.append(pose)
        self.steer.append(steer)
        self.dir.append(d)
        self.g.append(g)
        self.parent.append(parent)
        self.prim.append(prim)
        self.full_h.append(False)
        return len(self.g) - 1


def _edge_samples(prims: MotionPrimitives, steer: int, pose: Pose) -> np.ndarray:
    """All successors' samples moved to `pose`: (n_succ, m, 3)."""
    local = prims.samples[steer]
    c, s = math.cos(pose[2]), math.sin(pose[2])
    out = np.empty_like(local)
    out[..., 0] = pose[0] + c * local[..., 0] - s * local[..., 1]
    out[..., 1] = pose[1] + s * local[..., 0] + c * local[..., 1]
    out[..., 2] = pose[2] + local[..., 2]
    return out


def _rs_cost(
    path: reeds_shepp.RsPath, radius_m: float, params: PlannerParams, last_dir: float, goal_dir: float = 0.0
) -> float:
    """The search's cost of a Reeds-Shepp path driven on from a node reached in `last_dir`, the
    direction change at the goal included where it must go on in `goal_dir`."""
    cost = 0.0
    d_prev = last_dir
    for seg in path.segments:
        length = abs(seg.length) * radius_m
        if length < 1e-9:
            continue
        d = 1.0 if seg.length > 0 else -1.0
        cost += length * (1.0 if d > 0 else params.reverse_factor)
        if seg.steer != "S":
            cost += params.steer_weight * length
        if d_prev != 0.0 and d != d_prev:
            cost += params.direction_change_m
        d_prev = d
    if goal_dir != 0.0 and d_prev != 0.0 and d_prev != goal_dir:
        cost += params.direction_change_m
    return cost


def plan(
    cspace: CSpace,
    start: Pose,
    goal: Pose,
    params: PlannerParams | None = None,
    *,
    heuristic: str = "both",
    exhaustive: bool = False,
    keep_tree: bool = False,
    primitives: MotionPrimitives | None = None,
    heuristic_field: HeuristicField | None = None,
    compiled: bool = True,
) -> Plan:
    """Search a path from `start` to `goal` (poses of the rear axle's centre) on `cspace`.

    `heuristic`: "both" (the paper's maximum), "kinematic", "obstacle" or "none" (Dijkstra);
    `compiled`: see `search`."""
    return run_to_end(
        search(cspace, start, goal, params, heuristic=heuristic, exhaustive=exhaustive,
               keep_tree=keep_tree, primitives=primitives, heuristic_field=heuristic_field,
               compiled=compiled)
    )  # fmt: skip


def run_to_end(steps: Generator[object, None, T]) -> T:
    """What a stepped computation (`search`, the zone planner's `solve_steps`) returns, all steps taken."""
    while True:
        try:
            next(steps)
        except StopIteration as done:
            result: T = done.value
            return result


def search(
    cspace: CSpace,
    start: Pose,
    goal: Pose,
    params: PlannerParams | None = None,
    *,
    heuristic: str = "both",
    exhaustive: bool = False,
    keep_tree: bool = False,
    primitives: MotionPrimitives | None = None,
    heuristic_field: HeuristicField | None = None,
    yield_every: int = 500,
    compiled: bool = True,
) -> Generator[int, None, Plan]:
    """`plan` in steps: yields the expansions so far every `yield_every` expansions and returns the
    `Plan` (a caller with a cycle to keep, such as the behaviour in lockstep SIL, runs a few steps per
    cycle: the result depends on the expansions, never on the clock).

    `compiled`: the loop in `search_kernel` (numba); False: the same loop in Python, the reference the
    compiled one is held equal to (the same expansions, the same path to the last bit)."""
    p = params or PlannerParams()
    t0 = time.perf_counter()
    res = cspace.grid.resolution_m
    if heuristic not in ("both", "kinematic", "obstacle", "none"):
        raise ValueError(f"plan: heuristic {heuristic!r} is not one of both, kinematic, obstacle, none")
    for name, pose in (("start", start), ("goal", goal)):
        if len(pose) != 3 or not all(math.isfinite(v) for v in pose):
            raise ValueError(f"plan: {name} {pose} must be three finite numbers (x_m, y_m, heading_rad)")
    for name, pose in (("start", start), ("goal", goal)):
        if bool(cspace.collides(np.array([pose[0]]), np.array([pose[1]]), np.array([pose[2]]))[0]):
            return _fail(
                t0, f"the {name} pose {tuple(round(v, 3) for v in pose)} collides (or is off the map)"
            )
    step = p.sample_step_m or 0.5 * res
    prims = primitives or build_primitives(p.turn_radius_m, p.arc_m, p.n_steer, step, reverse=p.reverse)
    hf = heuristic_field or HeuristicField(cspace, goal, p.turn_radius_m, p.rs_range_m)
    use_obstacle = heuristic in ("both", "obstacle")
    use_kinematic = heuristic in ("both", "kinematic")
    if use_obstacle and not math.isfinite(float(hf.obstacle(start[0], start[1]))):
        return _fail(t0, "the goal cannot be reached from the start through the free space")
    w = p.heuristic_weight
    if not (math.isfinite(w) and w >= 1.0):
        raise ValueError(f"plan: heuristic_weight = {w} must be finite and >= 1")
    if yield_every < 1:
        raise ValueError(f"plan: yield_every = {yield_every} must be >= 1")
    setup = _Setup(cspace, start, goal, p, prims, hf, step, use_obstacle, use_kinematic, exhaustive,
                   keep_tree, yield_every, t0)  # fmt: skip
    if compiled:
        return (yield from _search_compiled(setup))
    return (yield from _search_reference(setup))


@dataclass(frozen=True)
class _Setup:
    """What both searches start from (`search` checked it)."""

    cspace: CSpace
    start: Pose
    goal: Pose
    p: PlannerParams
    prims: MotionPrimitives
    hf: HeuristicField
    step_m: float
    use_obstacle: bool
    use_kinematic: bool
    exhaustive: bool
    keep_tree: bool
    yield_every: int
    t0: float


def _fail(t0: float, reason: str, expansions: int = 0) -> Plan:
    return Plan(
        False,
        np.zeros((0, 3)),
        np.zeros(0),
        math.inf,
        0.0,
        0,
        expansions,
        1e3 * (time.perf_counter() - t0),
        reason,
    )


def _search_reference(su: _Setup) -> Generator[int, None, Plan]:
    """The search loop in Python (see the module docstring)."""
    cspace, start, goal, p, prims, hf = su.cspace, su.start, su.goal, su.p, su.prims, su.hf
    step, use_obstacle, use_kinematic, exhaustive = (
        su.step_m,
        su.use_obstacle,
        su.use_kinematic,
        su.exhaustive,
    )
    xy_bin = p.xy_bin_m
    n_h = p.closed_headings
    w = p.heuristic_weight
    ox, oy = cspace.grid.origin_xy_m
    radius = p.turn_radius_m

    def keys(x: np.ndarray, y: np.ndarray, th: np.ndarray) -> np.ndarray:
        ix = np.floor((x - ox) / xy_bin).astype(np.int64)
        iy = np.floor((y - oy) / xy_bin).astype(np.int64)
        ik = np.round(th * (n_h / (2.0 * math.pi))).astype(np.int64) % n_h
        return (iy * 100_003 + ix) * 1024 + ik

    def key_of(pose: Pose) -> int:
        ix = math.floor((pose[0] - ox) / xy_bin)
        iy = math.floor((pose[1] - oy) / xy_bin)
        ik = round(pose[2] * (n_h / (2.0 * math.pi))) % n_h
        return (iy * 100_003 + ix) * 1024 + ik

    def cheap_h(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        h = np.zeros(np.shape(x))
        if use_obstacle:
            h = np.maximum(h, hf.obstacle(x, y))
        if use_kinematic:
            h = np.maximum(h, np.hypot(x - goal[0], y - goal[1]))
        return h

    nodes = _Nodes()
    mid = p.n_steer // 2
    root = nodes.add(start, mid, float(p.start_direction), 0.0, -1, -1)
    best_g: dict[int, float] = {key_of(start): 0.0}
    heap: list[tuple[float, int, int]] = [(0.0, 0, root)]
    tie = 1
    expansions = 0
    best: tuple[float, int, reeds_shepp.RsPath | None] | None = None  # (cost, node, shot)
    tree: list[tuple[float, float, float, float]] = []
    eps = 1e-9

    while heap:
        f, _, nid = heapq.heappop(heap)
        if best is not None and f >= best[0] - eps:
            break
        pose = nodes.pose[nid]
        key = key_of(pose)
        g = nodes.g[nid]
        if g > best_g.get(key, math.inf) + eps:
            continue  # a cheaper node took this cell
        if use_kinematic and not nodes.full_h[nid]:
            # f already holds the cheap bounds (pushed with them): the kinematic one is added lazily,
            # computed only for nodes that reach the top of the queue
            nodes.full_h[nid] = True
            f_full = g + w * hf.kinematic(pose)
            if f_full > f + eps:
                heapq.heappush(heap, (f_full, tie, nid))
                tie += 1
                continue
        expansions += 1
        if expansions > p.max_expansions:
            break
        if expansions % su.yield_every == 0:
            yield expansions
        dist = math.hypot(pose[0] - goal[0], pose[1] - goal[1])
        near = dist < 2.0 * radius
        if dist <= p.shot_range_m and (exhaustive or near or expansions % p.shot_every == 1):
            shot = _shot(cspace, pose, goal, radius, step, p.shot_candidates if exhaustive or near else 1)
            if shot is not None:
                c = g + _rs_cost(shot, radius, p, nodes.dir[nid], p.goal_direction)
                if best is None or c < best[0]:
                    best = (c, nid, shot)
                if not exhaustive:
                    break
        steer = nodes.steer[nid]
        samples = _edge_samples(prims, steer, pose)
        n_succ, m, _ = samples.shape
        flat = samples.reshape(-1, 3)
        hit = cspace.collides(flat[:, 0], flat[:, 1], flat[:, 2]).reshape(n_succ, m).any(axis=1)
        ends = samples[:, -1, :]
        succ_keys = keys(ends[:, 0], ends[:, 1], ends[:, 2])
        hs = cheap_h(ends[:, 0], ends[:, 1])
        d_node = nodes.dir[nid]
        to_idx = prims.to_index[steer]
        dirs = prims.direction[steer]
        kap = prims.kappas
        for j in np.flatnonzero(~hit):
            d = float(dirs[j])
            to = int(to_idx[j])
            cost = prims.arc_m * (1.0 if d > 0 else p.reverse_factor)
            cost += p.steer_change_weight * abs(kap[to] - kap[steer]) * radius
            cost += p.steer_weight * abs(kap[to]) * radius * prims.arc_m
            if d_node != 0.0 and d != d_node:
                cost += p.direction_change_m
            g2 = g + cost
            k2 = int(succ_keys[j])
            if k2 == key or g2 >= best_g.get(k2, math.inf) - eps:
                continue
            h2 = float(hs[j])
            if not math.isfinite(h2):
                continue
            best_g[k2] = g2
            end = ends[j]
            child = nodes.add((float(end[0]), float(end[1]), float(end[2])), to, d, g2, nid, int(j))
            heapq.heappush(heap, (g2 + w * h2, tie, child))
            tie += 1
            if su.keep_tree:
                tree.append((pose[0], pose[1], float(end[0]), float(end[1])))

    if best is None:
        return _finish(su, None, expansions, tree)
    chain = []
    nid = best[1]
    while nodes.parent[nid] >= 0:
        parent = nodes.parent[nid]
        chain.append((nodes.pose[parent], nodes.steer[parent], nodes.prim[nid], nodes.dir[nid]))
        nid = parent
    return _finish(su, (best[0], nodes.pose[best[1]], best[2], chain[::-1]), expansions, tree)


_INITIAL_CAPACITY = 4096  # nodes and heap entries the compiled search starts with (it doubles them)


def _search_compiled(su: _Setup) -> Generator[int, None, Plan]:
    """The search loop in `search_kernel` (see the module docstring), driven in its steps."""
    p, prims, grid, hgrid = su.p, su.prims, su.cspace.grid, su.hf.cspace.grid
    kp = _primitive_arrays(prims)  # samples, n_succ, to_index, direction, kappas
    rows, cols = grid.shape
    n_h = p.closed_headings
    # poses on the map only (start and successors are free): a bin or two of slack for rounding
    bins_x = math.ceil(cols * grid.resolution_m / p.xy_bin_m) + 2
    bins_y = math.ceil(rows * grid.resolution_m / p.xy_bin_m) + 2
    params = _kernel.Params(
        float(su.goal[0]), float(su.goal[1]), float(su.goal[2]), float(p.turn_radius_m), float(prims.arc_m),
        float(p.reverse_factor), float(p.direction_change_m), float(p.steer_change_weight),
        float(p.steer_weight), float(p.shot_range_m), float(p.heuristic_weight), float(p.goal_direction),
        float(su.step_m), float(p.xy_bin_m), int(n_h), bins_x, bins_y, int(p.max_expansions),
        int(su.yield_every), int(p.shot_every), int(p.shot_candidates), su.use_obstacle, su.use_kinematic,
        su.exhaustive, float(grid.origin_xy_m[0]), float(grid.origin_xy_m[1]), float(grid.resolution_m),
        float(su.hf.goal[0]), float(su.hf.goal[1]), float(su.hf.goal[2]), float(su.hf.turn_radius_m),
        float(su.hf.rs_range_m), float(hgrid.origin_xy_m[0]), float(hgrid.origin_xy_m[1]),
        float(hgrid.resolution_m),
    )  # fmt: skip
    # the types the kernel was compiled (and warmed) for: another layout or a read-only array would
    # compile it again, for seconds, inside the plan
    blocked = _writable(np.ascontiguousarray(su.cspace.blocked, dtype=np.bool_))
    obstacle_m = _writable(np.ascontiguousarray(su.hf.obstacle_m, dtype=np.float64))
    cap = _INITIAL_CAPACITY
    node_f = np.empty((cap, 5))
    node_i = np.empty((cap, 3), dtype=np.int64)
    full_h = np.empty(cap, dtype=np.bool_)
    hf, ht, hn = np.empty(cap), np.empty(cap, dtype=np.int64), np.empty(cap, dtype=np.int64)
    # the closed set: `seen` zeroed (calloc: only the pages the search touches are ever written)
    best_g = np.empty(bins_y * bins_x * n_h)
    seen = np.zeros(bins_y * bins_x * n_h, dtype=np.bool_)
    si = np.zeros(8, dtype=np.int64)
    sf = np.zeros(4)
    node_f[0] = (su.start[0], su.start[1], su.start[2], float(p.start_direction), 0.0)
    node_i[0] = (p.n_steer // 2, -1, -1)
    full_h[0] = False
    hf[0], ht[0], hn[0] = 0.0, 0, 0
    root_key = _kernel.cell_key(float(su.start[0]), float(su.start[1]), float(su.start[2]), params)
    if root_key < 0:  # pragma: no cover - a bug: the start is free, so on the map
        raise RuntimeError("plan: the start off the closed set's table")
    best_g[root_key] = 0.0
    seen[root_key] = True
    si[_kernel.S_NODES], si[_kernel.S_HEAP], si[_kernel.S_TIE] = 1, 1, 1
    si[_kernel.S_PENDING] = si[_kernel.S_BEST_NODE] = -1
    while True:
        status = _kernel.run(
            params, blocked, obstacle_m, *kp, reeds_shepp._K_SOLVER, reeds_shepp._K_BACKWARDS,
            reeds_shepp._K_TWICE, reeds_shepp._K_EXTRA, reeds_shepp._K_MIRRORS, reeds_shepp._K_STEERS,
            reeds_shepp._K_SHAPES, reeds_shepp._K_REFLECT, node_f, node_i, full_h, hf, ht, hn, best_g, seen,
            si, sf,
        )  # fmt: skip
        if status == _kernel.YIELD:
            yield int(si[_kernel.S_EXPANSIONS])
        elif status == _kernel.GROW:
            n = int(si[_kernel.S_NODES])
            if n + kp[0].shape[1] > node_f.shape[0]:
                node_f, node_i, full_h = _grown(node_f, n), _grown(node_i, n), _grown(full_h, n)
            size = int(si[_kernel.S_HEAP])
            hf, ht, hn = _grown(hf, size), _grown(ht, size), _grown(hn, size)
        elif status == _kernel.ERROR:  # pragma: no cover - a bug: the table's bounds are the map's
            raise RuntimeError("plan: a pose off the closed set's table")
        else:
            break
    expansions = int(si[_kernel.S_EXPANSIONS])
    n = int(si[_kernel.S_NODES])
    tree: list[tuple[float, float, float, float]] = []
    if su.keep_tree:
        parents = node_i[1:n, _kernel.NPARENT]
        tree = list(map(tuple, np.column_stack((node_f[parents, :2], node_f[1:n, :2])).tolist()))
    nid = int(si[_kernel.S_BEST_NODE])
    if nid < 0:
        return _finish(su, None, expansions, tree)

    def pose_of(i: int) -> Pose:
        return (float(node_f[i, 0]), float(node_f[i, 1]), float(node_f[i, 2]))

    chain = []
    shot_pose = pose_of(nid)
    while node_i[nid, _kernel.NPARENT] >= 0:
        parent = int(node_i[nid, _kernel.NPARENT])
        chain.append((pose_of(parent), int(node_i[parent, _kernel.NSTEER]), int(node_i[nid, _kernel.NPRIM]),
                      float(node_f[nid, _kernel.NDIR])))  # fmt: skip
        nid = parent
    shot = reeds_shepp.solution_path(
        int(si[_kernel.S_BEST_WORD]),
        int(si[_kernel.S_BEST_MIRROR]),
        *sf[_kernel.SF_T : _kernel.SF_V + 1].tolist(),
    )
    return _finish(su, (float(sf[_kernel.SF_BEST_COST]), shot_pose, shot, chain[::-1]), expansions, tree)


def _writable(a: np.ndarray) -> np.ndarray:
    return a if a.flags.writeable else a.copy()


def _grown(a: np.ndarray, used: int) -> np.ndarray:
    """`a` twice as long, its first `used` rows kept."""
    out = np.empty((2 * a.shape[0], *a.shape[1:]), dtype=a.dtype)
    out[:used] = a[:used]
    return out


_KernelPrimitives = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]


@functools.lru_cache(maxsize=16)  # by the set's identity, as `build_primitives` keeps the sets
def _primitive_arrays(prims: MotionPrimitives) -> _KernelPrimitives:
    """The successor sets by steering index as the kernel takes them: samples (n_steer, most
    successors, m, 3), how many successors, their steering indices and directions (padded), and the
    curvatures."""
    n_steer = prims.n_steer
    most = max(s.shape[0] for s in prims.samples)
    m = prims.samples[0].shape[1]
    samples = np.zeros((n_steer, most, m, 3))
    n_succ = np.zeros(n_steer, dtype=np.int64)
    to_index = np.zeros((n_steer, most), dtype=np.int64)
    direction = np.zeros((n_steer, most))
    for i in range(n_steer):
        k = prims.samples[i].shape[0]
        samples[i, :k] = prims.samples[i]
        n_succ[i] = k
        to_index[i, :k] = prims.to_index[i]
        direction[i, :k] = prims.direction[i]
    return samples, n_succ, to_index, direction, np.array(prims.kappas, dtype=np.float64)


def warm_up() -> None:
    """Compile the search loop and the Reeds-Shepp kernels it calls, or load them from numba's cache
    (seconds on a machine that never compiled them): before a process's first plan, never in it."""
    reeds_shepp.warm_up()
    grid = GridMap(np.zeros((40, 40), dtype=bool), 0.25)
    cs = build_cspace(grid, Footprint(front_m=1.5, rear_m=0.5, width_m=1.0), margin_m=0.0, n_headings=36)
    params = PlannerParams(turn_radius_m=2.0, arc_m=0.75, closed_headings=36, shot_range_m=1.0)
    plan(cs, (2.0, 2.0, 0.0), (8.0, 8.0, math.pi), params)


_Edge = tuple[Pose, int, int, float]  # the parent's pose and steering, the primitive, its direction


def _finish(
    su: _Setup,
    best: tuple[float, Pose, reeds_shepp.RsPath | None, list[_Edge]] | None,
    expansions: int,
    tree: list[tuple[float, float, float, float]],
) -> Plan:
    """The `Plan` of a search that ended: `best` (cost, the pose the shot starts from, the shot, the
    edges from the start to that pose) or None."""
    if best is None:
        reason = (
            "the expansion limit was reached"
            if expansions > su.p.max_expansions
            else "no path: the search space is exhausted"
        )
        out = _fail(su.t0, reason, expansions)
        out.tree = tree
        return out
    cost, shot_pose, shot, chain = best
    poses, dirs_out = _reconstruct(su.prims, chain, su.start)
    if shot is not None:
        rs_poses, rs_dirs = reeds_shepp.sample(shot_pose, shot, su.p.turn_radius_m, su.step_m)
        poses = np.vstack([poses, rs_poses[1:]])
        dirs_out = np.concatenate([dirs_out, rs_dirs[1:]])
    seg = np.hypot(np.diff(poses[:, 0]), np.diff(poses[:, 1]))
    moving = dirs_out[1:]
    changes = int(np.sum(np.diff(moving[seg > 1e-9]) != 0)) if moving.size > 1 else 0
    return Plan(
        True, poses, dirs_out, cost, float(seg.sum()), changes, expansions,
        1e3 * (time.perf_counter() - su.t0), "", tree,
    )  # fmt: skip


def _shot(
    cspace: CSpace, pose: Pose, goal: Pose, radius_m: float, step_m: float, candidates: int
) -> reeds_shepp.RsPath | None:
    """The shortest of the `candidates` shortest Reeds-Shepp paths to the goal that is free."""
    paths = reeds_shepp.shortest_paths(*reeds_shepp.normalised(pose, goal, radius_m), candidates)
    (ox, oy), res = cspace.grid.origin_xy_m, cspace.grid.resolution_m
    x, y, th = pose
    for path in paths:
        # `sample` then `cspace.collides`, compiled, stopping at the first pose that collides
        curvature, length_m = reeds_shepp.segment_arrays(path, radius_m)
        if not path_collides(x, y, th, curvature, length_m, step_m, cspace.blocked, ox, oy, res):
            return path
    return None


def _reconstruct(prims: MotionPrimitives, chain: list[_Edge], start: Pose) -> tuple[np.ndarray, np.ndarray]:
    poses = [np.asarray([start])]
    dirs = [np.asarray([0.0])]
    for pose, steer, prim, d in chain:
        samples = _edge_samples(prims, steer, pose)[prim]
        poses.append(samples)
        dirs.append(np.full(samples.shape[0], d))
    out_dirs = np.concatenate(dirs)
    if out_dirs.size > 1:
        out_dirs[0] = out_dirs[1]
    return np.vstack(poses), out_dirs
