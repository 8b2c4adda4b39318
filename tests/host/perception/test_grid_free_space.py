"""Free space along the beams in the occupancy grid (seed 000 section 4, the free part of the inverse
sensor model): what a moving car leaves behind is cleared once the beams pass there, what stands or
hides behind an obstacle is not; and the compiled kernels (bywire.host.perception.grid_kernels) held
equal to plain references."""

from __future__ import annotations

import math

import numpy as np
import pytest
from grid_scenes import Box, cast
from hypothesis import given, settings
from hypothesis import strategies as st

from bywire.host.perception import grid_kernels
from bywire.host.perception.ego_pose import EgoPose
from bywire.host.perception.grid import EvidenceModel, GridLayout, OccupancyGrid
from bywire.host.perception.scan import Scan

LAYOUTS = [GridLayout.graded(), GridLayout.uniform()]
LAYOUT_IDS = ["graded", "uniform"]
CAR = (4.5, 1.8)


def footprint_cells(grid: OccupancyGrid, box: Box) -> np.ndarray:
    """Flat indices of the cells whose centres lie in the box's footprint (axis-aligned boxes)."""
    layout = grid.layout
    flat = np.flatnonzero(layout.active_mask())
    xy, _ = layout.cell_centres_m(flat)
    xy += np.asarray(grid.centre_m)
    inside = (np.abs(xy[:, 0] - box.x_m) <= box.size_x_m / 2) & (
        np.abs(xy[:, 1] - box.y_m) <= box.size_y_m / 2
    )
    return flat[inside]


def obstacles_in(grid: OccupancyGrid, cells: np.ndarray) -> int:
    return int((grid.snapshot().occupancy.reshape(-1)[cells] >= grid.model.obstacle_probability).sum())


# -- behaviour ----------------------------------------------------------------------------------------


@pytest.mark.parametrize("layout", LAYOUTS, ids=LAYOUT_IDS)
def test_a_car_that_drove_on_is_cleared_where_the_beams_now_pass(layout: GridLayout) -> None:
    # a car 12 m ahead and 4 m to the left for half a second, then gone: its cells are seen free
    car = Box(12.0, 4.0, *CAR)
    seen_free, seen_ground_only = (
        OccupancyGrid(layout),
        OccupancyGrid(layout, EvidenceModel(ray_free_evidence=0.0)),
    )
    for k in range(5):
        for grid in (seen_free, seen_ground_only):
            grid.update(cast((car,), range_noise_m=0.02, seed=k))
    cells = footprint_cells(seen_free, Box(car.x_m, car.y_m, car.size_x_m + 0.6, car.size_y_m + 0.6))
    assert obstacles_in(seen_free, cells) > 20
    for k in range(2):
        for grid in (seen_free, seen_ground_only):
            grid.update(cast(range_noise_m=0.02, seed=10 + k))
    assert obstacles_in(seen_free, cells) == 0
    # where only its own ground returns clear a cell, the car's near side is still there
    assert obstacles_in(seen_ground_only, cells) > 10


def test_a_standing_car_keeps_its_evidence_while_the_beams_pass_beside_it() -> None:
    car = Box(9.0, -3.5, *CAR)
    grid, reference = OccupancyGrid(), OccupancyGrid(model=EvidenceModel(ray_free_evidence=0.0))
    for k in range(12):
        for g in (grid, reference):
            g.update(cast((car,), range_noise_m=0.02, seed=k))
    mask, ref_mask = grid.snapshot().obstacle_mask(), reference.snapshot().obstacle_mask()
    np.testing.assert_array_equal(mask, ref_mask)
    m = grid.model
    assert np.all(grid.evidence[mask] >= m.evidence_max - m.decay - 1e-6)


def test_what_hides_behind_an_obstacle_only_decays() -> None:
    far = Box(24.0, 0.0, 1.8, 4.5)
    grid = OccupancyGrid()
    for k in range(3):
        grid.update(cast((far,), seed=k))
    cells = footprint_cells(grid, Box(far.x_m, far.y_m, far.size_x_m + 0.6, far.size_y_m + 0.6))
    before = grid.evidence.reshape(-1)[cells].copy()
    assert (before > 2.0).sum() > 5
    # a van stops between us and it: every beam towards the car now ends at the van
    van = Box(10.0, 0.0, 2.0, 5.0, height_m=2.9)
    grid.update(cast((van, far)))
    after = grid.evidence.reshape(-1)[cells]
    np.testing.assert_allclose(after, np.sign(before) * np.maximum(np.abs(before) - grid.model.decay, 0.0))


def test_the_road_before_an_obstacle_is_free_and_behind_it_unknown() -> None:
    box = Box(15.0, 0.0, 2.0, 2.0)
    grid = OccupancyGrid(GridLayout.uniform())
    grid.update(cast((box,)))
    snap = grid.snapshot()
    before = np.column_stack((np.linspace(3.0, 13.0, 21), np.zeros(21)))
    behind = np.column_stack((np.linspace(17.0, 30.0, 27), np.zeros(27)))
    m = grid.model
    np.testing.assert_allclose(
        grid.evidence.reshape(-1)[_cells_at(grid, before)], m.ray_free_evidence + m.decay, atol=1e-6
    )
    np.testing.assert_array_equal(snap.occupancy_at(behind), 0.5)
    assert (snap.occupancy_at(np.array([[14.0, 0.0]])) >= m.obstacle_probability).all()


def test_free_space_off_is_the_model_without_it() -> None:
    grid = OccupancyGrid(model=EvidenceModel(ray_free_evidence=0.0))
    grid.update(cast((Box(15.0, 0.0, 2.0, 2.0),)))
    # only cells that returned points hold evidence
    hit = np.zeros(grid.layout.n_cells, bool)
    hit[grid.measure(cast((Box(15.0, 0.0, 2.0, 2.0),)), EgoPose()).cells] = True
    assert np.all(hit[np.flatnonzero(grid.evidence)])
    with pytest.raises(ValueError, match="ray_free_evidence"):
        EvidenceModel(ray_free_evidence=0.5)


def _cells_at(grid: OccupancyGrid, xy: np.ndarray) -> np.ndarray:
    q = np.floor((xy - np.asarray(grid.centre_m)) / grid.layout.finest_cell_m).astype(np.int64)
    return grid.layout.flat_index(q[:, 0], q[:, 1])


# -- the kernels against plain references -------------------------------------------------------------


def reference_project(grid: OccupancyGrid, scan: Scan, pose: EgoPose) -> np.ndarray:
    """The numpy projection the kernel replaced (float32 throughout): each point's cell, -1 if left out."""
    m, layout = grid.model, grid.layout
    x, y, z = (scan.xyz_m[:, i].astype(np.float32) for i in range(3))
    c, s = np.float32(math.cos(pose.yaw_rad)), np.float32(math.sin(pose.yaw_rad))
    cx, cy = grid.centre_m
    inv = np.float32(1.0 / layout.finest_cell_m)
    with np.errstate(invalid="ignore"):
        qx = np.floor((c * x - s * y + np.float32(pose.x_m - cx)) * inv)
        qy = np.floor((s * x + c * y + np.float32(pose.y_m - cy)) * inv)
    h = layout.raster_side // 2
    keep = (qx >= -h) & (qx < h) & (qy >= -h) & (qy < h)
    keep &= z <= np.float32(m.max_height_m - scan.sensor_height_m)
    keep &= x * x + y * y >= np.float32(m.min_range_m**2)
    out = np.full(len(x), -1, np.int64)
    out[keep] = layout.flat_index(qx[keep].astype(np.int64), qy[keep].astype(np.int64))
    return out


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    layout=st.sampled_from([*LAYOUTS, GridLayout.graded(0.2, 30.0, 2)]),
    x=st.floats(-500.0, 500.0),
    yaw=st.floats(-math.pi, math.pi),
)
def test_the_projection_kernel_equals_the_numpy_projection(
    seed: int, layout: GridLayout, x: float, yaw: float
) -> None:
    rng = np.random.default_rng(seed)
    xyz = rng.normal(0.0, 40.0, (3000, 3)).astype(np.float32)
    xyz[:, 2] = rng.uniform(-3.0, 2.0, 3000)
    xyz[:50] = np.nan
    xyz[50:60, 1] = np.inf
    xyz[60:100] *= np.float32(0.02)  # on the car
    scan = Scan(xyz, np.zeros(3000, np.float32), np.zeros(3000, np.int16))
    grid = OccupancyGrid(layout)
    pose = EgoPose(x, x / 3.0, yaw)
    grid.recentre(pose.x_m, pose.y_m)
    _, flat = grid._project(scan, pose)
    np.testing.assert_array_equal(flat, reference_project(grid, scan, pose))


def test_the_sector_angle_is_atan2_within_2e_5_rad() -> None:
    a = np.linspace(-math.pi, math.pi, 100_001)
    for r in (1e-3, 1.0, 150.0):
        got = np.array([grid_kernels._atan2(r * math.sin(t), r * math.cos(t)) for t in a[::7]])
        want = np.arctan2(r * np.sin(a[::7]), r * np.cos(a[::7]))
        d = np.remainder(got - want + math.pi, 2 * math.pi) - math.pi
        assert np.abs(d).max() < 2e-5


def reference_sector_ranges(
    xyz: np.ndarray, cls: np.ndarray, yaw: float, z_low: float, sectors: int, guard: int
) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    x, y = xyz[:, 0].astype(float), xyz[:, 1].astype(float)
    dx, dy = c * x - s * y, s * x + c * y
    r = np.hypot(dx, dy)
    k = np.clip(((np.arctan2(dy, dx) + math.pi) * sectors / (2 * math.pi)).astype(int), 0, sectors - 1)
    free, nearest = np.empty(sectors), np.full(sectors, math.inf)
    for j in range(sectors):
        ground = r[(k == j) & (cls == 1)]
        block = (k == j) & (cls == 2)
        low = block & (xyz[:, 2] <= z_low)
        nearest[j] = r[block].min() if block.any() else math.inf
        far_ground = ground.max() if ground.size else 0.0
        free[j] = nearest[j] if low.any() else min(nearest[j], far_ground)
    for shift in range(-guard, guard + 1):
        free = np.minimum(free, np.roll(nearest, shift))
    return free


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    yaw=st.floats(-math.pi, math.pi),
    sectors=st.sampled_from([16, 360, 1024]),
    guard=st.integers(0, 3),
)
def test_the_sector_ranges_equal_a_plain_reference(seed: int, yaw: float, sectors: int, guard: int) -> None:
    rng = np.random.default_rng(seed)
    n = 4000
    xyz = np.column_stack((rng.uniform(-60.0, 60.0, (n, 2)), rng.uniform(-1.8, 1.0, n))).astype(np.float32)
    # no point within 1e-4 rad of a sector's edge: there the kernel's atan2 (2e-5 rad) may differ
    az = np.arctan2(xyz[:, 1].astype(float), xyz[:, 0].astype(float)) + yaw + math.pi
    u = np.remainder(az, 2 * math.pi) * sectors / (2 * math.pi)
    xyz = xyz[np.abs(u - np.round(u)) * 2 * math.pi / sectors > 1e-4]
    n = len(xyz)
    flat = rng.integers(-1, 50, n).astype(np.int32)  # cells 0..49, -1 left out
    cell_class = rng.integers(0, 3, 50).astype(np.uint8)
    cls = np.where(flat >= 0, cell_class[np.maximum(flat, 0)], 0)
    got = grid_kernels.sector_ranges(
        xyz, flat, cell_class, math.cos(yaw), math.sin(yaw), -1.0, sectors, guard
    )
    want = reference_sector_ranges(xyz, cls, yaw, -1.0, sectors, guard)
    np.testing.assert_allclose(got, want, rtol=1e-12)


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    layout=st.sampled_from(
        [GridLayout.graded(0.15, 19.2), GridLayout.uniform(0.3, 12.0), GridLayout.graded(0.2, 9.6, 2)]
    ),
)
def test_the_traced_cells_are_those_the_sector_rays_cross(seed: int, layout: GridLayout) -> None:
    """Sound: every listed cell is crossed by a sector's ray, lies wholly the margin short of the
    sector's range, and held no obstacle. Complete: every such cell that a ray crosses (its centre
    nearer the ray than half its side) is listed."""
    rng = np.random.default_rng(seed)
    sectors, start, margin = 256, 2.0, 0.2
    free = rng.uniform(0.0, 1.2 * layout.half_extent_m, sectors)
    half_step = layout.shift_step_m / 2
    px, py = rng.uniform(-half_step, half_step, 2)
    cls = np.zeros(layout.n_cells, np.uint8)
    cls[rng.integers(0, layout.n_cells, layout.n_cells // 50)] = 2
    stamp = np.zeros(layout.n_cells, np.int64)
    out = np.empty(layout.n_cells, np.int32)
    n = layout.cells_per_side
    k = grid_kernels.trace_free(
        free, start, margin, px, py, layout.finest_cell_m, n // 2, n, layout.levels, cls, stamp, 1, out
    )
    listed = out[:k]
    assert len(np.unique(listed)) == k and not (cls[listed] == 2).any()

    active = np.flatnonzero(layout.active_mask())
    xy, size = layout.cell_centres_m(active)
    rel = xy - np.array([px, py])
    theta = -math.pi + (np.arange(sectors) + 0.5) * 2 * math.pi / sectors
    u = np.column_stack((np.cos(theta), np.sin(theta)))
    along = rel @ u.T  # (cells, sectors): distance along each ray, and off it
    off = np.abs(rel[:, 0, None] * u[None, :, 1] - rel[:, 1, None] * u[None, :, 0])
    # the farthest corner from the sensor, within the margin of the range
    far = np.hypot(np.abs(rel[:, 0]) + size / 2, np.abs(rel[:, 1]) + size / 2)
    within = far[:, None] <= free[None, :] - margin + 1e-9
    crossed = (off <= size[:, None] / math.sqrt(2.0)) & (along >= start - size[:, None]) & within
    is_listed = np.isin(active, listed)
    assert crossed[is_listed].any(axis=1).all()
    sure = (
        (off < 0.49 * size[:, None])
        & (along >= start + size[:, None])
        & (far[:, None] <= free[None, :] - margin - 1e-9)
    )
    want = sure.any(axis=1) & (cls[active] != 2)
    assert is_listed[want].all()
