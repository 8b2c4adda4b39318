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
"""

from __future__ import annotations

import heapq
import math
import time
from collections.abc import Generator
from dataclasses import dataclass, field
from typing import TypeVar

import numpy as np

from . import reeds_shepp
from .cspace import CSpace
from .heuristics import HeuristicField
from .primitives import MotionPrimitives, build_primitives
from .reeds_shepp_kernel import path_collides

__all__ = ["Plan", "PlannerParams", "plan", "run_to_end", "search"]

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
) -> Plan:
    """Search a path from `start` to `goal` (poses of the rear axle's centre) on `cspace`.

    `heuristic`: "both" (the paper's maximum), "kinematic", "obstacle" or "none" (Dijkstra)."""
    return run_to_end(
        search(cspace, start, goal, params, heuristic=heuristic, exhaustive=exhaustive,
               keep_tree=keep_tree, primitives=primitives, heuristic_field=heuristic_field)
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
) -> Generator[int, None, Plan]:
    """`plan` in steps: yields the expansions so far every `yield_every` expansions and returns the
    `Plan` (a caller with a cycle to keep, such as the behaviour in lockstep SIL, runs a few steps per
    cycle: the result depends on the expansions, never on the clock)."""
    p = params or PlannerParams()
    t0 = time.perf_counter()
    res = cspace.grid.resolution_m
    if heuristic not in ("both", "kinematic", "obstacle", "none"):
        raise ValueError(f"plan: heuristic {heuristic!r} is not one of both, kinematic, obstacle, none")
    for name, pose in (("start", start), ("goal", goal)):
        if len(pose) != 3 or not all(math.isfinite(v) for v in pose):
            raise ValueError(f"plan: {name} {pose} must be three finite numbers (x_m, y_m, heading_rad)")
    empty = np.zeros((0, 3))

    def fail(reason: str, expansions: int = 0) -> Plan:
        return Plan(
            False, empty, np.zeros(0), math.inf, 0.0, 0, expansions, 1e3 * (time.perf_counter() - t0), reason
        )

    for name, pose in (("start", start), ("goal", goal)):
        if bool(cspace.collides(np.array([pose[0]]), np.array([pose[1]]), np.array([pose[2]]))[0]):
            return fail(f"the {name} pose {tuple(round(v, 3) for v in pose)} collides (or is off the map)")
    step = p.sample_step_m or 0.5 * res
    prims = primitives or build_primitives(p.turn_radius_m, p.arc_m, p.n_steer, step, reverse=p.reverse)
    hf = heuristic_field or HeuristicField(cspace, goal, p.turn_radius_m, p.rs_range_m)
    use_obstacle = heuristic in ("both", "obstacle")
    use_kinematic = heuristic in ("both", "kinematic")
    if use_obstacle and not math.isfinite(float(hf.obstacle(start[0], start[1]))):
        return fail("the goal cannot be reached from the start through the free space")
    xy_bin = p.xy_bin_m
    n_h = p.closed_headings
    w = p.heuristic_weight
    if not (math.isfinite(w) and w >= 1.0):
        raise ValueError(f"plan: heuristic_weight = {w} must be finite and >= 1")
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
        if expansions % yield_every == 0:
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
            if keep_tree:
                tree.append((pose[0], pose[1], float(end[0]), float(end[1])))

    if best is None:
        reason = (
            "the expansion limit was reached"
            if expansions > p.max_expansions
            else "no path: the search space is exhausted"
        )
        out = fail(reason, expansions)
        out.tree = tree
        return out
    poses, dirs_out = _reconstruct(nodes, prims, best[1], start)
    if best[2] is not None:
        rs_poses, rs_dirs = reeds_shepp.sample(nodes.pose[best[1]], best[2], radius, step)
        poses = np.vstack([poses, rs_poses[1:]])
        dirs_out = np.concatenate([dirs_out, rs_dirs[1:]])
    seg = np.hypot(np.diff(poses[:, 0]), np.diff(poses[:, 1]))
    moving = dirs_out[1:]
    changes = int(np.sum(np.diff(moving[seg > 1e-9]) != 0)) if moving.size > 1 else 0
    return Plan(
        True, poses, dirs_out, best[0], float(seg.sum()), changes, expansions,
        1e3 * (time.perf_counter() - t0), "", tree,
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


def _reconstruct(
    nodes: _Nodes, prims: MotionPrimitives, nid: int, start: Pose
) -> tuple[np.ndarray, np.ndarray]:
    chain = []
    while nid >= 0:
        chain.append(nid)
        nid = nodes.parent[nid]
    chain.reverse()
    poses = [np.asarray([start])]
    dirs = [np.asarray([0.0])]
    for child in chain[1:]:
        parent = nodes.parent[child]
        samples = _edge_samples(prims, nodes.steer[parent], nodes.pose[parent])[nodes.prim[child]]
        poses.append(samples)
        dirs.append(np.full(samples.shape[0], nodes.dir[child]))
    out_dirs = np.concatenate(dirs)
    if out_dirs.size > 1:
        out_dirs[0] = out_dirs[1]
    return np.vstack(poses), out_dirs
