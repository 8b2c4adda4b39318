"""Local coordinates (geo.py) and smooth paths (path.py): known answers on circles and lines, heading and
curvature consistency, projection round trips (with and without a hint), stubs, joins, offsets."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from pyproj import Geod
from roadnet_helpers import network

from bywire.host.roadnet.curves import (
    SHARPNESS_MAX_1PM2,
    connector,
    drivable_connector,
    path_through,
    smooth_curve,
)
from bywire.host.roadnet.geo import PlanarFrame, TransverseMercator, frame_for
from bywire.host.roadnet.path import DEFAULT_STEP_M, Path, PathPoint, concat, wrap_angle

# ---------------------------------------------------------------------------------------------- geo


def test_frame_origin_axes_and_round_trip() -> None:
    frame = TransverseMercator(34.5833, -117.3667)
    x, y = frame.to_xy(34.5833, -117.3667)
    assert abs(float(x)) < 1e-9 and abs(float(y)) < 1e-9
    # 0.001 deg north is ~110.9 m north at 34.6 deg latitude, straight up the y axis
    x, y = frame.to_xy(34.5843, -117.3667)
    assert abs(float(x)) < 1e-6 and float(y) == pytest.approx(110.92, abs=0.05)
    # east is +x
    x, y = frame.to_xy(34.5833, -117.3657)
    assert float(x) == pytest.approx(91.7, abs=0.2) and abs(float(y)) < 0.01
    lat, lon = frame.to_latlon(*frame.to_xy([34.57, 34.60], [-117.38, -117.35]))
    np.testing.assert_allclose(lat, [34.57, 34.60], atol=1e-10)
    np.testing.assert_allclose(lon, [-117.38, -117.35], atol=1e-10)


def test_frame_distances_match_geodesics() -> None:
    net = network("darpa_nqe/nqe_rndf.rdf")
    frame = frame_for(net)
    pts = list(net.waypoints())
    lat = np.array([p.lat for p in pts])
    lon = np.array([p.lon for p in pts])
    x, y = frame.to_xy(lat, lon)
    first = pts[0]
    assert abs(x[0]) < 1e-6 and abs(y[0]) < 1e-6  # centred on the first waypoint
    geod = Geod(ellps="WGS84")
    rng = np.random.default_rng(3)
    for _ in range(50):
        i, j = rng.integers(0, len(pts), size=2)
        _, _, d = geod.inv(lon[i], lat[i], lon[j], lat[j])
        # tmerc scale error ~ (x / R)^2 / 2 < 1e-7 within the NQE's 2 km
        assert math.hypot(x[i] - x[j], y[i] - y[j]) == pytest.approx(d, abs=2e-3 + 2e-6 * d)
    assert first.id.segment == 1


def test_planar_frame_is_identity_and_bad_origin_rejected() -> None:
    assert isinstance(frame_for(network("cornell_samples/Sample3.rndf")), PlanarFrame)
    x, y = PlanarFrame().to_xy([1.5], [-2.0])
    assert (float(x[0]), float(y[0])) == (1.5, -2.0)
    with pytest.raises(ValueError):
        TransverseMercator(95.0, 0.0)


# ---------------------------------------------------------------------------------------------- paths


def circle_points(
    radius_m: float, start_rad: float, sweep_rad: float, n: int
) -> tuple[np.ndarray, np.ndarray]:
    a = start_rad + np.linspace(0.0, sweep_rad, n)
    return radius_m * np.cos(a), radius_m * np.sin(a)


def test_straight_line_known_answers() -> None:
    p = path_through([0.0, 30.0, 100.0], [0.0, 30.0, 100.0])
    assert p.length_m == pytest.approx(100.0 * math.sqrt(2.0), rel=1e-12)
    np.testing.assert_allclose(p.heading_rad, math.pi / 4, atol=1e-12)
    np.testing.assert_allclose(p.curvature_1pm, 0.0, atol=1e-12)
    assert np.max(np.diff(p.s_m)) <= DEFAULT_STEP_M + 1e-9
    mid = p.point_at(p.length_m / 2)
    assert (mid.x_m, mid.y_m) == pytest.approx((50.0, 50.0))


def test_circle_curvature_heading_and_length() -> None:
    r = 20.0
    x, y = circle_points(r, 0.0, math.pi, 37)  # counter-clockwise: a left turn, curvature +1/r
    p = path_through(x, y)
    inner = (p.s_m > 0.15 * p.length_m) & (p.s_m < 0.85 * p.length_m)
    np.testing.assert_allclose(p.curvature_1pm[inner], 1.0 / r, rtol=0.01)
    # a cubic through sparse points of a circle ripples around 1/r between them: 15 deg apart, +-7 %
    coarse = path_through(*circle_points(r, 0.0, math.pi, 13))
    inner_c = (coarse.s_m > 0.15 * coarse.length_m) & (coarse.s_m < 0.85 * coarse.length_m)
    np.testing.assert_allclose(coarse.curvature_1pm[inner_c], 1.0 / r, rtol=0.07)
    # heading is the tangent of the circle: polar angle + 90 deg
    polar = np.arctan2(p.y_m, p.x_m)
    err = (p.heading_rad - (polar + math.pi / 2) + math.pi) % (2 * math.pi) - math.pi
    assert np.max(np.abs(err[inner])) < 0.01
    assert p.length_m == pytest.approx(math.pi * r, rel=0.005)
    # length is never shorter than the polyline through the points
    assert p.length_m >= float(np.sum(np.hypot(np.diff(x), np.diff(y))))


def test_heading_and_curvature_agree_with_the_samples() -> None:
    x = np.array([0.0, 20.0, 45.0, 60.0, 70.0, 72.0, 90.0])
    y = np.array([0.0, 5.0, -3.0, 10.0, 30.0, 45.0, 60.0])
    p = path_through(x, y)
    ds = np.diff(p.s_m)
    chord_heading = np.arctan2(np.diff(p.y_m), np.diff(p.x_m))
    mid_heading = np.unwrap(p.heading_rad)[:-1] + 0.5 * np.diff(np.unwrap(p.heading_rad))
    assert np.max(np.abs(wrap_vec(chord_heading - mid_heading))) < 2e-3
    dtheta = np.diff(np.unwrap(p.heading_rad)) / ds
    mid_k = 0.5 * (p.curvature_1pm[1:] + p.curvature_1pm[:-1])
    assert np.max(np.abs(dtheta - mid_k)) < 2e-3
    # the curve passes through its points, at the sample indices smooth_curve reports
    _, knots = smooth_curve(x, y)
    np.testing.assert_allclose(p.x_m[knots], x, atol=1e-9)
    np.testing.assert_allclose(p.y_m[knots], y, atol=1e-9)


def wrap_vec(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def test_near_duplicate_points_are_merged() -> None:
    path, knots = smooth_curve([0, 10, 10.05, 20], [0, 0, 0.0, 5], merge_m=0.5)
    assert knots[1] == knots[2] and list(knots) == sorted(knots)
    with pytest.raises(ValueError):
        smooth_curve([1, 1.0001], [2, 2.0])
    with pytest.raises(ValueError):
        smooth_curve([0, 1], [0, float("nan")])
    assert path.length_m > 20.0


def test_point_at_and_sample() -> None:
    x, y = circle_points(15.0, -0.5, 2.0, 9)
    p = path_through(x, y)
    assert p.point_at(-5.0) == p.start and p.point_at(1e9).s_m == p.length_m
    assert p.point_at(p.length_m)[:2] == pytest.approx(p.end[:2])
    s = np.linspace(0.0, p.length_m, 37)
    xs, ys, hs, ks = p.sample(s)
    for i in (0, 11, 36):
        q = p.point_at(float(s[i]))
        assert (q.x_m, q.y_m, q.curvature_1pm) == pytest.approx((xs[i], ys[i], ks[i]))
        assert abs(wrap_angle(q.heading_rad - hs[i])) < 1e-12


@settings(max_examples=60, deadline=None, derandomize=True)
@given(
    frac=st.floats(0.0, 1.0),
    offset=st.floats(-6.0, 6.0),
    dpsi=st.floats(-1.0, 1.0),
    hinted=st.booleans(),
)
def test_projection_round_trip(frac: float, offset: float, dpsi: float, hinted: bool) -> None:
    p = _SNAKE
    s = frac * p.length_m
    q = p.point_at(s)
    x = q.x_m - offset * math.sin(q.heading_rad)
    y = q.y_m + offset * math.cos(q.heading_rad)
    proj = p.project(x, y, hint_s=s + 3.0 if hinted else None, heading_rad=q.heading_rad + dpsi)
    # Inside the path the foot point is exact to the polyline's error: the chord's sagitta (h^2 k / 8,
    # ~1e-4 m) laterally, and along the path up to |offset| k h / 2 (a point off a polyline corner
    # projects onto one of its chords, whose direction is off by up to k h / 2). Beyond the ends the
    # foot is the end point itself and only the lateral offset is kept.
    if 0.0 < s < p.length_m:
        k_max = float(np.max(np.abs(p.curvature_1pm)))
        assert proj.s_m == pytest.approx(s, abs=5e-3 + abs(offset) * k_max * DEFAULT_STEP_M / 2)
    assert proj.lateral_offset_m == pytest.approx(offset, abs=5e-3)
    assert proj.heading_error_rad == pytest.approx(dpsi, abs=5e-3)


_SNAKE = path_through([0, 30, 60, 90, 120], [0, 15, 0, -15, 0])  # curvature <= ~0.06: radius > 6 m


def test_projection_without_heading_and_vectorised() -> None:
    proj = _SNAKE.project(30.0, 20.0)
    assert math.isnan(proj.heading_error_rad) and proj.lateral_offset_m > 0
    s, lat, _ = _SNAKE.project_points([30.0, 60.0], [20.0, -3.0])
    assert s[0] == pytest.approx(proj.s_m) and lat[0] == pytest.approx(proj.lateral_offset_m)
    assert lat[1] < 0


def test_hint_keeps_to_its_own_leg_of_a_hairpin() -> None:
    # out along y = 0, around a 6 m radius, back along y = 12: a point at y = 5 is nearer the outbound leg
    x = np.concatenate(
        (np.linspace(0, 50, 6), 50 + 6 * np.sin(np.linspace(0.3, math.pi - 0.3, 5)), np.linspace(50, 0, 6))
    )
    y = np.concatenate((np.zeros(6), 6 - 6 * np.cos(np.linspace(0.3, math.pi - 0.3, 5)), np.full(6, 12.0)))
    p = path_through(x, y)
    near_out = p.project(20.0, 5.0)
    assert near_out.s_m < 50.0 and near_out.lateral_offset_m == pytest.approx(5.0, abs=0.05)
    back_s = p.project(20.0, 12.0).s_m
    on_back = p.project(20.0, 5.0, hint_s=back_s)
    assert on_back.s_m == pytest.approx(back_s, abs=0.05) and on_back.lateral_offset_m == pytest.approx(
        7.0, abs=0.05
    )


def test_stub_between_and_slices() -> None:
    p = _SNAKE
    stub = p.stub(10.0)
    assert stub.length_m == pytest.approx(30.0) and stub.s_m[0] == 0.0
    assert stub.start[:2] == pytest.approx(p.point_at(10.0)[:2])
    assert stub.end[:2] == pytest.approx(p.point_at(40.0)[:2])
    tail = p.stub(p.length_m - 5.0)
    assert tail.length_m == pytest.approx(5.0)
    assert len(p.stub(p.length_m + 1.0)) == 1
    part = p.slice_samples(4, 20)
    assert part.s_m[0] == 0.0 and part.length_m == pytest.approx(p.s_m[20] - p.s_m[4])
    with pytest.raises(IndexError):
        p.slice_samples(5, len(p))


def test_concat_joins_and_refuses_gaps() -> None:
    a = path_through([0, 10], [0, 0])
    b = path_through([10, 10], [0, 10])
    c = concat([a, Path.point(10.0, 0.0, 0.0), b])
    assert c.length_m == pytest.approx(20.0) and len(c) == len(a) + len(b) - 1
    assert np.all(np.diff(c.s_m) > 0)
    with pytest.raises(ValueError, match=r"starts 1\.000 m from the end"):
        concat([a, path_through([11, 20], [0, 0])])
    with pytest.raises(ValueError):
        concat([])
    # headings stay continuous across the +-pi cut
    west1 = path_through([0, -10], [0, 0.01])
    west2 = path_through([-10, -20], [0.01, -0.01])
    w = concat([west1, west2])
    assert np.max(np.abs(np.diff(w.heading_unwrapped_rad))) < 0.01


def test_offset_and_reversed() -> None:
    r = 20.0
    x, y = circle_points(r, 0.0, math.pi / 2, 19)
    p = path_through(x, y)
    inner = p.offset(5.0)  # left of a left turn: towards the centre, radius 15
    mid = slice(len(p) // 3, 2 * len(p) // 3)
    np.testing.assert_allclose(inner.curvature_1pm[mid], 1.0 / 15.0, rtol=0.02)
    np.testing.assert_allclose(np.hypot(inner.x_m[mid], inner.y_m[mid]), 15.0, rtol=0.005)
    outer = p.offset(-5.0)
    np.testing.assert_allclose(outer.curvature_1pm[mid], 1.0 / 25.0, rtol=0.02)
    with pytest.raises(ValueError, match="centre of curvature"):
        p.offset(25.0)
    back = p.reversed()
    assert back.length_m == pytest.approx(p.length_m)
    assert back.start[:2] == pytest.approx(p.end[:2])
    assert abs(wrap_angle(back.start.heading_rad - p.end.heading_rad - math.pi)) < 1e-12
    assert back.curvature_1pm[5] == pytest.approx(-p.curvature_1pm[-6])


def test_path_validation() -> None:
    with pytest.raises(ValueError):
        Path([], [], [], [])
    with pytest.raises(ValueError):
        Path([0, 1], [0], [0, 0], [0, 0])
    with pytest.raises(ValueError):
        Path([0, 1], [0, float("nan")], [0, 0], [0, 0])
    with pytest.raises(ValueError):
        Path([0, 1], [0, 0], [0, 0], [0, 0], s_m=[0, -1])
    p = Path([0, 1, 2], [0, 0, 0], [0, 0, 0], [0, 0, 0])
    assert p.length_m == 2.0 and repr(p) == "Path(3 samples, 2.00 m)"
    with pytest.raises(ValueError):
        p.x_m[0] = 5.0  # samples are read-only


# ---------------------------------------------------------------------------------------------- connectors


@pytest.mark.parametrize(
    "start,end",
    [
        ((0, 0, 0, 0), (20, 20, math.pi / 2, 0)),  # a right-angle left turn
        ((0, 0, 0, 0.02), (30, -15, -math.pi / 2, -0.05)),  # a right turn out of a curve into one
        ((0, 0, 0, 0), (40, 3.7, 0, 0)),  # a lane change
        ((0, 0, 0, 0), (0, 4, math.pi, 0)),  # a U-turn to the lane on the left
    ],
)
def test_connector_matches_both_poses(start: tuple[float, ...], end: tuple[float, ...]) -> None:
    c = connector(start, end)
    assert (c.start.x_m, c.start.y_m) == (start[0], start[1])
    assert (c.end.x_m, c.end.y_m) == (end[0], end[1])
    assert abs(wrap_angle(c.start.heading_rad - start[2])) < 1e-9
    assert abs(wrap_angle(c.end.heading_rad - end[2])) < 1e-9
    assert c.start.curvature_1pm == pytest.approx(start[3], abs=1e-9)
    assert c.end.curvature_1pm == pytest.approx(end[3], abs=1e-9)
    assert c.length_m >= math.hypot(end[0] - start[0], end[1] - start[1])
    assert np.max(np.diff(c.s_m)) < 2 * DEFAULT_STEP_M


def test_connector_shapes_are_sensible() -> None:
    turn = connector((0, 0, 0, 0), (20, 20, math.pi / 2, 0))
    # a 90 deg turn between points 20 m apart each way: an arc of radius 20 would do; no kink, no loop
    assert np.max(np.abs(turn.curvature_1pm)) < 0.12
    assert turn.length_m == pytest.approx(math.pi * 10, rel=0.1)
    change = connector((0, 0, 0, 0), (40, 3.7, 0, 0))
    assert np.max(np.abs(change.heading_rad)) < 0.25 and np.all(np.diff(change.x_m) > 0)
    assert len(connector((1, 2, 0.3, 0.1), (1, 2.0000001, 2.0, 0))) == 1  # same place: a point
    # curvature continuity across a join: arc, connector, arc
    arc1 = path_through(*circle_points(30.0, -math.pi / 2, 0.6, 7))
    e = arc1.end
    x2, y2 = circle_points(25.0, 0.4, 0.8, 7)
    arc2 = path_through(x2 + 60.0, y2 + 10.0)
    joined = concat([arc1, connector(e, arc2.start), arc2])
    assert np.max(np.abs(np.diff(joined.curvature_1pm))) < 0.02
    assert np.max(np.abs(np.diff(joined.heading_unwrapped_rad))) < 0.02


# A Passat at full lock (l = 2.72 m, 30 deg) turns on 0.212 1/m: the graph's limit for exits.
PASSAT_FULL_LOCK_1PM = math.tan(math.radians(30.0)) / 2.72


def _peak(p: Path) -> float:
    return float(np.max(np.abs(p.curvature_1pm)))


def test_drivable_connector_opens_a_stop_line_turn_the_car_cannot_steer() -> None:
    # The sample mission's exit 11.1.4 -> 7.1.11 in its exit's frame: a right turn of 104 deg to an entry
    # 3.9 m ahead and 12.5 m to the right. The least-energy quintic turns on 2.9 m, the Passat at full
    # lock on 4.7 m: it ran 0.87 m wide there.
    start, end = (0.0, 0.0, 0.0, 0.0), (3.92, -12.5, math.radians(-104.0), 0.0)
    plain = connector(start, end)
    assert 1.0 / _peak(plain) < 3.0
    wide = drivable_connector(start, end, PASSAT_FULL_LOCK_1PM)
    assert _peak(wide) < PASSAT_FULL_LOCK_1PM + 0.005  # (a hair over it: the search's least excess)
    assert _peak(wide) < 0.65 * _peak(plain)
    assert (wide.start.x_m, wide.start.y_m) == (0.0, 0.0) and (wide.end.x_m, wide.end.y_m) == end[:2]
    assert abs(wrap_angle(wide.end.heading_rad - end[2])) < 1e-9 and abs(wide.start.heading_rad) < 1e-9
    # evenly sampled despite unequal tangents, and smooth: no kink, no curvature ramp steeper than the
    # search allows (a steering wheel turns at a finite rate), none at the run-in
    assert np.max(np.diff(wide.s_m)) <= DEFAULT_STEP_M * 1.05
    assert np.max(np.abs(np.diff(wide.heading_unwrapped_rad))) < 0.08
    sharpness = np.abs(np.diff(wide.curvature_1pm)) / np.diff(wide.s_m)
    assert np.max(sharpness) < 1.1 * SHARPNESS_MAX_1PM2
    # it runs in along the entry lane's line: the last metres are straight on it
    tail = wide.s_m > wide.length_m - 2.0
    assert np.max(np.abs(wide.curvature_1pm[tail])) < 1e-3


def test_drivable_connector_keeps_a_curve_that_is_already_drivable() -> None:
    start, end = (0.0, 0.0, 0.0, 0.0), (20.0, 20.0, math.pi / 2, 0.0)
    plain = connector(start, end)
    same = drivable_connector(start, end, 0.18)
    assert _peak(plain) < 0.18
    np.testing.assert_array_equal(same.x_m, plain.x_m)
    np.testing.assert_array_equal(same.curvature_1pm, plain.curvature_1pm)
    with pytest.raises(ValueError, match="max_curvature_1pm"):
        drivable_connector(start, end, 0.0)
    with pytest.raises(ValueError, match="max_curvature_1pm"):
        drivable_connector(start, end, math.nan)


@settings(max_examples=60, deadline=None)
@example(6.0, 7.0, 0.0, 0.0, 0.25)  # a shift too short for any curve: the search found one 0.002 sharper
@given(
    st.floats(2.0, 25.0),
    st.floats(-25.0, 25.0),
    st.floats(-2.4, 2.4),
    st.floats(-0.05, 0.05),
    st.floats(0.05, 0.3),
)
def test_drivable_connector_never_steers_harder_than_the_plain_one(
    ahead_m: float, side_m: float, turn_rad: float, k_end: float, limit: float
) -> None:
    start, end = (0.0, 0.0, 0.0, 0.0), (ahead_m, side_m, turn_rad, k_end)
    plain = connector(start, end)
    wide = drivable_connector(start, end, limit)
    assert _peak(wide) <= max(_peak(plain), limit) + 1e-3
    assert (wide.end.x_m, wide.end.y_m) == (ahead_m, side_m)
    assert abs(wrap_angle(wide.end.heading_rad - turn_rad)) < 1e-6
    assert wide.end.curvature_1pm == pytest.approx(k_end, abs=1e-6)
    assert np.all(np.isfinite(wide.curvature_1pm)) and np.max(np.diff(wide.s_m)) < 2 * DEFAULT_STEP_M


def test_pathpoint_is_a_pose() -> None:
    p = PathPoint(1.0, 2.0, 0.5, 0.01, 3.0)
    assert connector(p, (5.0, 2.0, 0.0, 0.0)).start == PathPoint(1.0, 2.0, 0.5, 0.01, 0.0)
