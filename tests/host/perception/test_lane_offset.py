"""The map's lateral offset from the observed lane markings (seed 000 Sec. 6) and its application to a
route: a shifted RNDF is recovered, a wrong match is rejected, and the route moves by the offset."""

from __future__ import annotations

import math

import numpy as np
import pytest
from lane_marker_scans import road_scan

from bywire.host.lateral import PathSamples
from bywire.host.perception.lane_markers import GridParams, MarkerGrid
from bywire.host.perception.lane_offset import (
    LaneOffset,
    LaneOffsetEstimator,
    OffsetFilter,
    OffsetMeasurement,
    OffsetParams,
    apply_offset,
    lane_frame,
    measure_offset,
)
from bywire.host.roadnet.path import Path

LANE_W_M = 3.5
# This lane's boundaries and the left neighbour's outer line (a two-lane road, we drive on the right),
# and a curb 0.75 m beyond the right edge line, in the real road's lateral coordinate (left > 0).
LINES_M = (-1.75, 1.75, 5.25)
CURB_M = -2.5


def drive(
    shift_m: float,
    road_deg: float,
    frames: int,
    estimator: LaneOffsetEstimator | None = None,
    first: int = 0,
) -> tuple[LaneOffsetEstimator, list[LaneOffset]]:
    """Drive the real lane's centre at 10 m/s along a straight road at `road_deg`, with the map's
    centreline `shift_m` to the right of the real one (the real lane is `shift_m` left of the map's)."""
    est = estimator or LaneOffsetEstimator()
    angle = math.radians(road_deg)
    d = np.array([math.cos(angle), math.sin(angle)])
    left = np.array([-d[1], d[0]])
    start = np.array([120.0, -40.0])
    s = np.arange(-60.0, 200.0, 4.0)  # an RNDF lane: waypoints every 4 m
    centreline = start + s[:, None] * d - shift_m * left
    outs = []
    for k in range(first, first + frames):
        x, y = start + d * (1.0 * k)
        scan = road_scan(lines_lateral_m=LINES_M, curb_lateral_m=CURB_M, stamp_s=0.1 * k, seed=k)
        outs.append(est.update(scan, _Pose(x, y, angle), centreline, LANE_W_M))
    return est, outs


class _Pose:
    def __init__(self, x_m: float, y_m: float, heading_rad: float) -> None:
        self.x_m, self.y_m, self.heading_rad = x_m, y_m, heading_rad


@pytest.mark.parametrize(("shift_m", "road_deg"), [(1.5, 30.0), (-1.5, -120.0), (0.0, 0.0), (-0.8, 95.0)])
def test_a_shifted_map_is_recovered(shift_m: float, road_deg: float) -> None:
    _, outs = drive(shift_m, road_deg, frames=4)
    last = outs[-1]
    # Measured within 1 cm of the shift from the first frame on (three lines, each to a tenth of a cell).
    assert last.valid and last.accepted
    assert abs(last.offset_m - shift_m) <= 0.2
    assert last.sigma_m <= 0.1
    m = last.measurement
    assert m is not None and m.inliers == 3  # the curb votes 0.75 m off: outvoted, not averaged in
    assert abs(m.angle_error_rad) <= math.radians(0.2)


def test_one_wrong_match_is_rejected() -> None:
    """After a few frames the filter knows the offset to centimetres; a frame whose lines were matched one
    lane over (a metre-sized jump) is gated out and the estimate does not move."""
    est, outs = drive(1.5, 30.0, frames=5)
    before = outs[-1]
    wrong = OffsetMeasurement(1.5 - LANE_W_M, 0.01, (), 3, 0.0)
    after = est.filter.update(wrong, stamp_s=before.stamp_s + 0.05)
    assert not after.accepted
    assert after.offset_m == pytest.approx(before.offset_m)
    assert after.valid
    # and the next good frame is taken again
    _, more = drive(1.5, 30.0, frames=1, estimator=est, first=5)
    assert more[-1].accepted and abs(more[-1].offset_m - 1.5) <= 0.2


def test_a_lasting_change_of_the_maps_error_restarts_the_filter() -> None:
    prm = OffsetParams(reset_after=4)
    f = OffsetFilter(prm)
    for k in range(10):
        f.update(OffsetMeasurement(1.5, 0.01, (), 3, 0.0), 0.1 * k)
    outs = [f.update(OffsetMeasurement(-0.9, 0.01, (), 3, 0.0), 1.0 + 0.1 * k) for k in range(4)]
    assert [o.accepted for o in outs] == [False, False, False, True]
    assert outs[-1].offset_m == pytest.approx(-0.9)
    # scattered outliers never restart it
    f2 = OffsetFilter(prm)
    for k in range(10):
        f2.update(OffsetMeasurement(1.5, 0.01, (), 3, 0.0), 0.1 * k)
    for k, z in enumerate((-2.0, -0.5, 3.5, -1.5, 0.0, 3.4)):
        out = f2.update(OffsetMeasurement(z, 0.01, (), 3, 0.0), 1.0 + 0.1 * k)
        assert not out.accepted
    assert out.offset_m == pytest.approx(1.5, abs=0.01)


def test_a_restart_takes_only_the_refusals_that_agree() -> None:
    """A refusal older than the last `reset_after` (one that did not agree with them) does not shift the
    value the filter restarts on."""
    f = OffsetFilter(OffsetParams(reset_after=3))
    for k in range(10):
        f.update(OffsetMeasurement(0.0, 0.01, (), 2, 0.0), 0.1 * k)
    outs = [
        f.update(OffsetMeasurement(z, 0.01, (), 2, 0.0), 1.0 + 0.1 * k)
        for k, z in enumerate((2.0, 1.0, 1.0, 1.0))
    ]
    assert [o.accepted for o in outs] == [False, False, False, True]
    assert outs[-1].offset_m == pytest.approx(1.0)  # not (2 + 1 + 1 + 1) / 4


def test_within_one_road_a_jump_never_restarts_the_filter() -> None:
    """An RNDF's error changes slowly along a road: within one map lane a restart moves the estimate by
    at most `max_restart_m`. On the DARPA sample a neighbour's lines taken for ours for 0.5-6 s restarted
    it on 0.7-1.5 m within a lane, and the car drove 1.47 m beside its lane. On another lane it may."""
    f = OffsetFilter(OffsetParams(reset_after=5))
    for k in range(10):
        f.update(OffsetMeasurement(0.0, 0.01, (), 2, 0.0), 0.1 * k, road="3.2")
    outs = [f.update(OffsetMeasurement(1.4, 0.01, (), 2, 0.0), 1.0 + 0.1 * k, road="3.2") for k in range(25)]
    assert not any(o.accepted for o in outs)
    assert outs[-1].offset_m == pytest.approx(0.0, abs=0.01)
    assert not outs[-1].valid  # nothing taken in for 2 s: the map is trusted as it is
    # a small lasting change within the road (beyond the gate, within the limit) still restarts it
    small = [f.update(OffsetMeasurement(0.45, 0.01, (), 2, 0.0), 4.0 + 0.1 * k, road="3.2") for k in range(5)]
    assert [o.accepted for o in small] == [False, False, False, False, True]
    assert small[-1].offset_m == pytest.approx(0.45)
    # on another road the error may be another one: the same jump restarts it
    other = [f.update(OffsetMeasurement(1.8, 0.01, (), 2, 0.0), 5.0 + 0.1 * k, road="4.1") for k in range(5)]
    assert [o.accepted for o in other] == [False, False, False, False, True]
    assert other[-1].offset_m == pytest.approx(1.8) and other[-1].valid


def test_a_road_that_is_not_named_restarts_as_before() -> None:
    f = OffsetFilter(OffsetParams(reset_after=3))
    for k in range(10):
        f.update(OffsetMeasurement(0.0, 0.01, (), 2, 0.0), 0.1 * k)
    outs = [f.update(OffsetMeasurement(1.4, 0.01, (), 2, 0.0), 1.0 + 0.1 * k) for k in range(3)]
    assert outs[-1].accepted and outs[-1].offset_m == pytest.approx(1.4)


def painted_grid(angle_deg: float, lateral_m: tuple[float, ...] = (-1.75, 1.75, 5.25)) -> MarkerGrid:
    """A marker image of straight lines through the image at `angle_deg` (world), `lateral_m` left of
    the line through the image centre, every cell they cross marked once."""
    grid = MarkerGrid(GridParams())
    grid.recentre(0.0, 0.0)
    a = math.radians(angle_deg)
    d, n = np.array([math.cos(a), math.sin(a)]), np.array([-math.sin(a), math.cos(a)])
    cx, cy = grid.centre_xy_m
    ox, oy = grid.origin_xy_m
    t = np.arange(-30.0, 30.0, 0.02)
    for lat in lateral_m:
        x = cx + t * d[0] + lat * n[0]
        y = cy + t * d[1] + lat * n[1]
        col = np.floor((x - ox) / grid.cell_m).astype(int)
        row = np.floor((y - oy) / grid.cell_m).astype(int)
        ok = (col >= 0) & (col < grid.image.shape[1]) & (row >= 0) & (row < grid.image.shape[0])
        grid.image[row[ok], col[ok]] = 1.0
    return grid


@pytest.mark.parametrize("angle_deg", [-2.5, 0.0, 3.0])
def test_lines_close_to_parallel_are_measured(angle_deg: float) -> None:
    m = measure_offset(painted_grid(angle_deg), [[-50.0, 0.0], [50.0, 0.0]], LANE_W_M)
    assert m is not None and abs(m.offset_m) <= 0.1
    assert m.angle_error_rad == pytest.approx(math.radians(angle_deg), abs=math.radians(0.2))


@pytest.mark.parametrize("angle_deg", [-6.0, 5.0, 8.0])
def test_lines_beyond_the_angle_window_are_not_measured(angle_deg: float) -> None:
    """The paper's "predicted and estimated lane boundaries are close to parallel": the Radon plane is
    searched within 4 deg of the map's lane. Where its energy still grows at the window's edge, the
    lines run farther off (a curve's chord, another road's paint) and the peaks at the edge's angle are
    not where the lines cross the car's normal: no measurement, rather than one of up to 0.5 m."""
    grid = painted_grid(angle_deg)
    assert measure_offset(grid, [[-50.0, 0.0], [50.0, 0.0]], LANE_W_M) is None
    # the same lines against a map lane that runs with them are measured
    a = math.radians(angle_deg)
    m = measure_offset(
        grid, [[-50.0 * math.cos(a), -50.0 * math.sin(a)], [50.0 * math.cos(a), 50.0 * math.sin(a)]], LANE_W_M
    )
    assert m is not None and abs(m.offset_m) <= 0.1


def test_the_offset_goes_invalid_without_markings() -> None:
    f = OffsetFilter(OffsetParams(timeout_s=2.0))
    assert not f.update(None, 0.0).valid  # nothing seen yet: the prior is a metre wide
    for k in range(5):
        f.update(OffsetMeasurement(0.4, 0.01, (), 2, 0.0), 0.1 * k)
    assert f.update(None, 2.3).valid
    gone = f.update(None, 2.5)
    assert not gone.valid and gone.offset_m == pytest.approx(0.4, abs=0.01)
    assert gone.variance_m2 <= OffsetParams().prior_sigma_m ** 2


def test_no_lines_no_measurement() -> None:
    grid = MarkerGrid(GridParams())
    grid.recentre(0.0, 0.0)
    assert measure_offset(grid, [[-50.0, 0.0], [50.0, 0.0]], LANE_W_M) is None


def test_lane_frame_is_the_foot_point_and_the_local_direction() -> None:
    pts = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 10.0]])
    fx, fy, psi = lane_frame(pts, 5.0, 2.0, window_m=4.0)
    assert (fx, fy) == pytest.approx((5.0, 0.0))
    assert psi == pytest.approx(0.0)
    _, _, psi_corner = lane_frame(pts, 10.0, 0.5, window_m=4.0)
    assert 0.0 < psi_corner < math.radians(45.0)  # the chord across the corner
    with pytest.raises(ValueError, match="2 points"):
        lane_frame(pts[:1], 0.0, 0.0)


def arc_path(radius_m: float = 30.0, length_m: float = 40.0) -> Path:
    s = np.arange(0.0, length_m + 1e-9, 0.25)
    phi = s / radius_m  # a left turn from (0, 0) heading east
    return Path(radius_m * np.sin(phi), radius_m * (1.0 - np.cos(phi)), phi, np.full_like(s, 1.0 / radius_m))


@pytest.mark.parametrize("offset_m", [1.5, -1.5, 0.3])
def test_applying_the_offset_moves_a_route_along_its_normals(offset_m: float) -> None:
    route = arc_path()
    moved = apply_offset(route, offset_m)
    normal = np.column_stack((-np.sin(route.heading_rad), np.cos(route.heading_rad)))
    np.testing.assert_allclose(moved.xy - route.xy, offset_m * normal, atol=1e-12)
    np.testing.assert_allclose(moved.heading_rad, route.heading_rad)
    # the parallel of a 30 m circle, d to its inside: a circle of 30 - d m
    np.testing.assert_allclose(moved.curvature_1pm, 1.0 / (30.0 - offset_m), rtol=1e-12)
    assert moved.length_m == pytest.approx(route.length_m * (30.0 - offset_m) / 30.0, rel=1e-3)


@pytest.mark.parametrize("direction", [1, -1])
def test_applying_the_offset_to_the_controllers_samples(direction: int) -> None:
    route = arc_path()
    samples = PathSamples.from_polyline(route.x_m, route.y_m, direction=1 if direction == 1 else -1)
    moved = apply_offset(samples, 1.5)
    normal = np.column_stack((-np.sin(samples.heading_rad), np.cos(samples.heading_rad)))
    np.testing.assert_allclose(
        np.column_stack((moved.x_m - samples.x_m, moved.y_m - samples.y_m)), 1.5 * normal, atol=1e-12
    )
    assert np.all(np.diff(moved.s_m) > 0.0) and moved.s_m[0] == samples.s_m[0]
    np.testing.assert_allclose(
        moved.curvature_1pm, samples.curvature_1pm / (1.0 - 1.5 * samples.curvature_1pm)
    )
    if direction == 1:  # the body's left is the lane's left: a left turn tightens
        assert moved.length_m < samples.length_m
    else:  # reversing, the nose points along the lane, against the travel: its left is the travel's right
        assert moved.length_m > samples.length_m


def test_an_invalid_offset_leaves_the_route_alone() -> None:
    route = arc_path()
    invalid = LaneOffset(stamp_s=0.0, offset_m=1.5, variance_m2=1.0, valid=False, accepted=False)
    assert apply_offset(route, invalid) is route
    valid = LaneOffset(stamp_s=0.0, offset_m=1.5, variance_m2=0.01, valid=True, accepted=True)
    assert apply_offset(route, valid).xy[0] == pytest.approx((0.0, 1.5))
    assert apply_offset(route, 0.0) is route


def test_an_offset_past_the_centre_of_curvature_is_refused() -> None:
    with pytest.raises(ValueError, match="centre of curvature"):
        apply_offset(arc_path(radius_m=5.0), 6.0)
    samples = PathSamples.from_polyline(*arc_path(radius_m=5.0, length_m=10.0).xy.T)
    with pytest.raises(ValueError, match="centre of curvature"):
        apply_offset(samples, 6.0)
    with pytest.raises(ValueError, match="finite"):
        apply_offset(samples, math.nan)
