"""The occupancy grid's per-revolution loops (grid.py; seed 000 section 4), compiled with numba.

Each kernel is one pass over a revolution's ~120 000 points or over the cells it touched, where numpy
ran a dozen passes (projection, cell index, four scatters, the reset) or could not run at all (a ray
walked cell by cell until its end). They hold no model: grid.py decides every number and passes it in,
and tests/host/perception/test_grid.py holds each kernel equal to a plain numpy or Python reference.

Floating point follows numpy's rules exactly (no fastmath): the projection is float32 as grid.py's
numpy projection was, so the same revolution lands in the same cells, and a replayed run is the same run.
Compiled once per machine (`cache=True`, beside this file or in the user's cache when that is read-only)
and released from the GIL while it runs (`nogil`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_TWO_PI = 2.0 * math.pi


@njit(cache=True, nogil=True)
def _level(qx: int, qy: int, half: int, levels: int) -> int:
    """The finest window holding finest cell (qx, qy): window k spans [-half * 2**k, half * 2**k)."""
    ax = qx if qx >= 0 else -qx - 1
    ay = qy if qy >= 0 else -qy - 1
    a = max(ax, ay)
    level = 0
    for k in range(levels - 1):
        if a >= half << k:
            level += 1
    return level


@njit(cache=True, nogil=True)
def _flat(qx: int, qy: int, level: int, half: int, n: int) -> int:
    return (level * n + (qy >> level) + half) * n + (qx >> level) + half


@njit(cache=True, nogil=True)
def project(
    xyz: np.ndarray,
    c: np.float32,
    s: np.float32,
    off_x: np.float32,
    off_y: np.float32,
    inv_cell: np.float32,
    z_top: np.float32,
    r2_min: np.float32,
    half: int,
    n: int,
    levels: int,
    flat_out: np.ndarray,
) -> int:
    """Each point's cell (flat index) or -1 where the grid leaves it out: outside the outermost window,
    higher than `z_top`, nearer the sensor than sqrt(`r2_min`), or not finite. Returns the count kept.
    The world-aligned coordinates are c x - s y + off_x and s x + c y + off_y, in float32."""
    h = float(half << (levels - 1))
    kept = 0
    for i in range(xyz.shape[0]):
        x = xyz[i, 0]
        y = xyz[i, 1]
        z = xyz[i, 2]
        fx = np.floor((c * x - s * y + off_x) * inv_cell)
        fy = np.floor((s * x + c * y + off_y) * inv_cell)
        # NaN fails every comparison: a point that is not finite is left out too.
        if not (fx >= -h and fx < h and fy >= -h and fy < h and z <= z_top and x * x + y * y >= r2_min):
            flat_out[i] = -1
            continue
        qx = int(fx)
        qy = int(fy)
        flat_out[i] = _flat(qx, qy, _level(qx, qy, half, levels), half, n)
        kept += 1
    return kept


@njit(cache=True, nogil=True)
def scatter_measures(
    flat: np.ndarray,
    z: np.ndarray,
    beam: np.ndarray,
    points: np.ndarray,
    z_min: np.ndarray,
    z_max: np.ndarray,
    beam_bits: np.ndarray,
) -> None:
    """Adds each point (flat >= 0) to its cell's count, lowest and highest z and beam mask (bit beam % 64)."""
    one = np.uint64(1)
    for i in range(flat.shape[0]):
        f = flat[i]
        if f < 0:
            continue
        points[f] += 1
        zi = z[i]
        if zi < z_min[f]:
            z_min[f] = zi
        if zi > z_max[f]:
            z_max[f] = zi
        beam_bits[f] |= one << np.uint64(beam[i] & 63)


@njit(cache=True, nogil=True)
def _popcount(v: np.uint64) -> int:
    v = v - ((v >> np.uint64(1)) & np.uint64(0x5555555555555555))
    v = (v & np.uint64(0x3333333333333333)) + ((v >> np.uint64(2)) & np.uint64(0x3333333333333333))
    v = (v + (v >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return int((v * np.uint64(0x0101010101010101)) >> np.uint64(56))


@njit(cache=True, nogil=True)
def gather_measures(
    points: np.ndarray,
    z_min: np.ndarray,
    z_max: np.ndarray,
    beam_bits: np.ndarray,
    cells_out: np.ndarray,
    points_out: np.ndarray,
    beams_out: np.ndarray,
    z_min_out: np.ndarray,
    z_max_out: np.ndarray,
) -> int:
    """The touched cells in index order with their measures, and the accumulators emptied again.
    One pass over the grid (a few hundred thousand cells) is cheaper than sorting the touched ones."""
    k = 0
    for f in range(points.shape[0]):
        if points[f] == 0:
            continue
        cells_out[k] = f
        points_out[k] = points[f]
        beams_out[k] = _popcount(beam_bits[f])
        z_min_out[k] = z_min[f]
        z_max_out[k] = z_max[f]
        k += 1
        points[f] = 0
        z_min[f] = np.inf
        z_max[f] = -np.inf
        beam_bits[f] = 0
    return k


@njit(cache=True, nogil=True)
def _atan2(y: float, x: float) -> float:
    """atan2 within 2e-5 rad (Abramowitz and Stegun 4.4.47 on [0, 1]): a point's sector for a fraction
    of libm's cost."""
    ax = abs(x)
    ay = abs(y)
    hi = max(ax, ay)
    if hi == 0.0:
        return 0.0
    a = min(ax, ay) / hi
    q = a * a
    r = a * (0.9998660 + q * (-0.3302995 + q * (0.1801410 + q * (-0.0851330 + q * 0.0208351))))
    if ay > ax:
        r = 0.5 * math.pi - r
    if x < 0.0:
        r = math.pi - r
    return -r if y < 0.0 else r


@njit(cache=True, nogil=True)
def sector_ranges(
    xyz: np.ndarray,
    flat: np.ndarray,
    cell_class: np.ndarray,
    c: float,
    s: float,
    z_low: float,
    sectors: int,
    guard: int,
) -> np.ndarray:
    """Per azimuth sector (world-aligned, sector 0 starting at -pi) how far its beams saw free: up to
    the nearest return in a cell of class 2 (an obstacle) if some obstacle return of the sector lies no
    higher than `z_low` (its beam came down to there on its way), else only up to the farthest return in
    a cell of class 1 (ground) short of that; 0 where no point tells. Returns in cells of class 0 (too
    few to tell) count for neither. No farther than the nearest obstacle return of the `guard` sectors on
    either side: a ray that passes an object closer than a cell's side stops where the sectors over the
    object saw it (a cell the ray crosses may hold a part of the object that no beam met)."""
    blocked = np.full(sectors, np.inf)
    blocked_low = np.full(sectors, np.inf)
    ground = np.zeros(sectors)
    scale = sectors / _TWO_PI
    for i in range(flat.shape[0]):
        f = flat[i]
        if f < 0 or cell_class[f] == 0:
            continue
        x = float(xyz[i, 0])
        y = float(xyz[i, 1])
        dx = c * x - s * y
        dy = s * x + c * y
        r = math.sqrt(dx * dx + dy * dy)
        k = int((_atan2(dy, dx) + math.pi) * scale)
        k = min(max(k, 0), sectors - 1)
        if cell_class[f] == 1:
            ground[k] = max(ground[k], r)
        else:
            blocked[k] = min(blocked[k], r)
            if xyz[i, 2] <= z_low:
                blocked_low[k] = min(blocked_low[k], r)
    out = np.empty(sectors)
    for k in range(sectors):
        free = blocked[k] if blocked_low[k] < np.inf else min(blocked[k], ground[k])
        for j in range(k - guard, k + guard + 1):
            free = min(free, blocked[j % sectors])
        out[k] = free
    return out


@njit(cache=True, nogil=True)
def trace_free(
    free_m: np.ndarray,
    start_m: float,
    margin_m: float,
    px: float,
    py: float,
    finest_m: float,
    half: int,
    n: int,
    levels: int,
    cell_class: np.ndarray,
    stamp: np.ndarray,
    revolution: int,
    cells_out: np.ndarray,
) -> int:
    """Walks each sector's centre ray from the sensor at (px, py) (metres from the grid centre), from
    `start_m` out, through every cell it crosses (Amanatides and Woo's traversal, one level's cells at a
    time: the windows nest, so a ray from the centre only ever goes out to coarser ones), and lists
    each cell once (`stamp` marks them with `revolution`) that lies wholly `margin_m` short of the
    sector's free range (its farthest corner), and that held no obstacle return this revolution
    (class 2). Returns the count."""
    sectors = free_m.shape[0]
    k_out = 0
    for k in range(sectors):
        end = free_m[k] - margin_m
        if end <= start_m:
            continue
        theta = -math.pi + (k + 0.5) * _TWO_PI / sectors
        ux = math.cos(theta)
        uy = math.sin(theta)
        step_x = 1 if ux > 0.0 else -1
        step_y = 1 if uy > 0.0 else -1
        t = start_m
        x0 = px + t * ux
        y0 = py + t * uy
        level = _level(math.floor(x0 / finest_m), math.floor(y0 / finest_m), half, levels)
        size = finest_m * (1 << level)
        ix = math.floor(x0 / size)
        iy = math.floor(y0 / size)
        while True:
            if ix < -half or ix >= half or iy < -half or iy >= half:
                level += 1  # out of this window: on into the next coarser one
                if level >= levels:
                    break
                size *= 2.0
                ix = math.floor((px + t * ux) / size)
                iy = math.floor((py + t * uy) / size)
                continue
            # where the ray leaves the cell through an x and through a y boundary
            bx = (ix + (1 if step_x > 0 else 0)) * size
            by = (iy + (1 if step_y > 0 else 0)) * size
            tx = (bx - px) / ux if ux != 0.0 else np.inf
            ty = (by - py) / uy if uy != 0.0 else np.inf
            t_exit = min(tx, ty)
            if t_exit > end:
                break
            # the cell's corner farthest from the sensor
            fx = max(abs(ix * size - px), abs((ix + 1) * size - px))
            fy = max(abs(iy * size - py), abs((iy + 1) * size - py))
            f = (level * n + iy + half) * n + ix + half
            if fx * fx + fy * fy <= end * end and stamp[f] != revolution and cell_class[f] != 2:
                stamp[f] = revolution
                cells_out[k_out] = f
                k_out += 1
            if tx < ty:
                ix += step_x
            else:
                iy += step_y
            t = t_exit
    return k_out


@njit(cache=True, nogil=True)
def classify(
    cells: np.ndarray,
    points: np.ndarray,
    z_min: np.ndarray,
    z_max: np.ndarray,
    threshold_m: np.ndarray,
    cells_per_level: int,
    min_points: int,
    cell_class: np.ndarray,
) -> None:
    """Each touched cell's class this revolution (eq. 1): 2 if it holds `min_points` or more returns
    whose heights differ by more than its level's threshold, 1 (ground) if they differ less, 0 if it
    holds too few returns to tell."""
    for i in range(cells.shape[0]):
        f = cells[i]
        if points[i] < min_points:
            cell_class[f] = 0
        elif z_max[i] - z_min[i] > threshold_m[f // cells_per_level]:
            cell_class[f] = 2
        else:
            cell_class[f] = 1


@njit(cache=True, nogil=True)
def integrate(
    evidence: np.ndarray,
    z_min_plane: np.ndarray,
    z_max_plane: np.ndarray,
    cells: np.ndarray,
    beams: np.ndarray,
    z_min: np.ndarray,
    z_max: np.ndarray,
    freed: np.ndarray,
    cell_class: np.ndarray,
    occupied: np.float32,
    multi_beam: np.float32,
    free: np.float32,
    ray_free: np.float32,
    lo: np.float32,
    hi: np.float32,
    decay: np.float32,
) -> None:
    """Eq. 2 with eq. 5's decay on the flat evidence, in float32: a touched cell of class 2 adds
    `occupied` (+ `multi_beam` if two or more beams saw it), one of class 1 `free`, one of class 0
    nothing; each freed cell `ray_free` (a freed cell seen as ground takes the stronger of its two);
    clamped to [lo, hi]. Then every cell moves `decay` towards 0. The touched cells' lowest and highest
    returns go to the z planes, and their class is emptied."""
    zero = np.float32(0.0)
    for i in range(freed.shape[0]):
        f = freed[i]
        if cell_class[f] == 0:
            evidence[f] = min(max(evidence[f] + ray_free, lo), hi)
        else:
            cell_class[f] = 3  # seen as ground and crossed by a ray
    for i in range(cells.shape[0]):
        f = cells[i]
        c = cell_class[f]
        if c == 2:
            d = occupied + (multi_beam if beams[i] >= 2 else zero)
        elif c == 1:
            d = free
        elif c == 3:
            d = min(free, ray_free)
        else:
            d = zero
        evidence[f] = min(max(evidence[f] + d, lo), hi)
        z_min_plane[f] = z_min[i]
        z_max_plane[f] = z_max[i]
        cell_class[f] = 0
    for i in range(evidence.shape[0]):
        o = evidence[i]
        evidence[i] = o - min(max(o, -decay), decay)
