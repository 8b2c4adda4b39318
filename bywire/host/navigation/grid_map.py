"""The obstacle map the zone planner searches on: a boolean occupancy grid with its geometry (seed 000
Sec. 10.1: "an obstacle map obtained from a 360-deg laser range scanner").

`GridMap` holds `occupied[row, col]` (row: +y, col: +x), the cell size and the world position of cell
(0, 0)'s corner. Anything outside the grid is occupied: the planner never leaves the map it was given.
It is built from the perception's occupancy grid (`from_probabilities`), from an image or a `.npy`
array (`load`: the `bywire zone plan` command), or from boxes (`from_boxes`: scenarios and tests).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["GridMap", "load"]


@dataclass(frozen=True)
class GridMap:
    occupied: np.ndarray  # bool (rows, cols); row index grows with y, column index with x
    resolution_m: float  # cell edge
    origin_xy_m: tuple[float, float] = (0.0, 0.0)  # world position of cell (0, 0)'s lower-left corner

    def __post_init__(self) -> None:
        if self.occupied.ndim != 2 or self.occupied.dtype != bool:
            raise ValueError(
                f"GridMap: occupied must be a 2-D bool array, not {self.occupied.dtype} {self.occupied.shape}"
            )
        if min(self.occupied.shape) < 2:
            raise ValueError(f"GridMap: the grid {self.occupied.shape} must be at least 2 x 2 cells")
        if not (math.isfinite(self.resolution_m) and self.resolution_m > 0.0):
            raise ValueError(f"GridMap: resolution_m = {self.resolution_m} must be finite and > 0")

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.occupied.shape[0]), int(self.occupied.shape[1]))

    @property
    def size_m(self) -> tuple[float, float]:
        """(width along x, height along y) in metres."""
        return self.shape[1] * self.resolution_m, self.shape[0] * self.resolution_m

    def cell_of(self, x_m: np.ndarray | float, y_m: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """(row, col) of the cells holding the points (may be outside the grid)."""
        col = np.floor((np.asarray(x_m) - self.origin_xy_m[0]) / self.resolution_m).astype(np.int64)
        row = np.floor((np.asarray(y_m) - self.origin_xy_m[1]) / self.resolution_m).astype(np.int64)
        return row, col

    def centre_of(self, row: np.ndarray | int, col: np.ndarray | int) -> tuple[np.ndarray, np.ndarray]:
        """World position (x_m, y_m) of cell centres."""
        x = self.origin_xy_m[0] + (np.asarray(col) + 0.5) * self.resolution_m
        y = self.origin_xy_m[1] + (np.asarray(row) + 0.5) * self.resolution_m
        return x, y

    def cell_centres(self) -> tuple[np.ndarray, np.ndarray]:
        """World positions (x_m, y_m) of every cell's centre, each (rows, cols)."""
        rr, cc = np.mgrid[0 : self.shape[0], 0 : self.shape[1]]
        return self.centre_of(rr, cc)

    def inside(self, row: np.ndarray, col: np.ndarray) -> np.ndarray:
        return (row >= 0) & (row < self.shape[0]) & (col >= 0) & (col < self.shape[1])

    def occupied_at(self, x_m: np.ndarray | float, y_m: np.ndarray | float) -> np.ndarray:
        """Occupancy of the cells under the points; outside the grid counts as occupied."""
        row, col = self.cell_of(x_m, y_m)
        ok = self.inside(row, col)
        out = np.ones(row.shape, dtype=bool)
        out[ok] = self.occupied[row[ok], col[ok]]
        return out

    def with_boxes(self, boxes: list[tuple[float, float, float, float, float]]) -> GridMap:
        """This map with oriented boxes (centre x, centre y, heading, length, width) filled: a cell is
        filled where any part of it is in a box."""
        occ = self.occupied.copy()
        rows, cols = self.shape
        for bx, by, heading, length, width in boxes:
            reach = 0.5 * math.hypot(length, width) + self.resolution_m
            lo_r, lo_c = self.cell_of(bx - reach, by - reach)
            hi_r, hi_c = self.cell_of(bx + reach, by + reach)
            r0, r1 = max(int(lo_r), 0), min(int(hi_r) + 1, rows)
            c0, c1 = max(int(lo_c), 0), min(int(hi_c) + 1, cols)
            if r0 >= r1 or c0 >= c1:
                continue
            yy, xx = np.mgrid[r0:r1, c0:c1]
            cx, cy = self.centre_of(yy, xx)
            c, s = math.cos(heading), math.sin(heading)
            along = (cx - bx) * c + (cy - by) * s
            across = -(cx - bx) * s + (cy - by) * c
            slack = 0.5 * self.resolution_m * (abs(c) + abs(s))
            occ[r0:r1, c0:c1] |= (np.abs(along) <= 0.5 * length + slack) & (
                np.abs(across) <= 0.5 * width + slack
            )
        return GridMap(occ, self.resolution_m, self.origin_xy_m)

    @classmethod
    def from_probabilities(
        cls,
        p_occupied: np.ndarray,
        resolution_m: float,
        origin_xy_m: tuple[float, float],
        threshold: float = 0.5,
    ) -> GridMap:
        """An occupancy grid's cells above `threshold` (unknown cells count as free: the grid's own prior)."""
        return cls(np.asarray(p_occupied) > threshold, resolution_m, origin_xy_m)

    @classmethod
    def from_boxes(
        cls,
        size_m: tuple[float, float],
        resolution_m: float,
        boxes: list[tuple[float, float, float, float, float]],
        origin_xy_m: tuple[float, float] = (0.0, 0.0),
    ) -> GridMap:
        """A map `size_m` (x, y) with oriented boxes (centre x, centre y, heading, length, width) filled."""
        cols = round(size_m[0] / resolution_m)
        rows = round(size_m[1] / resolution_m)
        return cls(np.zeros((rows, cols), dtype=bool), resolution_m, origin_xy_m).with_boxes(boxes)


def load(path: Path, resolution_m: float, origin_xy_m: tuple[float, float] = (0.0, 0.0)) -> GridMap:
    """A map from a `.npy` array (nonzero: occupied) or an image (dark: occupied), row 0 at the *top* of
    an image as image tools draw it (flipped so that y grows upwards) and at y = origin in an array."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: no such map file")
    if path.suffix.lower() == ".npy":
        try:
            arr = np.load(path, allow_pickle=False)
        except (ValueError, OSError) as exc:
            raise ValueError(f"{path}: not a numpy array file ({exc})") from exc
        if arr.ndim != 2 or not (np.issubdtype(arr.dtype, np.number) or arr.dtype == bool):
            raise ValueError(f"{path}: a map must be a 2-D numeric array, not {arr.dtype} {arr.shape}")
        return GridMap(np.asarray(arr != 0), resolution_m, origin_xy_m)
    import matplotlib.image as mpimg

    try:
        img = mpimg.imread(path)
    except (ValueError, OSError, SyntaxError) as exc:
        raise ValueError(f"{path}: not an image matplotlib can read ({exc})") from exc
    if img.ndim == 3:
        img = img[..., :3].mean(axis=2)
    img = img.astype(float)
    if img.max() > 1.0:
        img = img / 255.0
    return GridMap(np.flipud(img < 0.5).copy(), resolution_m, origin_xy_m)
