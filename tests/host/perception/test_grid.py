"""The occupancy grid of seed 000 section 4 (bywire.host.perception.grid): eqs. 1-5 on synthetic scans,
the layouts, the shift with the car, and the fast cell measures held equal to a plain reference."""

from __future__ import annotations

import math

import numpy as np
import pytest
from grid_scenes import Box, cast
from hypothesis import given, settings
from hypothesis import strategies as st

from bywire.host.perception.ego_pose import EgoPose
from bywire.host.perception.grid import (
    CellMeasures,
    EvidenceModel,
    GridLayout,
    GridSnapshot,
    OccupancyGrid,
    _cell_measures,
    _MeasureScratch,
    fuse_max,
    logistic,
)
from bywire.host.perception.scan import Scan

LAYOUTS = [GridLayout.graded(), GridLayout.uniform()]
LAYOUT_IDS = ["graded", "uniform"]


def points_scan(xyz: list[tuple[float, float, float]], beams: list[int] | None = None) -> Scan:
    a = np.asarray(xyz, np.float32).reshape(-1, 3)
    b = np.asarray(beams if beams is not None else range(len(a)), np.int16)
    return Scan(a, np.zeros(len(a), np.float32), b)


def reference_measures(flat: np.ndarray, z: np.ndarray, beam: np.ndarray) -> CellMeasures:
    """Section 4's measures cell by cell, the obvious way."""
    cells = np.unique(flat)
    n, b, lo, hi = [], [], [], []
    for c in cells:
        m = flat == c
        n.append(m.sum())
        b.append(len(np.unique(beam[m] & 63)))
        lo.append(z[m].min())
        hi.append(z[m].max())
    f32 = np.float32
    return CellMeasures(
        cells.astype(np.int32),
        np.array(n, np.int32),
        np.array(b, np.int32),
        np.array(lo, f32),
        np.array(hi, f32),
    )


# -- layouts -------------------------------------------------------------------------------------------


def test_the_layouts_cover_the_same_range_with_their_cell_sizes() -> None:
    graded, uniform = LAYOUTS
    assert graded.cell_sizes_m == pytest.approx((0.15, 0.3, 0.6))
    assert uniform.cell_sizes_m == pytest.approx((0.15,))
    assert graded.half_extent_m == pytest.approx(76.8) and uniform.half_extent_m == pytest.approx(76.8)
    assert graded.raster_side == uniform.raster_side == 1024
    # the graded layout holds a fifth of the uniform one's cells
    assert graded.n_cells * 5 < uniform.n_cells
    with pytest.raises(ValueError):
        GridLayout(0.15, 250, 2)


@settings(max_examples=200, deadline=None)
@given(
    x=st.floats(-76.7, 76.7),
    y=st.floats(-76.7, 76.7),
    layout=st.sampled_from([*LAYOUTS, GridLayout.graded(levels=4), GridLayout.graded(0.2, 30.0, 2)]),
)
def test_a_point_lies_in_its_cell_of_the_finest_window_holding_it(
    x: float, y: float, layout: GridLayout
) -> None:
    if max(abs(x), abs(y)) >= layout.half_extent_m:
        return
    q = np.floor(np.array([[x, y]]) / layout.finest_cell_m).astype(np.int32)
    flat = layout.flat_index(q[:, 0], q[:, 1])
    (cx, cy), size = (v[0] for v in layout.cell_centres_m(flat))
    assert abs(x - cx) <= size / 2 + 1e-9 and abs(y - cy) <= size / 2 + 1e-9
    level = int(flat[0]) // layout.cells_per_side**2
    # level k's window holds the finest cells -N/2 * 2^k <= q < N/2 * 2^k on both axes
    finest = next(
        k
        for k in range(layout.levels)
        if all(-layout.cells_per_side << k <= 2 * v < layout.cells_per_side << k for v in q[0])
    )
    assert level == finest
    assert layout.active_mask().reshape(-1)[flat[0]]


def test_compose_paints_each_cell_over_its_finest_cells() -> None:
    layout = GridLayout(0.5, 8, 2)
    values = np.zeros(layout.shape, np.int32)
    values[1, 0, 7] = 5  # coarse cell, lower right corner: x in [3, 4) m, y in [-4, -3) m
    values[0, 4, 4] = 9  # fine cell at x, y in [0, 0.5) m
    raster = layout.compose(values)
    assert raster.shape == (16, 16)
    assert (raster[0:2, 14:16] == 5).all() and raster.sum() == 5 * 4 + 9
    assert raster[8, 8] == 9


# -- eq. 1, 2: measures and the inverse sensor model ------------------------------------------------


def test_cell_measures_count_points_and_distinct_beams_and_take_the_elevation_difference() -> None:
    # one 15 cm cell, x in [10.05, 10.2), y in [0, 0.15): four points of beams 3, 3, 7, 12
    scan = points_scan(
        [(10.10, 0.05, -1.7), (10.11, 0.06, -1.6), (10.12, 0.07, -1.2), (10.13, 0.1, -1.65)], [3, 3, 7, 12]
    )
    grid = OccupancyGrid(GridLayout.uniform())
    me = grid.update(scan)
    assert len(me) == 1
    assert (me.points[0], me.beams[0]) == (4, 3)
    assert me.elevation_m[0] == pytest.approx(0.5)


@settings(max_examples=60, deadline=None)
@given(
    n=st.integers(1, 400),
    cells=st.integers(1, 50),
    seed=st.integers(0, 2**31 - 1),
    ordered=st.booleans(),
)
def test_the_scattered_measures_equal_the_plain_ones_in_any_order(
    n: int, cells: int, seed: int, ordered: bool
) -> None:
    rng = np.random.default_rng(seed)
    flat = rng.integers(0, cells, n).astype(np.int32) * 37
    if ordered:
        flat = np.sort(flat)
    z = rng.normal(0.0, 1.0, n).astype(np.float32)
    beam = rng.integers(0, 80, n).astype(np.int16)
    scratch = _MeasureScratch(cells * 37)
    for _ in range(2):  # the second revolution finds the scratch as empty as the first
        got, want = _cell_measures(flat, z, beam, scratch), reference_measures(flat, z, beam)
        for name in ("cells", "points", "beams", "z_min_m", "z_max_m"):
            np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)


@pytest.mark.parametrize(
    ("dz_m", "expected"), [(0.10, "free"), (0.14, "free"), (0.20, "occupied"), (1.0, "occupied")]
)
def test_eq1_threshold_splits_ground_from_obstacle(dz_m: float, expected: str) -> None:
    grid = OccupancyGrid(GridLayout.uniform())
    grid.update(points_scan([(5.01, 1.01, -1.7), (5.02, 1.02, -1.7 + dz_m)]))
    p = grid.snapshot().occupancy_at(np.array([[5.0, 1.0]]))[0]
    assert (p > 0.5) == (expected == "occupied") and (p < 0.5) == (expected == "free")


def test_a_single_point_gives_no_evidence_and_two_beams_more_than_one() -> None:
    one = OccupancyGrid(GridLayout.uniform())
    one.update(points_scan([(5.01, 1.01, 0.5)]))
    assert np.count_nonzero(one.evidence) == 0
    same, two = OccupancyGrid(GridLayout.uniform()), OccupancyGrid(GridLayout.uniform())
    same.update(points_scan([(5.01, 1.01, -1.7), (5.02, 1.02, -1.0)], [4, 4]))
    two.update(points_scan([(5.01, 1.01, -1.7), (5.02, 1.02, -1.0)], [4, 5]))
    assert two.evidence.max() > same.evidence.max() > 0


def test_the_elevation_threshold_grows_with_the_cell() -> None:
    m = EvidenceModel()
    assert m.elevation_threshold_for(0.15) == pytest.approx(0.165)
    assert m.elevation_threshold_for(0.6) == pytest.approx(0.21)


@pytest.mark.parametrize("grade", [0.0, 0.08, -0.10])
@pytest.mark.parametrize("layout", LAYOUTS, ids=LAYOUT_IDS)
def test_a_road_with_a_grade_has_no_obstacle_and_is_seen_free(grade: float, layout: GridLayout) -> None:
    grid = OccupancyGrid(layout)
    grid.update(cast(grade=grade))
    snap = grid.snapshot()
    assert snap.obstacle_mask().sum() == 0
    assert (grid.evidence < 0).sum() > 5000


@pytest.mark.parametrize("layout", LAYOUTS, ids=LAYOUT_IDS)
def test_a_wall_is_an_obstacle_exactly_where_it_stands(layout: GridLayout) -> None:
    grid = OccupancyGrid(layout)
    grid.update(cast((Box(12.0, 0.0, 0.3, 10.0, 2.0),)))
    cells = grid.snapshot().obstacle_cells()
    assert len(cells) > 20
    # cells on the wall's face (x = 11.85 m) and along its length, nowhere else
    assert np.all(np.abs(cells.xy_m[:, 0] - 11.9) <= 0.3 + cells.size_m)
    assert cells.xy_m[:, 1].min() < -3.0 and cells.xy_m[:, 1].max() > 3.0
    assert np.all(np.abs(cells.xy_m[:, 1]) <= 5.0 + cells.size_m)


@pytest.mark.parametrize("layout", LAYOUTS, ids=LAYOUT_IDS)
def test_a_box_on_a_graded_road_is_an_obstacle_and_the_road_is_not(layout: GridLayout) -> None:
    box = Box(20.0, -4.0, 4.0, 2.0, 1.5)
    grid = OccupancyGrid(layout)
    grid.update(cast((box,), grade=0.06))
    cells = grid.snapshot().obstacle_cells()
    inside = (np.abs(cells.xy_m[:, 0] - box.x_m) <= 2.0 + cells.size_m) & (
        np.abs(cells.xy_m[:, 1] - box.y_m) <= 1.0 + cells.size_m
    )
    assert inside.sum() >= 10 and inside.all()


def test_points_above_the_car_beyond_the_grid_on_the_car_or_not_finite_are_left_out() -> None:
    grid = OccupancyGrid(GridLayout.uniform())
    scan = points_scan(
        [
            (8.0, 0.0, 2.0),  # a branch 3.7 m over the road
            (8.0, 0.0, 2.1),
            (90.0, 0.0, -1.7),  # beyond the window
            (90.0, 0.0, -1.0),
            (0.5, 0.2, -1.0),  # the car's own body
            (0.5, 0.2, -0.2),
            (math.nan, 1.0, -1.0),
            (1.0, math.inf, -1.0),
        ]
    )
    assert len(grid.update(scan)) == 0
    assert len(grid.update(points_scan([]))) == 0
    assert np.count_nonzero(grid.evidence) == 0


# -- eq. 3, 5: logistic and decay ---------------------------------------------------------------------


@given(st.floats(-30.0, 30.0))
def test_eq3_logistic(o: float) -> None:
    assert float(logistic(np.array([o]))[0]) == pytest.approx(1.0 - 1.0 / (1.0 + math.exp(o)), abs=1e-6)


def test_eq3_logistic_is_half_at_zero_and_saturates_without_overflow() -> None:
    p = logistic(np.array([0.0, 1e4, -1e4]))
    np.testing.assert_array_equal(p, [0.5, 1.0, 0.0])


def test_eq5_evidence_decays_by_epsilon_per_revolution_to_unknown_and_never_past_it() -> None:
    model = EvidenceModel(decay=0.2, occupied_evidence=1.0, multi_beam_evidence=0.0)
    grid = OccupancyGrid(GridLayout.uniform(), model)
    grid.update(points_scan([(5.01, 1.01, -1.7), (5.02, 1.02, -1.0)]))
    peak = float(grid.evidence.max())
    assert peak == pytest.approx(0.8)
    seen = [peak]
    for _ in range(6):
        grid.update(points_scan([]))
        seen.append(float(grid.evidence.max()))
    assert seen == pytest.approx([0.8, 0.6, 0.4, 0.2, 0.0, 0.0, 0.0], abs=1e-6)
    assert grid.evidence.min() == 0.0


@settings(max_examples=50, deadline=None)
@given(st.lists(st.sampled_from(["occupied", "free", "none"]), min_size=1, max_size=40))
def test_eq5_evidence_stays_within_its_bounds_and_follows_the_update_rule(steps: list[str]) -> None:
    model = EvidenceModel(ray_free_evidence=0.0)  # one cell: no free space traced towards it
    grid = OccupancyGrid(GridLayout.uniform(), model)
    scans = {
        "occupied": points_scan([(5.01, 1.01, -1.7), (5.02, 1.02, -1.0)], [1, 2]),
        "free": points_scan([(5.01, 1.01, -1.7), (5.02, 1.02, -1.68)], [1, 2]),
        "none": points_scan([]),
    }
    occupied = model.occupied_evidence + model.multi_beam_evidence
    delta = {"occupied": occupied, "free": model.free_evidence, "none": 0.0}
    o = 0.0
    for step in steps:
        grid.update(scans[step])
        o = min(max(o + delta[step], model.evidence_min), model.evidence_max)
        o -= min(max(o, -model.decay), model.decay)
        assert float(grid.evidence.sum()) == pytest.approx(o, abs=1e-5)  # the one cell hit
        assert model.evidence_min <= grid.evidence.min() and grid.evidence.max() <= model.evidence_max


# -- eq. 4: max fusion --------------------------------------------------------------------------------


def test_eq4_fusion_takes_the_most_pessimistic_sensor() -> None:
    lidar, other = OccupancyGrid(), OccupancyGrid()
    lidar.update(cast((Box(10.0, 0.0, 1.0, 1.0),)))
    other.update(cast())  # sees only road: free where the first sees the box
    fused = fuse_max([lidar.snapshot(), other.snapshot()])
    np.testing.assert_array_equal(
        fused.occupancy, np.maximum(lidar.snapshot().occupancy, other.snapshot().occupancy)
    )
    np.testing.assert_array_equal(fused.obstacle_mask(), lidar.snapshot().obstacle_mask())
    assert fused.obstacle_mask().sum() > 0


def test_eq4_fusion_refuses_grids_that_do_not_line_up() -> None:
    a, b = OccupancyGrid(), OccupancyGrid(GridLayout.uniform())
    a.update(points_scan([]))
    b.update(points_scan([]))
    with pytest.raises(ValueError, match="differ"):
        fuse_max([a.snapshot(), b.snapshot()])
    c = OccupancyGrid()
    c.update(points_scan([]), EgoPose(5.0, 0.0))
    with pytest.raises(ValueError, match="differ"):
        fuse_max([a.snapshot(), c.snapshot()])
    with pytest.raises(ValueError):
        fuse_max([])


# -- the grid moves with the car, its cells stay in the world ------------------------------------------


@pytest.mark.parametrize("layout", LAYOUTS, ids=LAYOUT_IDS)
def test_shifting_keeps_the_evidence_at_its_place_in_the_world(layout: GridLayout) -> None:
    grid = OccupancyGrid(layout, EvidenceModel(decay=0.0))
    start = EgoPose(1000.3, -200.7, 0.4)
    box = Box(1000.3 + 12.0, -200.7 + 3.0, 1.0, 1.0, 1.5)
    grid.update(cast((box,), pose=start), start)
    before = grid.snapshot().obstacle_cells()
    centre_box = np.array([[box.x_m, box.y_m]])
    # drive away (the box passes into the coarse windows), turn, and come back, seeing nothing
    for pose in [EgoPose(990.0, -210.0, 1.0), EgoPose(960.2, -190.4, -2.0), EgoPose(1001.0, -201.0, 0.3)]:
        grid.update(points_scan([]), pose)
        snap = grid.snapshot()
        # wherever the box now is, its cells are obstacles: the box's faces, within a coarse cell
        assert (snap.occupancy_at(before.xy_m) >= 0.65).all(), pose
        far = np.abs(snap.obstacle_cells().xy_m - centre_box).max(axis=1)
        assert far.max() <= 0.5 + 0.6, pose
    # back in the finest window: the cells seen at first, and no more than the coarse cells around them
    after = grid.snapshot().obstacle_cells()
    assert len(before) <= len(after) <= 16 * len(before)


def test_a_uniform_grid_moves_its_cells_exactly() -> None:
    # one cell seen, nothing traced free towards it: the only evidence in the grid
    grid = OccupancyGrid(GridLayout.uniform(0.5, 10.0), EvidenceModel(decay=0.0, ray_free_evidence=0.0))
    grid.update(points_scan([(3.1, 2.1, -1.7), (3.2, 2.2, -1.0)]))
    (flat0,) = np.flatnonzero(grid.evidence)
    world0 = grid.layout.cell_centres_m(np.array([flat0]))[0][0] + grid.centre_m
    rng = np.random.default_rng(1)
    for _ in range(20):
        x, y, yaw = rng.uniform(-6.0, 6.0, 3)
        pose = EgoPose(float(x), float(y), float(yaw))
        grid.update(points_scan([]), pose)
        flat = np.flatnonzero(grid.evidence)
        if np.abs(np.array(world0) - np.array(grid.centre_m)).max() < 9.5:
            assert len(flat) == 1
            world = grid.layout.cell_centres_m(flat)[0][0] + grid.centre_m
            np.testing.assert_allclose(world, world0, atol=1e-9)


def test_the_centre_follows_the_car_in_steps_of_the_coarsest_cell() -> None:
    grid = OccupancyGrid(GridLayout.graded())
    for x in [0.0, 0.29, 0.31, 7.0, -13.9]:
        grid.update(points_scan([]), EgoPose(x, -x / 2))
        assert abs(grid.centre_m[0] - x) <= 0.3 + 1e-9 and abs(grid.centre_m[1] + x / 2) <= 0.3 + 1e-9
        assert grid.centre_m[0] / 0.6 == pytest.approx(round(grid.centre_m[0] / 0.6))


def test_the_yaw_turns_the_scan_into_the_world_frame() -> None:
    grid = OccupancyGrid(GridLayout.uniform())
    # a point 10 m ahead of a car facing +y (yaw 90 deg) is 10 m north of it in the world
    grid.update(points_scan([(10.01, 0.01, -1.7), (10.02, 0.02, -1.0)]), EgoPose(0.0, 0.0, math.pi / 2))
    cells = grid.snapshot().obstacle_cells()
    assert len(cells) == 1
    np.testing.assert_allclose(cells.xy_m[0], [-0.075, 9.975], atol=1e-6)


def test_a_snapshot_does_not_change_when_the_grid_moves_on() -> None:
    grid = OccupancyGrid()
    grid.update(cast((Box(10.0, 0.0, 1.0, 1.0),)))
    snap = grid.snapshot()
    occupancy = snap.occupancy.copy()
    grid.update(cast(), EgoPose(3.0, 0.0))
    np.testing.assert_array_equal(snap.occupancy, occupancy)
    assert isinstance(snap, GridSnapshot)


def test_obstacle_points_are_the_boxs_not_the_roads_and_leave_the_evidence_alone() -> None:
    scan = cast((Box(10.0, 0.0, 2.0, 2.0, 1.0),), grade=0.05)
    grid = OccupancyGrid()
    obstacle = grid.obstacle_points(scan, EgoPose())
    assert np.count_nonzero(grid.evidence) == 0
    x, y, z = scan.xyz_m.T
    face = (np.abs(x - 9.0) < 0.05) & (np.abs(y) < 0.9) & (z > -1.2)  # the face towards the sensor
    assert obstacle[face].mean() > 0.9
    road = (np.abs(x - 10.0) > 1.5) | (np.abs(y) > 1.5)
    assert obstacle[road].sum() == 0
