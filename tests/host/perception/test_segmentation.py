"""Obstacle cells into objects (seed 000 section 5, bywire.host.perception.segmentation): connected
components at distance d, the minimum size, and each object's box and height."""

from __future__ import annotations

import math
from unittest import mock

import numpy as np
import pytest
from grid_scenes import Box, cast
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from bywire.host.perception import segmentation
from bywire.host.perception.grid import GridLayout, GridSnapshot, OccupancyGrid
from bywire.host.perception.segmentation import ParticipantShape, SegmentationParams, SegmentedObject, segment


def snapshot_of(layout: GridLayout, mask: np.ndarray, top_m: float = 0.0) -> GridSnapshot:
    occupancy = np.where(mask, 0.9, 0.5).astype(np.float32).reshape(layout.shape)
    z_min = np.where(mask, -1.7, np.nan).astype(np.float32).reshape(layout.shape)
    z_max = np.where(mask, -1.7 + top_m, np.nan).astype(np.float32).reshape(layout.shape)
    return GridSnapshot(layout, (0.0, 0.0), occupancy, z_min, z_max)


def blocks(layout: GridLayout, *spans: tuple[int, int, int, int]) -> np.ndarray:
    """A one-level mask with rectangles of cells [y0, y1) x [x0, x1)."""
    mask = np.zeros(layout.shape, bool)
    for y0, y1, x0, x1 in spans:
        mask[0, y0:y1, x0:x1] = True
    return mask


SMALL = GridLayout.uniform(0.15, 6.0)  # 80 x 80 cells


@pytest.mark.parametrize(("gap_cells", "objects"), [(1, 1), (3, 1), (4, 2), (8, 2)])
def test_cells_join_within_d_and_stay_apart_beyond(gap_cells: int, objects: int) -> None:
    # d = 0.5 m: a gap of 3 cells (0.45 m) joins, 4 (0.60 m) does not
    mask = blocks(SMALL, (10, 20, 10, 15), (10, 20, 15 + gap_cells, 20 + gap_cells))
    seg = segment(snapshot_of(SMALL, mask), SegmentationParams(join_distance_m=0.5, min_cells=1))
    assert len(seg.objects) == objects
    assert sum(o.cells for o in seg.objects) == mask.sum()


@pytest.mark.parametrize(("gap_m", "objects"), [(0.25, 1), (1.2, 2)])
def test_two_boxes_further_apart_than_d_are_two_objects(gap_m: float, objects: int) -> None:
    grid = OccupancyGrid()
    grid.update(cast((Box(10.0, -0.5, 1.0, 1.0), Box(10.0, 0.5 + gap_m, 1.0, 1.0))))
    seg = segment(grid.snapshot())
    near = [o for o in seg.objects if abs(o.x_m - 10.0) < 2.0 and abs(o.y_m) < 3.0]
    assert len(near) == objects
    assert all(o.height_m == pytest.approx(1.5, abs=0.2) for o in near)


def test_components_smaller_than_the_minimum_are_dropped() -> None:
    mask = blocks(SMALL, (10, 11, 10, 11), (30, 31, 30, 32), (50, 52, 50, 52))
    seg = segment(snapshot_of(SMALL, mask), SegmentationParams(min_cells=3))
    assert [o.cells for o in seg.objects] == [4]
    assert (seg.object_of_cell == -1).sum() == 3


def test_an_empty_grid_has_no_objects() -> None:
    seg = segment(snapshot_of(SMALL, np.zeros(SMALL.shape, bool)))
    assert seg.objects == [] and len(seg.cells) == 0


@pytest.mark.parametrize("yaw_deg", [0.0, 30.0, -60.0, 90.0])
def test_an_objects_box_has_the_rectangles_centre_size_and_orientation(yaw_deg: float) -> None:
    layout = GridLayout.uniform(0.1, 8.0)
    c = layout.cell_centres_m(np.arange(layout.n_cells))[0]
    yaw = math.radians(yaw_deg)
    u = (c[:, 0] - 1.0) * math.cos(yaw) + (c[:, 1] + 2.0) * math.sin(yaw)
    v = -(c[:, 0] - 1.0) * math.sin(yaw) + (c[:, 1] + 2.0) * math.cos(yaw)
    mask = (np.abs(u) <= 2.0) & (np.abs(v) <= 0.8)
    (o,) = segment(snapshot_of(layout, mask, top_m=1.4)).objects
    assert (o.x_m, o.y_m) == pytest.approx((1.0, -2.0), abs=0.05)
    assert o.length_m == pytest.approx(4.0, abs=0.25) and o.width_m == pytest.approx(1.6, abs=0.25)
    assert abs(math.remainder(o.yaw_rad - yaw, math.pi)) < math.radians(2.0)
    assert -math.pi / 2 <= o.yaw_rad < math.pi / 2
    assert o.height_m == pytest.approx(1.4, abs=1e-5)
    assert o.area_m2 == pytest.approx(mask.sum() * 0.01)


def test_an_object_across_a_window_edge_of_the_graded_layout_is_one_object() -> None:
    layout = GridLayout.graded(0.15, 12.0, 2)  # 0.15 m cells to 6 m, 0.3 m beyond
    n = layout.cells_per_side
    mask = np.zeros(layout.shape, bool)
    mask[0, n // 2 : n // 2 + 3, n - 10 :] = True  # fine cells up to the edge at x = 6 m
    mask[1, n // 2 : n // 2 + 2, 3 * n // 4 : 3 * n // 4 + 5] = True  # coarse cells from the edge on
    seg = segment(snapshot_of(layout, mask), SegmentationParams(min_cells=1))
    assert len(seg.objects) == 1
    (o,) = seg.objects
    assert o.length_m == pytest.approx(10 * 0.15 + 5 * 0.3, abs=0.05)  # the two widths tilt the axis


def reference_components(xy: np.ndarray, size: np.ndarray, d_m: float) -> list[set[int]]:
    """Section 5's graph, pair by pair: cells whose squares are at most d apart on each axis."""
    parent = list(range(len(xy)))

    def find(i: int) -> int:
        while parent[i] != i:
            i = parent[i]
        return i

    for i in range(len(xy)):
        for j in range(i + 1, len(xy)):
            gap = np.abs(xy[i] - xy[j]) - (size[i] + size[j]) / 2
            if (gap <= d_m + 1e-9).all():
                parent[find(i)] = find(j)
    groups: dict[int, set[int]] = {}
    for i in range(len(xy)):
        groups.setdefault(find(i), set()).add(i)
    return sorted(groups.values(), key=min)


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    density=st.floats(0.01, 0.2),
    d_m=st.sampled_from([0.0, 0.15, 0.3, 0.5, 1.0]),
    graded=st.booleans(),
)
def test_the_components_are_those_of_the_cell_graph(
    seed: int, density: float, d_m: float, graded: bool
) -> None:
    layout = GridLayout.graded(0.15, 2.4, 2) if graded else GridLayout.uniform(0.15, 1.8)
    mask = (np.random.default_rng(seed).random(layout.shape) < density) & layout.active_mask()
    seg = segment(snapshot_of(layout, mask), SegmentationParams(join_distance_m=d_m, min_cells=1))
    want = reference_components(seg.cells.xy_m, seg.cells.size_m, d_m)
    got: dict[int, set[int]] = {}
    for i, k in enumerate(seg.object_of_cell):
        got.setdefault(int(k), set()).add(i)
    assert sorted(got.values(), key=min) == want


def raster_numbering(snapshot: GridSnapshot, d_m: float, min_cells: int) -> np.ndarray:
    """The object index of each obstacle cell as one raster of the finest cell size numbers them: every
    cell painted as its block, dilated by g = floor(d / finest cell) towards +x and +y, labelled
    8-connected; objects in the order of their labels, too-small ones -1."""
    layout = snapshot.layout
    raster = np.asarray(layout.compose(snapshot.obstacle_mask()), bool)
    g = math.floor(d_m / layout.finest_cell_m + 1e-9)
    grown = raster.copy()
    for k in range(1, g + 1):
        grown[k:] |= raster[:-k]
    wide = grown.copy()
    for k in range(1, g + 1):
        wide[:, k:] |= grown[:, :-k]
    labels, _ = ndimage.label(wide, structure=np.ones((3, 3), bool))
    n = layout.cells_per_side
    level, rest = np.divmod(np.flatnonzero(snapshot.obstacle_mask()), n * n)
    iy, ix = np.divmod(rest, n)
    half = layout.raster_side // 2
    label = labels[((iy - n // 2) << level) + half, ((ix - n // 2) << level) + half]
    keep = np.bincount(label)[label] >= min_cells
    out = np.full(label.size, -1)
    out[keep] = np.unique(label[keep], return_inverse=True)[1]
    return out


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    density=st.floats(0.005, 0.3),
    d_m=st.sampled_from([0.0, 0.15, 0.3, 0.5, 0.9, 2.0, 5.0]),
    levels=st.integers(1, 4),
    min_cells=st.integers(1, 4),
)
def test_objects_are_numbered_as_the_labels_of_one_fine_raster(
    seed: int, density: float, d_m: float, levels: int, min_cells: int
) -> None:
    # The levels are labelled each on its own cells and joined across the windows' edges (the cells
    # near an edge paired all with all, or through a k-d tree when there are many); the result must
    # be the one raster's, in its order, whatever the layout and d.
    layout = GridLayout(0.15, 24, levels)
    mask = (np.random.default_rng(seed).random(layout.shape) < density) & layout.active_mask()
    want = raster_numbering(snapshot_of(layout, mask), d_m, min_cells)
    for all_pairs_max in (1 << 17, 0):
        with mock.patch.object(segmentation, "_ALL_PAIRS_MAX", all_pairs_max):
            seg = segment(snapshot_of(layout, mask), SegmentationParams(d_m, min_cells))
        assert np.array_equal(seg.object_of_cell, want)


def test_the_participant_shape_takes_cars_and_people_not_walls_or_kerbs() -> None:
    shape = ParticipantShape()

    def obj(length: float, width: float, height: float) -> SegmentedObject:
        return SegmentedObject(0.0, 0.0, length, width, 0.0, height, 10, length * width)

    assert shape.accepts(obj(4.5, 1.8, 1.5)) and shape.accepts(obj(0.6, 0.5, 1.8))
    assert shape.accepts(obj(16.5, 2.55, 4.0))
    assert not shape.accepts(obj(40.0, 1.0, 3.0))  # a wall
    assert not shape.accepts(obj(3.0, 0.3, 0.15))  # a kerb
    assert not shape.accepts(obj(8.0, 8.0, 3.0))  # a building's corner
