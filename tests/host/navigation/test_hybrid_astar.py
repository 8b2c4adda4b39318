"""Hybrid A* (seed 000 Sec. 10.2-10.3) as a library on any occupancy grid: Autoware's four parking goals
solved, every pose of every path free against the car's exact outline; both heuristics admissible
against the search's own optimal cost on random small maps; weighted search within its bound of the
optimum (which holds only because cheaper nodes re-open their cell); clear answers where there is no path."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from planning_checks import assert_exactly_free

from bywire.host.navigation.cspace import Footprint, build_cspace
from bywire.host.navigation.grid_map import GridMap
from bywire.host.navigation.heuristics import HeuristicField
from bywire.host.navigation.hybrid_astar import PlannerParams, plan
from bywire.host.navigation.reference_maps import autoware_lot


@pytest.fixture(scope="module")
def lot():  # type: ignore[no-untyped-def]
    problem = autoware_lot()
    return problem, build_cspace(problem.grid, problem.footprint, margin_m=0.0)


@pytest.mark.parametrize("goal", range(4))
def test_autowares_parking_goals_are_reached_on_a_free_path(lot, goal: int) -> None:  # type: ignore[no-untyped-def]
    problem, cs = lot
    name, g = problem.goals[goal]
    result = plan(cs, problem.start, g, PlannerParams(turn_radius_m=problem.turn_radius_m))
    assert result.found, f"{name}: {result.reason}"
    assert np.allclose(result.poses[0], problem.start)
    end = result.poses[-1]
    assert math.hypot(end[0] - g[0], end[1] - g[1]) < 1e-6
    assert abs(math.remainder(end[2] - g[2], 2 * math.pi)) < 1e-6
    steps = np.hypot(*np.diff(result.poses[:, :2], axis=0).T)
    assert steps.max() <= 0.15  # sampled at half a cell: a controller can follow it
    headings = np.diff(np.unwrap(result.poses[:, 2]))
    assert np.all(
        np.abs(headings) <= steps / problem.turn_radius_m + 1e-6
    )  # never tighter than the car turns
    assert set(np.unique(result.directions)) <= {-1.0, 1.0}
    assert result.length_m == pytest.approx(steps.sum())
    assert_exactly_free(result.poses, problem.grid, problem.footprint, 0.0)
    assert set(result.summary()) >= {"found", "length_m", "direction_changes", "plan_ms", "expansions"}


SMALL_CAR = Footprint(front_m=1.5, rear_m=0.5, width_m=1.0)  # a small robot car on small maps: quick searches
SMALL = PlannerParams(
    turn_radius_m=2.0, arc_m=0.75, xy_bin_m=0.5, closed_headings=36, heuristic_weight=1.0, shot_range_m=12.0
)


def _small_map(boxes: list[tuple[float, float, float]]) -> GridMap:
    return GridMap.from_boxes((8.0, 8.0), 0.25, [(x, y, th, 1.5, 1.0) for x, y, th in boxes])


poses = st.tuples(st.floats(1.5, 6.5), st.floats(1.5, 6.5), st.floats(-math.pi, math.pi))


@settings(
    max_examples=10, deadline=None, suppress_health_check=[HealthCheck.filter_too_much, HealthCheck.too_slow]
)
@given(
    st.lists(st.tuples(st.floats(0.5, 7.5), st.floats(0.5, 7.5), st.floats(0, math.pi)), max_size=3),
    poses,
    poses,
)
def test_both_heuristics_are_admissible_against_the_searchs_own_optimum(boxes, start, goal) -> None:  # type: ignore[no-untyped-def]
    grid = _small_map(boxes)
    cs = build_cspace(grid, SMALL_CAR, margin_m=0.0, n_headings=36)
    free = ~cs.collides(
        np.array([start[0], goal[0]]), np.array([start[1], goal[1]]), np.array([start[2], goal[2]])
    )
    assume(free.all())
    # the reference: the graph's optimum by an exhaustive search without a heuristic (Dijkstra)
    optimum = plan(cs, start, goal, SMALL, heuristic="none", exhaustive=True)
    assume(optimum.found)
    hf = HeuristicField(cs, goal, SMALL.turn_radius_m, rs_range_m=1e9)
    assert hf.kinematic(start) <= optimum.cost + 1e-6
    assert float(hf.obstacle(start[0], start[1])) <= optimum.cost + 1e-6
    # and along the optimal path: each pose's cost-to-go is at least the rest's length (measured along
    # the samples' chords, a hair short of the arcs: 0.1 % of slack)
    rest = np.concatenate([np.cumsum(np.hypot(*np.diff(optimum.poses[::-1, :2], axis=0).T))[::-1], [0.0]])
    for (x, y, th), r in zip(optimum.poses[::4], rest[::4], strict=True):
        assert float(hf.obstacle(x, y)) <= 1.001 * r + 1e-6
        assert hf.kinematic((x, y, th)) <= 1.001 * r + 1e-6


def test_weighted_search_stays_within_its_bound_of_the_optimum() -> None:
    grid = _small_map([(4.0, 4.0, 0.3), (2.5, 6.0, 1.2)])
    cs = build_cspace(grid, SMALL_CAR, margin_m=0.0, n_headings=36)
    start, goal = (1.5, 1.5, 0.0), (6.0, 6.5, math.pi)
    opt = plan(cs, start, goal, SMALL, exhaustive=True)
    assert opt.found
    for w in (1.0, 1.5, 3.0):
        params = PlannerParams(**{**SMALL.__dict__, "heuristic_weight": w})
        result = plan(cs, start, goal, params, exhaustive=True)
        assert result.found and opt.cost - 1e-6 <= result.cost <= w * opt.cost + 1e-6


def test_no_path_is_said_plainly() -> None:
    occ = np.zeros((40, 40), dtype=bool)
    occ[:, 20] = True  # a wall across the map
    cs = build_cspace(GridMap(occ, 0.25), SMALL_CAR, margin_m=0.0, n_headings=36)
    result = plan(cs, (1.5, 5.0, 0.0), (7.5, 5.0, math.pi), SMALL)
    assert not result.found and "cannot be reached" in result.reason
    result = plan(cs, (5.0, 5.0, 0.0), (7.5, 5.0, math.pi), SMALL)
    assert not result.found and "start pose" in result.reason
    with pytest.raises(ValueError, match="heuristic"):
        plan(cs, (1.5, 5.0, 0.0), (3.0, 5.0, 0.0), SMALL, heuristic="voronoi")
    with pytest.raises(ValueError, match="goal"):
        plan(cs, (1.5, 5.0, 0.0), (math.nan, 5.0, 0.0), SMALL)


def test_the_compiled_shot_check_agrees_with_sampling_and_the_cspace(lot) -> None:  # type: ignore[no-untyped-def]
    """`reeds_shepp_kernel.path_collides` (the shot's check, compiled) against `reeds_shepp.sample` then
    `CSpace.collides` on the Autoware lot: the same verdict for every Reeds-Shepp candidate between
    random poses, free and blocked both among them, and at the grid's edge."""
    from bywire.host.navigation import reeds_shepp as rs
    from bywire.host.navigation.reeds_shepp_kernel import path_collides

    problem, cs = lot
    grid = cs.grid
    ox, oy = grid.origin_xy_m
    rng = np.random.default_rng(7)
    verdicts = []
    while len(verdicts) < 600:
        a = (rng.uniform(-1, 31), rng.uniform(-1, 31), rng.uniform(-math.pi, math.pi))
        if cs.collides(np.array([a[0]]), np.array([a[1]]), np.array([a[2]]))[0] and rng.random() < 0.9:
            continue  # mostly from free poses: free paths and blocked ones both
        b = (a[0] + rng.uniform(-5, 5), a[1] + rng.uniform(-5, 5), rng.uniform(-math.pi, math.pi))
        for path in rs.all_paths(*rs.normalised(a, b, problem.turn_radius_m)):
            poses, _ = rs.sample(a, path, problem.turn_radius_m, 0.1)
            want = bool(cs.collides(poses[:, 0], poses[:, 1], poses[:, 2]).any())
            curvature, length_m = rs.segment_arrays(path, problem.turn_radius_m)
            got = path_collides(*a, curvature, length_m, 0.1, cs.blocked, ox, oy, grid.resolution_m)
            assert got == want, (a, b, path)
            verdicts.append(want)
    assert verdicts.count(False) >= 20 and verdicts.count(True) >= 20
