"""The follow QP's fast path (DAQP on the condensed problem, warm-started) against the cvxpy oracle (the
position form, written independently) on problems hypothesis draws: grids, weights, headway and
acceleration references, hard gap or none, leaders following, closing in and braking hard."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bywire.host.platoon.follow_oracle import follow_oracle
from bywire.host.platoon.follow_qp import FollowParams, FollowQP, LeaderPrediction

# The command is a variable of the condensed problem and an active-set solution is exact for its
# working set; the oracle solves the position form to 1e-10, where its command (2 x^1 / dt^2) carries
# ~3e-7 m/s^2 at dt 0.2 s (measured: 1.5e-10 typical, 3e-7 with a bound active at a^0).
ACCEL_TOL_MPS2 = 1e-4
POS_TOL_M = 1e-3
LIMIT_TOL = 1e-5  # DAQP's primal tolerance is 1e-6 on the rows (m/s, m) and bounds (m/s^2)

PROPS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])

params_st = st.builds(
    FollowParams,
    headway_s=st.sampled_from([0.3, 0.6, 1.2, 2.4]),
    reserve_m=st.floats(2.0, 25.0),
    horizon_s=st.sampled_from([2.0, 5.0, 10.0]),
    dt_s=st.sampled_from([0.1, 0.2, 0.25]),
    w_dist=st.floats(0.1, 10.0),
    w_vel=st.floats(0.1, 10.0),
    w_acc=st.floats(0.5, 20.0),
    min_gap_m=st.one_of(st.none(), st.floats(0.5, 5.0)),
    headway_ref=st.sampled_from(["host", "leader"]),
    accel_ref=st.sampled_from(["zero", "leader"]),
)


@st.composite
def situations(draw: st.DrawFn, params: FollowParams) -> tuple[float, LeaderPrediction]:
    v_max = params.speed_max_mps
    speed = draw(st.floats(0.0, v_max + 2.0))  # a little over the limit too (noise, a downhill)
    gap = draw(st.floats(3.0, 120.0))
    lead_speed = draw(st.floats(0.0, v_max))
    lead_accel = draw(st.floats(-8.0, 2.5))
    return speed, LeaderPrediction.constant_accel(gap, lead_speed, lead_accel, params)


def _limits_hold(params: FollowParams, speed: float, leader: LeaderPrediction, x: np.ndarray) -> None:
    """The paper's conditions 2 and 3 and the hard gap, read from the returned positions."""
    dt = params.dt_s
    ext = np.concatenate(([x[1] - 2.0 * dt * speed], x))  # the ghost point x^{-1}
    acc = (ext[2:] - 2.0 * ext[1:-1] + ext[:-2]) / dt**2
    assert np.all(acc >= params.accel_min_mps2 - LIMIT_TOL)
    assert np.all(acc <= params.accel_max_mps2 + LIMIT_TOL)
    mid = np.diff(x) / dt
    t_mid = params.time_grid_s()[:-1] + 0.5 * dt
    assert np.all(mid <= np.maximum(params.speed_max_mps, speed + params.accel_min_mps2 * t_mid) + LIMIT_TOL)
    assert np.all(mid >= np.minimum(params.speed_min_mps, speed + params.accel_max_mps2 * t_mid) - LIMIT_TOL)
    if params.min_gap_m is not None:
        assert np.all(x[1:] <= leader.positions_m[1:] - params.min_gap_m + LIMIT_TOL)


@PROPS
@given(data=st.data(), params=params_st)
def test_fast_path_agrees_with_the_oracle(data: st.DataObject, params: FollowParams) -> None:
    speed, leader = data.draw(situations(params))
    fast = FollowQP(params).solve(speed, leader)
    oracle = follow_oracle(params, speed, leader)
    assert fast.feasible == oracle.feasible, (fast.status, oracle.status)
    if not fast.feasible:
        assert fast.accel_cmd_mps2 == params.accel_min_mps2
        return
    assert abs(fast.accel_cmd_mps2 - oracle.accel_cmd_mps2) <= ACCEL_TOL_MPS2
    assert np.max(np.abs(fast.positions_m - oracle.positions_m)) <= POS_TOL_M
    _limits_hold(params, speed, leader, fast.positions_m)
    dt = params.dt_s
    x = fast.positions_m
    assert fast.accel_cmd_mps2 == pytest.approx(2.0 * (x[1] - speed * dt) / dt**2, abs=1e-9)
    assert fast.accel_next_mps2 == pytest.approx((x[2] - 2.0 * x[1] + x[0]) / dt**2, abs=1e-9)


@PROPS
@given(data=st.data(), params=params_st, n=st.integers(2, 6))
def test_a_warm_start_never_changes_the_answer(data: st.DataObject, params: FollowParams, n: int) -> None:
    """One `FollowQP` through a run of problems (each solve starting from the working set the last one
    left, infeasible ones among them) answers each as a fresh one does."""
    warm = FollowQP(params)
    for _ in range(n):
        speed, leader = data.draw(situations(params))
        w = warm.solve(speed, leader)
        c = FollowQP(params).solve(speed, leader)
        assert w.feasible == c.feasible, (w.status, c.status)
        assert w.accel_cmd_mps2 == pytest.approx(c.accel_cmd_mps2, abs=1e-7)
        assert np.allclose(w.positions_m, c.positions_m, atol=1e-6)
