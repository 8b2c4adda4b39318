"""The world model's fast paths, held bit for bit to the forms they replace (SIL must replay exactly):
the CYRA prediction at one time on Python floats against its array form, the CYRA transition matrix
written out entry by entry against its matrix products, a vehicle state's
lazily computed position 1-sigma against the covariance prediction done at once, and the scalar
foot-point arc length against the vectorised projection."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bywire.host.geo import LocalFrame
from bywire.host.world.lanemap import record_lane
from bywire.host.world.vehicles import (
    VehicleManagerConfig,
    VehicleMessage,
    VehicleTrack,
    _transition,
    _transition_matrices,
    cyra_predict,
    cyra_predict_scalar,
)

FRAME = LocalFrame(51.4708, 5.6230)
_reals = st.floats(-1e4, 1e4, allow_nan=False, allow_infinity=False)


def _bits(a: np.ndarray) -> bytes:
    return np.ascontiguousarray(a, dtype=np.float64).tobytes()


@settings(max_examples=400, deadline=None)
@given(
    st.lists(_reals, min_size=6, max_size=6),
    st.one_of(st.floats(1e-9, 10.0), st.sampled_from([1e-3, 0.02, 0.1, 0.5 * (1.0 - math.sqrt(0.6))])),
)
def test_transition_written_out_equals_the_matrix_products(state: list[float], dt: float) -> None:
    x = np.array(state)
    assert _bits(_transition(x, dt)) == _bits(_transition_matrices(x, dt))
    x[3] = 0.0  # a standing car: the products' zeros carry signs
    x[2] = -0.0
    assert _bits(_transition(x, dt)) == _bits(_transition_matrices(x, dt))


def test_transition_with_non_finite_state_takes_the_matrix_form() -> None:
    x = np.array([0.0, 0.0, 0.3, math.inf, 0.0, 0.0])
    with np.errstate(invalid="ignore"):
        assert np.array_equal(_transition(x, 0.1), _transition_matrices(x, 0.1), equal_nan=True)


def _message(t: float, x: float, y: float, psi: float, v: float, w: float, a: float) -> VehicleMessage:
    return VehicleMessage(7, t, x, y, psi, v, w, a)


@settings(max_examples=150, deadline=None)
@given(
    st.floats(-500.0, 500.0),
    st.floats(-math.pi, math.pi),
    st.floats(0.0, 40.0),
    st.floats(-0.3, 0.3),
    st.floats(-6.0, 3.0),
    st.floats(-0.05, 1.5),
)
def test_lazy_position_std_equals_the_prediction_at_once(
    x: float, psi: float, v: float, w: float, a: float, ahead_s: float
) -> None:
    track = VehicleTrack(_message(10.0, x, 0.0, psi, v, w, a), 10.0, VehicleManagerConfig())
    track.update(_message(10.1, x + v * 0.1 * math.cos(psi), v * 0.1 * math.sin(psi), psi, v, w, a), 10.12)
    t_query = 10.1 + ahead_s
    _, P = track._predict(t_query - track.t_s)
    expected = math.sqrt(max(float(np.linalg.eigvalsh(P[:2, :2])[-1]), 0.0))
    state = track.state_at(t_query)
    # A message applied between the state and the question changes nothing: the state keeps its own.
    track.update(_message(10.2, x + 50.0, 3.0, psi, v + 1.0, w, a), 10.22)
    assert state.position_std_m.hex() == expected.hex()
    assert state.position_std_m is state.position_std_m  # computed once


def _curvy_map(seed: int):  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, 400)
    amp, waves = rng.uniform(0.0, 40.0), rng.uniform(0.2, 2.0)
    track = np.column_stack((300.0 * t, amp * np.sin(2.0 * math.pi * waves * t)))
    return record_lane(track + rng.normal(0.0, 0.03, track.shape), FRAME).with_offset_lane(0, 3.5, 1)


_MAPS = [_curvy_map(seed) for seed in range(3)]


@settings(max_examples=400, deadline=None)
@given(
    st.integers(0, len(_MAPS) - 1),
    st.integers(0, 1),
    st.floats(-30.0, 330.0),
    st.floats(-8.0, 8.0),
)
def test_scalar_arc_length_equals_the_vectorised_projection(
    which: int, lane_id: int, along: float, side: float
) -> None:
    lane_map = _MAPS[which]
    lane = lane_map.lane(lane_id)
    k = min(max(int(along / 0.5), 0), len(lane.points_m) - 1)
    x, y = float(lane.points_m[k, 0]) + 0.37 * side, float(lane.points_m[k, 1]) + side
    if along < 0.0 or along > 300.0:  # before the start and past the end: the extrapolated foot points
        x += along - min(max(along, 0.0), 300.0)
    s_path = float(lane.path.project_points(x, y)[0][0])
    assert lane.path.project_point_s(x, y).hex() == s_path.hex()
    s_map = float(lane_map.project(lane_id, np.array([[x, y]])).s_m[0])
    assert lane_map.project_s(lane_id, x, y).hex() == s_map.hex()


def test_scalar_arc_length_of_a_vertex_and_a_non_finite_point() -> None:
    lane_map = _MAPS[0]
    lane = lane_map.lane(0)
    for k in (0, 1, 57, len(lane.points_m) - 2, len(lane.points_m) - 1):
        x, y = (float(v) for v in lane.points_m[k])
        assert lane_map.project_s(0, x, y) == float(lane_map.project(0, np.array([[x, y]])).s_m[0])
    # A non-finite point takes the vectorised path and raises its error.
    with pytest.raises(ValueError, match="finite"):
        lane_map.project(0, np.array([[math.nan, 0.0]]))
    with pytest.raises(ValueError, match="finite"):
        lane_map.project_s(0, math.nan, 0.0)


@settings(max_examples=1500, deadline=None)
@given(
    st.floats(-1e5, 1e5),
    st.floats(-1e5, 1e5),
    st.one_of(st.floats(-7.0, 7.0), st.sampled_from([0.0, math.pi, -math.pi, 0.5 * math.pi])),
    st.one_of(st.floats(-1.0, 60.0), st.sampled_from([0.0, 36.0, 130.0 / 3.6])),
    st.one_of(st.floats(-1.0, 1.0), st.floats(-1e-4, 1e-4), st.just(0.0)),
    st.one_of(st.floats(-9.0, 5.0), st.just(0.0)),
    st.one_of(st.floats(-0.5, 12.0), st.just(0.0), st.floats(0.0, 1e-3)),
    st.sampled_from([130.0 / 3.6, 27.0, 36.0]),
)
def test_scalar_cyra_equals_the_array_form(
    x: float, y: float, psi: float, v: float, w: float, a: float, dt: float, v_max: float
) -> None:
    p = cyra_predict(x, y, psi, v, w, a, np.asarray(dt, dtype=np.float64), v_max)
    expected = (p.x_m, p.y_m, p.heading_rad, p.speed_mps, p.accel_mps2)
    got = cyra_predict_scalar(x, y, psi, v, w, a, dt, v_max)
    assert [float(e).hex() for e in expected] == [g.hex() for g in got]


def test_scalar_cyra_with_a_non_finite_input_takes_the_array_form() -> None:
    with np.errstate(invalid="ignore"):
        got = cyra_predict_scalar(0.0, 0.0, 0.0, 10.0, math.nan, 0.0, 1.0)
        p = cyra_predict(0.0, 0.0, 0.0, 10.0, math.nan, 0.0, np.asarray(1.0))
    assert np.array_equal(
        np.array(got), np.array([p.x_m, p.y_m, p.heading_rad, p.speed_mps, p.accel_mps2]), equal_nan=True
    )


@settings(max_examples=200, deadline=None)
@given(
    st.integers(0, len(_MAPS) - 1),
    st.integers(0, 1),
    st.lists(st.tuples(st.floats(-40.0, 340.0), st.floats(-8.0, 8.0)), min_size=1, max_size=60),
)
def test_arc_lengths_alone_equal_the_full_projection(
    which: int, lane_id: int, points: list[tuple[float, float]]
) -> None:
    """A predicted trajectory's arc lengths (before the start and past the end too)."""
    lane_map = _MAPS[which]
    xy = np.array([(along, side + 0.1 * along) for along, side in points])
    assert _bits(lane_map.project_s_many(lane_id, xy)) == _bits(lane_map.project(lane_id, xy).s_m)
    path = lane_map.lane(lane_id).path
    assert _bits(path.project_points_s(xy[:, 0], xy[:, 1])) == _bits(
        path.project_points(xy[:, 0], xy[:, 1])[0]
    )
