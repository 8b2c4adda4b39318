"""Smooth, densely sampled planar paths with arc length (seed 000 sec. 8, Fig. 10b/c).

A `Path` is a polyline in local metric coordinates (x east, y north, metres) sampled every ~0.25 m, with
the heading (rad, counter-clockwise from east) and the curvature (1/m, positive turning left) of the
smooth curve it was sampled from, and the cumulative arc length ``s`` (0 at the first sample).  It is what
the section-8 planner hands the controllers: `stub(s0)` is the ~30 m "path stub" ahead of the car.

Curves (how the samples are made):

- `smooth_curve` / `Path.from_points`: the interpolating cubic spline through the points, parameterised by
  chord length (scipy ``CubicSpline``), sampled uniformly inside every chord.  It is C2 in its parameter
  and the parameter speed |dP/dt| stays close to 1, so heading and curvature are continuous along it
  (Fig. 10b).  End conditions are "natural" (zero curvature at both ends) unless end headings are given,
  then "clamped" to those directions.  Consecutive points closer than `merge_m` count as one.
- `connector`: the quintic Hermite curve from one pose (x, y, heading, curvature) to another, with
  derivatives P'(0) = L t0, P''(0) = L^2 k0 n0 (and alike at the end), L the chord length, t the unit
  tangent and n the left normal.  Then |P' x P''| / |P'|^3 = k0 at the start: the connector matches
  position, heading *and* curvature of the curves it joins, so a lane, an exit and the next lane make one
  path of continuous curvature (Fig. 10c).  (Deviation: the paper says "spline interpolation" only; a
  cubic Hermite, the usual choice, would leave curvature jumps at every join.)
- `drivable_connector`: a `connector` whose peak curvature a car can steer. RNDF exits between a stop
  line and a close entry make the least-energy curve turn on a 2.8-3 m radius where a Passat needs
  4.7 m (l / tan 30 deg), and the car leaves the curve by most of a metre. Where the plain connector is
  too tight the search widens: different tangent lengths at the two ends (turn early and run in long,
  or the reverse), and a straight run-in on the entry lane's own line before its first waypoint (the
  turn ends inside the intersection, aligned with the lane it enters). It keeps the least bending
  energy among the curves under the limit, or when none is, the least curvature over the limit summed
  along the curve (what a car at full lock falls behind), with no sharper peak and no steeper curvature
  ramp than the plain curve's or SHARPNESS_MAX_1PM2. A closed loop of the urban controller on a Passat
  model (steering lag and rate limit, 2 m/s) ran 0.67 m wide of the sample mission's exit
  11.1.4 -> 7.1.11 on the plain curve and 0.06 m on this one; over the sample network's 14 exits
  tighter than 0.18 1/m the mean worst offset fell from 0.24 to 0.12 m.

Projection (`project`): the foot point on the polyline, found among the segments next to the nearest
samples (a kd-tree over the samples, built on first use) or, given `hint_s` (the last known s, what a
controller has), in a window around it: that is faster and never jumps to another part of a path that
passes close to itself (a loop, a U-turn).  If the best point of the window lies on the window's edge the
search falls back to the whole path.  Offsets are signed, left of the direction of travel positive.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Iterable, Sequence
from typing import NamedTuple

import numpy as np
import numpy.typing as npt
from scipy.interpolate import CubicSpline
from scipy.spatial import cKDTree

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]

# 0.25 m: a lateral controller's look-ahead is metres; at 0.25 m spacing the chord of a 5 m radius curve
# departs from the arc by 1.6 mm, and a lane of 1 km is 4000 samples (32 kB per array).
DEFAULT_STEP_M = 0.25
# Two waypoints closer than this are one point for the spline (real RNDFs repeat points; a zero chord
# would make the chord-length parameter non-increasing).
DUPLICATE_M = 1e-3
# Largest gap tolerated between the end of one path and the start of the next in `concat`.
JOIN_TOLERANCE_M = 1e-3
# Window of a hinted projection, metres of arc behind and ahead of the hint.
HINT_WINDOW_M = 25.0


class PathPoint(NamedTuple):
    x_m: float
    y_m: float
    heading_rad: float
    curvature_1pm: float
    s_m: float


class Projection(NamedTuple):
    """Foot point of a position on a path: its arc length, the signed offset (left > 0) and the heading
    error (given heading minus path heading, wrapped to [-pi, pi); NaN if no heading was given)."""

    s_m: float
    lateral_offset_m: float
    heading_error_rad: float


def wrap_angle(angle_rad: float) -> float:
    """Angle wrapped to [-pi, pi)."""
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


def _readonly(a: npt.ArrayLike) -> FloatArray:
    out = np.array(a, dtype=np.float64)  # a copy: nobody else can change a path's samples
    out.setflags(write=False)
    return out


class Path:
    """Immutable sampled curve: x, y (m), heading (rad), curvature (1/m), arc length s (m, from 0)."""

    __slots__ = ("_heading", "_k", "_s", "_tree", "_x", "_y")

    def __init__(
        self,
        x_m: npt.ArrayLike,
        y_m: npt.ArrayLike,
        heading_rad: npt.ArrayLike,
        curvature_1pm: npt.ArrayLike,
        s_m: npt.ArrayLike | None = None,
    ) -> None:
        x, y = _readonly(x_m), _readonly(y_m)
        n = x.shape[0] if x.ndim == 1 else -1
        if n < 1:
            raise ValueError("a path needs at least one sample (1-D arrays)")
        h = _unwrap(np.asarray(heading_rad, dtype=np.float64).ravel()).reshape(np.shape(heading_rad))
        k = _readonly(curvature_1pm)
        s = (
            np.concatenate(([0.0], np.cumsum(np.hypot(np.diff(x), np.diff(y)))))
            if s_m is None
            else np.asarray(s_m, dtype=np.float64) - float(np.asarray(s_m, dtype=np.float64)[0])
        )
        for name, arr in (("y", y), ("heading", h), ("curvature", k), ("s", s)):
            if arr.shape != (n,):
                raise ValueError(f"path {name} has shape {arr.shape}, expected ({n},) like x")
        if not all(np.isfinite(a).all() for a in (x, y, h, k, s)):
            raise ValueError("path samples must be finite")
        if n > 1 and np.any(np.diff(s) < 0.0):
            raise ValueError("path arc length must not decrease")
        self._x, self._y, self._k = x, y, k
        self._heading = _readonly(h)  # unwrapped: interpolation never crosses the +-pi cut
        self._s = _readonly(s)
        self._tree: cKDTree | None = None

    # -- construction

    @classmethod
    def _trusted(cls, x: FloatArray, y: FloatArray, h: FloatArray, k: FloatArray, s: FloatArray) -> Path:
        """No checks, no copies: for arrays this module made (finite, s from 0, increasing, h unwrapped)."""
        self = cls.__new__(cls)
        for a in (x, y, h, k, s):
            a.setflags(write=False)
        self._x, self._y, self._heading, self._k, self._s = x, y, h, k, s
        self._tree = None
        return self

    @classmethod
    def from_points(
        cls,
        x_m: npt.ArrayLike,
        y_m: npt.ArrayLike,
        step_m: float = DEFAULT_STEP_M,
        *,
        start_heading_rad: float | None = None,
        end_heading_rad: float | None = None,
    ) -> Path:
        """The smooth curve through the points (see the module docstring), sampled every ~step_m."""
        return smooth_curve(
            x_m, y_m, step_m, start_heading_rad=start_heading_rad, end_heading_rad=end_heading_rad
        )[0]

    @staticmethod
    def concat(paths: Iterable[Path], tolerance_m: float = JOIN_TOLERANCE_M) -> Path:
        """Paths joined end to start (see the module function `concat`)."""
        return concat(paths, tolerance_m)

    @classmethod
    def point(cls, x_m: float, y_m: float, heading_rad: float, curvature_1pm: float = 0.0) -> Path:
        """A path of one sample (length 0), e.g. an exit between two waypoints at the same place."""
        return cls([x_m], [y_m], [heading_rad], [curvature_1pm])

    # -- samples

    @property
    def x_m(self) -> FloatArray:
        return self._x

    @property
    def y_m(self) -> FloatArray:
        return self._y

    @property
    def heading_rad(self) -> FloatArray:
        """Headings wrapped to [-pi, pi)."""
        return (self._heading + np.pi) % (2.0 * np.pi) - np.pi

    @property
    def heading_unwrapped_rad(self) -> FloatArray:
        return self._heading

    @property
    def curvature_1pm(self) -> FloatArray:
        return self._k

    @property
    def s_m(self) -> FloatArray:
        return self._s

    @property
    def xy(self) -> FloatArray:
        return np.column_stack((self._x, self._y))

    @property
    def length_m(self) -> float:
        return float(self._s[-1])

    def __len__(self) -> int:
        return int(self._x.shape[0])

    def __repr__(self) -> str:
        return f"Path({len(self)} samples, {self.length_m:.2f} m)"

    @property
    def start(self) -> PathPoint:
        return self.at_index(0)

    @property
    def end(self) -> PathPoint:
        return self.at_index(len(self) - 1)

    def at_index(self, i: int) -> PathPoint:
        """Sample i as a pose."""
        return PathPoint(
            float(self._x[i]),
            float(self._y[i]),
            wrap_angle(float(self._heading[i])),
            float(self._k[i]),
            float(self._s[i]),
        )

    def point_at(self, s_m: float) -> PathPoint:
        """Interpolated pose at arc length `s_m` (clamped to [0, length_m])."""
        s = min(max(float(s_m), 0.0), self.length_m)
        n = len(self)
        if n == 1:
            return self.at_index(0)
        i = int(np.searchsorted(self._s, s, side="right")) - 1
        i = min(max(i, 0), n - 2)
        ds = self._s[i + 1] - self._s[i]
        f = 0.0 if ds <= 0.0 else (s - self._s[i]) / ds
        return PathPoint(
            float(self._x[i] + f * (self._x[i + 1] - self._x[i])),
            float(self._y[i] + f * (self._y[i + 1] - self._y[i])),
            wrap_angle(float(self._heading[i] + f * (self._heading[i + 1] - self._heading[i]))),
            float(self._k[i] + f * (self._k[i + 1] - self._k[i])),
            s,
        )

    def sample(self, s_m: npt.ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """Vectorised `point_at`: x, y, heading (wrapped), curvature at each s (clamped to the path)."""
        s = np.clip(np.asarray(s_m, dtype=np.float64), 0.0, self.length_m)
        if len(self) == 1:
            ones = np.ones_like(s)
            return (
                ones * self._x[0],
                ones * self._y[0],
                ones * wrap_angle(self._heading[0]),
                ones * self._k[0],
            )
        h = np.interp(s, self._s, self._heading)
        return (
            np.interp(s, self._s, self._x),
            np.interp(s, self._s, self._y),
            (h + np.pi) % (2.0 * np.pi) - np.pi,
            np.interp(s, self._s, self._k),
        )

    # -- projection

    def project(
        self, x_m: float, y_m: float, hint_s: float | None = None, *, heading_rad: float | None = None
    ) -> Projection:
        """Arc length, signed lateral offset (left > 0) and heading error of the foot point of (x, y)."""
        n = len(self)
        if n == 1:
            lateral = -math.sin(self._heading[0]) * (x_m - self._x[0]) + math.cos(self._heading[0]) * (
                y_m - self._y[0]
            )
            return Projection(0.0, lateral, self._heading_error(heading_rad, float(self._heading[0])))
        result = None
        if hint_s is not None and math.isfinite(hint_s):
            lo = int(np.searchsorted(self._s, hint_s - HINT_WINDOW_M, side="left"))
            hi = int(np.searchsorted(self._s, hint_s + HINT_WINDOW_M, side="right"))
            lo, hi = max(lo - 1, 0), min(hi, n - 1)  # segments lo .. hi-1
            if hi > lo:
                seg = np.arange(lo, hi)
                best, t = self._best_segment(x_m, y_m, seg)
                at_edge = (best == lo and t == 0.0 and lo > 0) or (best == hi - 1 and t == 1.0 and hi < n - 1)
                if not at_edge:
                    result = (best, t)
        if result is None:
            result = self._global_foot(x_m, y_m)
        i, t = result
        s = float(self._s[i] + t * (self._s[i + 1] - self._s[i]))
        fx = self._x[i] + t * (self._x[i + 1] - self._x[i])
        fy = self._y[i] + t * (self._y[i + 1] - self._y[i])
        heading = float(self._heading[i] + t * (self._heading[i + 1] - self._heading[i]))
        lateral = -math.sin(heading) * (x_m - fx) + math.cos(heading) * (y_m - fy)
        return Projection(s, float(lateral), self._heading_error(heading_rad, heading))

    def project_points(
        self, x_m: npt.ArrayLike, y_m: npt.ArrayLike
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Vectorised global `project` of many points: arc lengths, lateral offsets, path headings."""
        px = np.atleast_1d(np.asarray(x_m, dtype=np.float64))
        py = np.atleast_1d(np.asarray(y_m, dtype=np.float64))
        n = len(self)
        if n == 1:
            h0 = float(self._heading[0])
            lat = -math.sin(h0) * (px - self._x[0]) + math.cos(h0) * (py - self._y[0])
            return np.zeros_like(px), lat, np.full_like(px, wrap_angle(h0))
        if self._tree is None:
            self._tree = cKDTree(self.xy)
        _, idx = self._tree.query(np.column_stack((px, py)), k=min(8, n))
        idx = np.asarray(idx).reshape(px.size, -1)
        seg = np.clip(np.concatenate((idx - 1, idx), axis=1), 0, n - 2)  # (m, 2k) candidate segments
        x0, y0 = self._x[seg], self._y[seg]
        dx, dy = self._x[seg + 1] - x0, self._y[seg + 1] - y0
        len2 = dx * dx + dy * dy
        with np.errstate(invalid="ignore", divide="ignore"):
            t = np.where(len2 > 0.0, ((px[:, None] - x0) * dx + (py[:, None] - y0) * dy) / len2, 0.0)
        t = np.clip(t, 0.0, 1.0)
        d2 = (x0 + t * dx - px[:, None]) ** 2 + (y0 + t * dy - py[:, None]) ** 2
        j = np.argmin(d2, axis=1)
        rows = np.arange(px.size)
        i, tb = seg[rows, j], t[rows, j]
        s = self._s[i] + tb * (self._s[i + 1] - self._s[i])
        h = self._heading[i] + tb * (self._heading[i + 1] - self._heading[i])
        fx, fy = x0[rows, j] + tb * dx[rows, j], y0[rows, j] + tb * dy[rows, j]
        lateral = -np.sin(h) * (px - fx) + np.cos(h) * (py - fy)
        return s, lateral, (h + np.pi) % (2.0 * np.pi) - np.pi

    @staticmethod
    def _heading_error(heading_rad: float | None, path_heading: float) -> float:
        return math.nan if heading_rad is None else wrap_angle(heading_rad - path_heading)

    def _best_segment(self, x: float, y: float, seg: IntArray) -> tuple[int, float]:
        x0, y0 = self._x[seg], self._y[seg]
        dx, dy = self._x[seg + 1] - x0, self._y[seg + 1] - y0
        len2 = dx * dx + dy * dy
        with np.errstate(invalid="ignore", divide="ignore"):
            t = np.where(len2 > 0.0, ((x - x0) * dx + (y - y0) * dy) / len2, 0.0)
        t = np.clip(t, 0.0, 1.0)
        d2 = (x0 + t * dx - x) ** 2 + (y0 + t * dy - y) ** 2
        j = int(np.argmin(d2))
        return int(seg[j]), float(t[j])

    def _global_foot(self, x: float, y: float) -> tuple[int, float]:
        if self._tree is None:
            self._tree = cKDTree(self.xy)
        n = len(self)
        k = min(8, n)
        _, idx = self._tree.query((x, y), k=k)
        idx = np.atleast_1d(idx)
        seg = np.unique(np.clip(np.concatenate((idx - 1, idx)), 0, n - 2))
        return self._best_segment(x, y, seg)

    # -- derived paths

    def between(self, s0_m: float, s1_m: float) -> Path:
        """The part from s0 to s1 (clamped, s1 >= s0), end points interpolated; its s starts at 0."""
        s0 = min(max(float(s0_m), 0.0), self.length_m)
        s1 = min(max(float(s1_m), s0), self.length_m)
        if len(self) == 1 or s1 - s0 <= 0.0:
            p = self.point_at(s0)
            return Path.point(p.x_m, p.y_m, p.heading_rad, p.curvature_1pm)
        inner = np.nonzero((self._s > s0) & (self._s < s1))[0]
        s = np.concatenate(([s0], self._s[inner], [s1]))
        h = np.interp(s, self._s, self._heading)
        return Path(
            np.interp(s, self._s, self._x),
            np.interp(s, self._s, self._y),
            h,
            np.interp(s, self._s, self._k),
            s,
        )

    def stub(self, s0_m: float, length_m: float = 30.0) -> Path:
        """The path stub of seed 000 sec. 8: from s0 up to `length_m` ahead (less at the end); s from 0."""
        return self.between(s0_m, s0_m + length_m)

    def slice_samples(self, i0: int, i1: int) -> Path:
        """Samples i0..i1 inclusive as a path (s from 0)."""
        if not 0 <= i0 <= i1 < len(self):
            raise IndexError(f"sample range {i0}..{i1} outside 0..{len(self) - 1}")
        sl = slice(i0, i1 + 1)
        return Path._trusted(
            self._x[sl], self._y[sl], self._heading[sl], self._k[sl], self._s[sl] - self._s[i0]
        )

    def offset(self, lateral_m: float) -> Path:
        """The parallel curve `lateral_m` to the left (negative: right), e.g. the neighbouring lane.

        Curvature of the offset curve: k / (1 - d k). ValueError where the offset reaches the centre of
        curvature (1 - d k <= 0): the parallel curve has a cusp there.
        """
        d = float(lateral_m)
        scale = 1.0 - d * self._k
        if np.any(scale <= 1e-6):
            i = int(np.argmax(scale <= 1e-6))
            raise ValueError(
                f"offset {d} m reaches the centre of curvature at s = {self._s[i]:.2f} m "
                f"(radius {1.0 / abs(self._k[i]):.2f} m)"
            )
        x = self._x - d * np.sin(self._heading)
        y = self._y + d * np.cos(self._heading)
        return Path(x, y, self._heading, self._k / scale)

    def reversed(self) -> Path:
        """The same curve travelled the other way: heading + pi, curvature negated."""
        return Path(self._x[::-1], self._y[::-1], self._heading[::-1] + np.pi, -self._k[::-1])


def concat(paths: Iterable[Path], tolerance_m: float = JOIN_TOLERANCE_M) -> Path:
    """Paths joined end to start into one (ValueError if one does not start where the previous ends)."""
    items = list(paths)
    if not items:
        raise ValueError("concat needs at least one path")
    xs, ys, hs, ks, ss = (
        [items[0].x_m],
        [items[0].y_m],
        [items[0].heading_unwrapped_rad],
        [items[0].curvature_1pm],
        [items[0].s_m],
    )
    total = items[0].length_m
    prev = items[0]
    for k, p in enumerate(items[1:], start=1):
        gap = math.hypot(p.x_m[0] - prev.x_m[-1], p.y_m[0] - prev.y_m[-1])
        if gap > tolerance_m:
            raise ValueError(f"path {k} starts {gap:.3f} m from the end of path {k - 1}")
        prev = p
        if len(p) == 1:
            continue
        xs.append(p.x_m[1:])
        ys.append(p.y_m[1:])
        # keep the heading continuous across the join (each part is unwrapped on its own)
        h = p.heading_unwrapped_rad
        shift = hs[-1][-1] - h[0]
        hs.append(h[1:] + 2.0 * np.pi * np.round(shift / (2.0 * np.pi)))
        ks.append(p.curvature_1pm[1:])
        ss.append(p.s_m[1:] + total)
        total += p.length_m
    return Path(
        np.concatenate(xs), np.concatenate(ys), np.concatenate(hs), np.concatenate(ks), np.concatenate(ss)
    )


# ---------------------------------------------------------------------------------------------- curves


def smooth_curve(
    x_m: npt.ArrayLike,
    y_m: npt.ArrayLike,
    step_m: float = DEFAULT_STEP_M,
    *,
    start_heading_rad: float | None = None,
    end_heading_rad: float | None = None,
    merge_m: float = DUPLICATE_M,
) -> tuple[Path, IntArray]:
    """Chord-length cubic spline through the points, and the sample index of every input point.

    A point closer than `merge_m` to the last point kept is merged into it (shares its sample index): a
    chord of centimetres between metres-long ones makes the spline hook (VAIL lane 6.1 has two waypoints
    0.1 m apart). ValueError if fewer than two distinct points remain.
    """
    if not step_m > 0.0:
        raise ValueError(f"step_m must be > 0, got {step_m}")
    px = np.asarray(x_m, dtype=np.float64).ravel()
    py = np.asarray(y_m, dtype=np.float64).ravel()
    if px.shape != py.shape or not (np.isfinite(px).all() and np.isfinite(py).all()):
        raise ValueError("x and y must be finite and of equal length")
    keep = [0]
    owner = np.zeros(px.size, dtype=np.intp)
    for i in range(1, px.size):
        if math.hypot(px[i] - px[keep[-1]], py[i] - py[keep[-1]]) > max(merge_m, DUPLICATE_M):
            keep.append(i)
        owner[i] = len(keep) - 1
    if len(keep) < 2:
        raise ValueError("a curve needs at least two distinct points")
    kx, ky = px[keep], py[keep]
    chord = np.hypot(np.diff(kx), np.diff(ky))
    t = np.concatenate(([0.0], np.cumsum(chord)))
    bc: object
    if start_heading_rad is None and end_heading_rad is None:
        bc = "natural"
    else:
        start = (
            (2, [0.0, 0.0])
            if start_heading_rad is None
            else (1, [math.cos(start_heading_rad), math.sin(start_heading_rad)])
        )
        end = (
            (2, [0.0, 0.0])
            if end_heading_rad is None
            else (1, [math.cos(end_heading_rad), math.sin(end_heading_rad)])
        )
        bc = (start, end)
    spline = CubicSpline(t, np.column_stack((kx, ky)), bc_type=bc)  # type: ignore[arg-type]
    per = np.maximum(1, np.ceil(chord / step_m).astype(np.intp))
    knot_sample = np.concatenate(([0], np.cumsum(per)))
    frac = np.arange(int(knot_sample[-1])) - np.repeat(knot_sample[:-1], per)
    ts = np.concatenate((np.repeat(t[:-1], per) + frac / np.repeat(per, per) * np.repeat(chord, per), t[-1:]))
    p, d1, d2 = spline(ts), spline(ts, 1), spline(ts, 2)
    path = _from_derivatives(p, d1, d2)
    return path, knot_sample[owner]


def _unwrap(angles: FloatArray) -> FloatArray:
    """np.unwrap for 1-D arrays, without its generality (it dominated the cost of short paths)."""
    if angles.size < 2:
        return angles
    step = np.diff(angles)
    step -= 2.0 * np.pi * np.round(step / (2.0 * np.pi))
    return np.concatenate((angles[:1], angles[0] + np.cumsum(step)))


def _from_derivatives(p: FloatArray, d1: FloatArray, d2: FloatArray) -> Path:
    speed2 = d1[:, 0] ** 2 + d1[:, 1] ** 2
    heading = _unwrap(np.arctan2(d1[:, 1], d1[:, 0]))
    with np.errstate(invalid="ignore", divide="ignore"):
        k = np.where(speed2 > 0.0, (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]) / speed2**1.5, 0.0)
    x, y = np.ascontiguousarray(p[:, 0]), np.ascontiguousarray(p[:, 1])
    s = np.concatenate(([0.0], np.cumsum(np.hypot(np.diff(x), np.diff(y)))))
    return Path._trusted(x, y, heading, k, s)


# Quintic Hermite basis: row r of each matrix holds the coefficients of u^0..u^5 of the r-th basis
# function, in the order p0, v0, a0, a1, v1, p1 (position, first and second derivative at both ends).
_Q = np.array(
    [
        [1, 0, 0, -10, 15, -6],
        [0, 1, 0, -6, 8, -3],
        [0, 0, 0.5, -1.5, 1.5, -0.5],
        [0, 0, 0, 0.5, -1, 0.5],
        [0, 0, 0, -4, 7, -3],
        [0, 0, 0, 10, -15, 6],
    ],
    dtype=np.float64,
)
_POW = np.arange(6)
_DQ = _Q[:, 1:] * _POW[1:]  # coefficients of u^0..u^4 of the first derivatives
_DDQ = _DQ[:, 1:] * _POW[1:5]  # coefficients of u^0..u^3 of the second derivatives


def _basis(u: FloatArray) -> FloatArray:
    """Values, first and second derivatives of the six basis functions at parameters u: (3, len(u), 6)."""
    powers = np.cumprod(np.column_stack([np.ones_like(u)] + [u] * 5), axis=1)  # u^0 .. u^5
    out = np.stack((powers @ _Q.T, powers[:, :5] @ _DQ.T, powers[:, :4] @ _DDQ.T))
    out.setflags(write=False)
    return out


@functools.lru_cache(maxsize=1024)
def _uniform_basis(n: int) -> FloatArray:
    return _basis(np.linspace(0.0, 1.0, n))


_COARSE_BASIS = _uniform_basis(33)
# Tangent lengths tried, in chord lengths: the one with the least bending energy wins. L = chord is the
# usual choice and right for gentle turns; tight turns between close points want it shorter, an entry
# that lies to the side of the exit's heading longer (else the curve has a cusp).
_SCALE_FACTORS = np.array([0.4, 0.6, 0.8, 1.0, 1.25, 1.6, 2.0, 2.5, 3.0])


# The wider search of `drivable_connector`: tangent lengths per end (in chord lengths), and run-ins on the
# entry lane's line (metres before the entry; at most RUN_IN_MAX_FRACTION of the way along that line).
_END_SCALE_FACTORS = np.array([0.3, 0.45, 0.6, 0.8, 1.0, 1.25, 1.6, 2.0, 2.5, 3.0])
_RUN_IN_M = np.array([0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0])
RUN_IN_MAX_FRACTION = 0.6
SHARPNESS_MAX_1PM2 = 0.3
_SEARCH_BASIS = _uniform_basis(25)


def _hermite_parts(start: Sequence[float], end: Sequence[float]) -> FloatArray:
    """The quintic Hermite data of two poses split by what multiplies it: (5, 6, 2) for 1, L0, L1, L0^2,
    L1^2 (L0, L1 the tangent lengths at the start and the end)."""
    x0, y0, h0, k0 = start
    x1, y1, h1, k1 = end
    c0, s0, c1, s1 = math.cos(h0), math.sin(h0), math.cos(h1), math.sin(h1)
    data = np.zeros((5, 6, 2))
    data[0, 0], data[0, 5] = (x0, y0), (x1, y1)  # positions
    data[1, 1], data[2, 4] = (c0, s0), (c1, s1)  # unit tangents (times L0, L1)
    data[3, 2], data[4, 3] = (-k0 * s0, k0 * c0), (-k1 * s1, k1 * c1)  # k n, n the left normal (L0^2, L1^2)
    return data


def _asymmetric(basis: FloatArray, parts: FloatArray, l0: FloatArray, l1: FloatArray) -> FloatArray:
    """Curve, first and second derivative for every pair (l0[i], l1[i]): (3, len(l0), samples, 2)."""
    samples = basis.shape[1]
    terms = (basis.reshape(-1, 6) @ parts.transpose(1, 0, 2).reshape(6, 10)).reshape(3, samples, 5, 2)
    weights = np.stack((np.ones_like(l0), l0, l1, l0 * l0, l1 * l1), axis=1)  # (pairs, 5)
    flat = weights @ terms.transpose(2, 0, 1, 3).reshape(5, -1)  # (pairs, 3 * samples * 2)
    out: FloatArray = flat.reshape(len(l0), 3, samples, 2).transpose(1, 0, 2, 3)
    return out


def connector(
    start: PathPoint | Sequence[float],
    end: PathPoint | Sequence[float],
    step_m: float = DEFAULT_STEP_M,
    scale_factors: Sequence[float] | None = None,
) -> Path:
    """Quintic Hermite curve from pose `start` to pose `end` (x, y, heading, curvature) matching both.

    The tangent length L is chosen among `scale_factors` (default `_SCALE_FACTORS`) x chord for the least
    bending energy; ``scale_factors=(1.0,)`` skips the search. A zero-length connector (the poses within
    DUPLICATE_M) is the single sample `start`.
    """
    x0, y0, h0, k0 = (float(v) for v in tuple(start)[:4])
    x1, y1, h1, k1 = (float(v) for v in tuple(end)[:4])
    chord = math.hypot(x1 - x0, y1 - y0)
    if chord <= DUPLICATE_M:
        return Path.point(x0, y0, h0, k0)
    parts = _hermite_parts((x0, y0, h0, k0), (x1, y1, h1, k1))
    scales = (
        _SCALE_FACTORS if scale_factors is None else np.asarray(scale_factors, dtype=np.float64)
    ) * chord
    pos, vel, acc = _asymmetric(_COARSE_BASIS, parts, scales, scales)
    best = int(np.argmin(_energy(vel, acc)))
    approx_len = float(np.sum(np.hypot(*np.diff(pos[best], axis=0).T)))
    n = max(2, math.ceil(approx_len / step_m) + 1)
    one = scales[best : best + 1]
    pos, vel, acc = _asymmetric(_uniform_basis(n), parts, one, one)[:, 0]
    # the end samples are the poses themselves, exactly (no rounding drift across joins)
    pos[0], pos[-1] = (x0, y0), (x1, y1)
    return _from_derivatives(pos, vel, acc)


def _energy(vel: FloatArray, acc: FloatArray) -> FloatArray:
    """Bending energy per curve, int k^2 ds = mean over u of cross^2 / |P'|^5; a cusp (|P'| -> 0) makes
    it explode."""
    speed = np.hypot(vel[..., 0], vel[..., 1])
    cross = vel[..., 0] * acc[..., 1] - vel[..., 1] * acc[..., 0]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        out: FloatArray = np.where(speed > 1e-9, cross**2 / speed**5, np.inf).mean(axis=-1)
    return out


def _bending(
    pos: FloatArray, vel: FloatArray, acc: FloatArray, limit: float
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Per curve: peak |curvature|, bending energy (mean over u of k^2 ds/du), the curvature over
    `limit` summed along the arc (mean over u of (|k| - limit)+ ds/du: the heading a car at `limit`
    falls behind) and the peak sharpness |dk/ds| between samples."""
    speed = np.hypot(vel[..., 0], vel[..., 1])
    cross = vel[..., 0] * acc[..., 1] - vel[..., 1] * acc[..., 0]
    energy = _energy(vel, acc)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        k = np.where(speed > 1e-9, cross / speed**3, np.inf)
        excess = (np.maximum(np.abs(k) - limit, 0.0) * speed).mean(axis=-1)
        ds = np.hypot(*np.moveaxis(np.diff(pos, axis=-2), -1, 0))
        sharp = (np.abs(np.diff(k, axis=-1)) / ds).max(axis=-1)
    return np.abs(k).max(axis=-1), energy, excess, np.nan_to_num(sharp, nan=np.inf)


def _sharpness(path: Path) -> float:
    return float(np.max(np.abs(np.diff(path.curvature_1pm)) / np.maximum(np.diff(path.s_m), 1e-9)))


def _excess_of(path: Path, limit: float) -> float:
    """The curvature over `limit` summed along `path` (1/m x m = rad)."""
    over = np.maximum(np.abs(path.curvature_1pm) - limit, 0.0)
    return float(np.sum(0.5 * (over[1:] + over[:-1]) * np.diff(path.s_m)))


def drivable_connector(
    start: PathPoint | Sequence[float],
    end: PathPoint | Sequence[float],
    max_curvature_1pm: float,
    step_m: float = DEFAULT_STEP_M,
) -> Path:
    """`connector`, or where its peak |curvature| exceeds `max_curvature_1pm` (a car's full lock), the
    curve of the wider search (module docstring) that keeps under it with the least bending energy, or
    where none does, the one whose curvature over the limit sums to the least along its length (the
    heading a car at full lock falls behind) without a sharper peak; `connector` stays if it is no
    worse. The result starts at `start` and ends at `end` with their headings and curvatures; a run-in
    is a straight piece on `end`'s line, curvature 0 at the join (lanes are straight at their first
    waypoint to well within the limit), bending to `end`'s own curvature at `end`."""
    if not (math.isfinite(max_curvature_1pm) and max_curvature_1pm > 0.0):
        raise ValueError(f"max_curvature_1pm {max_curvature_1pm!r}: must be a positive number (1/m)")
    plain = connector(start, end, step_m)
    plain_peak = float(np.max(np.abs(plain.curvature_1pm)))
    if len(plain) < 2 or plain_peak <= max_curvature_1pm:
        return plain
    a = tuple(float(v) for v in tuple(start)[:4])
    b = tuple(float(v) for v in tuple(end)[:4])
    # no ramp of curvature steeper than the plain curve's or SHARPNESS_MAX_1PM2 (a steering wheel turns
    # at a finite rate: a near-instant ramp is a kink to the car)
    sharp_max = max(_sharpness(plain), SHARPNESS_MAX_1PM2)
    cb, sb = math.cos(b[2]), math.sin(b[2])
    along_entry = (b[0] - a[0]) * cb + (b[1] - a[1]) * sb  # how far the entry lane's line runs from us
    f0, f1 = (g.ravel() for g in np.meshgrid(_END_SCALE_FACTORS, _END_SCALE_FACTORS))
    # (0: under the limit, by energy / 1: over it, by excess), then the curve: the least key wins
    best: tuple[tuple[int, float], tuple[float, float, float, float], float, float] | None = None
    for run_in in _RUN_IN_M:
        if run_in > 0.0 and run_in > RUN_IN_MAX_FRACTION * along_entry:
            break
        join = (b[0] - run_in * cb, b[1] - run_in * sb, b[2], b[3] if run_in == 0.0 else 0.0)
        chord = math.hypot(join[0] - a[0], join[1] - a[1])
        if chord <= DUPLICATE_M:
            continue
        pos, vel, acc = _asymmetric(_SEARCH_BASIS, _hermite_parts(a, join), f0 * chord, f1 * chord)
        peak, energy, excess, sharp = _bending(pos, vel, acc, max_curvature_1pm)
        smooth = sharp <= sharp_max
        ok = smooth & (peak <= max_curvature_1pm)
        # under the limit: least energy; none under it: least excess, never a sharper peak than plain's
        if ok.any():
            i = int(np.argmin(np.where(ok, energy, np.inf)))
        else:
            i = int(np.argmin(np.where(smooth & (peak <= plain_peak), excess, np.inf)))
        if not (math.isfinite(float(excess[i])) and smooth[i]) or float(peak[i]) > plain_peak:
            continue
        key = (0, float(energy[i])) if ok[i] else (1, float(excess[i]))
        if best is None or key < best[0]:
            best = (key, join, float(f0[i] * chord), float(f1[i] * chord))
    if best is None:
        return plain
    join, l0, l1 = best[1:]
    parts = _hermite_parts(a, join)
    l0s, l1s = np.array([l0]), np.array([l1])
    # unequal tangents make the parameter speed uneven: sample at even arc length, not even u
    fine_u = np.linspace(0.0, 1.0, 257)
    fine = _asymmetric(_basis(fine_u), parts, l0s, l1s)[0, 0]
    fine_s = np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(fine, axis=0).T))))
    n = max(2, math.ceil(float(fine_s[-1]) / step_m) + 1)
    u = np.interp(np.linspace(0.0, float(fine_s[-1]), n), fine_s, fine_u)
    u[0], u[-1] = 0.0, 1.0
    pos, vel, acc = _asymmetric(_basis(u), parts, l0s, l1s)[:, 0]
    pos[0], pos[-1] = a[:2], join[:2]
    turn = _from_derivatives(pos, vel, acc)
    if math.hypot(b[0] - join[0], b[1] - join[1]) > DUPLICATE_M:
        # the run-in: on end's line, from curvature 0 at the join to end's own (a Hermite: both match)
        turn = concat((turn, connector(join, b, step_m, scale_factors=(1.0,))))
    # judged again on the final samples (the search saw 25 a curve): never a sharper peak than the plain
    # curve, and where neither is steerable, strictly less to fall behind
    turn_peak = float(np.max(np.abs(turn.curvature_1pm)))
    if turn_peak > plain_peak or (
        turn_peak > max_curvature_1pm
        and _excess_of(turn, max_curvature_1pm) >= _excess_of(plain, max_curvature_1pm)
    ):
        return plain
    return turn
