"""The compiled search loop (`search_kernel`) against the Python one it replaces (`hybrid_astar`'s
reference, `compiled=False`): the same expansions, the same steps, the same path to the last bit (every
pose, direction, the cost, the length, the direction changes), the same tree, on every goal of the
reference maps and on random small maps with every heuristic, weight and direction setting; the
compiled `math.hypot` that makes this possible against CPython's own; and the compiled grid Dijkstra of
the obstacle heuristic against scipy's on the sparse graph of the grid (how it was computed before)."""

from __future__ import annotations

import math
from collections.abc import Generator

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from bywire.host.navigation import hybrid_astar
from bywire.host.navigation.cspace import Footprint, build_cspace
from bywire.host.navigation.grid_map import GridMap
from bywire.host.navigation.heuristics import free_space_distance
from bywire.host.navigation.hybrid_astar import Plan, PlannerParams, plan, search
from bywire.host.navigation.primitives import build_primitives
from bywire.host.navigation.reference_maps import reference_problems
from bywire.host.navigation.search_kernel import py_hypot


def _steps(gen: Generator[int, None, Plan]) -> tuple[list[int], Plan]:
    steps = []
    while True:
        try:
            steps.append(next(gen))
        except StopIteration as done:
            return steps, done.value


def _assert_same(a: Plan, b: Plan) -> None:
    assert (a.found, a.reason, a.expansions) == (b.found, b.reason, b.expansions)
    assert a.poses.shape == b.poses.shape and np.array_equal(a.poses, b.poses)
    assert np.array_equal(a.directions, b.directions)
    assert a.cost == b.cost or (math.isinf(a.cost) and math.isinf(b.cost))
    assert (a.length_m, a.direction_changes) == (b.length_m, b.direction_changes)
    assert a.tree == b.tree


@pytest.mark.parametrize("problem", reference_problems(), ids=lambda p: p.name)
def test_the_compiled_search_finds_the_references_paths_on_the_reference_maps(problem) -> None:  # type: ignore[no-untyped-def]
    margin = 0.0 if problem.name == "autoware_lot" else 0.3  # as `bench zone` plans them
    cs = build_cspace(problem.grid, problem.footprint, margin_m=margin)
    params = PlannerParams(turn_radius_m=problem.turn_radius_m)
    for _, goal in problem.goals:
        ref_steps, ref = _steps(search(cs, problem.start, goal, params, yield_every=100, compiled=False))
        got_steps, got = _steps(search(cs, problem.start, goal, params, yield_every=100))
        assert ref.found
        _assert_same(ref, got)
        assert ref_steps == got_steps


SMALL_CAR = Footprint(front_m=1.5, rear_m=0.5, width_m=1.0)
poses = st.tuples(st.floats(1.0, 7.0), st.floats(1.0, 7.0), st.floats(-4.0, 4.0))


@settings(
    max_examples=25, deadline=None, suppress_health_check=[HealthCheck.filter_too_much, HealthCheck.too_slow]
)
@given(
    boxes=st.lists(st.tuples(st.floats(0.5, 7.5), st.floats(0.5, 7.5), st.floats(0, math.pi)), max_size=4),
    start=poses,
    goal=poses,
    heuristic=st.sampled_from(["both", "both", "kinematic", "obstacle", "none"]),
    exhaustive=st.booleans(),
    weight=st.sampled_from([1.0, 1.5, 2.5]),
    directions=st.tuples(st.sampled_from([-1.0, 0.0, 1.0]), st.sampled_from([-1.0, 0.0, 1.0])),
    reverse_factor=st.sampled_from([1.0, 1.5, 2.5]),
    n_steer=st.sampled_from([3, 5]),
    graph=st.sampled_from([(0.75, 0.5), (0.5, 0.3), (1.5, 0.5)]),  # arc_m, xy_bin_m
    rate_limited=st.booleans(),
    rs_range_m=st.sampled_from([3.0, 1e9]),
    origin=st.sampled_from([(0.0, 0.0), (-3.7, 12.3)]),
    capacity=st.sampled_from([16, 4096]),
)
def test_the_compiled_search_is_the_reference_on_random_small_maps(  # type: ignore[no-untyped-def]
    boxes, start, goal, heuristic, exhaustive, weight, directions, reverse_factor, n_steer, graph,
    rate_limited, rs_range_m, origin, capacity,
) -> None:  # fmt: skip
    ox, oy = origin
    start, goal = (start[0] + ox, start[1] + oy, start[2]), (goal[0] + ox, goal[1] + oy, goal[2])
    boxes = [(x + ox, y + oy, th, 1.5, 1.0) for x, y, th in boxes]
    grid = GridMap.from_boxes((8.0, 8.0), 0.25, boxes, origin_xy_m=origin)
    cs = build_cspace(grid, SMALL_CAR, margin_m=0.0, n_headings=36)
    free = ~cs.collides(
        np.array([start[0], goal[0]]), np.array([start[1], goal[1]]), np.array([start[2], goal[2]])
    )
    assume(free.all())
    arc_m, xy_bin_m = graph
    params = PlannerParams(
        turn_radius_m=2.0, arc_m=arc_m, n_steer=n_steer, xy_bin_m=xy_bin_m, closed_headings=36,
        heuristic_weight=weight, shot_range_m=12.0, rs_range_m=rs_range_m, reverse_factor=reverse_factor,
        start_direction=directions[0], goal_direction=directions[1], max_expansions=1500,
    )  # fmt: skip
    # steering rate limited: successor sets of different sizes (the kernel's are padded)
    prims = build_primitives(2.0, arc_m, n_steer, 0.125, max_kappa_rate_per_m2=0.4) if rate_limited else None
    kw = {
        "heuristic": heuristic,
        "exhaustive": exhaustive,
        "keep_tree": True,
        "yield_every": 37,
        "primitives": prims,
    }
    ref_steps, ref = _steps(search(cs, start, goal, params, compiled=False, **kw))  # type: ignore[arg-type]
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(hybrid_astar, "_INITIAL_CAPACITY", capacity)  # small: the arrays grow, often
        got_steps, got = _steps(search(cs, start, goal, params, **kw))  # type: ignore[arg-type]
    _assert_same(ref, got)
    assert ref_steps == got_steps


def test_a_search_that_finds_nothing_says_so_alike() -> None:
    occ = np.zeros((40, 40), dtype=bool)
    occ[:, 20] = True  # a wall across the map; without the obstacle heuristic nothing says so up front
    cs = build_cspace(GridMap(occ, 0.25), SMALL_CAR, margin_m=0.0, n_headings=36)
    start, goal = (1.5, 5.0, 0.0), (8.5, 5.0, math.pi)
    for limit in (300, 100_000):  # the limit reached, the search space exhausted
        params = PlannerParams(turn_radius_m=2.0, arc_m=0.75, closed_headings=36, max_expansions=limit)
        ref = plan(cs, start, goal, params, heuristic="none", compiled=False)
        got = plan(cs, start, goal, params, heuristic="none")
        assert not ref.found and ("limit" in ref.reason) == (limit == 300)
        _assert_same(ref, got)


def test_the_compiled_hypot_is_cpythons() -> None:
    rng = np.random.default_rng(3)
    values = [0.0, -0.0, 5e-324, 2.2250738585072014e-308, 1e-310, 1.0, 3.0, 4.0, 1e308, 1.7e308, math.inf]
    values += list(rng.uniform(-50.0, 50.0, 2000)) + list(rng.uniform(-1e-3, 1e-3, 500))
    values += list(np.exp(rng.uniform(-700.0, 700.0, 500)))
    for a, b in zip(values, values[::-1] + values, strict=False):
        want, got = math.hypot(a, b), py_hypot(float(a), float(b))
        assert want == got or (math.isnan(want) and math.isnan(got)), (a, b)
    assert math.isnan(py_hypot(math.nan, 1.0)) and py_hypot(math.nan, math.inf) == math.inf


def _scipy_free_space_distance(free: np.ndarray, goal_cell: tuple[int, int], res_m: float) -> np.ndarray:
    """`heuristics.free_space_distance` as it was: scipy's Dijkstra on the grid's 8-connected graph."""
    rows, cols = free.shape
    idx = np.arange(rows * cols).reshape(rows, cols)
    src: list[np.ndarray] = []
    dst: list[np.ndarray] = []
    wts: list[np.ndarray] = []
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        r0, r1 = max(0, -dr), rows - max(0, dr)
        c0, c1 = max(0, -dc), cols - max(0, dc)
        a = free[r0:r1, c0:c1] & free[r0 + dr : r1 + dr, c0 + dc : c1 + dc]
        if dr and dc:
            a &= free[r0 + dr : r1 + dr, c0:c1] | free[r0:r1, c0 + dc : c1 + dc]
        i = idx[r0:r1, c0:c1][a]
        j = idx[r0 + dr : r1 + dr, c0 + dc : c1 + dc][a]
        w = res_m * (math.sqrt(2.0) if dr and dc else 1.0)
        src += [i, j]
        dst += [j, i]
        wts += [np.full(i.size, w), np.full(i.size, w)]
    n = rows * cols
    graph = coo_matrix(
        (np.concatenate(wts), (np.concatenate(src), np.concatenate(dst))), shape=(n, n)
    ).tocsr()
    out = np.asarray(dijkstra(graph, directed=False, indices=int(idx[goal_cell])), dtype=float).reshape(
        rows, cols
    )
    if not free[goal_cell]:
        out[:] = np.inf
        out[goal_cell] = 0.0
    return out


def test_the_compiled_grid_distance_is_scipys() -> None:
    rng = np.random.default_rng(5)
    cases = []
    for problem in reference_problems():
        cs = build_cspace(problem.grid, problem.footprint, margin_m=0.3)
        for _, goal in problem.goals:
            row, col = cs.grid.cell_of(goal[0], goal[1])
            free = cs.disk_free.copy()
            free[int(row), int(col)] = True
            cases.append((free, (int(row), int(col)), cs.grid.resolution_m))
    for _ in range(40):
        shape = (int(rng.integers(2, 40)), int(rng.integers(2, 40)))
        free = rng.random(shape) < rng.uniform(0.3, 1.0)
        cases.append(
            (free, (int(rng.integers(shape[0])), int(rng.integers(shape[1]))), rng.uniform(0.05, 1.0))
        )
    for free, goal_cell, res in cases:
        want = _scipy_free_space_distance(free, goal_cell, res)
        got = free_space_distance(free, goal_cell, res)
        assert np.array_equal(want, got)


def test_every_plan_runs_the_one_compiled_loop_warm_up_compiled() -> None:
    """A plan whose arguments reach the kernel with other types (a read-only table, another layout,
    an int for a float) would compile the loop again, for seconds, inside the plan: every kind of call
    runs the one signature `warm_up` compiles."""
    from bywire.host.navigation import heuristics, search_kernel
    from bywire.host.navigation.cspace import CSpace

    hybrid_astar.warm_up()
    grid = GridMap.from_boxes((8.0, 8.0), 0.25, [(4.0, 4.0, 0.3, 1.5, 1.0)])
    cs = build_cspace(grid, SMALL_CAR, margin_m=0.0, n_headings=36)
    blocked = cs.blocked.copy()
    blocked.setflags(write=False)
    read_only = CSpace(cs.grid, blocked, cs.disk_free, cs.footprint, cs.margin_m)
    params = PlannerParams(turn_radius_m=2, arc_m=1, closed_headings=36, reverse_factor=2)  # ints
    prims = build_primitives(2.0, 0.75, 3, 0.125, max_kappa_rate_per_m2=0.4)
    for space in (cs, read_only):
        for kw in ({}, {"exhaustive": True, "keep_tree": True}, {"heuristic": "none"}, {"primitives": prims}):
            plan(space, (1.5, 1.5, 0), (6, 6.5, 3), params, **kw)  # type: ignore[arg-type]
    assert len(search_kernel.run.signatures) == 1
    assert len(heuristics._grid_distance.signatures) == 1
