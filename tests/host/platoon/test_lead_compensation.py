"""Delay-compensated leader prediction (host/platoon/lead_compensation.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bywire.host.platoon.follow_qp import FollowParams, LeaderPrediction
from bywire.host.platoon.lead_compensation import (
    JerkEstimator,
    LeadCompensationParams,
    cap_prediction_speed,
    compensate_prediction,
)

P = LeadCompensationParams(lead_s=0.3, jerk_tau_s=0.2)


def test_jerk_of_a_ramp_converges_to_its_slope() -> None:
    est = JerkEstimator(P)
    jerk = 0.0
    for k in range(40):  # 10 Hz updates of an acceleration ramp at -2 m/s^3
        jerk = est.update(0.1 * k, {7: -2.0 * 0.1 * k})[7]
    assert jerk == pytest.approx(-2.0, abs=1e-6)


def test_repeated_update_changes_nothing_and_absent_vehicles_are_forgotten() -> None:
    est = JerkEstimator(P)
    est.update(0.0, {1: 0.0, 2: 0.0})
    j1 = est.update(0.1, {1: 0.5, 2: 0.0})
    assert j1[1] > 0.0 and j1[2] == 0.0
    assert est.update(0.1, {1: 0.5, 2: 0.0}) == j1  # the same world update seen by a second release
    assert est.update(0.2, {1: 0.5})[1] < j1[1]  # constant acceleration: the jerk decays
    assert est.update(0.3, {2: 3.0})[2] == 0.0  # 2 was absent: a fresh start, not a 30 m/s^3 jerk


def test_a_gap_in_reports_restarts_the_estimate() -> None:
    est = JerkEstimator(P)
    est.update(0.0, {1: 0.0})
    assert est.update(1.0, {1: 2.0})[1] == 0.0  # 1 s without a report: not a jerk


def test_jerk_is_bounded() -> None:
    est = JerkEstimator(P)
    est.update(0.0, {1: -8.0})
    assert est.update(0.01, {1: 3.0})[1] == P.max_jerk_mps3


def test_no_jerk_leaves_the_prediction_alone() -> None:
    fp = FollowParams()
    pred = LeaderPrediction.constant_accel(25.0, 20.0, -1.0, fp)
    pos, spd = compensate_prediction(fp.time_grid_s(), pred.positions_m, pred.speeds_mps, -1.0, 0.0, P, 30.0)
    assert pos is pred.positions_m and spd is pred.speeds_mps


def test_compensation_equals_the_constant_acceleration_prediction_at_the_lead_acceleration() -> None:
    fp = FollowParams()
    t = fp.time_grid_s()
    a, jerk = -0.5, -2.0  # braking harder: in 0.3 s it will be at -1.1 m/s^2
    pred = LeaderPrediction.constant_accel(25.0, 20.0, a, fp)
    pos, spd = compensate_prediction(t, pred.positions_m, pred.speeds_mps, a, jerk, P, fp.speed_max_mps)
    want = LeaderPrediction.constant_accel(25.0, 20.0, a + P.lead_s * jerk, fp)
    np.testing.assert_allclose(spd, want.speeds_mps, atol=1e-9)
    np.testing.assert_allclose(pos, want.positions_m, atol=1e-9)


def test_compensated_speeds_stay_within_zero_and_the_limit() -> None:
    fp = FollowParams()
    t = fp.time_grid_s()
    pred = LeaderPrediction.constant_accel(25.0, 3.0, -1.0, fp)  # stops after 3 s
    pos, spd = compensate_prediction(t, pred.positions_m, pred.speeds_mps, -1.0, -10.0, P, 27.8)
    assert spd.min() == 0.0 and np.all(np.diff(pos) >= -1e-12)  # it stops earlier, never backs up
    assert pos[-1] < pred.positions_m[-1]


@settings(max_examples=200, deadline=None)
@given(
    gap=st.floats(0.0, 200.0),
    v=st.floats(0.0, 40.0),
    a=st.floats(-8.0, 3.0),
    jerk=st.floats(-1e3, 1e3) | st.sampled_from([math.nan, math.inf, -math.inf]),
)
def test_compensation_is_bounded_by_the_acceleration_bounds(
    gap: float, v: float, a: float, jerk: float
) -> None:
    fp = FollowParams()
    t = fp.time_grid_s()
    pred = LeaderPrediction.constant_accel(gap, v, a, fp)
    pos, spd = compensate_prediction(t, pred.positions_m, pred.speeds_mps, a, jerk, P, fp.speed_max_mps)
    assert np.all(np.isfinite(pos)) and np.all(np.isfinite(spd))
    lo, hi = P.accel_bounds_mps2
    # never further from the uncompensated prediction than the bounded acceleration change allows
    span = max(hi - a, a - lo)
    assert np.all(np.abs(spd - pred.speeds_mps) <= span * t + 1e-9)


@pytest.mark.parametrize(
    "kw",
    [
        {"lead_s": -0.1},
        {"lead_s": 3.0},
        {"jerk_tau_s": 0.0},
        {"max_jerk_mps3": 0.0},
        {"accel_bounds_mps2": (1, 2)},
    ],
)
def test_bad_parameters_are_refused(kw: dict[str, object]) -> None:
    with pytest.raises(ValueError):
        LeadCompensationParams(**kw)  # type: ignore[arg-type]


def test_capping_the_speed_equals_the_prediction_with_our_limit() -> None:
    loose, ours = FollowParams(speed_max_mps=40.0), FollowParams(speed_max_mps=27.78)
    t = ours.time_grid_s()
    fast = LeaderPrediction.constant_accel(20.0, 23.0, 1.1, loose)  # through 100 km/h after ~4.3 s
    pos, spd = cap_prediction_speed(t, fast.positions_m, fast.speeds_mps, ours.speed_max_mps)
    want = LeaderPrediction.constant_accel(20.0, 23.0, 1.1, ours)
    np.testing.assert_allclose(spd, want.speeds_mps, atol=1e-12)
    # the trapezoid cuts the corner in the one step where the limit is reached: millimetres
    np.testing.assert_allclose(pos, want.positions_m, atol=0.01)
    slow = LeaderPrediction.constant_accel(20.0, 20.0, 0.0, ours)
    same = cap_prediction_speed(t, slow.positions_m, slow.speeds_mps, ours.speed_max_mps)
    assert same[0] is slow.positions_m and same[1] is slow.speeds_mps


def test_the_follow_qp_no_longer_chases_a_leader_through_our_limit() -> None:
    from bywire.host.platoon.follow_qp import FollowQP

    ours = FollowParams(headway_s=0.6, reserve_m=8.0, min_gap_m=2.0, speed_max_mps=27.78, accel_ref="leader")
    loose = FollowParams(speed_max_mps=130.0 / 3.6)
    fast = LeaderPrediction.constant_accel(21.33, 23.06, 1.1, loose)  # as the world model predicts it
    qp = FollowQP(ours)
    chased = qp.solve(22.61, fast).accel_cmd_mps2
    cap = cap_prediction_speed(ours.time_grid_s(), fast.positions_m, fast.speeds_mps, ours.speed_max_mps)
    capped = qp.solve(22.61, LeaderPrediction(*cap)).accel_cmd_mps2
    # the heat's case (seed 12, t = 106.6 s): 1.31 m/s^2 chasing, ~0.94 with the leader capped like us
    assert chased > capped + 0.25 and capped == pytest.approx(0.94, abs=0.05)
