"""The occupancy grid of seed 000 section 4 (eqs. 1-5): vehicle-centred, world-aligned, shifted with the car.

Each revolution goes through section 4's three steps:

1. project: the scan's points are rotated by the ego yaw and placed relative to the grid's centre, whose
   axes are the world's (the car stays within one shift step of the centre; the grid moves in whole
   cells, so a cell stays bound to its place in the world and keeps its evidence while inside);
2. measure per cell (`CellMeasures`): point count n_i, number of distinct beams b_i and the elevation
   difference e_i = max z - min z (eq. 1);
3. an inverse sensor model turns the measures into evidence, accumulated with decay (eq. 5) and read as
   occupancy by the logistic of eq. 3. The grids of several sensors fuse by the maximum (eq. 4,
   `fuse_max`).

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
- Free space comes from cells seen as ground; the cells a beam crossed before its return are not
  marked free (no ray casting).
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

    def __post_init__(self) -> None:
        if not self.evidence_min <= 0.0 < self.evidence_max:
            raise ValueError("evidence_min <= 0 < evidence_max: 0 is 'unknown'")
        if self.decay < 0.0 or self.min_points < 1:
            raise ValueError("decay must be >= 0 and min_points >= 1")
        if not 0.5 < self.obstacle_probability < 1.0:
            raise ValueError(f"obstacle_probability {self.obstacle_probability} must be in (0.5, 1)")

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
        self.evidence = np.zeros(shape, np.float32)
        self.z_min_m = np.full(shape, np.nan, np.float32)
        self.z_max_m = np.full(shape, np.nan, np.float32)
        self.updates = 0
        self._centre_steps: tuple[int, int] | None = None
        self._scratch = np.empty(self.layout.n_cells, np.float32)
        self._measure_scratch = _MeasureScratch(self.layout.n_cells)

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
        measures = self.measure(scan, pose)
        self._integrate(measures)
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
        keep, flat = self._project(scan, pose)
        return _cell_measures(flat, scan.xyz_m[keep, 2], scan.beam[keep], self._measure_scratch)

    def obstacle_points(self, scan: Scan, pose: EgoPose | None = None) -> Bool:
        """Per point of the scan: in a cell whose elevation difference this revolution exceeds the
        threshold (eq. 1); the grid's evidence is not changed. Section 6 keeps lane markers off these.
        The rest is not all road: a flat roof's cells are level too, and a lone point tells nothing."""
        keep, flat = self._project(scan, pose if pose is not None else EgoPose())
        me = _cell_measures(flat, scan.xyz_m[keep, 2], scan.beam[keep], self._measure_scratch)
        n2 = self.layout.cells_per_side**2
        step = (me.points >= self.model.min_points) & (
            me.elevation_m > self._elevation_threshold_m[me.cells // n2]
        )
        out = np.zeros(len(scan), bool)
        out[keep] = step[np.searchsorted(me.cells, flat)]
        return out

    def _project(self, scan: Scan, pose: EgoPose) -> tuple[Bool, IntArray]:
        """Which points the grid takes, and their cells."""
        m = self.model
        x, y, z = scan.xyz_m[:, 0], scan.xyz_m[:, 1], scan.xyz_m[:, 2]
        c, s = np.float32(math.cos(pose.yaw_rad)), np.float32(math.sin(pose.yaw_rad))
        cx, cy = self.centre_m
        inv = np.float32(1.0 / self.layout.finest_cell_m)
        with np.errstate(invalid="ignore"):  # inf * 0 is NaN, which the comparisons below drop
            qx = np.floor((c * x - s * y + np.float32(pose.x_m - cx)) * inv)
            qy = np.floor((s * x + c * y + np.float32(pose.y_m - cy)) * inv)
        h = self.layout.raster_side // 2
        # NaN fails every comparison, so a non-finite point is dropped here too.
        keep = (qx >= -h) & (qx < h) & (qy >= -h) & (qy < h)
        keep &= z <= np.float32(m.max_height_m - scan.sensor_height_m)
        keep &= x * x + y * y >= np.float32(m.min_range_m**2)
        # intp: the index type ufunc.at uses, so the scatter converts nothing
        return keep, self.layout.flat_index(qx[keep].astype(np.intp), qy[keep].astype(np.intp))

    def _integrate(self, me: CellMeasures) -> None:
        m = self.model
        n2 = self.layout.cells_per_side**2
        step = me.elevation_m > self._elevation_threshold_m[me.cells // n2]
        delta = np.where(
            step,
            np.float32(m.occupied_evidence) + np.float32(m.multi_beam_evidence) * (me.beams >= 2),
            np.float32(m.free_evidence),
        )
        delta = np.where(me.points >= m.min_points, delta, np.float32(0.0))
        ev = self.evidence.reshape(-1)
        ev[me.cells] = np.clip(ev[me.cells] + delta, m.evidence_min, m.evidence_max)
        self.z_min_m.reshape(-1)[me.cells] = me.z_min_m
        self.z_max_m.reshape(-1)[me.cells] = me.z_max_m
        # Eq. 5's decay, towards 0 from either side: o - clip(o, -eps, eps).
        np.clip(ev, -m.decay, m.decay, out=self._scratch)
        ev -= self._scratch

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
    """Per-cell accumulators the size of the grid, all empty between revolutions: a revolution resets
    only the cells it touched, so the cost follows the points, not the grid."""

    def __init__(self, n_cells: int) -> None:
        self.points = np.zeros(n_cells, np.int32)
        self.z_min_m = np.full(n_cells, np.inf, np.float32)
        self.z_max_m = np.full(n_cells, -np.inf, np.float32)
        self.beams = np.zeros(n_cells, np.uint64)
        self.ones = np.ones(0, np.int32)


def _cell_measures(
    flat: npt.NDArray[np.integer], z: F32, beam: npt.NDArray[np.int16], scratch: _MeasureScratch
) -> CellMeasures:
    """n_i, b_i, min and max z per cell by unbuffered scatter (`ufunc.at`, whose loops for matching
    dtypes are fast since numpy 1.25); distinct beams as one bit per beam, set once per run of
    consecutive points of one cell and beam (a scan arrives beam by beam in azimuth order, so a run is
    mostly several points). Any order of the points gives the same result."""
    n = flat.shape[0]
    if n == 0:
        empty_i, empty_f = np.zeros(0, np.int32), np.zeros(0, np.float32)
        return CellMeasures(empty_i, empty_i, empty_i, empty_f, empty_f)
    if scratch.ones.shape[0] < n:
        scratch.ones = np.ones(n, np.int32)
    z = np.asarray(z, np.float32)
    np.add.at(scratch.points, flat, scratch.ones[:n])
    np.minimum.at(scratch.z_min_m, flat, z)
    np.maximum.at(scratch.z_max_m, flat, z)
    change = (flat[1:] != flat[:-1]) | (beam[1:] != beam[:-1])
    starts = np.concatenate(([0], np.flatnonzero(change) + 1))
    bits = np.left_shift(np.uint64(1), (beam[starts] & 63).astype(np.uint64))
    np.bitwise_or.at(scratch.beams, flat[starts], bits)
    cells = np.flatnonzero(scratch.points)
    out = CellMeasures(
        cells.astype(np.int32),
        scratch.points[cells],
        _popcount64(scratch.beams[cells]),
        scratch.z_min_m[cells],
        scratch.z_max_m[cells],
    )
    scratch.points[cells] = 0
    scratch.z_min_m[cells] = np.inf
    scratch.z_max_m[cells] = -np.inf
    scratch.beams[cells] = 0
    return out


def _popcount64(v: npt.NDArray[np.uint64]) -> I32:
    count = getattr(np, "bitwise_count", None)  # numpy >= 2.0
    if count is not None:
        return np.asarray(count(v), np.int32)
    return np.unpackbits(v.view(np.uint8).reshape(-1, 8), axis=1).sum(axis=1).astype(np.int32)


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
    """The rows and columns a shift by (sx, sy) fine cells left empty, from the coarse cells over them."""
    n = fine.shape[0]
    up = np.repeat(np.repeat(_centre_block(coarse), 2, axis=0), 2, axis=1)
    if abs(sx) >= n or abs(sy) >= n:
        fine[...] = up
        return
    rows = slice(n - sy, n) if sy > 0 else slice(0, -sy)
    cols = slice(n - sx, n) if sx > 0 else slice(0, -sx)
    fine[rows] = up[rows]
    fine[:, cols] = up[:, cols]
