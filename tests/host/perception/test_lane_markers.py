"""Lane markers (seed 000 Sec. 6): paint and curbs from synthetic revolutions of a known road, their
accumulation into the vehicle-centred marker image, and what the real KITTI scans show."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from lane_marker_scans import lateral_of, road_scan
from shared_data import shared_data_dir

from bywire.host.lateral import VehiclePose
from bywire.host.perception.lane_markers import (
    GridParams,
    LaneMarkerMap,
    MarkerFeatures,
    MarkerGrid,
    MarkerParams,
    extract_features,
    extract_features_reference,
    marker_png,
)
from bywire.host.perception.radon import find_lines
from bywire.host.perception.scan import Scan, read_kitti_bin

CELL_M = GridParams().cell_m
LINES_M = (-1.75, 1.75, 5.25)
CURB_M = -3.0
KITTI = "lidar_kitti/odometry_seq00_frames0-5"


def distance_to_nearest(values: np.ndarray, targets: tuple[float, ...]) -> np.ndarray:
    return np.min(np.abs(values[:, None] - np.asarray(targets)[None, :]), axis=1)


@pytest.mark.parametrize("road_angle_deg", [0.0, 30.0, -75.0])
def test_paint_and_curb_are_found_where_they_are(road_angle_deg: float) -> None:
    angle = math.radians(road_angle_deg)
    feats = extract_features(road_scan(lines_lateral_m=LINES_M, curb_lateral_m=CURB_M, road_angle_rad=angle))
    paint = lateral_of(feats.paint_xy_m, angle)
    curb = lateral_of(feats.curb_xy_m, angle)
    # Every paint point within a cell of a painted line (they are 0.15 m wide: measured 7.5 cm at most),
    # and every line seen by many (each ring crosses it twice: ~370 points per line within 30 m).
    assert np.all(distance_to_nearest(paint, LINES_M) <= CELL_M)
    for line in LINES_M:
        assert np.count_nonzero(np.abs(paint - line) <= CELL_M) >= 200
    # The curb: one feature per ring crossing it, on its face (measured within 4 cm).
    assert curb.size >= 80
    assert np.all(np.abs(curb - CURB_M) <= CELL_M)


def test_the_plane_is_the_road_not_the_sidewalk() -> None:
    """A third of the ground near the car is sidewalk, 15 cm up: the plane must stay on the road."""
    feats = extract_features(road_scan(curb_lateral_m=CURB_M))
    a, b, c = feats.plane
    assert abs(a - -1.73) <= 0.01 and abs(b) <= 1e-3 and abs(c) <= 1e-3
    assert np.all(lateral_of(feats.paint_xy_m) >= CURB_M)  # no paint on the (brighter) sidewalk


def test_each_beam_is_judged_against_its_own_median() -> None:
    """Beams reading the road at 0.5 .. 1.5 of its reflectance: a bright beam's asphalt reads as much as
    a dim beam's paint, and a threshold for all beams would take one or miss the other."""
    scan = road_scan(lines_lateral_m=LINES_M, curb_lateral_m=None, beam_gain_spread=1.0, seed=3)
    paint = lateral_of(extract_features(scan).paint_xy_m)
    assert np.all(distance_to_nearest(paint, LINES_M) <= CELL_M)
    for line in LINES_M:
        assert np.count_nonzero(np.abs(paint - line) <= CELL_M) >= 200


def test_beams_may_come_interleaved() -> None:
    """Points in firing order across beams (as a sensor sends them) give the same features."""
    grouped = extract_features(road_scan(seed=5))
    interleaved_scan = road_scan(seed=5, interleaved=True)
    interleaved = extract_features(interleaved_scan)

    def as_set(a: np.ndarray) -> set[tuple[float, float]]:
        return {(round(float(x), 4), round(float(y), 4)) for x, y in a}

    assert as_set(grouped.paint_xy_m) == as_set(interleaved.paint_xy_m)
    assert as_set(grouped.curb_xy_m) == as_set(interleaved.curb_xy_m)
    assert interleaved.ground.shape == (len(interleaved_scan),)
    assert np.count_nonzero(interleaved.ground) == np.count_nonzero(grouped.ground)


def test_a_ground_mask_from_elsewhere_narrows_the_ground() -> None:
    """The occupancy grid's non-obstacle points, say: ground must be on the road plane and in the mask."""
    scan = road_scan(seed=2)
    own = extract_features(scan)
    again = extract_features(scan, ground_mask=np.ones(len(scan), bool))
    np.testing.assert_array_equal(again.paint_xy_m, own.paint_xy_m)
    np.testing.assert_array_equal(again.ground, own.ground)
    right_only = extract_features(scan, ground_mask=scan.xyz_m[:, 1] < 0.0)
    assert not right_only.ground[scan.xyz_m[:, 1] >= 0.0].any()
    paint = lateral_of(right_only.paint_xy_m)
    assert paint.size > 0 and np.all(paint < 0.0)
    assert np.all(lateral_of(right_only.curb_xy_m) < 0.0)
    with pytest.raises(ValueError, match="ground_mask"):
        extract_features(scan, ground_mask=np.zeros(3, bool))


def test_an_empty_scan_has_no_features() -> None:
    empty = Scan(np.zeros((0, 3), np.float32), np.zeros(0, np.float32), np.zeros(0, np.int16))
    feats = extract_features(empty)
    assert feats.paint_xy_m.shape == (0, 2) and feats.curb_xy_m.shape == (0, 2)


def test_the_grid_keeps_a_marker_in_its_world_cell_as_it_moves() -> None:
    grid = MarkerGrid(GridParams(size_cells=64, cell_m=0.25, decay_tau_s=1.0))
    grid.recentre(100.3, -20.1)
    marker = np.array([[103.1, -18.6]])
    grid.add(marker, stamp_s=0.0)
    rows, cols = grid.cells_of(marker)
    assert grid.image[rows[0], cols[0]] == 1.0
    grid.recentre(104.9, -17.2)  # 4.6 m and 2.9 m on: 18 and 12 cells
    rows2, cols2 = grid.cells_of(marker)
    assert (rows2[0], cols2[0]) != (rows[0], cols[0])
    assert grid.image[rows2[0], cols2[0]] == 1.0 and grid.image.sum() == 1.0
    # the car's cell is the centre cell; the origin stays on the world's cell lattice
    cx, cy = grid.centre_xy_m
    assert abs(cx - 104.9) <= grid.cell_m and abs(cy - -17.2) <= grid.cell_m
    assert all(abs(v / grid.cell_m - round(v / grid.cell_m)) < 1e-9 for v in grid.origin_xy_m)
    grid.recentre(200.0, 0.0)  # further than the grid is wide: nothing of it is left
    assert grid.image.sum() == 0.0


def test_the_grid_decays_and_counts_a_cell_once_per_scan() -> None:
    grid = MarkerGrid(GridParams(size_cells=16, cell_m=1.0, decay_tau_s=0.5))
    grid.recentre(0.0, 0.0)
    many = np.array([[2.2, 3.3], [2.7, 3.9], [2.5, 3.5]])  # three points, one cell
    grid.add(many, stamp_s=10.0)
    assert grid.image.sum() == 1.0
    grid.add(np.zeros((0, 2)), stamp_s=10.25)
    assert grid.image.sum() == pytest.approx(math.exp(-0.25 / 0.5), rel=1e-6)
    grid.add(np.array([[-50.0, 0.0]]), stamp_s=10.25)  # outside: ignored, no decay for dt = 0
    assert grid.image.sum() == pytest.approx(math.exp(-0.5), rel=1e-6)


def test_accumulated_markers_give_the_roads_lines() -> None:
    """Driving 1 m per revolution along a road at 30 deg in the world: the marker image's lines are the
    painted ones and the curb, at their places, along the road."""
    angle = math.radians(30.0)
    direction = np.array([math.cos(angle), math.sin(angle)])
    start = np.array([50.0, 20.0])
    markers = LaneMarkerMap()
    for k in range(8):
        x, y = start + direction * k
        scan = road_scan(road_angle_rad=0.0, curb_lateral_m=CURB_M, stamp_s=0.1 * k, seed=k)
        markers.update(scan, VehiclePose(x, y, angle))
    found = find_lines(markers.grid.image, markers.grid.cell_m)
    normal = angle + math.pi / 2.0  # the road's left normal: offsets are lateral positions
    turn = math.remainder(found.normal_rad - normal, 2.0 * math.pi)
    sign = 1.0 if abs(turn) < math.pi / 2.0 else -1.0
    assert abs(math.degrees(math.remainder(turn, math.pi))) <= 0.2
    # Lateral positions relative to the grid's centre, which is within a cell of the car (on the axis).
    cx, cy = markers.grid.centre_xy_m
    car = start + direction * 7
    centre_lateral = float(np.array([-direction[1], direction[0]]) @ (np.array([cx, cy]) - car))
    lateral = sorted(sign * ln.offset_m + centre_lateral for ln in found.lines)
    assert len(lateral) == 4
    for got, want in zip(lateral, sorted((*LINES_M, CURB_M)), strict=True):
        assert abs(got - want) <= CELL_M


def test_marker_png_writes_an_image(tmp_path: Path) -> None:
    markers = LaneMarkerMap()
    markers.update(road_scan(), VehiclePose(0.0, 0.0, 0.0))
    out = marker_png(markers.grid, tmp_path / "markers.png")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def kitti_scans() -> list[Scan]:
    folder = shared_data_dir() / KITTI
    files = sorted(folder.glob("*.bin"))
    if not files:
        pytest.skip(f"KITTI odometry scans not found in {folder} (shared data, never copied into the repo)")
    return [read_kitti_bin(f, stamp_s=0.1 * k) for k, f in enumerate(files)]


def test_kitti_markers_run_along_the_road() -> None:
    """KITTI odometry 00, frames 0-5: a residential street just past a junction whose side street has a
    dashed centre line; no painted lane lines along the street itself.

    What the marker image shows (accumulated at 0.72 m per frame, the registration's ego-motion; the
    listed poses do not fit these scans): curbs along both sides ahead and round the junction's corners,
    paint on the dashed line and the gutters. Its dominant direction lies 3.9-4.7 deg left of the
    sensor's x axis after each of the six revolutions; the car drives 3.1 deg left of its x axis in the
    sequence's ground truth (0.047 m sideways per 0.86 m), i.e. along the road. Asserted within 6 deg,
    to the left. Its lines lie 4.4 and 2.5 m left and 3.0, 4.5 and 6.5 m right of the sensor (kerbs, gutters,
    the feet of parked cars: the scans alone do not tell which); asserted: lines on both sides within
    8 m."""
    markers = LaneMarkerMap()
    for k, scan in enumerate(kitti_scans()):
        markers.update(scan, VehiclePose(0.72 * k, 0.0, 0.0))
    feats = markers.last
    assert feats is not None and len(feats.paint_xy_m) > 100 and len(feats.curb_xy_m) > 100
    found = find_lines(markers.grid.image, markers.grid.cell_m)
    along_deg = math.degrees(math.remainder(found.normal_rad - math.pi / 2.0, math.pi))
    assert abs(along_deg) <= 6.0, along_deg
    assert along_deg > 0.0  # the road runs left of the car's heading, as the ground truth says
    # normal close to -90 deg: a positive offset is to the right of the car
    left = [ln for ln in found.lines if -8.0 <= np.sign(math.sin(found.normal_rad)) * ln.offset_m < 0.0]
    right = [ln for ln in found.lines if 0.0 < np.sign(math.sin(found.normal_rad)) * ln.offset_m <= 8.0]
    assert left and right


def assert_same_features(got: MarkerFeatures, want: MarkerFeatures) -> None:
    np.testing.assert_array_equal(got.paint_xy_m, want.paint_xy_m)
    np.testing.assert_array_equal(got.curb_xy_m, want.curb_xy_m)
    np.testing.assert_array_equal(got.ground, want.ground)
    assert got.plane == want.plane


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    road_angle_deg=st.floats(-180.0, 180.0),
    curb=st.sampled_from([None, -3.0, 2.5]),
    interleaved=st.booleans(),
    masked=st.booleans(),
    contrast=st.sampled_from([0.05, 0.15]),
    neighbours=st.integers(0, 3),
    missing=st.integers(0, 3),
)
def test_the_compiled_features_equal_the_numpy_ones(
    seed: int,
    road_angle_deg: float,
    curb: float | None,
    interleaved: bool,
    masked: bool,
    contrast: float,
    neighbours: int,
    missing: int,
) -> None:
    """Bit for bit, on roads with noise in height and reflectance and points dropped (the scan's gaps)."""
    rng = np.random.default_rng(seed)
    scan = road_scan(
        road_angle_rad=math.radians(road_angle_deg),
        curb_lateral_m=curb,
        n_azimuth=int(rng.integers(300, 1500)),
        beam_gain_spread=float(rng.uniform(0.0, 1.0)),
        interleaved=interleaved,
        seed=seed,
    )
    keep = rng.random(len(scan)) > rng.uniform(0.0, 0.2)
    xyz = scan.xyz_m[keep] + rng.normal(0.0, 0.02, (int(keep.sum()), 3)).astype(np.float32)
    refl = np.clip(scan.reflectance[keep] + rng.normal(0.0, 0.05, xyz.shape[0]), 0.0, 1.0)
    scan = dataclasses.replace(scan, xyz_m=xyz, reflectance=refl.astype(np.float32), beam=scan.beam[keep])
    params = MarkerParams(paint_contrast=contrast, paint_max_neighbours=neighbours, curb_max_missing=missing)
    mask = rng.random(len(scan)) < 0.9 if masked else None
    assert_same_features(extract_features(scan, params, mask), extract_features_reference(scan, params, mask))


def test_the_compiled_features_equal_the_numpy_ones_on_kitti() -> None:
    rng = np.random.default_rng(7)
    for scan in kitti_scans():
        assert_same_features(extract_features(scan), extract_features_reference(scan))
        mask = rng.random(len(scan)) < 0.9
        assert_same_features(
            extract_features(scan, ground_mask=mask), extract_features_reference(scan, ground_mask=mask)
        )
