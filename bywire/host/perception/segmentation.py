"""Obstacle cells of the grid segmented into objects (seed 000 section 5, "obstacle detection").

Section 5: each grid cell is a node of a graph, two are connected if their distance is within a
threshold d (0.5 m), the connected components are the objects, and components of fewer than a minimum
number of cells are discarded as noise.

Here the obstacle cells of any layout are painted onto one raster of the finest cell size (a coarse
cell as a block), so the distance between two cells is the gap between their squares whatever their
sizes. Cells with a gap of at most g = floor(d / finest cell) are joined by dilating the raster by g
cells towards +x and +y only (two cells then touch exactly when their gap is <= g) and labelling it
8-connected (scipy.ndimage.label): one pass, no graph of cell pairs. Deviation: the gap is measured per
axis (Chebyshev), so cells diagonal to each other are joined up to d * sqrt(2) apart.

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
from scipy import ndimage

from bywire.host.perception.grid import GridSnapshot, ObstacleCells

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]


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
    raster = np.asarray(layout.compose(snapshot.obstacle_mask(p_min)), bool)
    gap = math.floor(params.join_distance_m / layout.finest_cell_m + 1e-9)
    labels, _ = ndimage.label(_dilate_towards_plus(raster, gap), structure=np.ones((3, 3), bool))
    row, col = _raster_position(snapshot, cells.cells)
    label = labels[row, col].astype(np.int64)
    count = np.bincount(label)
    keep = count[label] >= params.min_cells
    kept_labels, object_of_cell = np.unique(label[keep], return_inverse=True)
    out_index = np.full(len(cells), -1, np.int64)
    out_index[keep] = object_of_cell
    objects = _describe(cells, snapshot.centre_m, out_index[keep], np.flatnonzero(keep), len(kept_labels))
    return Segmentation(objects, cells, out_index)


def _dilate_towards_plus(mask: npt.NDArray[np.bool_], gap: int) -> npt.NDArray[np.bool_]:
    rows = mask.copy()
    for k in range(1, gap + 1):
        rows[k:] |= mask[:-k]
    out = rows.copy()
    for k in range(1, gap + 1):
        out[:, k:] |= rows[:, :-k]
    return out


def _raster_position(snapshot: GridSnapshot, flat: npt.NDArray[np.integer]) -> tuple[I64, I64]:
    """The raster pixel of each cell's lower-left corner (`GridLayout.compose`)."""
    layout = snapshot.layout
    n = layout.cells_per_side
    level, rest = np.divmod(np.asarray(flat, np.int64), n * n)
    iy, ix = np.divmod(rest, n)
    half = layout.raster_side // 2
    row = np.left_shift(iy - n // 2, level) + half
    col = np.left_shift(ix - n // 2, level) + half
    return row.astype(np.int64), col.astype(np.int64)


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
    order = np.argsort(obj, kind="stable")
    first = np.concatenate(([0], np.flatnonzero(np.diff(obj[order])) + 1))
    u_lo = np.minimum.reduceat((u - half)[order], first)
    u_hi = np.maximum.reduceat((u + half)[order], first)
    v_lo = np.minimum.reduceat((v - half)[order], first)
    v_hi = np.maximum.reduceat((v + half)[order], first)
    z_top = np.fmax.reduceat(cells.z_max_m[which][order], first)
    z_bottom = np.fmin.reduceat(cells.z_min_m[which][order], first)
    n_cells = np.bincount(obj, minlength=n_objects)
    out = []
    for i in range(n_objects):
        uc, vc = 0.5 * (u_lo[i] + u_hi[i]), 0.5 * (v_lo[i] + v_hi[i])
        cy, sy = math.cos(yaw[i]), math.sin(yaw[i])
        length, width, heading = float(u_hi[i] - u_lo[i]), float(v_hi[i] - v_lo[i]), float(yaw[i])
        if width > length:
            length, width, heading = width, length, heading + math.pi / 2
        heading = (heading + math.pi / 2) % math.pi - math.pi / 2
        height = float(z_top[i] - z_bottom[i])
        out.append(
            SegmentedObject(
                x_m=float(centre_m[0] + mx[i] + cy * uc - sy * vc),
                y_m=float(centre_m[1] + my[i] + sy * uc + cy * vc),
                length_m=length,
                width_m=width,
                yaw_rad=heading,
                height_m=height if math.isfinite(height) else 0.0,
                cells=int(n_cells[i]),
                area_m2=float(area[i]),
            )
        )
    return out
