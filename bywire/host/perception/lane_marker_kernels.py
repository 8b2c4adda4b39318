"""The lane markers' per-revolution passes (lane_markers.py; seed 000 section 6), compiled with numba.

Each kernel is one or two passes over a revolution's points where numpy ran dozens (masks, gathers,
differences, searches of the same 80 000 near-ground points), and the runs of paint and the windows of
a curb are followed point by point along a beam, as the method describes them. They hold no model:
lane_markers.py decides every number and passes it in, and the numpy it replaced stays there as the
reference (`lane_markers.extract_features_reference`) that tests/host/perception/test_lane_markers.py
holds each revolution's features equal to, bit for bit.

Floating point follows numpy's rules exactly (no fastmath, so no fused multiply-adds): the same float32
arithmetic in the same order, a constant in the precision numpy compared it in (a Python float against
a float32 array is a float32 since NumPy 2), so the same revolution gives the same features. The one
float64 reduction, the plane's least squares, stays in numpy. Compiled once per machine (`cache=True`)
and released from the GIL while it runs (`nogil`), as `grid_kernels`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def candidates(
    xyz: np.ndarray,
    beam: np.ndarray,
    refl: np.ndarray,
    mask: np.ndarray,
    order: np.ndarray,
    z_offset: np.float32,
    band: np.float32,
    r2_min: np.float32,
    r2_max: np.float32,
    idx_out: np.ndarray,
    x_out: np.ndarray,
    y_out: np.ndarray,
    z_out: np.ndarray,
    r2_out: np.ndarray,
    beam_out: np.ndarray,
    refl_out: np.ndarray,
    mask_out: np.ndarray,
) -> int:
    """The points with |z + `z_offset`| <= `band` and `r2_min` <= x^2 + y^2 <= `r2_max` (float32), taken in
    the order `order` gives (none: the scan's), with their position k in that order (`idx_out`) and
    their coordinates, squared range, beam, reflectance and `mask` (none: all True). Returns the count."""
    n = xyz.shape[0]
    by_order = order.shape[0] > 0
    has_mask = mask.shape[0] > 0
    m = 0
    for k in range(n):
        i = order[k] if by_order else k
        x = xyz[i, 0]
        y = xyz[i, 1]
        z = xyz[i, 2]
        r2 = x * x + y * y
        if abs(z + z_offset) <= band and r2 >= r2_min and r2 <= r2_max:
            idx_out[m] = k
            x_out[m] = x
            y_out[m] = y
            z_out[m] = z
            r2_out[m] = r2
            beam_out[m] = beam[i]
            refl_out[m] = refl[i]
            mask_out[m] = mask[i] if has_mask else True
            m += 1
    return m


@njit(cache=True, nogil=True)
def plane_points(
    x: np.ndarray,
    y: np.ndarray,
    z: np.ndarray,
    stride: int,
    r2_min: float,
    r2_max: float,
    z_flat: float,
    band: float,
    x_out: np.ndarray,
    y_out: np.ndarray,
    z_out: np.ndarray,
    xb_out: np.ndarray,
    yb_out: np.ndarray,
    zb_out: np.ndarray,
) -> tuple[int, int]:
    """Every `stride`-th point as float64, those with `r2_min` <= x^2 + y^2 <= `r2_max` (the plane's
    points), and of those the ones with |z - `z_flat`| <= `band` (its RANSAC's). Returns both counts."""
    m = 0
    mb = 0
    for k in range(0, x.shape[0], stride):
        xf = np.float64(x[k])
        yf = np.float64(y[k])
        zf = np.float64(z[k])
        r2 = xf * xf + yf * yf
        if r2 >= r2_min and r2 <= r2_max:
            x_out[m] = xf
            y_out[m] = yf
            z_out[m] = zf
            m += 1
            if abs(zf - z_flat) <= band:
                xb_out[mb] = xf
                yb_out[mb] = yf
                zb_out[mb] = zf
                mb += 1
    return m, mb


@njit(cache=True, nogil=True)
def inlier_counts(
    coef: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    z: np.ndarray,
    tolerance: np.float32,
    counts_out: np.ndarray,
) -> None:
    """Per candidate plane (`coef`: rows a, b, c), the points with |z - ((a + b x) + c y)| <= `tolerance`."""
    for p in range(coef.shape[1]):
        a = coef[0, p]
        b = coef[1, p]
        c = coef[2, p]
        count = 0
        for i in range(x.shape[0]):
            if abs(z[i] - ((a + b * x[i]) + c * y[i])) <= tolerance:
                count += 1
        counts_out[p] = count


@njit(cache=True, nogil=True)
def plane_inliers(
    x: np.ndarray,
    y: np.ndarray,
    z: np.ndarray,
    a: float,
    b: float,
    c: float,
    tolerance: float,
    x_out: np.ndarray,
    y_out: np.ndarray,
    z_out: np.ndarray,
) -> int:
    """The points with |z - ((a + b x) + c y)| <= `tolerance` (float64), in order. Returns the count."""
    m = 0
    for i in range(x.shape[0]):
        if abs(z[i] - ((a + b * x[i]) + c * y[i])) <= tolerance:
            x_out[m] = x[i]
            y_out[m] = y[i]
            z_out[m] = z[i]
            m += 1
    return m


@njit(cache=True, nogil=True)
def ground(
    x: np.ndarray,
    y: np.ndarray,
    z: np.ndarray,
    mask: np.ndarray,
    idx: np.ndarray,
    order: np.ndarray,
    a: np.float32,
    b: np.float32,
    c: np.float32,
    tolerance: np.float32,
    height_out: np.ndarray,
    ground_out: np.ndarray,
    scan_ground_out: np.ndarray,
) -> None:
    """Each point's height over the plane z = a + b x + c y (float32) and whether it is ground: within
    `tolerance` of it and in `mask`; the ground also per point of the scan (`scan_ground_out`, all
    False on entry), at position idx in `order` (none: the scan's)."""
    by_order = order.shape[0] > 0
    for i in range(x.shape[0]):
        h = z[i] - ((a + b * x[i]) + c * y[i])
        g = abs(h) <= tolerance and mask[i]
        height_out[i] = h
        ground_out[i] = g
        scan_ground_out[order[idx[i]] if by_order else idx[i]] = g


@njit(cache=True, nogil=True)
def _adjacent(beam: np.ndarray, idx: np.ndarray, k: int) -> bool:
    """Points k and k + 1 are neighbours in the scan: one beam, one after the other."""
    return beam[k + 1] == beam[k] and idx[k + 1] - idx[k] == 1


@njit(cache=True, nogil=True)
def paint(
    x: np.ndarray,
    y: np.ndarray,
    refl: np.ndarray,
    beam: np.ndarray,
    idx: np.ndarray,
    ground: np.ndarray,
    n_beams: int,
    levels: int,
    contrast: np.float64,
    max_width: np.float32,
    isolation: np.float32,
    max_neighbours: int,
    paint_out: np.ndarray,
) -> None:
    """The paint points (lane_markers.py's step 2): ground brighter than its beam's median ground
    reflectance (from a histogram of `levels` levels; beams 0 .. `n_beams` - 1) by `contrast`, single
    dark ground points between two bright neighbours filled, in runs of neighbours no wider than
    `max_width`, with ground neighbours on both sides and at most `max_neighbours` other runs of their
    beam within `isolation` (runs k apart in the scan's order, k = 1 .. `max_neighbours` + 1)."""
    n = x.shape[0]
    # one histogram of beam * levels + level, as np.bincount counted it
    hist = np.zeros(n_beams * levels, np.int64)
    for i in range(n):
        if ground[i]:
            hist[beam[i] * levels + min(int(refl[i] * np.float32(levels)), levels - 1)] += 1
    threshold = np.full(n_beams, np.nan)
    for b in range(n_beams):
        total = 0
        for q in range(levels):
            total += hist[b * levels + q]
        if total == 0:
            continue
        half = (total + 1) // 2
        cum = 0
        for q in range(levels):
            cum += hist[b * levels + q]
            if cum >= half:
                threshold[b] = (q + 0.5) / levels + contrast
                break
    bright = np.zeros(n, np.bool_)
    for i in range(n):
        bright[i] = ground[i] and refl[i] > threshold[beam[i]]  # NaN: never bright
    # a dark point between two bright neighbours: filled (from the unfilled neighbours)
    filled = bright.copy()
    for i in range(1, n - 1):
        if (
            not bright[i]
            and ground[i]
            and bright[i - 1]
            and bright[i + 1]
            and _adjacent(beam, idx, i - 1)
            and _adjacent(beam, idx, i)
        ):
            filled[i] = True
    # runs of bright scan neighbours, first and last point (inclusive)
    starts = np.empty(n, np.int64)
    ends = np.empty(n, np.int64)
    runs = 0
    for i in range(n):
        if not filled[i]:
            continue
        if i > 0 and filled[i - 1] and _adjacent(beam, idx, i - 1):
            ends[runs - 1] = i
        else:
            starts[runs] = i
            ends[runs] = i
            runs += 1
    keep = np.empty(runs, np.bool_)
    cx = np.empty(runs, np.float32)
    cy = np.empty(runs, np.float32)
    half32 = np.float32(0.5)
    for r in range(runs):
        s = starts[r]
        e = ends[r]
        width = math.hypot(x[e] - x[s], y[e] - y[s])
        before = s > 0 and _adjacent(beam, idx, s - 1) and ground[s - 1]
        after = e < n - 1 and _adjacent(beam, idx, e) and ground[e + 1]
        keep[r] = width <= max_width and before and after
        cx[r] = half32 * (x[s] + x[e])
        cy[r] = half32 * (y[s] + y[e])
    count = np.zeros(runs, np.int64)
    for k in range(1, max_neighbours + 2):
        for r in range(runs - k):
            if (
                beam[starts[r + k]] == beam[starts[r]]
                and math.hypot(cx[r + k] - cx[r], cy[r + k] - cy[r]) <= isolation
            ):
                count[r + k] += 1
                count[r] += 1
    for i in range(n):
        paint_out[i] = False
    for r in range(runs):
        if keep[r] and count[r] <= max_neighbours:
            for i in range(starts[r], ends[r] + 1):
                paint_out[i] = True


@njit(cache=True, nogil=True)
def curbs(
    r2: np.ndarray,
    height: np.ndarray,
    beam: np.ndarray,
    idx: np.ndarray,
    ground: np.ndarray,
    dphi: np.ndarray,
    near: np.float32,
    window: np.float32,
    step_min: np.float32,
    step_max: np.float32,
    max_missing: int,
    curb_out: np.ndarray,
) -> int:
    """The curb points (lane_markers.py's step 3), as positions among the points; returns their count.

    Among the points within `near` of the plane, heights smoothed over three neighbours, a window from
    each to the point about `window` further along its ring (r * `dphi` of its beam apart) whose rise
    is `step_min` .. `step_max`, its lower end on the ground, no break between them (another beam, or
    more than `max_missing` points missing from the scan). Per run of consecutive such windows, the
    middle of those within 10 % of the largest rise."""
    n_all = height.shape[0]
    sub = np.empty(n_all, np.int64)
    n = 0
    for k in range(n_all):
        if abs(height[k]) <= near:
            sub[n] = k
            n += 1
    if n < 3:
        return 0
    raw = np.empty(n, np.float32)
    for k in range(n):
        raw[k] = height[sub[k]]
    hs = raw.copy()
    third = np.float32(1.0 / 3.0)
    for k in range(1, n - 1):
        hs[k] = ((raw[k - 1] + raw[k]) + raw[k + 1]) * third
    piece = np.empty(n, np.int64)  # a break before point k counts at k
    piece[0] = 0
    for k in range(1, n):
        cut = beam[sub[k]] != beam[sub[k - 1]] or idx[sub[k]] - idx[sub[k - 1]] > max_missing + 1
        piece[k] = piece[k - 1] + (1 if cut else 0)
    hit_i = np.empty(n, np.int64)
    hit_j = np.empty(n, np.int64)
    hit_mag = np.empty(n, np.float64)
    hits = 0
    for i in range(n):
        spacing = np.sqrt(r2[sub[i]]) * dphi[beam[sub[i]]]
        lag = np.ceil(window / spacing)
        # A window that ends past the last point (or never: a point at the sensor) holds no rise.
        if not lag < n - i:
            continue
        j = i + int(lag)
        dz = hs[j] - hs[i]
        mag = abs(dz)
        if not (mag >= step_min and mag <= step_max) or piece[i] != piece[j]:
            continue
        if ground[sub[i]] if dz > np.float32(0.0) else ground[sub[j]]:  # the lower side on the road
            hit_i[hits] = i
            hit_j[hits] = j
            hit_mag[hits] = np.float64(mag)
            hits += 1
    m = 0
    lo = 0
    while lo < hits:
        hi = lo + 1
        while hi < hits and hit_i[hi] == hit_i[hi - 1] + 1:
            hi += 1
        best = hit_mag[lo]
        for k in range(lo + 1, hi):
            best = max(best, hit_mag[k])
        total = 0.0
        count = 0
        for k in range(lo, hi):
            if hit_mag[k] >= 0.9 * best:
                total += (hit_i[k] + hit_j[k]) / 2.0
                count += 1
        curb_out[m] = sub[int(np.rint(total / count))]
        m += 1
        lo = hi
    return m
