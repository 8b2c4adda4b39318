"""Reeds-Shepp paths (seed 000 Sec. 10.3.1): every candidate we return drives exactly to the goal (our
own integration of its arcs); the shortest is never longer than the paths of an independent
implementation (rsplan, MIT) and equals OMPL's ReedsSheppStateSpace distance (BSD, a C++ library)."""

from __future__ import annotations

import math
import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bywire.host.navigation import reeds_shepp as rs

coord = st.floats(-15.0, 15.0, allow_nan=False)
angle = st.floats(-math.pi, math.pi, allow_nan=False)


def _poses(n: int, seed: int) -> list[tuple[tuple[float, float, float], tuple[float, float, float]]]:
    rnd = random.Random(seed)

    def pose() -> tuple[float, float, float]:
        return (rnd.uniform(-12, 12), rnd.uniform(-12, 12), rnd.uniform(-math.pi, math.pi))

    return [(pose(), pose()) for _ in range(n)]


@settings(max_examples=300, deadline=None)
@given(coord, coord, angle, coord, coord, angle, st.floats(1.0, 8.0))
def test_every_candidate_drives_to_the_goal(x0, y0, t0, x1, y1, t1, radius) -> None:  # type: ignore[no-untyped-def]
    start, goal = (x0, y0, t0), (x1, y1, t1)
    paths = rs.all_paths(*rs.normalised(start, goal, radius))
    assert paths, "CSC always has a solution"
    for path in paths:
        poses, signs = rs.sample(start, path, radius, 0.05)
        end = poses[-1]
        assert math.hypot(end[0] - x1, end[1] - y1) < 1e-6 * max(1.0, radius)
        assert abs(math.remainder(end[2] - t1, 2 * math.pi)) < 1e-6
        steps = poses[1:, :2] - poses[:-1, :2]
        assert (abs(steps).max() if len(steps) else 0.0) <= 0.05 + 1e-9  # sampled as asked
        assert set(signs.tolist()) <= {1.0, -1.0}
    best = min(p.length for p in paths)
    assert rs.shortest_length(start, goal, radius) == pytest.approx(best * radius, abs=1e-9)
    assert rs.shortest_path(start, goal, radius).length == pytest.approx(best, abs=1e-12)


@settings(max_examples=500, deadline=None)
@given(coord, coord, angle)
def test_the_compiled_words_equal_the_python_reference(x, y, phi) -> None:  # type: ignore[no-untyped-def]
    """`reeds_shepp_kernel` (numba) against `_solutions_reference` (Python): the same words, mirrors and
    directions in the same order, lengths and (t, u, v) within 1e-12 (the C library's sin, cos and hypot
    against CPython's differ in the last bit), and the shortest length the same."""
    ours, ref = rs._solutions(x, y, phi), rs._solutions_reference(x, y, phi)
    assert [sol[1:3] + sol[4:] for sol in ours] == [sol[1:3] + sol[4:] for sol in ref]
    for a, b in zip(ours, ref, strict=True):
        assert a[0] == pytest.approx(b[0], rel=1e-12, abs=1e-12)
        assert a[3] == pytest.approx(b[3], rel=1e-12, abs=1e-12)
    best = min(sol[0] for sol in ref)
    assert rs.shortest_normalised_length(x, y, phi) == pytest.approx(best, rel=1e-12, abs=1e-12)


@given(st.floats(-1e7, 1e7, allow_nan=False))
def test_the_compiled_remainder_is_ieees(a: float) -> None:
    from bywire.host.navigation.reeds_shepp_kernel import _wrap

    for x in (a, math.pi, -math.pi, 3 * math.pi, 0.0, -0.0):
        ours, ref = _wrap(x), math.remainder(x, 2 * math.pi)
        assert ours == ref and math.copysign(1, ours) == math.copysign(1, ref)


def test_the_shortest_is_never_longer_than_an_independent_implementations() -> None:
    rsplan = pytest.importorskip("rsplan", reason="rsplan (the bench extra) is not installed")
    longer = 0
    for start, goal in _poses(300, 1):
        theirs = rsplan.path(start, goal, 2.0, 0.0, 0.05)
        their_len = sum(abs(seg.length) for seg in theirs.segments)
        ours = rs.shortest_length(start, goal, 2.0)
        assert ours <= their_len + 1e-6
        longer += their_len > ours + 1e-3
    # rsplan leaves out some of the 48 words: it is longer on a good share of random problems
    assert longer > 30


def test_the_shortest_equals_ompls_reeds_shepp_distance() -> None:
    ob = pytest.importorskip("ompl.base", reason="OMPL (the bench extra) is not installed")
    space = ob.ReedsSheppStateSpace(2.5)
    bounds = ob.RealVectorBounds(2)
    bounds.setLow(-100)
    bounds.setHigh(100)
    space.setBounds(bounds)
    a, b = space.allocState(), space.allocState()
    for start, goal in _poses(2000, 2):
        a.setX(start[0]), a.setY(start[1]), a.setYaw(start[2])
        b.setX(goal[0]), b.setY(goal[1]), b.setYaw(goal[2])
        assert rs.shortest_length(start, goal, 2.5) == pytest.approx(space.distance(a, b), abs=1e-9)


def test_known_paths() -> None:
    # straight ahead and straight back; a quarter circle left
    assert rs.shortest_length((0, 0, 0), (7, 0, 0), 3.0) == pytest.approx(7.0)
    assert rs.shortest_length((0, 0, 0), (-7, 0, 0), 3.0) == pytest.approx(7.0)
    p = rs.shortest_path((0, 0, 0), (3, 3, math.pi / 2), 3.0)
    assert [s.steer for s in p.segments if abs(s.length) > 1e-9] == ["L"]
    assert p.length * 3.0 == pytest.approx(3.0 * math.pi / 2)
    assert rs.shortest_path((0, 0, 0), (-7, 0, 0), 3.0).direction_changes == 0
    with pytest.raises(ValueError, match="radius_m"):
        rs.shortest_length((0, 0, 0), (1, 0, 0), 0.0)
