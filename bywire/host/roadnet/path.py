"""The sampled path: smooth, densely sampled planar paths with arc length (seed 000 sec. 8, Fig. 10b/c).

A `Path` is a polyline in local metric coordinates (x east, y north, metres) sampled every ~0.25 m, with
the heading (rad, counter-clockwise from east) and the curvature (1/m, positive turning left) of the
smooth curve it was sampled from, and the cumulative arc length ``s`` (0 at the first sample).  It is what
the section-8 planner hands the controllers: `stub(s0)` is the ~30 m "path stub" ahead of the car.
How the curves are made and sampled into paths is `curves` (`curves.path_through` for a curve through points).

Projection (`project`): the foot point on the polyline, found among the segments next to the nearest
samples (a kd-tree over the samples, built on first use) or, given `hint_s` (the last known s, what a
controller has), in a window around it: that is faster and never jumps to another part of a path that
passes close to itself (a loop, a U-turn).  If the best point of the window lies on the window's edge the
search falls back to the whole path.  Offsets are signed, left of the direction of travel positive.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import NamedTuple

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]

# 0.25 m: a lateral controller's look-ahead is metres; at 0.25 m spacing the chord of a 5 m radius curve
# departs from the arc by 1.6 mm, and a lane of 1 km is 4000 samples (32 kB per array).
DEFAULT_STEP_M = 0.25
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

    __slots__ = ("_heading", "_k", "_lists", "_s", "_tree", "_x", "_y")

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
        self._lists: tuple[list[float], list[float], list[float]] | None = None

    # -- construction

    @classmethod
    def _trusted(cls, x: FloatArray, y: FloatArray, h: FloatArray, k: FloatArray, s: FloatArray) -> Path:
        """No checks, no copies: for arrays this module made (finite, s from 0, increasing, h unwrapped)."""
        self = cls.__new__(cls)
        for a in (x, y, h, k, s):
            a.setflags(write=False)
        self._x, self._y, self._heading, self._k, self._s = x, y, h, k, s
        self._tree = None
        self._lists = None
        return self

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
        s, i, tb, x0, y0, dx, dy, rows, j = self._feet(px, py)
        h = self._heading[i] + tb * (self._heading[i + 1] - self._heading[i])
        fx, fy = x0[rows, j] + tb * dx[rows, j], y0[rows, j] + tb * dy[rows, j]
        lateral = -np.sin(h) * (px - fx) + np.cos(h) * (py - fy)
        return s, lateral, (h + np.pi) % (2.0 * np.pi) - np.pi

    def project_points_s(self, x_m: npt.ArrayLike, y_m: npt.ArrayLike) -> FloatArray:
        """`project_points`' arc lengths alone (the same computation, stopped there)."""
        px = np.atleast_1d(np.asarray(x_m, dtype=np.float64))
        py = np.atleast_1d(np.asarray(y_m, dtype=np.float64))
        if len(self) == 1:
            return np.zeros_like(px)
        return self._feet(px, py)[0]

    def _feet(
        self, px: FloatArray, py: FloatArray
    ) -> tuple[
        FloatArray, IntArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, IntArray, IntArray
    ]:
        """Foot points of many points (n >= 2 samples): s, segment, fraction along it, the candidate
        segments' starts and directions, and the rows and columns of the chosen ones."""
        n = len(self)
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
        return s, i, tb, x0, y0, dx, dy, rows, j

    def project_point_s(self, x_m: float, y_m: float) -> float:
        """`project_points(x_m, y_m)`'s arc length for one point, bit for bit (tests hold it to that).

        One point through the vectorised path is two dozen numpy calls on arrays of 16; here the same
        candidate segments (the kd-tree asked the same question), the same IEEE operations in the same
        order on Python floats, and `np.argmin`'s first minimum. Kept to s: the lateral offset and
        heading would need numpy's own sin and cos."""
        n = len(self)
        if n == 1:
            return 0.0
        if self._tree is None:
            self._tree = cKDTree(self.xy)
        if self._lists is None:
            self._lists = (self._x.tolist(), self._y.tolist(), self._s.tolist())
        xs, ys, ss = self._lists
        px, py = float(x_m), float(y_m)
        _, idx = self._tree.query(np.array(((px, py),)), k=min(8, n))
        near = idx[0].tolist()  # one row of k indexes (k >= 2 here)
        last = n - 2
        best_d2 = math.inf
        best_i, best_t = -1, 0.0
        for i in [min(max(k - 1, 0), last) for k in near] + [min(max(k, 0), last) for k in near]:
            x0, y0 = xs[i], ys[i]
            dx, dy = xs[i + 1] - x0, ys[i + 1] - y0
            len2 = dx * dx + dy * dy
            t = ((px - x0) * dx + (py - y0) * dy) / len2 if len2 > 0.0 else 0.0
            t = 0.0 if t < 0.0 else (1.0 if t > 1.0 else t)
            ex, ey = x0 + t * dx - px, y0 + t * dy - py
            d2 = ex * ex + ey * ey
            if d2 < best_d2 or best_i < 0:
                best_d2, best_i, best_t = d2, i, t
        return ss[best_i] + best_t * (ss[best_i + 1] - ss[best_i])

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


def _unwrap(angles: FloatArray) -> FloatArray:
    """np.unwrap for 1-D arrays, without its generality (it dominated the cost of short paths)."""
    if angles.size < 2:
        return angles
    step = np.diff(angles)
    step -= 2.0 * np.pi * np.round(step / (2.0 * np.pi))
    return np.concatenate((angles[:1], angles[0] + np.cumsum(step)))


def _from_derivatives(p: FloatArray, d1: FloatArray, d2: FloatArray) -> Path:
    """The path of a parametric curve's samples `p` with its first and second derivatives there (heading
    and curvature from them): how `curves` turns its curves into paths."""
    speed2 = d1[:, 0] ** 2 + d1[:, 1] ** 2
    heading = _unwrap(np.arctan2(d1[:, 1], d1[:, 0]))
    with np.errstate(invalid="ignore", divide="ignore"):
        k = np.where(speed2 > 0.0, (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]) / speed2**1.5, 0.0)
    x, y = np.ascontiguousarray(p[:, 0]), np.ascontiguousarray(p[:, 1])
    s = np.concatenate(([0.0], np.cumsum(np.hypot(np.diff(x), np.diff(y)))))
    return Path._trusted(x, y, heading, k, s)
