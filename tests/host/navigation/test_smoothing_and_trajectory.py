"""The searched path made drivable: smoothing (conjugate gradient) never moves a stretch into collision
or into a turn tighter than the car's, keeps the start, cusps and goal; the ruckig speed profile drives
each stretch from standstill to standstill within the speed, acceleration and jerk limits, reversing
where the path reverses."""

from __future__ import annotations

import math

import numpy as np
import pytest
from planning_checks import assert_exactly_free

from bywire.host.navigation.cspace import build_cspace
from bywire.host.navigation.grid_map import GridMap
from bywire.host.navigation.hybrid_astar import PlannerParams, plan
from bywire.host.navigation.reference_maps import autoware_lot
from bywire.host.navigation.smoothing import (
    SmoothingParams,
    _curvature,
    _resample,
    smooth_path,
    split_at_cusps,
)
from bywire.host.navigation.trajectory import SpeedLimits, launch_profile, speed_profile


@pytest.fixture(scope="module")
def planned():  # type: ignore[no-untyped-def]
    problem = autoware_lot()
    cs = build_cspace(problem.grid, problem.footprint, margin_m=0.0)
    plans = [
        plan(cs, problem.start, g, PlannerParams(turn_radius_m=problem.turn_radius_m))
        for _, g in problem.goals
    ]
    return problem, cs, plans


def _roughness(xy: np.ndarray) -> float:
    r = _resample(xy, 0.25)
    dd = r[:-2] - 2 * r[1:-1] + r[2:]
    return float(np.sum(dd * dd))


def test_smoothing_keeps_the_path_free_and_drivable(planned) -> None:  # type: ignore[no-untyped-def]
    problem, cs, plans = planned
    smoothed_any = 0
    for result in plans:
        poses, dirs, counts = smooth_path(cs, result.poses, result.directions, problem.turn_radius_m)
        smoothed_any += counts["smoothed"]
        assert np.allclose(poses[0, :2], result.poses[0, :2])
        assert np.allclose(poses[-1, :2], result.poses[-1, :2])
        before, after = split_at_cusps(result.directions), split_at_cusps(dirs)
        assert len(before) == len(after)  # the same stretches, in the same directions
        for (a0, a1), (b0, b1) in zip(before, after, strict=True):
            assert result.directions[a1] == dirs[b1]
            assert np.allclose(result.poses[a0, :2], poses[b0, :2])  # the cusps stay
            assert np.allclose(result.poses[a1, :2], poses[b1, :2])
            part = poses[b0 : b1 + 1, :2]
            searched = result.poses[a0 : a1 + 1, :2]
            if part.shape != searched.shape or not np.allclose(part, searched):  # this stretch was smoothed
                assert np.all(_curvature(part) <= 1.05 / problem.turn_radius_m + 1e-9)
                assert _roughness(part) < _roughness(result.poses[a0 : a1 + 1, :2])
        assert_exactly_free(poses, problem.grid, problem.footprint, 0.0)
    assert smoothed_any >= 4


def test_smoothing_that_would_collide_keeps_the_searched_stretch() -> None:
    occ = np.zeros((80, 80), dtype=bool)
    occ[30:50, 30:50] = True  # a block the path bends round
    grid = GridMap(occ, 0.25)
    from bywire.host.navigation.cspace import Footprint

    car = Footprint(1.5, 0.5, 1.0)
    cs = build_cspace(grid, car, margin_m=0.0, n_headings=36)
    result = plan(cs, (3.0, 10.0, 0.0), (17.0, 10.5, 0.0), PlannerParams(turn_radius_m=2.0, reverse=False))
    assert result.found
    # a "smoother" that only straightens (no obstacle term, no fidelity) would cut the corner
    reckless = SmoothingParams(w_obstacle=0.0, w_fidelity=0.0, w_smooth=1.0, max_iterations=2000)
    poses, _, _ = smooth_path(cs, result.poses, result.directions, 2.0, reckless)
    assert not cs.collides(poses[:, 0], poses[:, 1], poses[:, 2]).any()
    careful, _, _ = smooth_path(cs, result.poses, result.directions, 2.0)
    assert not cs.collides(careful[:, 0], careful[:, 1], careful[:, 2]).any()


def test_the_speed_profile_is_jerk_limited_rest_to_rest(planned) -> None:  # type: ignore[no-untyped-def]
    problem, cs, plans = planned
    lim = SpeedLimits(speed_mps=2.5, accel_mps2=1.0, jerk_mps3=2.0, lateral_accel_mps2=1.0, cusp_pause_s=1.0)
    for result in plans:
        poses, dirs, _ = smooth_path(cs, result.poses, result.directions, problem.turn_radius_m)
        tr = speed_profile(poses, dirs, lim, dt_s=0.02)
        assert tr.speed_mps[0] == pytest.approx(0.0, abs=1e-9) and tr.speed_mps[-1] == pytest.approx(
            0.0, abs=1e-9
        )
        assert np.all(np.abs(tr.speed_mps) <= lim.speed_mps + 1e-6)
        assert np.all(np.abs(tr.accel_mps2) <= lim.accel_mps2 + 1e-6)
        dt = np.diff(tr.t_s)
        ok = dt > 1e-3
        jerk = np.abs(np.diff(tr.accel_mps2)[ok] / dt[ok])
        assert np.all(jerk <= lim.jerk_mps3 + 1e-3)
        assert np.all(np.diff(tr.t_s) >= 0.0)
        assert math.hypot(tr.x_m[-1] - poses[-1, 0], tr.y_m[-1] - poses[-1, 1]) < 1e-6
        # reversing stretches are driven backwards, and the car stands at each cusp
        stretches = split_at_cusps(dirs)
        if len(stretches) > 1:
            assert (tr.speed_mps < -0.1).any() and (tr.speed_mps > 0.1).any()
            assert np.sum(np.isclose(tr.speed_mps, 0.0, atol=1e-9)) >= 2 * len(stretches)
    with pytest.raises(ValueError, match="jerk_mps3"):
        speed_profile(plans[0].poses, plans[0].directions, SpeedLimits(jerk_mps3=0.0))


def test_a_legs_drive_off_follows_the_jerk_limited_profile_by_speed_reached() -> None:
    """What the behaviour asks on a manoeuvre's leg: ruckig's drive-off, looked up by the speed reached.
    Integrating the lookup (the car doing what is asked) reaches the target without ever exceeding the
    acceleration or the jerk limit, starts from standstill (the lead), and asks nothing at the target."""
    lim = SpeedLimits(accel_mps2=1.0, jerk_mps3=2.0)
    prof = launch_profile(2.2, lim)
    assert prof.accel_at(0.0, lead_s=0.0) == pytest.approx(0.0, abs=1e-9)  # rest: a jerk-limited start
    assert prof.accel_at(0.0, lead_s=0.1) == pytest.approx(2.0 * 0.1, rel=0.05)
    assert prof.accel_at(2.2, lead_s=0.1) == 0.0 and prof.accel_at(3.0, lead_s=0.1) == 0.0
    v, a_prev, dt = 0.0, 0.0, 0.01
    accels = []
    for _ in range(1000):
        a = prof.accel_at(v, lead_s=0.1)
        accels.append(a)
        assert abs(a - a_prev) <= lim.jerk_mps3 * (dt + 0.1) + 1e-9
        v += a * dt
        a_prev = a
    assert v == pytest.approx(2.2, abs=0.05) and max(accels) <= lim.accel_mps2 + 1e-9
    assert launch_profile(2.21, lim) is prof  # cached at the caps' resolution
    with pytest.raises(ValueError, match="target_mps"):
        launch_profile(0.0, lim)
