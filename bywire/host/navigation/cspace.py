"""Configuration-space obstacles by convolution (seed 000 Sec. 10.1, Fig. 16; Kavraki 1995): for each of
`n_headings` heading bins the car's footprint, rotated and rasterised, is convolved with the obstacle map
(scipy's FFT convolution, all bins in one call), so that whether a pose collides is one table lookup.

The footprint is a rectangle about the rear axle's centre (the planner's reference point): `front_m`
ahead of it, `rear_m` behind, `width_m` wide, grown by `margin_m` (the paper: 1 m of safety distance; our
default is smaller, set per use). A lookup is made at a pose anywhere in a cell and at a heading anywhere
in a bin, against obstacle cells that may be touched anywhere in their area, so each heading's kernel is
the set of obstacle cells the grown rectangle touches from *some* pose in the reference cell at *some*
heading in the bin (`_kernels`, exact by separating axes): a pose the table calls free is free by
`margin_m`, never by less (the test checks it against the exact rectangle), and the table is no more
cautious than the cell and bin sizes make it. Cells outside the map are obstacles. The kernels' spectra
are cached: a replan on a new grid of the same size pays two FFTs per heading, not four.

`disk_free` is the paper's orientation-invariant superset of the free space (Sec. 10.3.2: the
intersection of all the rotated footprints, a disk about the reference point, shrunk by the same
slack so that no free pose is ever outside it): the distance heuristic searches it.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from scipy import fft as sp_fft
from scipy import ndimage

from .grid_map import GridMap

__all__ = ["PASSAT_FOOTPRINT", "CSpace", "Footprint", "build_cspace"]


@dataclass(frozen=True)
class Footprint:
    """The car's outline about the rear axle's centre, metres."""

    front_m: float  # rear axle to front bumper
    rear_m: float  # rear axle to rear bumper
    width_m: float

    def corners(self, margin_m: float = 0.0) -> np.ndarray:
        f, r, w = self.front_m + margin_m, self.rear_m + margin_m, 0.5 * self.width_m + margin_m
        return np.array([[f, w], [f, -w], [-r, -w], [-r, w]], dtype=float)

    def reach_m(self, margin_m: float = 0.0) -> float:
        """The farthest point of the grown footprint from the reference point."""
        return float(np.max(np.hypot(*self.corners(margin_m).T)))

    def inscribed_m(self, margin_m: float = 0.0) -> float:
        """The largest disk about the reference point inside every rotation of the grown footprint."""
        return min(self.front_m, self.rear_m, 0.5 * self.width_m) + margin_m


# VW Passat B6 Variant (AnnieWAY's car): wheelbase 2.72 m, 0.95 m front overhang, 4.77 m long, 1.82 m wide.
PASSAT_FOOTPRINT = Footprint(front_m=2.72 + 0.95, rear_m=4.77 - 2.72 - 0.95, width_m=1.82)


@dataclass(frozen=True)
class CSpace:
    grid: GridMap
    blocked: (
        np.ndarray
    )  # bool (n_headings, rows, cols): the reference point in that cell at that heading collides
    disk_free: np.ndarray  # bool (rows, cols): orientation-invariant superset of the free positions
    footprint: Footprint
    margin_m: float

    @property
    def n_headings(self) -> int:
        return int(self.blocked.shape[0])

    def heading_bin(self, heading_rad: np.ndarray | float) -> np.ndarray:
        n = self.n_headings
        return np.round(np.asarray(heading_rad) * (n / (2.0 * math.pi))).astype(np.int64) % n

    def collides(self, x_m: np.ndarray, y_m: np.ndarray, heading_rad: np.ndarray) -> np.ndarray:
        """Per pose: the car there (grown by `margin_m`) touches an obstacle or leaves the map."""
        row, col = self.grid.cell_of(x_m, y_m)
        inside = self.grid.inside(row, col)
        out = np.ones(row.shape, dtype=bool)
        k = self.heading_bin(heading_rad)
        out[inside] = self.blocked[k[inside], row[inside], col[inside]]
        return out


_SUB_HEADINGS = 9  # footprints OR-ed across a heading bin (the residual between them: `_residual_m`)


def _residual_m(footprint: Footprint, margin_m: float, n_headings: int) -> float:
    """How far the farthest corner moves between two of the bin's sampled headings, halved."""
    step = 2.0 * math.pi / n_headings / (_SUB_HEADINGS - 1)
    return footprint.reach_m(margin_m) * math.sin(0.5 * step)


def _kernels(footprint: Footprint, margin_m: float, res_m: float, n_headings: int) -> np.ndarray:
    """(n_headings, K, K) masks centred on the reference cell: the obstacle cells that the grown footprint
    touches from some pose in the reference cell at some heading in the bin.

    Exact by construction: a pose anywhere in a cell sweeps the rectangle over that cell's square, so an
    obstacle cell is touched iff the rectangle at the cell's centre meets a square of twice the cell's
    half-size about the obstacle's centre (separating axes: the grid's two and the rectangle's two); the
    headings of a bin are covered by `_SUB_HEADINGS` rectangles grown by the residual between them."""
    grow = margin_m + _residual_m(footprint, margin_m, n_headings)
    f, r, w = footprint.front_m + grow, footprint.rear_m + grow, 0.5 * footprint.width_m + grow
    radius = math.ceil(footprint.reach_m(grow) / res_m) + 2
    offs = np.arange(-radius, radius + 1) * res_m
    oy, ox = np.meshgrid(offs, offs, indexing="ij")
    half_l, half_w, centre_shift = 0.5 * (f + r), w, 0.5 * (f - r)
    h = res_m  # the two squares' half-sizes added: 2 x res / 2
    out = np.zeros((n_headings, 2 * radius + 1, 2 * radius + 1), dtype=bool)
    bin_width = 2.0 * math.pi / n_headings
    for k in range(n_headings):
        for th in k * bin_width + np.linspace(-0.5 * bin_width, 0.5 * bin_width, _SUB_HEADINGS):
            ux, uy = math.cos(th), math.sin(th)
            cx, cy = centre_shift * ux, centre_shift * uy  # the rectangle's centre
            dx, dy = ox - cx, oy - cy
            sep = np.abs(dx) > h + half_l * abs(ux) + half_w * abs(uy)
            sep |= np.abs(dy) > h + half_l * abs(uy) + half_w * abs(ux)
            sep |= np.abs(dx * ux + dy * uy) > half_l + h * (abs(ux) + abs(uy))
            sep |= np.abs(-dx * uy + dy * ux) > half_w + h * (abs(ux) + abs(uy))
            out[k] |= ~sep
    return out


@functools.lru_cache(maxsize=8)
def _kernel_spectra(
    footprint: Footprint, margin_m: float, res_m: float, n_headings: int, shape: tuple[int, int]
) -> tuple[np.ndarray, int]:
    """The mirrored kernels' real FFTs at the padded map's FFT size (kept: a replan reuses them)."""
    kernels = _kernels(footprint, margin_m, res_m, n_headings)
    spectra = sp_fft.rfft2(kernels[:, ::-1, ::-1].astype(np.float32), s=shape, axes=(1, 2), workers=-1)
    return spectra, kernels.shape[1] // 2


def build_cspace(
    grid: GridMap,
    footprint: Footprint = PASSAT_FOOTPRINT,
    margin_m: float = 0.3,
    n_headings: int = 72,
) -> CSpace:
    """The configuration-space obstacles of `grid` for `footprint` (see the module docstring)."""
    if not (math.isfinite(margin_m) and margin_m >= 0.0):
        raise ValueError(f"build_cspace: margin_m = {margin_m} must be finite and >= 0")
    if n_headings < 8:
        raise ValueError(f"build_cspace: n_headings = {n_headings} must be at least 8")
    res = grid.resolution_m
    rows, cols = grid.shape
    half = math.ceil(footprint.reach_m(margin_m + _residual_m(footprint, margin_m, n_headings)) / res) + 2
    size = 2 * half + 1
    # The map grown by a kernel's reach of obstacle all round (outside is an obstacle), correlated with
    # each footprint (a convolution with the kernel mirrored), all headings in one batch of FFTs; of the
    # full result, the part over the map.
    occ = np.pad(grid.occupied.astype(np.float32), half, mode="constant", constant_values=1.0)
    shape = (sp_fft.next_fast_len(occ.shape[0] + size - 1, real=True),
             sp_fft.next_fast_len(occ.shape[1] + size - 1, real=True))  # fmt: skip
    spectra, k_half = _kernel_spectra(footprint, margin_m, res, n_headings, shape)
    assert k_half == half
    occ_f = sp_fft.rfft2(occ, s=shape, workers=-1)
    hits = sp_fft.irfft2(spectra * occ_f[None], s=shape, axes=(1, 2), workers=-1)
    blocked = hits[:, 2 * half : 2 * half + rows, 2 * half : 2 * half + cols] > 0.5
    free_dist = ndimage.distance_transform_edt(~grid.occupied) * res
    disk = footprint.inscribed_m(margin_m) - res * math.sqrt(2.0)
    border = _border_distance(grid.shape) * res
    disk_free = (free_dist > disk) & (border > disk)
    return CSpace(grid, blocked, disk_free, footprint, margin_m)


def _border_distance(shape: tuple[int, int]) -> np.ndarray:
    """Each cell centre's distance to the map's edge, in cells (outside is an obstacle)."""
    rows = np.arange(shape[0]) + 0.5
    cols = np.arange(shape[1]) + 0.5
    dr = np.minimum(rows, shape[0] - rows)[:, None]
    dc = np.minimum(cols, shape[1] - cols)[None, :]
    return np.minimum(dr, dc)
