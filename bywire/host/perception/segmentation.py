"""Obstacle cells of the grid segmented into objects (seed 000 section 5, "obstacle detection").

Section 5: each grid cell is a node of a graph, two are connected if their distance is within a
threshold d (0.5 m), the connected components are the objects, and components of fewer than a minimum
number of cells are discarded as noise.

The distance between two cells is the gap between their squares whatever their sizes, in whole
finest cells: cells with a gap of at most g = floor(d / finest cell) on both axes are joined. Within
one level of the layout (cells of 2**k finest cells) that is a lattice offset of at most 1 + g // 2**k
cells on each axis, so each level's obstacle mask is dilated by g // 2**k cells towards +x and +y only
(two cells then touch exactly when they are joined) and labelled 8-connected (scipy.ndimage.label) on
the level's own N x N cells. Across levels only cells near a window's edge can be joined: those pairs
are found among the few cells within g of the edge (scipy.spatial.cKDTree, Chebyshev) and checked
exactly, and the per-level components they link are merged (scipy.sparse.csgraph). The result is
that of labelling one raster of the finest cell size with every cell painted as its block, at an
eighth of the cost on the default three levels; objects are numbered as that raster's labels are, by
each component's first cell in row-major raster order. Deviation: the gap is measured per axis
(Chebyshev), so cells diagonal to each other are joined up to d * sqrt(2) apart.

Each object gets the centre and extent of the box on its principal axes (area-weighted second moments
of its cells, each cell a square), its cell count and its height (highest minus lowest return in its
cells). The box centre is that of what the sensor saw: of a car seen from behind, the rear face.

`ParticipantShape` is the shape half of section 5's "heuristics based on their shape and location
relative to the road network" that pick traffic-participant candidates; the location half needs the
road network and is the behaviour's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import ndimage, sparse
from scipy.sparse import csgraph
from scipy.spatial import cKDTree

from bywire.host.perception.grid import GridLayout, GridSnapshot, ObstacleCells

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]


# Cells near a window's edge are paired all with all up to this many pairs (a street has a few
# hundred on either side: 35 000 pairs on KITTI), beyond it through a k-d tree.
_ALL_PAIRS_MAX = 1 << 17


@dataclass(frozen=True)
class SegmentationParams:
    # d of section 5.
    join_distance_m: float = 0.5
    # Section 5's noise floor; 3 cells drop the lone cells a single stray return makes.
    min_cells: int = 3

    def __post_init__(self) -> None:
        if self.join_distance_m < 0.0 or self.min_cells < 1:
            raise ValueError("join_distance_m must be >= 0 and min_cells >= 1")


@dataclass(frozen=True)
class SegmentedObject:
    """One object in the grid's world frame: box centre (m), length along yaw >= width across it (m),
    yaw in [-pi/2, pi/2) (an orientation: a box has no front), height (m), cell count, area (m^2)."""

    x_m: float
    y_m: float
    length_m: float
    width_m: float
    yaw_rad: float
    height_m: float
    cells: int
    area_m2: float

    def corners_m(self) -> F64:
        """The box's four corners (4, 2), counter-clockwise."""
        return box_corners_m(self.x_m, self.y_m, self.length_m, self.width_m, self.yaw_rad)


def box_corners_m(x_m: float, y_m: float, length_m: float, width_m: float, yaw_rad: float) -> F64:
    """The four corners (4, 2) of an oriented box on the ground plane, counter-clockwise."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    u = np.array([1.0, -1.0, -1.0, 1.0]) * length_m / 2
    v = np.array([1.0, 1.0, -1.0, -1.0]) * width_m / 2
    return np.column_stack((x_m + c * u - s * v, y_m + s * u + c * v))


@dataclass(frozen=True)
class Segmentation:
    """The objects and, per obstacle cell of `cells`, the index of its object (-1: too small)."""

    objects: list[SegmentedObject]
    cells: ObstacleCells
    object_of_cell: I64


@dataclass(frozen=True)
class ParticipantShape:
    """Sizes a car, truck, cyclist or pedestrian can have (metres); walls, hedges and kerbs fail."""

    max_length_m: float = 20.0  # a semi-trailer, 16.5 m, seen with some smear
    max_width_m: float = 3.5  # 2.55 m legal width plus mirrors and smear
    min_height_m: float = 0.5  # below it: kerbs, low walls
    max_height_m: float = 4.5  # 4 m legal height plus margin
    max_area_m2: float = 60.0

    def accepts(self, o: SegmentedObject) -> bool:
        return (
            o.length_m <= self.max_length_m
            and o.width_m <= self.max_width_m
            and self.min_height_m <= o.height_m <= self.max_height_m
            and o.area_m2 <= self.max_area_m2
        )


def segment(
    snapshot: GridSnapshot, params: SegmentationParams | None = None, p_min: float | None = None
) -> Segmentation:
    """Section 5's connected components of the snapshot's obstacle cells (occupancy >= p_min; None:
    the grid's own obstacle probability)."""
    params = params if params is not None else SegmentationParams()
    layout = snapshot.layout
    cells = snapshot.obstacle_cells(p_min)
    if len(cells) == 0:
        return Segmentation([], cells, np.zeros(0, np.int64))
    mask = snapshot.obstacle_mask(p_min)
    gap = math.floor(params.join_distance_m / layout.finest_cell_m + 1e-9)
    row, col, size = _raster_squares(layout, cells.cells)
    comp, n_comp = _components(layout, mask, row, col, size, gap)
    # Objects are numbered by their first cell in row-major raster order (as a raster's labels are).
    first = np.full(n_comp, np.iinfo(np.int64).max)
    np.minimum.at(first, comp, row * layout.raster_side + col)
    kept = np.flatnonzero(np.bincount(comp, minlength=n_comp) >= params.min_cells)
    object_of_comp = np.full(n_comp, -1, np.int64)
    object_of_comp[kept[np.argsort(first[kept])]] = np.arange(kept.size)
    out_index = object_of_comp[comp]
    which = np.flatnonzero(out_index >= 0)
    objects = _describe(cells, snapshot.centre_m, out_index[which], which, kept.size)
    return Segmentation(objects, cells, out_index)


def _components(
    layout: GridLayout, mask: npt.NDArray[np.bool_], row: I64, col: I64, size: I64, gap: int
) -> tuple[I64, int]:
    """The component (0 .. C - 1) of each cell of `mask` (levels, N, N), in flat order, and C: cells
    whose squares (`_raster_squares`, in flat order) are at most `gap` finest cells apart on both axes
    are joined (see the module docstring)."""
    eight = np.ones((3, 3), bool)
    node_of_level = []
    n_nodes = 0
    for k in range(layout.levels):
        level = mask[k]
        m = gap >> k  # (|di| - 1) * 2**k <= gap  <=>  |di| <= 1 + m, per axis
        labels, count = ndimage.label(_dilate_towards_plus(level, m), structure=eight)
        node_of_level.append(labels[level].astype(np.int64) + (n_nodes - 1))  # row-major: flat order
        n_nodes += int(count)
    node = np.concatenate(node_of_level)
    if layout.levels == 1 or node.size == 0:
        return node, n_nodes
    a, b = _pairs_across_windows(layout, row, col, size, gap)
    if a.size == 0:
        return node, n_nodes
    # Merge the per-level components the pairs link: a graph of those components only.
    linked, end = np.unique(np.concatenate((node[a], node[b])), return_inverse=True)
    graph = sparse.coo_matrix(
        (np.ones(a.size, np.int8), (end[: a.size], end[a.size :])), shape=(linked.size, linked.size)
    )
    _, merged = csgraph.connected_components(graph, directed=False)
    label = np.arange(n_nodes)
    label[linked] = n_nodes + merged  # apart from every unlinked component's own number
    numbers, comp = np.unique(label, return_inverse=True)
    return comp[node].astype(np.int64), int(numbers.size)


def _pairs_across_windows(layout: GridLayout, row: I64, col: I64, size: I64, gap: int) -> tuple[I64, I64]:
    """Index pairs (fine, coarse) of cells of different levels whose squares (raster rows, columns,
    sides; the cells level by level, as in flat order) are at most `gap` apart on both axes."""
    half = layout.raster_side // 2
    # doubled centres: two squares are within gap on an axis when |2 dc| <= 2 gap + s_fine + s_coarse
    centre_r, centre_c = 2 * row + size, 2 * col + size
    starts = np.searchsorted(size, 1 << np.arange(layout.levels))
    out_a, out_b = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)]
    for k in range(layout.levels - 1):
        # window k's square on the raster: [lo, hi) on both axes; its cells, then the coarser ones
        lo, hi = half - (layout.cells_per_side << k) // 2, half + (layout.cells_per_side << k) // 2
        s = 1 << k
        rf, cf = row[starts[k] : starts[k + 1]], col[starts[k] : starts[k + 1]]
        inside_edge = np.minimum(np.minimum(rf - lo, cf - lo), np.minimum(hi - rf - s, hi - cf - s))
        fine = starts[k] + np.flatnonzero(inside_edge <= gap)
        rc, cc, sc = row[starts[k + 1] :], col[starts[k + 1] :], size[starts[k + 1] :]
        outside_gap = np.maximum(np.maximum(lo - rc - sc, rc - hi), np.maximum(lo - cc - sc, cc - hi))
        coarse = starts[k + 1] + np.flatnonzero(outside_gap <= gap)
        if fine.size == 0 or coarse.size == 0:
            continue
        if fine.size * coarse.size <= _ALL_PAIRS_MAX:  # a street's few hundred: every pair
            bound = 2 * gap + size[fine][:, None] + size[coarse][None, :]
            joined = (np.abs(centre_r[fine][:, None] - centre_r[coarse][None, :]) <= bound) & (
                np.abs(centre_c[fine][:, None] - centre_c[coarse][None, :]) <= bound
            )
            fi, ci = np.nonzero(joined)
            out_a.append(fine[fi])
            out_b.append(coarse[ci])
            continue
        reach = 2 * gap + s + int(size[coarse].max())
        near = cKDTree(np.column_stack((centre_r[fine], centre_c[fine]))).sparse_distance_matrix(
            cKDTree(np.column_stack((centre_r[coarse], centre_c[coarse]))),
            reach + 0.5,
            p=np.inf,
            output_type="ndarray",
        )
        i, j = fine[near["i"]], coarse[near["j"]]
        bound_ij = 2 * gap + size[i] + size[j]
        ok = (np.abs(centre_r[i] - centre_r[j]) <= bound_ij) & (np.abs(centre_c[i] - centre_c[j]) <= bound_ij)
        out_a.append(i[ok])
        out_b.append(j[ok])
    return np.concatenate(out_a), np.concatenate(out_b)


def _dilate_towards_plus(mask: npt.NDArray[np.bool_], gap: int) -> npt.NDArray[np.bool_]:
    if gap == 0:
        return mask
    rows = mask.copy()
    for k in range(1, gap + 1):
        rows[k:] |= mask[:-k]
    out = rows.copy()
    for k in range(1, gap + 1):
        out[:, k:] |= rows[:, :-k]
    return out


def _raster_squares(layout: GridLayout, flat: npt.NDArray[np.integer]) -> tuple[I64, I64, I64]:
    """Each cell's square on the raster of the finest cell size (`GridLayout.compose`): the row and
    column of its lower-left corner and its side, in finest cells."""
    n = layout.cells_per_side
    level, rest = np.divmod(np.asarray(flat, np.int64), n * n)
    iy, ix = np.divmod(rest, n)
    half = layout.raster_side // 2
    row = np.left_shift(iy - n // 2, level) + half
    col = np.left_shift(ix - n // 2, level) + half
    return row, col, np.left_shift(1, level)


def _describe(
    cells: ObstacleCells, centre_m: tuple[float, float], obj: I64, which: I64, n_objects: int
) -> list[SegmentedObject]:
    if n_objects == 0:
        return []
    # Relative to the grid centre: world coordinates can be large, their squares lose the metres.
    x = cells.xy_m[which, 0] - centre_m[0]
    y = cells.xy_m[which, 1] - centre_m[1]
    size = cells.size_m[which]
    w = size * size
    area = np.bincount(obj, w, n_objects)
    mx = np.bincount(obj, w * x, n_objects) / area
    my = np.bincount(obj, w * y, n_objects) / area
    dx, dy = x - mx[obj], y - my[obj]
    # A square cell of side s spreads s^2 / 12 along any axis on its own.
    own = np.bincount(obj, w * w / 12.0, n_objects) / area
    cxx = np.bincount(obj, w * dx * dx, n_objects) / area + own
    cyy = np.bincount(obj, w * dy * dy, n_objects) / area + own
    cxy = np.bincount(obj, w * dx * dy, n_objects) / area
    yaw = 0.5 * np.arctan2(2.0 * cxy, cxx - cyy)
    c, s = np.cos(yaw)[obj], np.sin(yaw)[obj]
    u = dx * c + dy * s
    v = -dx * s + dy * c
    half = 0.5 * size * (np.abs(c) + np.abs(s))  # a square's half extent along any axis
    # A stable sort of small integers is a radix sort: 16 bits hold any scene's objects.
    order = np.argsort(obj.astype(np.int16) if n_objects <= 1 << 15 else obj, kind="stable")
    first = np.concatenate(([0], np.flatnonzero(np.diff(obj[order])) + 1))
    u_lo = np.minimum.reduceat((u - half)[order], first)
    u_hi = np.maximum.reduceat((u + half)[order], first)
    v_lo = np.minimum.reduceat((v - half)[order], first)
    v_hi = np.maximum.reduceat((v + half)[order], first)
    z_top = np.fmax.reduceat(cells.z_max_m[which][order], first)
    z_bottom = np.fmin.reduceat(cells.z_min_m[which][order], first)
    # Per object in Python floats (the same IEEE arithmetic as numpy's, without its scalar overhead).
    rows = zip(
        (0.5 * (u_lo + u_hi)).tolist(),
        (0.5 * (v_lo + v_hi)).tolist(),
        (u_hi - u_lo).tolist(),
        (v_hi - v_lo).tolist(),
        yaw.tolist(),
        (z_top - z_bottom).tolist(),  # float32, as measured
        mx.tolist(),
        my.tolist(),
        np.bincount(obj, minlength=n_objects).tolist(),
        area.tolist(),
        strict=True,
    )
    out = []
    for uc, vc, length, width, yaw_i, height, mx_i, my_i, n_cells, area_i in rows:
        cy, sy = math.cos(yaw_i), math.sin(yaw_i)
        heading = yaw_i
        if width > length:
            length, width, heading = width, length, heading + math.pi / 2
        heading = (heading + math.pi / 2) % math.pi - math.pi / 2
        out.append(
            SegmentedObject(
                x_m=centre_m[0] + mx_i + cy * uc - sy * vc,
                y_m=centre_m[1] + my_i + sy * uc + cy * vc,
                length_m=length,
                width_m=width,
                yaw_rad=heading,
                height_m=height if math.isfinite(height) else 0.0,
                cells=n_cells,
                area_m2=area_i,
            )
        )
    return out
