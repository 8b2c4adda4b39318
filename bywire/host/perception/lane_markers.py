"""Lane markers from the LIDAR: painted lines and curbs, accumulated into a marker image (seed 000 Sec. 6).

"Painted lane markings are detected within the intensity readings of the LIDAR, whereas curbs cause
small height changes in the range data ... subsequent scans are registered spatially and accumulated
employing absolute positioning information from the dead-reckoning system." Features are found in each
scan and only then mapped, "to minimize the effect of errors in the vehicle localization".

Per scan (`extract_features`), on the points of each beam in firing order:

1. Ground: the road plane z = a + b x + c y within `max_range_m`, by RANSAC over the points within
   `ground_band_m` of z = -sensor height (the plane with the most points within half the tolerance: the
   road, whose near rings are the densest, not the sidewalk 15 cm above it, which a least-squares fit
   through both would tilt towards), refined by least squares on its inliers. Ground points lie within
   `ground_tolerance_m` of it and, if a ground mask from elsewhere is given (the occupancy grid's points
   that are not obstacles), in that mask too.
2. Paint: ground points brighter than their beam's median ground reflectance by `paint_contrast`
   (single dark points between two bright ones filled: worn paint), in runs along the beam no wider
   than `paint_max_width_m`, bounded by ground on both sides, with at most `paint_max_neighbours` other
   runs within `paint_isolation_m`. The median is per beam because reflectance depends on range and on
   each laser's calibration; the narrow, bounded, isolated run is the paper's "high-intensity gradient"
   inside the road: a line crosses a beam once, dark on both sides, which neither a wide bright patch
   (a concrete slab) nor grass (bright at the LIDAR's 905 nm, speckled) does.
3. Curbs: a rise of `curb_step_min_m` .. `curb_step_max_m` along a beam's ring within `curb_window_m`
   of ground, from a ground point (a step up from the road, not any step in the clutter beside it). A
   ring does not see a curb as a jump between two neighbours: the rays that meet the face climb it over
   dh / tan(-elevation) of ground. Of the windows that hold the whole rise, the middle one's centre is
   the feature: on the face.

Accumulation (`MarkerGrid`): a square, world-aligned grid centred on the car (`size_cells` x `cell_m`,
40 m by default), shifted by whole cells as the car moves (no resampling: a marker stays in its cell),
decaying by exp(-dt / `decay_tau_s`) per scan; each scan adds 1 to every cell in which it saw a feature
(once per scan, however many points: near rings are ten times denser than far ones and would otherwise
drown them).

Deviations: the paper classifies ground with the occupancy grid of its Sec. 4.1 and searches each laser's
ground points for continuous chunks without curb-sized height changes; we fit one road plane per scan
(the road near the car) and let the plane's tolerance and the bounded-run test stand for the chunks
(a sidewalk is off the plane by a curb's height). The paper says of curbs only that they "cause small
height changes in the range data"; the rise along a ring above is ours. Points are not
motion-compensated within a revolution (KITTI's files are not either): at 10 m/s the scan's start and
end are 1 m apart along the road, which shifts markings along themselves, not across.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np
import numpy.typing as npt

from . import lane_marker_kernels
from .radon import RadonSpectrum
from .scan import HDL64E_BEAMS, Scan

__all__ = [
    "GridParams",
    "LaneMarkerMap",
    "MarkerFeatures",
    "MarkerGrid",
    "MarkerParams",
    "PlanarPose",
    "extract_features",
    "extract_features_reference",
    "fit_ground_plane",
    "marker_png",
    "warm_up",
]

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

# Reflectance is quantised to this many levels for the per-beam median (one histogram for all beams
# instead of 64 sorts); 1/256 is far below the paint contrast.
_REFLECTANCE_LEVELS = 256
# Fewer band points than this and the plane fit is not trusted: the flat ground z = -height is used.
_MIN_PLANE_POINTS = 200
# Plane fit on every 4th candidate point.
_PLANE_STRIDE = 4
# RANSAC for the road plane: 64 candidates from three random band points each; with half of the band
# on the road, a candidate has all three there with probability 1/8, so all 64 miss it with 2e-4.
# Scored on every 8th of the fitted points (2-3 k).
_RANSAC_PLANES = 64
_RANSAC_STRIDE = 8
_RANSAC_CHUNK = 8  # candidates scored at a time: 8 x 3 k residuals, 100 kB
# A candidate steeper than this is a wall or a car's side, not a road (the steepest streets are 20 %).
_MAX_TILT_RAD = math.radians(15.0)


class PlanarPose(Protocol):
    """A pose on the local plane: `UrbanPose`, `world.pose.Pose` and `lateral.VehiclePose` all are one."""

    @property
    def x_m(self) -> float: ...
    @property
    def y_m(self) -> float: ...
    @property
    def heading_rad(self) -> float: ...


@dataclass(frozen=True)
class MarkerParams:
    """Feature extraction; see the module docstring for each step."""

    # The car's own roof and bonnet return inside 3 m; beyond 30 m the lowest beams' rings are more than
    # 2 m apart and a 10 cm line is hit by one point per ring at best.
    min_range_m: float = 3.0
    max_range_m: float = 30.0
    # Plane fit: a first band wide enough for a 2 deg pitch at 15 m (0.5 m), then the ground itself.
    ground_band_m: float = 0.5
    # A ground point's distance to the plane: road roughness and range noise (HDL-64E: 2 cm) at a
    # grazing angle, below a curb (10-20 cm).
    ground_tolerance_m: float = 0.08
    # Reflectance (0..1) above the beam's median ground reflectance. KITTI's asphalt reads 0.25-0.35
    # with a spread (MAD) of about 0.04; its lane paint reads 0.5 and more.
    paint_contrast: float = 0.15
    # A painted line is 0.1-0.3 m wide; a beam crossing it at 60 deg from its direction sees 0.6 m.
    paint_max_width_m: float = 0.6
    # Isolation: a line crosses a beam once (a double centre line twice, 0.1-0.3 m apart); grass, which
    # is bright at the LIDAR's 905 nm, and gravel give many short bright runs per metre of beam.
    paint_isolation_m: float = 1.0
    paint_max_neighbours: int = 1
    # Curb: a 10-20 cm step (a flush kerb at a driveway drops to ~5 cm and is not looked for) ...
    curb_step_min_m: float = 0.08
    curb_step_max_m: float = 0.25
    # ... within this much of a beam's ring. A ring does not see a step as a jump between two points:
    # the rays that meet the curb's face climb it over dh / tan(-elevation) of ground (0.3 m at the
    # lowest beam, 0.85 m at -10 deg for 15 cm). Over 1 m a crowned road (2.5 %) rises 2.5 cm.
    curb_window_m: float = 1.0
    # Points a ring may miss (no return, a dropped point) and still be continuous.
    curb_max_missing: int = 2

    def __post_init__(self) -> None:
        if not 0.0 <= self.min_range_m < self.max_range_m:
            raise ValueError(f"ranges {self.min_range_m} .. {self.max_range_m} m: need 0 <= min < max")
        if not 0.0 < self.curb_step_min_m < self.curb_step_max_m:
            raise ValueError(
                f"curb steps {self.curb_step_min_m} .. {self.curb_step_max_m} m: need 0 < min < max"
            )
        if not self.curb_window_m > 0.0 or self.curb_max_missing < 0:
            raise ValueError(
                f"curb_window_m = {self.curb_window_m}, curb_max_missing = {self.curb_max_missing}"
            )


@dataclass(frozen=True, eq=False)
class MarkerFeatures:
    """One scan's features in the sensor frame (x forward, y left, metres) and the ground it found."""

    paint_xy_m: FloatArray  # (K, 2)
    curb_xy_m: FloatArray  # (M, 2)
    ground: BoolArray  # (N,) per point of the scan, in the scan's order
    plane: tuple[float, float, float]  # a, b, c of z = a + b x + c y (metres)


def fit_ground_plane(
    xyz_m: npt.NDArray[np.floating], sensor_height_m: float, params: MarkerParams = MarkerParams()
) -> tuple[float, float, float]:
    """z = a + b x + c y through the road near the sensor (see the module docstring)."""
    return _fit_plane(xyz_m[:, 0], xyz_m[:, 1], xyz_m[:, 2], sensor_height_m, params)


def _fit_plane(
    x_in: npt.NDArray[np.floating],
    y_in: npt.NDArray[np.floating],
    z_in: npt.NDArray[np.floating],
    sensor_height_m: float,
    params: MarkerParams,
) -> tuple[float, float, float]:
    # Every 4th point: 10-15 k points for 3 parameters is plenty, and a quarter of the cost.
    xf: FloatArray = np.asarray(x_in[::_PLANE_STRIDE], dtype=np.float64)
    yf: FloatArray = np.asarray(y_in[::_PLANE_STRIDE], dtype=np.float64)
    zf: FloatArray = np.asarray(z_in[::_PLANE_STRIDE], dtype=np.float64)
    r2 = xf * xf + yf * yf
    near = (r2 >= params.min_range_m**2) & (r2 <= params.max_range_m**2)
    x, y, z = xf[near], yf[near], zf[near]
    flat = (-float(sensor_height_m), 0.0, 0.0)
    band = np.abs(z - flat[0]) <= params.ground_band_m
    if np.count_nonzero(band) < _MIN_PLANE_POINTS:
        return flat
    # The road, not the sidewalk: a least-squares plane through both sits between them and tilts
    # towards the sidewalk (a quarter of the ground near a car, 15 cm higher), and far sidewalk then
    # fits it as well as the road. RANSAC picks the plane with the most points within half the
    # tolerance; the road has the most, as the rings near the car, the densest, lie on it.
    plane = _ransac_plane(x[band], y[band], z[band], params, _inlier_counts)
    if plane is None:
        return flat
    for _ in range(2):  # least squares on the inliers, twice: the sample's three points are noisy
        res_all = z - (plane[0] + plane[1] * x + plane[2] * y)
        sel = np.abs(res_all) <= params.ground_tolerance_m
        refit = _lsq_plane(x[sel], y[sel], z[sel])
        if refit is None:
            break
        plane = refit
    return plane


def _fit_plane_compiled(
    x: npt.NDArray[np.float32],
    y: npt.NDArray[np.float32],
    z: npt.NDArray[np.float32],
    sensor_height_m: float,
    params: MarkerParams,
) -> tuple[float, float, float]:
    """`_fit_plane` in `lane_marker_kernels`' passes: the same plane, bit for bit."""
    flat = (-float(sensor_height_m), 0.0, 0.0)
    n = -(-x.size // _PLANE_STRIDE)
    xf, yf, zf, xb, yb, zb = np.empty((6, n))
    m, mb = lane_marker_kernels.plane_points(
        x, y, z, _PLANE_STRIDE, params.min_range_m**2, params.max_range_m**2, flat[0],
        params.ground_band_m, xf, yf, zf, xb, yb, zb,
    )  # fmt: skip
    if mb < _MIN_PLANE_POINTS:
        return flat
    plane = _ransac_plane(xb[:mb], yb[:mb], zb[:mb], params, _inlier_counts_compiled)
    if plane is None:
        return flat
    xs, ys, zs = np.empty((3, m))
    for _ in range(2):
        k = lane_marker_kernels.plane_inliers(
            xf[:m], yf[:m], zf[:m], *plane, params.ground_tolerance_m, xs, ys, zs
        )
        refit = _lsq_plane(xs[:k], ys[:k], zs[:k])
        if refit is None:
            break
        plane = refit
    return plane


InlierCounter = Callable[
    [
        npt.NDArray[np.float32],
        npt.NDArray[np.float32],
        npt.NDArray[np.float32],
        npt.NDArray[np.float32],
        np.float32,
    ],
    npt.NDArray[np.intp],
]


def _ransac_plane(
    xb: FloatArray, yb: FloatArray, zb: FloatArray, params: MarkerParams, inlier_counts: InlierCounter
) -> tuple[float, float, float] | None:
    """The RANSAC's plane through the band points xb, yb, zb (None: no candidate is a road)."""
    tri = _ransac_samples(xb.size)
    p0 = np.stack((xb[tri[:, 0]], yb[tri[:, 0]], zb[tri[:, 0]]), axis=1)
    e1 = np.stack((xb[tri[:, 1]], yb[tri[:, 1]], zb[tri[:, 1]]), axis=1) - p0
    e2 = np.stack((xb[tri[:, 2]], yb[tri[:, 2]], zb[tri[:, 2]]), axis=1) - p0
    normal = np.cross(e1, e2)
    norm = np.linalg.norm(normal, axis=1)
    ok = norm > 1e-9
    normal[ok] /= norm[ok, None]
    ok &= np.abs(normal[:, 2]) >= math.cos(_MAX_TILT_RAD)  # a road, not a wall
    if not ok.any():
        return None
    normal, p0 = normal[ok], p0[ok]
    # z = a + b x + c y of each candidate
    b = -normal[:, 0] / normal[:, 2]
    c = -normal[:, 1] / normal[:, 2]
    a = p0[:, 2] - b * p0[:, 0] - c * p0[:, 1]
    probe = slice(None, None, _RANSAC_STRIDE)
    xp, yp, zp = (v[probe].astype(np.float32) for v in (xb, yb, zb))
    coef = np.stack((a, b, c)).astype(np.float32)
    inliers = inlier_counts(coef, xp, yp, zp, np.float32(0.5 * params.ground_tolerance_m))
    best = int(np.argmax(inliers))
    return (float(a[best]), float(b[best]), float(c[best]))


def _inlier_counts_compiled(
    coef: npt.NDArray[np.float32],
    x: npt.NDArray[np.float32],
    y: npt.NDArray[np.float32],
    z: npt.NDArray[np.float32],
    tolerance: np.float32,
) -> npt.NDArray[np.intp]:
    counts = np.empty(coef.shape[1], np.intp)
    lane_marker_kernels.inlier_counts(coef, x, y, z, tolerance, counts)
    return counts


def _inlier_counts(
    coef: npt.NDArray[np.float32],
    x: npt.NDArray[np.float32],
    y: npt.NDArray[np.float32],
    z: npt.NDArray[np.float32],
    tolerance: np.float32,
) -> npt.NDArray[np.intp]:
    """Per candidate plane (coef: a, b, c rows), the points with |z - ((a + b x) + c y)| <= tolerance:
    a few planes at a time in two buffers that stay in the cache (all 64 planes' residuals at once
    were a megabyte, five times over)."""
    n_planes = coef.shape[1]
    counts = np.empty(n_planes, np.intp)
    res = np.empty((_RANSAC_CHUNK, x.size), np.float32)
    tmp = np.empty_like(res)
    within = np.empty(res.shape, bool)
    for lo in range(0, n_planes, _RANSAC_CHUNK):
        k = min(_RANSAC_CHUNK, n_planes - lo)
        r, t, w = res[:k], tmp[:k], within[:k]
        np.multiply(coef[1, lo : lo + k, None], x, out=r)
        np.add(coef[0, lo : lo + k, None], r, out=r)
        np.multiply(coef[2, lo : lo + k, None], y, out=t)
        r += t
        np.subtract(z, r, out=r)
        np.abs(r, out=r)
        np.less_equal(r, tolerance, out=w)
        counts[lo : lo + k] = np.count_nonzero(w, axis=1)
    return counts


@functools.lru_cache(maxsize=64)
def _ransac_samples(n: int) -> npt.NDArray[np.int64]:
    """The RANSAC's three points per candidate plane among n band points: fixed (a generator seeded 0),
    so that the same scan always gives the same plane; a function of n alone, drawn once per n."""
    out = np.random.default_rng(0).integers(0, n, size=(_RANSAC_PLANES, 3))
    out.setflags(write=False)
    return out


def _lsq_plane(xs: FloatArray, ys: FloatArray, zs: FloatArray) -> tuple[float, float, float] | None:
    """Least-squares z = a + b x + c y through the points (None: too few, or degenerate)."""
    if xs.size < _MIN_PLANE_POINTS:
        return None
    # The 3 x 3 normal equations (lstsq's answer without its (N, 3) copy), summed without BLAS: its
    # threads fight the other processes for 2 cores and turned a 0.1 ms sum into 40 ms.
    sx, sy, sxx, syy, sxy = xs.sum(), ys.sum(), (xs * xs).sum(), (ys * ys).sum(), (xs * ys).sum()
    a_mat = np.array([[xs.size, sx, sy], [sx, sxx, sxy], [sy, sxy, syy]])
    rhs = np.array([zs.sum(), (xs * zs).sum(), (ys * zs).sum()])
    try:
        sol = np.linalg.solve(a_mat, rhs)
    except np.linalg.LinAlgError:
        return None
    return (float(sol[0]), float(sol[1]), float(sol[2]))


def _beam_medians(refl: npt.NDArray[np.float32], beam: npt.NDArray[np.int16]) -> FloatArray:
    """Median reflectance per beam (NaN where a beam has none), from one 2-D histogram."""
    n_beams = max(int(beam.max()) + 1, HDL64E_BEAMS) if beam.size else HDL64E_BEAMS
    levels = _REFLECTANCE_LEVELS
    q = np.minimum((refl * levels).astype(np.int64), levels - 1)
    hist = np.bincount(beam.astype(np.int64) * levels + q, minlength=n_beams * levels).reshape(
        n_beams, levels
    )
    cum = np.cumsum(hist, axis=1)
    total = cum[:, -1]
    idx = np.argmax(cum >= (total[:, None] + 1) // 2, axis=1)
    med = (idx + 0.5) / levels
    return np.where(total > 0, med, np.nan)


def extract_features(
    scan: Scan, params: MarkerParams = MarkerParams(), ground_mask: BoolArray | None = None
) -> MarkerFeatures:
    """Paint and curb features of one revolution (sensor frame); see the module docstring.

    Points must come in firing order within each beam (a scan as the sensor delivers it, or KITTI's files,
    which are stored beam by beam); they may be interleaved across beams. `ground_mask` (per point of
    the scan) is what ground must also be: the occupancy grid's `~OccupancyGrid.obstacle_points(scan,
    pose)` keeps paint and the foot of curbs off cells with an obstacle's height step in them.

    Computed in `lane_marker_kernels`' compiled passes (`warm_up` loads them); the features are
    `extract_features_reference`'s, bit for bit, for a scan of the documented dtypes (float32 points
    and reflectance, int16 beams; others are converted to them first).
    """
    n = len(scan)
    empty = np.zeros((0, 2))
    no_plane = (-float(scan.sensor_height_m), 0.0, 0.0)
    if n == 0:
        return MarkerFeatures(empty, empty, np.zeros(0, bool), no_plane)
    xyz = np.ascontiguousarray(scan.xyz_m, np.float32)
    beam_scan = np.ascontiguousarray(scan.beam, np.int16)
    refl_scan = np.ascontiguousarray(scan.reflectance, np.float32)
    order = _NO_ORDER
    if n > 1 and not bool(np.all(beam_scan[1:] >= beam_scan[:-1])):
        order = np.argsort(beam_scan, kind="stable")  # grouped by beam, firing order kept
    mask = _NO_MASK
    if ground_mask is not None:
        mask = np.ascontiguousarray(ground_mask, dtype=bool)
        if mask.shape != (n,):
            raise ValueError(f"ground_mask has shape {mask.shape}, the scan {n} points")
    # Only points near the ground and in range can be paint or the foot of a curb: the rest (walls,
    # cars, trees, the far road; a third of a scan) is dropped before anything else is computed. Their
    # position in the scan (grouped by beam) is kept (`idx`) so that neighbours in firing order are known.
    idx = np.empty(n, np.intp)
    x, y, z, r2, refl = np.empty((5, n), np.float32)
    beam = np.empty(n, np.int16)
    in_mask = np.empty(n, bool)
    m = lane_marker_kernels.candidates(
        xyz, beam_scan, refl_scan, mask, order, np.float32(scan.sensor_height_m),
        np.float32(params.ground_band_m + params.curb_step_max_m), np.float32(params.min_range_m**2),
        np.float32(params.max_range_m**2), idx, x, y, z, r2, beam, refl, in_mask,
    )  # fmt: skip
    if m == 0:
        return MarkerFeatures(empty, empty, np.zeros(n, bool), no_plane)
    idx, x, y, z, r2, refl = idx[:m], x[:m], y[:m], z[:m], r2[:m], refl[:m]
    beam, in_mask = beam[:m], in_mask[:m]
    if int(beam.min()) < 0:
        raise ValueError(f"beam {int(beam.min())}: beams are numbered from 0")
    plane = _fit_plane_compiled(x, y, z, scan.sensor_height_m, params)
    height = np.empty(m, np.float32)
    ground = np.empty(m, bool)
    ground_out = np.zeros(n, bool)
    a, b, c = (np.float32(v) for v in plane)
    lane_marker_kernels.ground(
        x, y, z, in_mask, idx, order, a, b, c, np.float32(params.ground_tolerance_m), height, ground,
        ground_out,
    )  # fmt: skip

    paint = np.empty(m, bool)
    lane_marker_kernels.paint(
        x, y, refl, beam, idx, ground, max(int(beam.max()) + 1, HDL64E_BEAMS), _REFLECTANCE_LEVELS,
        np.float64(np.float32(params.paint_contrast)), np.float32(params.paint_max_width_m),
        np.float32(params.paint_isolation_m), params.paint_max_neighbours, paint,
    )  # fmt: skip
    curb = np.empty(m, np.intp)
    k = lane_marker_kernels.curbs(
        r2, height, beam, idx, ground, _beam_step_rad(beam_scan if order is _NO_ORDER else beam_scan[order]),
        np.float32(params.curb_step_max_m + params.ground_tolerance_m), np.float32(params.curb_window_m),
        np.float32(params.curb_step_min_m), np.float32(params.curb_step_max_m), params.curb_max_missing, curb,
    )  # fmt: skip
    paint_xy = np.column_stack((x[paint], y[paint])).astype(np.float64)
    curb_xy = np.column_stack((x[curb[:k]], y[curb[:k]])).astype(np.float64)
    return MarkerFeatures(paint_xy, curb_xy, ground_out, plane)


_NO_ORDER = np.zeros(0, np.intp)
_NO_MASK = np.zeros(0, bool)


def _beam_step_rad(beam_sorted: npt.NDArray[np.int16]) -> npt.NDArray[np.float32]:
    """A beam's angle between points: a turn over its points per turn (in the whole scan, grouped by
    beam here, so that each beam's count is where its group ends less where it starts)."""
    beam_ids = np.arange(max(HDL64E_BEAMS, int(beam_sorted[-1]) + 1) + 1, dtype=beam_sorted.dtype)
    per_turn = np.diff(np.searchsorted(beam_sorted, beam_ids))
    return (2.0 * np.pi / np.maximum(per_turn, 1)).astype(np.float32)


def extract_features_reference(
    scan: Scan, params: MarkerParams = MarkerParams(), ground_mask: BoolArray | None = None
) -> MarkerFeatures:
    """`extract_features` in numpy, step by step as the module docstring describes them: the reference
    the compiled passes are held equal to (tests), and the place to read the method."""
    n = len(scan)
    empty = np.zeros((0, 2))
    no_plane = (-float(scan.sensor_height_m), 0.0, 0.0)
    if n == 0:
        return MarkerFeatures(empty, empty, np.zeros(0, bool), no_plane)
    order: npt.NDArray[np.intp] | None = None
    if n > 1 and not bool(np.all(scan.beam[1:] >= scan.beam[:-1])):
        order = np.argsort(scan.beam, kind="stable")  # grouped by beam, firing order kept
    xyz = scan.xyz_m if order is None else scan.xyz_m[order]
    beam_all = scan.beam if order is None else scan.beam[order]
    refl_all = scan.reflectance if order is None else scan.reflectance[order]
    mask = None
    if ground_mask is not None:
        mask = np.asarray(ground_mask, dtype=bool)
        if mask.shape != (n,):
            raise ValueError(f"ground_mask has shape {mask.shape}, the scan {n} points")
        mask = mask if order is None else mask[order]
    # Only points near the ground and in range can be paint or the foot of a curb: the rest (walls,
    # cars, trees, the far road; a third of a scan) is dropped before anything else is computed. Their
    # position in the scan is kept (`idx`) so that neighbours in firing order are still known.
    x_all, y_all, z_all = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    r2_all = x_all * x_all + y_all * y_all
    cand = np.abs(z_all + np.float32(scan.sensor_height_m)) <= params.ground_band_m + params.curb_step_max_m
    cand &= r2_all >= np.float32(params.min_range_m**2)
    cand &= r2_all <= np.float32(params.max_range_m**2)
    idx = np.flatnonzero(cand)
    x, y, z, r2 = x_all[idx], y_all[idx], z_all[idx], r2_all[idx]
    beam, refl = beam_all[idx], refl_all[idx]
    plane = _fit_plane(x, y, z, scan.sensor_height_m, params) if idx.size else no_plane
    height = z - (np.float32(plane[0]) + np.float32(plane[1]) * x + np.float32(plane[2]) * y)
    ground = np.abs(height) <= np.float32(params.ground_tolerance_m)
    if mask is not None:
        ground &= mask[idx]
    adjacent = (beam[1:] == beam[:-1]) & (np.diff(idx) == 1)  # subset i and i + 1 are scan neighbours

    paint = _paint(x, y, refl, beam, ground, adjacent, params)
    curb_xy = _curbs(x, y, r2, height, beam, idx, ground, _beam_step_rad(beam_all), params)

    ground_sorted = np.zeros(n, bool)
    ground_sorted[idx] = ground
    if order is None:
        ground_out = ground_sorted
    else:
        ground_out = np.empty_like(ground_sorted)
        ground_out[order] = ground_sorted
    paint_xy = np.column_stack((x[paint], y[paint])).astype(np.float64)
    return MarkerFeatures(paint_xy, curb_xy, ground_out, plane)


def _paint(
    x: npt.NDArray[np.float32],
    y: npt.NDArray[np.float32],
    refl: npt.NDArray[np.float32],
    beam: npt.NDArray[np.int16],
    ground: BoolArray,
    adjacent: BoolArray,
    params: MarkerParams,
) -> BoolArray:
    n = x.size
    threshold = _beam_medians(refl[ground], beam[ground]) + np.float32(params.paint_contrast)
    bright = ground & (refl > threshold[beam])  # NaN median: never bright
    if not bright.any():
        return bright
    # A dark point between two bright neighbours is a speck of worn paint, not the road: filled.
    hole = np.zeros(n, bool)
    hole[1:-1] = ~bright[1:-1] & ground[1:-1] & bright[:-2] & bright[2:] & adjacent[:-1] & adjacent[1:]
    bright |= hole
    # runs of bright points that are scan neighbours
    link = bright[1:] & bright[:-1] & adjacent  # i and i + 1 in one run
    first = bright.copy()
    first[1:] &= ~link
    last = bright.copy()
    last[:-1] &= ~link
    starts, ends = np.flatnonzero(first), np.flatnonzero(last)  # inclusive, paired in order
    width = np.hypot(x[ends] - x[starts], y[ends] - y[starts])
    # bounded by (dark) ground, the scan neighbour on both sides
    before = np.maximum(starts - 1, 0)
    after = np.minimum(ends, n - 2)
    ok_before = (starts > 0) & adjacent[before] & ground[before]
    ok_after = (ends < n - 1) & adjacent[after] & ground[np.minimum(ends + 1, n - 1)]
    keep = (width <= params.paint_max_width_m) & ok_before & ok_after
    keep &= _isolated(0.5 * (x[starts] + x[ends]), 0.5 * (y[starts] + y[ends]), beam[starts], params)
    lit = np.flatnonzero(bright)
    out = np.zeros(n, bool)
    out[lit] = keep[np.searchsorted(starts, lit, side="right") - 1]  # the run each bright point is in
    return out


def _isolated(
    cx: npt.NDArray[np.float32],
    cy: npt.NDArray[np.float32],
    beam: npt.NDArray[np.int16],
    params: MarkerParams,
) -> BoolArray:
    """Runs with at most `paint_max_neighbours` other runs of their beam within `paint_isolation_m`:
    a line (or a double line) crosses a beam once, grass and gravel speckle it with many short runs."""
    m = cx.size
    count = np.zeros(m, np.int64)
    for k in range(1, params.paint_max_neighbours + 2):
        if m <= k:
            break
        near = (beam[k:] == beam[:-k]) & (
            np.hypot(cx[k:] - cx[:-k], cy[k:] - cy[:-k]) <= np.float32(params.paint_isolation_m)
        )
        count[k:] += near
        count[:-k] += near
    return count <= params.paint_max_neighbours


def _curbs(
    x: npt.NDArray[np.float32],
    y: npt.NDArray[np.float32],
    r2: npt.NDArray[np.float32],
    height: npt.NDArray[np.float32],
    beam: npt.NDArray[np.int16],
    idx: npt.NDArray[np.intp],
    ground: BoolArray,
    dphi_rad: npt.NDArray[np.float32],
    params: MarkerParams,
) -> FloatArray:
    near = np.abs(height) <= np.float32(params.curb_step_max_m + params.ground_tolerance_m)
    sub = np.flatnonzero(near)
    n = sub.size
    if n < 3:
        return np.zeros((0, 2))
    bs = beam[sub]
    hs = height[sub]
    # Heights smoothed over three neighbours: range noise (2 cm) is not a step.
    hs[1:-1] = (hs[:-2] + hs[1:-1] + hs[2:]) * np.float32(1.0 / 3.0)
    # Each window ends about curb_window_m further along the ring: at range r a beam's points are
    # r * dphi apart (dphi: a turn over the beam's points per turn).
    spacing = np.sqrt(r2[sub])
    spacing *= dphi_rad[bs]
    lag = np.ceil(np.divide(np.float32(params.curb_window_m), spacing, out=spacing), out=spacing)
    ends = lag.astype(np.intp)
    ends += np.arange(n)
    inside = ends < n
    dz_all = np.take(hs, ends, mode="clip") - hs  # past the end: the last point (outside anyway)
    mag_all = np.abs(dz_all)
    # the rise first (few windows have one), then the rest on those only
    i = np.flatnonzero(
        (mag_all >= np.float32(params.curb_step_min_m))
        & (mag_all <= np.float32(params.curb_step_max_m))
        & inside
    )
    j = ends[i]
    # The ring must run on without a break between them: same beam, no more than curb_max_missing
    # points missing from the scan at any place in between (an obstacle's points are not near). A break
    # before point k of the ring counts at k; i and j are on one piece when none counts in (i, j].
    breaks = 1 + np.flatnonzero((bs[1:] != bs[:-1]) | (np.diff(idx[sub]) > params.curb_max_missing + 1))
    dz = dz_all[i]
    same_piece = np.searchsorted(breaks, i, side="right") == np.searchsorted(breaks, j, side="right")
    hit = same_piece & np.where(dz > 0.0, ground[sub[i]], ground[sub[j]])  # lower side on the road
    mag_all = mag_all[i]
    i, j, mag = i[hit], j[hit], mag_all[hit].astype(np.float64)
    if i.size == 0:
        return np.zeros((0, 2))
    # Every window over the step sees it, those that hold all of it see its whole rise: per run of
    # consecutive windows, the curb is the middle of those within 10 % of the largest rise.
    new_run = np.ones(i.size, bool)
    new_run[1:] = i[1:] != i[:-1] + 1
    run = np.cumsum(new_run) - 1
    best = np.maximum.reduceat(mag, np.flatnonzero(new_run))
    top = mag >= 0.9 * best[run]
    mid = np.bincount(run[top], weights=(i[top] + j[top]) / 2.0) / np.bincount(run[top])
    m = sub[np.rint(mid).astype(np.intp)]
    return np.column_stack((x[m], y[m])).astype(np.float64)


def warm_up() -> None:
    """Compile `extract_features`' kernels (`lane_marker_kernels`), or load them from numba's cache, as
    `grid.warm_up` does the grid's: the first revolution in a process otherwise pays for it, which a
    real-time module pays in its start instead. Four rings of road with a painted line and a curb,
    enough points for the plane's RANSAC: every kernel runs."""
    k = np.arange(1600)
    ring = k // 400
    azimuth = (k % 400) * (2.0 * math.pi / 400)
    x, y = (5.0 + ring) * np.cos(azimuth), (5.0 + ring) * np.sin(azimuth)
    z = np.where(y > 3.0, -1.58, -1.73)
    xyz = np.stack((x, y, z), axis=1).astype(np.float32)
    reflectance = np.where(np.abs(y - 1.0) < 0.1, 0.8, 0.3).astype(np.float32)
    scan = Scan(xyz, reflectance, ring.astype(np.int16), sensor_height_m=1.73)
    extract_features(scan, ground_mask=np.ones(len(scan), bool))
    RadonSpectrum(np.eye(8, dtype=np.float32)).energy([0.0])  # and the Radon's slices (radon_kernels)


@dataclass(frozen=True)
class GridParams:
    """The marker image: 256 cells of 0.15625 m = 40 m square (a power of two for the Radon's FFT)."""

    size_cells: int = 256
    cell_m: float = 0.15625
    # Time constant of the decay: 1 s is 10 revolutions, 10 m of road at 10 m/s, long enough to fill
    # the gaps between a dashed line's dashes (3 m paint, 6 m gap) and short enough that a stale offset
    # of the dead reckoning (a few cm per second) does not blur a line.
    decay_tau_s: float = 1.0

    def __post_init__(self) -> None:
        if self.size_cells < 4 or self.size_cells % 2:
            raise ValueError(f"size_cells = {self.size_cells}: must be even and >= 4")
        if not (math.isfinite(self.cell_m) and self.cell_m > 0.0):
            raise ValueError(f"cell_m = {self.cell_m}: must be finite and > 0")
        if not self.decay_tau_s > 0.0:
            raise ValueError(f"decay_tau_s = {self.decay_tau_s}: must be > 0")


class MarkerGrid:
    """A vehicle-centred, world-aligned, decaying image of marker features.

    `image[row, col]`: row along world y (north), column along world x (east); cell (0, 0) has its lower
    left corner at `origin_xy_m`, always a whole number of cells, so that shifting never resamples.
    The Radon transform's origin (`radon.py`) is the centre of cell (n/2, n/2): `centre_xy_m`.
    """

    def __init__(self, params: GridParams = GridParams()) -> None:
        self.params = params
        n = params.size_cells
        self.image = np.zeros((n, n), np.float32)
        self._origin = np.zeros(2, np.int64)  # in cells
        self._stamp_s: float | None = None
        self._started = False

    @property
    def cell_m(self) -> float:
        return self.params.cell_m

    @property
    def origin_xy_m(self) -> tuple[float, float]:
        return (float(self._origin[0]) * self.cell_m, float(self._origin[1]) * self.cell_m)

    @property
    def centre_xy_m(self) -> tuple[float, float]:
        half = self.params.size_cells // 2 + 0.5
        ox, oy = self.origin_xy_m
        return (ox + half * self.cell_m, oy + half * self.cell_m)

    def recentre(self, x_m: float, y_m: float) -> None:
        """Shift the grid by whole cells so that (x, y) lies in the centre cell; what leaves is lost,
        what enters is empty."""
        n = self.params.size_cells
        want = np.array([math.floor(x_m / self.cell_m), math.floor(y_m / self.cell_m)], np.int64) - n // 2
        if not self._started:
            self._origin = want
            self._started = True
            return
        dx, dy = (int(v) for v in want - self._origin)
        if dx == 0 and dy == 0:
            return
        self._origin = want
        if abs(dx) >= n or abs(dy) >= n:
            self.image[:] = 0.0
            return
        old = self.image
        new = np.zeros_like(old)
        # new[r, c] = old[r + dy, c + dx]
        new[max(-dy, 0) : n - max(dy, 0), max(-dx, 0) : n - max(dx, 0)] = old[
            max(dy, 0) : n - max(-dy, 0), max(dx, 0) : n - max(-dx, 0)
        ]
        self.image = new

    def cells_of(self, world_xy_m: FloatArray) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
        """(rows, cols) of world points; outside the grid they are out of range 0 .. n - 1."""
        cols = np.floor(world_xy_m[:, 0] / self.cell_m).astype(np.int64) - self._origin[0]
        rows = np.floor(world_xy_m[:, 1] / self.cell_m).astype(np.int64) - self._origin[1]
        return rows, cols

    def add(self, world_xy_m: FloatArray, stamp_s: float) -> None:
        """Decay by the time since the last scan, then add 1 to each cell holding a feature of this one."""
        if self._stamp_s is not None:
            dt = max(float(stamp_s) - self._stamp_s, 0.0)
            self.image *= np.float32(math.exp(-dt / self.params.decay_tau_s))
        self._stamp_s = float(stamp_s)
        n = self.params.size_cells
        rows, cols = self.cells_of(np.asarray(world_xy_m, dtype=np.float64).reshape(-1, 2))
        inside = (rows >= 0) & (rows < n) & (cols >= 0) & (cols < n)
        seen = np.zeros(n * n, bool)
        seen[rows[inside] * n + cols[inside]] = True
        self.image += seen.reshape(n, n)


def _to_world(xy_m: FloatArray, pose: PlanarPose, sensor_offset_m: tuple[float, float]) -> FloatArray:
    c, s = math.cos(pose.heading_rad), math.sin(pose.heading_rad)
    bx = xy_m[:, 0] + sensor_offset_m[0]
    by = xy_m[:, 1] + sensor_offset_m[1]
    return np.column_stack((pose.x_m + c * bx - s * by, pose.y_m + s * bx + c * by))


class LaneMarkerMap:
    """Features of each scan mapped with the car's pose into one `MarkerGrid` (seed 000 Sec. 6, Fig. 7).

    `pose` is the car's pose on the local plane (x east, y north, heading counter-clockwise from east)
    when the scan was taken; `sensor_offset_m` is where the LIDAR sits in the car's frame (forward, left)
    relative to that pose's reference point (the rear axle for `UrbanPose`).
    """

    def __init__(
        self,
        marker_params: MarkerParams = MarkerParams(),
        grid_params: GridParams = GridParams(),
        sensor_offset_m: tuple[float, float] = (0.0, 0.0),
    ) -> None:
        self.params = marker_params
        self.grid = MarkerGrid(grid_params)
        self.sensor_offset_m = (float(sensor_offset_m[0]), float(sensor_offset_m[1]))
        self.last: MarkerFeatures | None = None

    def update(self, scan: Scan, pose: PlanarPose, ground_mask: BoolArray | None = None) -> MarkerFeatures:
        """Extract one revolution's features and map them (`add`)."""
        feats = extract_features(scan, self.params, ground_mask)
        self.add(feats, pose, scan.stamp_s)
        return feats

    def add(self, feats: MarkerFeatures, pose: PlanarPose, stamp_s: float) -> None:
        """Map a revolution's features with the car's pose: shift the grid to the sensor, decay, deposit."""
        c, s = math.cos(pose.heading_rad), math.sin(pose.heading_rad)
        ox, oy = self.sensor_offset_m
        self.grid.recentre(pose.x_m + c * ox - s * oy, pose.y_m + s * ox + c * oy)
        pts = np.concatenate((feats.paint_xy_m, feats.curb_xy_m))
        self.grid.add(_to_world(pts, pose, self.sensor_offset_m), stamp_s)
        self.last = feats


def marker_png(grid: MarkerGrid | npt.ArrayLike, path: Path | str, *, scale: float | None = None) -> Path:
    """The marker image as a greyscale PNG, north up (for docs and for looking at a run; not an artefact
    to commit). Values are scaled to `scale` (default: the 99.5th percentile of the non-zero cells)."""
    import matplotlib.image  # only here: nothing else in perception needs matplotlib

    img = np.asarray(grid.image if isinstance(grid, MarkerGrid) else grid, dtype=np.float64)
    nz = img[img > 0.0]
    top = scale if scale is not None else (float(np.percentile(nz, 99.5)) if nz.size else 1.0)
    out = Path(path)
    matplotlib.image.imsave(
        out, np.clip(img / max(top, 1e-12), 0.0, 1.0)[::-1], cmap="gray", vmin=0.0, vmax=1.0
    )
    return out
