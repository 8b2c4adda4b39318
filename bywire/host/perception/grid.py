"""The occupancy grid of seed 000 section 4 (eqs. 1-5): vehicle-centred, world-aligned, shifted with the car.

Each revolution goes through section 4's three steps:

1. project: the scan's points are rotated by the ego yaw and placed relative to the grid's centre, whose
   axes are the world's (the car stays within one shift step of the centre; the grid moves in whole
   cells, so a cell stays bound to its place in the world and keeps its evidence while inside);
2. measure per cell (`CellMeasures`): point count n_i, number of distinct beams b_i and the elevation
   difference e_i = max z - min z (eq. 1);
3. an inverse sensor model turns the measures, and the free space the beams crossed on their way, into
   evidence, accumulated with decay (eq. 5) and read as occupancy by the logistic of eq. 3. The grids
   of several sensors fuse by the maximum (eq. 4, `fuse_max`).

The per-revolution loops are compiled kernels (`grid_kernels`, numba); this module holds the model and
every number, and `warm_up()` loads the kernels before a real-time module's first frame.

Layouts (`GridLayout`): nested square windows around the centre, level k with `cells_per_side` cells of
`finest_cell_m * 2**k`, each window twice the size of the one inside it. One level is the paper's uniform
15 cm grid; several are the fix its section 12 reports for vehicles lost beyond 60 m ("reducing the grid
resolution with distance": far cells of 15 cm saw too few points to ever update). A point belongs to
the finest window that holds it. All windows share the centre and move in steps of the coarsest cell, so
every coarse cell is wholly inside or wholly outside the next finer window; on a move, what the fine
windows knew is max-pooled into the coarse level and what enters a fine window is copied from it.

Deviations from the paper:
- Inverse models of n_i and b_i: the paper learned them from labelled data we do not have. Here a cell
  with fewer than `min_points` points gets no evidence at all (eq. 1 would call a single point "free"),
  and an elevation step seen by two or more beams adds `multi_beam_evidence` (one noisy return is
  one beam).
- Free evidence: eq. 5 clamps at 0, so every cell has p >= 0.5 and "free" cannot be told from
  "unknown" (which Figure 4 does). The evidence here is signed, clamped to [evidence_min,
  evidence_max], and the decay of eq. 5 moves it towards 0 (unknown) from either side by `decay` per
  revolution. With evidence_min = 0 this is eq. 5 with a ceiling; the ceiling bounds how long a cell
  seen occupied for a minute stays occupied once the car there drives off.
- Decay applies to every cell on every update, as eq. 5 is written (the text says "cells that are not
  updated"; for an updated cell it is a constant offset on its evidence).
- The elevation threshold grows with the cell, 0.15 m + `max_grade` * cell size: a coarse cell on a
  graded road spans that much road height without any obstacle in it.
- Free space (the inverse model's free part): besides cells seen as ground, the cells the beams crossed
  before their returns, traced in 2-D through a polar image of `free_space_sectors` azimuth sectors
  (`grid_kernels.sector_ranges`, `trace_free`), not beam by beam in 3-D. A sector is free up to its
  nearest obstacle return if one of them lies low enough that its beam passed under anything of a
  car's height on the way, else only to its farthest ground return; it stops where its neighbours saw
  an obstacle; a cell is free when wholly short of that. Cells with an obstacle return this revolution
  never are, and a crossed cell seen as ground takes the stronger of the two free evidences, not both.
- Points more than `max_height_m` over the ground plane under the car (branches, signs the car
  passes under) and within `min_range_m` of the sensor (the car itself) are left out.
- Beam ids count modulo 64 (a 64-bit mask per cell); a sensor with more beams undercounts b_i.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
import numpy.typing as npt

from bywire.host.perception import grid_kernels
from bywire.host.perception.ego_pose import EgoPose
from bywire.host.perception.scan import Scan

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
I32 = npt.NDArray[np.int32]
IntArray = npt.NDArray[np.signedinteger[Any]]
Bool = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class GridLayout:
    """`levels` nested windows of `cells_per_side`^2 cells; level k's cells are `finest_cell_m * 2**k`."""

    finest_cell_m: float = 0.15
    cells_per_side: int = 256
    levels: int = 3

    def __post_init__(self) -> None:
        if not self.finest_cell_m > 0.0:
            raise ValueError(f"cell size {self.finest_cell_m} m must be positive")
        if self.levels < 1 or self.cells_per_side < 4 or self.cells_per_side % 4:
            raise ValueError(
                f"{self.levels} levels of {self.cells_per_side} cells: need >= 1 level, N % 4 == 0"
            )
        if self.raster_side > 1 << 14:
            raise ValueError(f"{self.raster_side} finest cells per side is beyond any LIDAR's use")

    @classmethod
    def uniform(cls, cell_m: float = 0.15, half_extent_m: float = 76.8) -> GridLayout:
        """The paper's layout: one cell size over the whole window."""
        return cls(cell_m, 4 * max(1, round(half_extent_m / cell_m / 2.0)), 1)

    @classmethod
    def graded(cls, finest_cell_m: float = 0.15, half_extent_m: float = 76.8, levels: int = 3) -> GridLayout:
        """Cells double in size with each doubling of the distance (Chebyshev) from the centre."""
        coarsest_m = finest_cell_m * 2 ** (levels - 1)
        return cls(finest_cell_m, 4 * max(1, round(half_extent_m / coarsest_m / 2.0)), levels)

    @property
    def name(self) -> str:
        if self.levels == 1:
            return f"uniform {self.finest_cell_m:.2f} m"
        return f"graded {self.finest_cell_m:.2f}-{self.cell_m(self.levels - 1):.2f} m"

    def cell_m(self, level: int) -> float:
        return self.finest_cell_m * (1 << level)

    @property
    def cell_sizes_m(self) -> tuple[float, ...]:
        return tuple(self.cell_m(k) for k in range(self.levels))

    def level_half_extent_m(self, level: int) -> float:
        return self.cells_per_side / 2 * self.cell_m(level)

    @property
    def half_extent_m(self) -> float:
        return self.level_half_extent_m(self.levels - 1)

    @property
    def shift_step_m(self) -> float:
        """The grid moves in whole coarsest cells, so the windows stay nested cell for cell."""
        return self.cell_m(self.levels - 1)

    @property
    def shape(self) -> tuple[int, int, int]:
        return (self.levels, self.cells_per_side, self.cells_per_side)

    @property
    def n_cells(self) -> int:
        return self.levels * self.cells_per_side**2

    @property
    def raster_side(self) -> int:
        """Cells per side of the whole window at the finest size (`compose`)."""
        return self.cells_per_side << (self.levels - 1)

    def active_mask(self) -> Bool:
        """(levels, N, N): cells that hold their own area (a coarse level's centre is the finer level's)."""
        n, q = self.cells_per_side, self.cells_per_side // 4
        active = np.ones(self.shape, bool)
        active[1:, q : n - q, q : n - q] = False
        return active

    def flat_index(self, qx: IntArray, qy: IntArray) -> IntArray:
        """The cell of points given by their finest-cell coordinates from the centre (floor(x / finest),
        signed integers), all inside the outermost window: the finest window holding a point gives its
        level. The result has the coordinates' dtype."""
        half = self.cells_per_side // 2
        sign = qx.dtype.itemsize * 8 - 1
        # a = q for q >= 0 and -q - 1 below: the windows [-h, h) become a < h on both sides.
        a = np.maximum(qx ^ (qx >> sign), qy ^ (qy >> sign))
        level = np.zeros(qx.shape, qx.dtype)
        for k in range(self.levels - 1):
            level += a >= (half << k)
        cx = (qx >> level) + half
        cy = (qy >> level) + half
        return (level * self.cells_per_side + cy) * self.cells_per_side + cx

    def cell_centres_m(self, flat: npt.NDArray[np.integer]) -> tuple[F64, F64]:
        """Centres (K, 2) of cells relative to the grid centre, and their sizes (K,), metres."""
        n = self.cells_per_side
        level, rest = np.divmod(np.asarray(flat, np.int64), n * n)
        iy, ix = np.divmod(rest, n)
        size = self.finest_cell_m * np.left_shift(1, level).astype(np.float64)
        xy = np.column_stack((ix - n / 2 + 0.5, iy - n / 2 + 0.5)) * size[:, None]
        return xy, size

    def compose(self, values: npt.NDArray[np.generic]) -> npt.NDArray[np.generic]:
        """One (R, R) raster of the finest cell size (R = `raster_side`, row = y, column = x, the centre
        at R/2): each level's cells painted over the coarser ones around it."""
        out = values[0]
        n = self.cells_per_side
        for k in range(1, self.levels):
            f = 1 << k
            big = np.repeat(np.repeat(values[k], f, axis=0), f, axis=1)
            off = (n * f - out.shape[0]) // 2
            big[off : off + out.shape[0], off : off + out.shape[0]] = out
            out = big
        return out


@dataclass(frozen=True)
class EvidenceModel:
    """The inverse sensor model and the evidence bookkeeping of eqs. 1-5 (evidence in log-odds)."""

    # Eq. 1's threshold: a cell whose points differ in height by more is an obstacle (section 4).
    elevation_threshold_m: float = 0.15
    # The steepest road grade expected; a cell of size s on it spans max_grade * s of road height.
    max_grade: float = 0.10
    # Fewer points than this tell nothing about a cell's elevation difference.
    min_points: int = 2
    # alpha_3 * l_occ and alpha_3 * l_free of eq. 2 with the elevation model.
    occupied_evidence: float = 1.0
    free_evidence: float = -0.5
    # alpha_2 * the beam model: an elevation step seen by >= 2 beams is a surface, not one stray return.
    multi_beam_evidence: float = 0.5
    # epsilon_t of eq. 5, per revolution: 0.2 takes a cell from the ceiling to unknown in 1.5 s unseen.
    decay: float = 0.2
    evidence_min: float = -2.0
    evidence_max: float = 3.0
    # Occupancy (eq. 3) at which a cell counts as an obstacle: 0.65 is one revolution's step evidence.
    obstacle_probability: float = 0.65
    # A passenger car's body ends about 2 m from a roof-mounted sensor.
    min_range_m: float = 2.0
    # Over the ground plane under the car: what is higher, the car (1.5 m) passes under.
    max_height_m: float = 3.0
    # The free part of the inverse sensor model: a cell the beams crossed before their returns adds
    # this (0 turns the ray tracing off). Stronger than ground seen in the cell itself, so that what a
    # car that drove on left behind (at most evidence_max) is below the obstacle level two revolutions
    # after the beams pass there again: 3.0 - 2 * (1.0 + decay) < obstacle_evidence.
    ray_free_evidence: float = -1.0
    # Azimuth sectors of the free-space image: 0.35 deg, so that a sector's ray is no farther from the
    # next than a cell's side at every window's outer edge (19.2 m: 0.12 m; 76.8 m: 0.47 m), and each
    # sector holds a return of every beam (2000 azimuth steps a revolution).
    free_space_sectors: int = 1024
    # A cell is free when its farthest corner is this much nearer than its sector's nearest obstacle
    # return (or farthest ground return): the range noise (2 cm, 1 sigma) ten times.
    free_space_margin_m: float = 0.2
    # ... and no farther than the nearest obstacle return of this many sectors on either side: a ray
    # that grazes an object stops where the sector over it did. More (3 sectors, 1 deg) left a car that
    # drove past a trail twice as long beside its last position, for no fewer missed cars (SIL,
    # left_turn_oncoming replayed offline: 0.56 false objects per list against 0.23).
    free_space_guard_sectors: int = 1
    # Past the last ground return a sector is free up to its obstacle if a beam met the obstacle no
    # higher than this over the road under the car: on its way down that beam passed under the roof of
    # anything a car's height between (the rings of the ground returns lie 10 m apart at 50 m).
    free_space_low_return_m: float = 1.0

    def __post_init__(self) -> None:
        if not self.evidence_min <= 0.0 < self.evidence_max:
            raise ValueError("evidence_min <= 0 < evidence_max: 0 is 'unknown'")
        if self.decay < 0.0 or self.min_points < 1:
            raise ValueError("decay must be >= 0 and min_points >= 1")
        if not 0.5 < self.obstacle_probability < 1.0:
            raise ValueError(f"obstacle_probability {self.obstacle_probability} must be in (0.5, 1)")
        if (
            self.ray_free_evidence > 0.0
            or self.free_space_sectors < 3
            or self.free_space_margin_m < 0.0
            or not 0 <= self.free_space_guard_sectors < self.free_space_sectors // 2
        ):
            raise ValueError(
                "ray_free_evidence must be <= 0 (0: off), free_space_sectors >= 3, free_space_margin_m >= 0,"
                " 0 <= free_space_guard_sectors < free_space_sectors / 2"
            )

    @property
    def obstacle_evidence(self) -> float:
        p = self.obstacle_probability
        return math.log(p / (1.0 - p))

    def elevation_threshold_for(self, cell_m: float) -> float:
        return self.elevation_threshold_m + self.max_grade * cell_m


@dataclass(frozen=True)
class CellMeasures:
    """Section 4's measures of one revolution for the cells it hit (sorted flat cell indices)."""

    cells: I32
    points: I32  # n_i
    beams: I32  # b_i
    z_min_m: F32  # sensor frame
    z_max_m: F32

    @property
    def elevation_m(self) -> F32:
        """e_i of eq. 1."""
        return self.z_max_m - self.z_min_m

    def __len__(self) -> int:
        return int(self.cells.shape[0])


def logistic(evidence: npt.NDArray[np.floating]) -> F32:
    """Eq. 3: p = 1 - 1 / (1 + exp(o))."""
    o = np.asarray(evidence, np.float32)
    return (0.5 + 0.5 * np.tanh(0.5 * o)).astype(np.float32)  # the same function, without exp's overflow


@dataclass(frozen=True)
class GridSnapshot:
    """A grid's state at one time, as the segmentation, the tracker and the reactive layer read it.

    occupancy, z_min_m, z_max_m: (levels, N, N) arrays of the layout (z: the lowest and highest return
    of the last revolution that hit the cell, sensor frame, NaN if none); centre_m: the world position of
    the grid's centre. Cells of a coarse level inside the finer window are not its own
    (`layout.active_mask`).
    """

    layout: GridLayout
    centre_m: tuple[float, float]
    occupancy: F32
    z_min_m: F32
    z_max_m: F32
    obstacle_probability: float = EvidenceModel.obstacle_probability

    def obstacle_mask(self, p_min: float | None = None) -> Bool:
        p = self.obstacle_probability if p_min is None else p_min
        return (self.occupancy >= p) & self.layout.active_mask()

    def obstacle_cells(self, p_min: float | None = None) -> ObstacleCells:
        flat = np.flatnonzero(self.obstacle_mask(p_min)).astype(np.int32)
        xy, size = self.layout.cell_centres_m(flat)
        xy += np.asarray(self.centre_m)
        return ObstacleCells(flat, xy, size, self.z_min_m.reshape(-1)[flat], self.z_max_m.reshape(-1)[flat])

    def occupancy_at(self, xy_m: npt.NDArray[np.floating]) -> F32:
        """Occupancy at world points (K, 2); NaN outside the grid."""
        xy = np.asarray(xy_m, np.float64) - np.asarray(self.centre_m)
        q = np.floor(xy / self.layout.finest_cell_m)
        h = self.layout.raster_side // 2
        inside = ((q >= -h) & (q < h)).all(axis=1)
        qi = np.where(inside[:, None], q, 0).astype(np.int32)
        flat = self.layout.flat_index(qi[:, 0], qi[:, 1])
        return np.where(inside, self.occupancy.reshape(-1)[flat], np.nan).astype(np.float32)


@dataclass(frozen=True)
class ObstacleCells:
    """Obstacle cells: flat index, world centre (K, 2) and size (K,) in metres, heights seen there."""

    cells: I32
    xy_m: F64
    size_m: F64
    z_min_m: F32
    z_max_m: F32

    def __len__(self) -> int:
        return int(self.cells.shape[0])


class OccupancyGrid:
    """One sensor's evidence grid. `update(scan, pose)` once per revolution; `snapshot()` to read."""

    def __init__(self, layout: GridLayout | None = None, model: EvidenceModel | None = None) -> None:
        self.layout = layout if layout is not None else GridLayout.graded()
        self.model = model if model is not None else EvidenceModel()
        shape = self.layout.shape
        n_cells = self.layout.n_cells
        self.evidence = np.zeros(shape, np.float32)
        self.z_min_m = np.full(shape, np.nan, np.float32)
        self.z_max_m = np.full(shape, np.nan, np.float32)
        self.updates = 0
        self._centre_steps: tuple[int, int] | None = None
        self._measure_scratch = _MeasureScratch(n_cells)
        # This revolution's class of each cell (1 ground, 2 obstacle; 0 not hit or too few points to
        # tell), emptied after each update; the revolution that last freed each cell; freed cells.
        self._cell_class = np.zeros(n_cells, np.uint8)
        self._free_stamp = np.zeros(n_cells, np.int64)
        self._freed = np.empty(n_cells, np.int32)

    @cached_property
    def _elevation_threshold_m(self) -> F32:
        return np.array([self.model.elevation_threshold_for(s) for s in self.layout.cell_sizes_m], np.float32)

    @property
    def centre_m(self) -> tuple[float, float]:
        step = self.layout.shift_step_m
        cx, cy = self._centre_steps if self._centre_steps is not None else (0, 0)
        return (cx * step, cy * step)

    def update(self, scan: Scan, pose: EgoPose | None = None) -> CellMeasures:
        """Integrate one revolution taken at `pose` (the sensor's pose in the world; None: the origin)."""
        pose = pose if pose is not None else EgoPose()
        self.recentre(pose.x_m, pose.y_m)
        xyz, flat = self._project(scan, pose)
        measures = _cell_measures(flat, xyz[:, 2], scan.beam, self._measure_scratch)
        self._integrate(measures, scan, xyz, flat, pose)
        self.updates += 1
        return measures

    def recentre(self, x_m: float, y_m: float) -> None:
        """Move the grid so that its centre is the shift-step lattice point nearest (x_m, y_m)."""
        step = self.layout.shift_step_m
        new = (math.floor(x_m / step + 0.5), math.floor(y_m / step + 0.5))
        old = self._centre_steps
        self._centre_steps = new
        if old is not None and new != old:
            self._shift(new[0] - old[0], new[1] - old[1])

    def measure(self, scan: Scan, pose: EgoPose) -> CellMeasures:
        """Steps 1 and 2 of section 4 for one revolution, against the grid's current centre."""
        xyz, flat = self._project(scan, pose)
        return _cell_measures(flat, xyz[:, 2], scan.beam, self._measure_scratch)

    def obstacle_points(self, scan: Scan, pose: EgoPose | None = None) -> Bool:
        """Per point of the scan: in a cell whose elevation difference this revolution exceeds the
        threshold (eq. 1); the grid's evidence is not changed. Section 6 keeps lane markers off these.
        The rest is not all road: a flat roof's cells are level too, and a lone point tells nothing."""
        xyz, flat = self._project(scan, pose if pose is not None else EgoPose())
        me = _cell_measures(flat, xyz[:, 2], scan.beam, self._measure_scratch)
        n2 = self.layout.cells_per_side**2
        step = (me.points >= self.model.min_points) & (
            me.elevation_m > self._elevation_threshold_m[me.cells // n2]
        )
        keep = flat >= 0
        out = np.zeros(len(scan), bool)
        out[keep] = step[np.searchsorted(me.cells, flat[keep])]
        return out

    def _project(self, scan: Scan, pose: EgoPose) -> tuple[F32, I32]:
        """The scan's points as float32 (N, 3), and each one's cell, -1 for those the grid leaves out."""
        m = self.model
        layout = self.layout
        xyz = np.ascontiguousarray(scan.xyz_m, np.float32)
        flat = np.empty(xyz.shape[0], np.int32)
        cx, cy = self.centre_m
        grid_kernels.project(
            xyz,
            np.float32(math.cos(pose.yaw_rad)),
            np.float32(math.sin(pose.yaw_rad)),
            np.float32(pose.x_m - cx),
            np.float32(pose.y_m - cy),
            np.float32(1.0 / layout.finest_cell_m),
            np.float32(m.max_height_m - scan.sensor_height_m),
            np.float32(m.min_range_m**2),
            layout.cells_per_side // 2,
            layout.cells_per_side,
            layout.levels,
            flat,
        )
        return xyz, flat

    def _integrate(self, me: CellMeasures, scan: Scan, xyz: F32, flat: I32, pose: EgoPose) -> None:
        m = self.model
        grid_kernels.classify(
            me.cells,
            me.points,
            me.z_min_m,
            me.z_max_m,
            self._elevation_threshold_m,
            self.layout.cells_per_side**2,
            m.min_points,
            self._cell_class,
        )
        freed = self._freed[:0]
        if m.ray_free_evidence < 0.0 and len(me):
            freed = self._trace_free(scan, xyz, flat, pose)
        grid_kernels.integrate(
            self.evidence.reshape(-1),
            self.z_min_m.reshape(-1),
            self.z_max_m.reshape(-1),
            me.cells,
            me.beams,
            me.z_min_m,
            me.z_max_m,
            freed,
            self._cell_class,
            np.float32(m.occupied_evidence),
            np.float32(m.multi_beam_evidence),
            np.float32(m.free_evidence),
            np.float32(m.ray_free_evidence),
            np.float32(m.evidence_min),
            np.float32(m.evidence_max),
            np.float32(m.decay),
        )

    def _trace_free(self, scan: Scan, xyz: F32, flat: I32, pose: EgoPose) -> I32:
        """The cells the beams crossed this revolution before their returns (the free part of the inverse
        sensor model), through an azimuth image of free range (`grid_kernels.sector_ranges`) whose sector
        rays are walked through the grid; cells with an obstacle return this revolution are never free."""
        m = self.model
        layout = self.layout
        free_m = grid_kernels.sector_ranges(
            xyz,
            flat,
            self._cell_class,
            math.cos(pose.yaw_rad),
            math.sin(pose.yaw_rad),
            m.free_space_low_return_m - scan.sensor_height_m,
            m.free_space_sectors,
            m.free_space_guard_sectors,
        )
        cx, cy = self.centre_m
        k = grid_kernels.trace_free(
            free_m,
            m.min_range_m,
            m.free_space_margin_m,
            pose.x_m - cx,
            pose.y_m - cy,
            layout.finest_cell_m,
            layout.cells_per_side // 2,
            layout.cells_per_side,
            layout.levels,
            self._cell_class,
            self._free_stamp,
            self.updates + 1,
            self._freed,
        )
        return self._freed[:k]

    def snapshot(self) -> GridSnapshot:
        return GridSnapshot(
            self.layout,
            self.centre_m,
            logistic(self.evidence),
            self.z_min_m.copy(),
            self.z_max_m.copy(),
            self.model.obstacle_probability,
        )

    def _shift(self, dx_steps: int, dy_steps: int) -> None:
        layout = self.layout
        planes = (
            (self.evidence, 0.0, np.maximum),
            (self.z_min_m, np.nan, np.fmin),
            (self.z_max_m, np.nan, np.fmax),
        )
        # What the fine windows know goes to the coarse level before a part of them leaves.
        for k in range(1, layout.levels):
            for a, _, pool in planes:
                _pool_into(a[k], a[k - 1], pool)
        for k in range(layout.levels):
            r = 1 << (layout.levels - 1 - k)
            for a, fill, _ in planes:
                _shift_in_place(a[k], dx_steps * r, dy_steps * r, fill)
        # What enters a fine window comes from the coarse level around it, coarsest first.
        for k in range(layout.levels - 1, 0, -1):
            r = 1 << (layout.levels - k)
            for a, _, _ in planes:
                _fill_margin_from_coarse(a[k - 1], a[k], dx_steps * r, dy_steps * r)


def warm_up() -> None:
    """Compile the update's kernels (`grid_kernels`), or load them from numba's cache: the first update
    in a process otherwise pays about a second for it (10-20 s on a machine that never compiled them),
    which a real-time module pays in its start, not in its first frame."""
    grid = OccupancyGrid(GridLayout(1.0, 8, 2))
    xyz = np.array([[3.0, 0.1, -1.7], [3.1, 0.2, -1.0], [-3.2, 0.3, -1.7], [-3.1, 0.4, -1.69]], np.float32)
    scan = Scan(xyz, np.zeros(4, np.float32), np.arange(4, dtype=np.int16))
    grid.update(scan)
    grid.obstacle_points(scan)


def fuse_max(snapshots: Sequence[GridSnapshot]) -> GridSnapshot:
    """Eq. 4: the most pessimistic of several sensors' grids, cell by cell (same layout and centre)."""
    if not snapshots:
        raise ValueError("no grids to fuse")
    first = snapshots[0]
    for s in snapshots[1:]:
        if s.layout != first.layout or s.centre_m != first.centre_m:
            raise ValueError(
                f"grids differ: {s.layout.name} at {s.centre_m} vs {first.layout.name} at {first.centre_m}"
            )
    return GridSnapshot(
        first.layout,
        first.centre_m,
        np.maximum.reduce([s.occupancy for s in snapshots]),
        np.fmin.reduce([s.z_min_m for s in snapshots]),
        np.fmax.reduce([s.z_max_m for s in snapshots]),
        min(s.obstacle_probability for s in snapshots),
    )


class _MeasureScratch:
    """Per-cell accumulators the size of the grid, all empty between revolutions: a revolution empties
    only the cells it touched, so the cost follows the points, not the grid."""

    def __init__(self, n_cells: int) -> None:
        self.points = np.zeros(n_cells, np.int32)
        self.z_min_m = np.full(n_cells, np.inf, np.float32)
        self.z_max_m = np.full(n_cells, -np.inf, np.float32)
        self.beams = np.zeros(n_cells, np.uint64)


def _cell_measures(
    flat: npt.NDArray[np.integer], z: F32, beam: npt.NDArray[np.int16], scratch: _MeasureScratch
) -> CellMeasures:
    """n_i, b_i, min and max z per cell (points with flat < 0 left out): one scatter over the points and
    one pass over the grid that lists the touched cells in order and empties them (`grid_kernels`);
    distinct beams as one bit per beam. Any order of the points gives the same result."""
    flat = np.asarray(flat, np.int32)
    n = flat.shape[0]
    grid_kernels.scatter_measures(
        flat,
        np.ascontiguousarray(z, np.float32),
        np.asarray(beam, np.int16),
        scratch.points,
        scratch.z_min_m,
        scratch.z_max_m,
        scratch.beams,
    )
    cells, points, beams = np.empty(n, np.int32), np.empty(n, np.int32), np.empty(n, np.int32)
    z_min, z_max = np.empty(n, np.float32), np.empty(n, np.float32)
    k = grid_kernels.gather_measures(
        scratch.points, scratch.z_min_m, scratch.z_max_m, scratch.beams, cells, points, beams, z_min, z_max
    )
    return CellMeasures(cells[:k], points[:k], beams[:k], z_min[:k], z_max[:k])


def _shift_in_place(a: F32, sx: int, sy: int, fill: float) -> None:
    """The plane's contents for a centre moved by (sx, sy) cells; what enters is `fill`."""
    n = a.shape[0]
    if abs(sx) >= n or abs(sy) >= n:
        a.fill(fill)
        return
    # numpy copies overlapping slices through a buffer, so these moves are safe in place.
    if sy > 0:
        a[:-sy] = a[sy:]
        a[-sy:] = fill
    elif sy < 0:
        a[-sy:] = a[:sy]
        a[:-sy] = fill
    if sx > 0:
        a[:, :-sx] = a[:, sx:]
        a[:, -sx:] = fill
    elif sx < 0:
        a[:, -sx:] = a[:, :sx]
        a[:, :-sx] = fill


def _centre_block(coarse: F32) -> F32:
    n = coarse.shape[0]
    return coarse[n // 4 : n - n // 4, n // 4 : n - n // 4]


def _pool_into(coarse: F32, fine: F32, pool: np.ufunc) -> None:
    # Four strided views: ufunc.reduce over the axes of a (n/2, 2, n/2, 2) view is ten times slower.
    block = _centre_block(coarse)
    pool(fine[0::2, 0::2], fine[0::2, 1::2], out=block)
    pool(block, fine[1::2, 0::2], out=block)
    pool(block, fine[1::2, 1::2], out=block)


def _fill_margin_from_coarse(fine: F32, coarse: F32, sx: int, sy: int) -> None:
    """The rows and columns a shift by (sx, sy) fine cells left empty, from the coarse cells over them
    (only those rows and columns are upsampled)."""
    n = fine.shape[0]
    block = _centre_block(coarse)
    if abs(sx) >= n or abs(sy) >= n:
        fine[...] = _upsampled(block)
        return
    r0, r1 = (n - sy, n) if sy > 0 else (0, -sy)
    c0, c1 = (n - sx, n) if sx > 0 else (0, -sx)
    if r1 > r0:
        lo = r0 // 2
        fine[r0:r1] = _upsampled(block[lo : (r1 + 1) // 2])[r0 - 2 * lo : r1 - 2 * lo]
    if c1 > c0:
        lo = c0 // 2
        fine[:, c0:c1] = _upsampled(block[:, lo : (c1 + 1) // 2])[:, c0 - 2 * lo : c1 - 2 * lo]


def _upsampled(a: F32) -> F32:
    return np.repeat(np.repeat(a, 2, axis=0), 2, axis=1)
