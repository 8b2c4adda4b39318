"""The lateral offset between the map's lane and the observed lane markings (seed 000 Sec. 6, Fig. 8).

"Because we observed a systematic error of RNDF data in some areas, it appeared to be sensible to
determine a correcting offset from the detected lane markings. To accomplish this, the lane markings
specified in the RNDF are first projected into the Radon plane. Assuming that the offset of the road map
data does not exceed one lane width, the deviation is obtained in a second step from the distances to the
maxima in the Radon plane closest to the predicted positions. Assuming further that predicted and
estimated lane boundaries are close to parallel, the vertical distance is sufficient to determine the
offset."

One measurement (`measure_offset`), on the marker image of `lane_markers.MarkerGrid`:

1. The map lane near the car: the centreline's foot point F of the image centre and the chord direction
   psi of the centreline from `centreline_window_m` behind F to as far ahead (a lane is smooth over a
   few tens of metres; the chord averages the RNDF's waypoint kinks).
2. The Radon plane at normals psi + 90 deg +- `max_angle_error_rad` (the lines are "close to parallel"):
   the angle of most high-passed energy, then the peaks of its projection (`radon.lines_at`). No
   measurement where that angle is the window's edge: the energy still grows there, the lines run
   farther off the map's direction than "close to parallel" (the chord across a curve's start or end,
   another road's paint), and the peaks at the edge's angle are not where the lines cross the car's
   normal (up to 0.5 m off in synthetic 25-30 m curves, 0.10-0.17 m once such frames are left out).
3. Each observed line's signed lateral distance from the centreline, d = p - n . (F - C) (left > 0,
   n the left normal, C the image centre), is matched to the nearest expected marking e_j: where the
   map puts them (`markings_m`, the urban host's lane_offset module reads them off the road network:
   midway to a lane beside, that lane's far edge, or the lane's own edge), by default the lane's
   boundaries at +-w/2 and the neighbouring lanes' at +-3w/2 (abutting lanes); the residual d - e_j is that
   line's vote for the offset. Votes beyond `max_offset_lane_widths` x w are dropped (the paper's "does
   not exceed one lane width": a vote at +-w/2 is ambiguous between two markings).
4. The offset is the strength-weighted median of the votes, refined to the weighted mean of the votes
   within `inlier_m` of it (a robust mean); its variance is the inliers' spread over their number plus a
   floor `measurement_sigma_m`^2 (the cell size and the map's own noise).

Filtering (`OffsetFilter`): a scalar Kalman filter, random walk with `process_sigma_m_per_sqrt_s`; a
measurement whose innovation exceeds `gate_sigmas` standard deviations is rejected (a wrong match is a
whole lane width, metres, against a spread of centimetres). `reset_after` consecutive rejected but
mutually consistent measurements restart the filter on them: the map's error really did change (a new
road, a new survey). Within one road (the map lane the caller names with each measurement) a restart
moves the estimate by `max_restart_m` at most: an RNDF's error changes slowly along a road (the random
walk follows that through the gate) and does not exceed a lane width, and every larger restart within a
lane on the DARPA sample was a misreading (another lane's lines matched as ours for 0.5-6 s, restarted on
0.7-1.5 m). The offset is valid while its standard deviation is below `valid_sigma_m` and a measurement
was accepted within `timeout_s`.

Convention: offset > 0 means the real lane lies to the LEFT of the map's lane, left taken along the
centreline in the order of its points (its driving direction). `apply_offset` moves a route that way.
Deviation: the paper compares the Radon maxima with the RNDF's projected markings in the Radon plane
directly; we do the same along the one normal the observed lines share (they are parallel), which is the
paper's "vertical distance", and add the robust mean and the filter, which it does not describe.
"""

from __future__ import annotations

import math
from collections.abc import Hashable
from dataclasses import dataclass, replace
from typing import overload

import numpy as np
import numpy.typing as npt

from bywire.host.lateral import PathSamples
from bywire.host.roadnet.path import Path

from .lane_markers import BoolArray, GridParams, LaneMarkerMap, MarkerGrid, MarkerParams, PlanarPose
from .radon import HIGHPASS_M, LineSet, RadonSpectrum, dominant_normal, lines_at
from .scan import Scan

__all__ = [
    "LaneOffset",
    "LaneOffsetEstimator",
    "OffsetFilter",
    "OffsetMeasurement",
    "OffsetParams",
    "apply_offset",
    "lane_frame",
    "measure_offset",
]

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class OffsetParams:
    """Matching and filtering; see the module docstring."""

    # Expected markings in lane widths left of the centreline: this lane's two boundaries and the
    # neighbours' outer ones (on a two-lane road those are the curbs or the edge lines).
    markings_lane_widths: tuple[float, ...] = (-1.5, -0.5, 0.5, 1.5)
    # The RNDF's error "does not exceed one lane width": a vote is at most half of one from its marking.
    max_offset_lane_widths: float = 0.5
    # The lane's direction: its chord over +-15 m, about the marker image's half width (20 m).
    centreline_window_m: float = 15.0
    # Observed lines are "close to parallel" to the map's; 4 deg is 1.4 m over a 20 m half image.
    max_angle_error_rad: float = math.radians(4.0)
    highpass_m: float = HIGHPASS_M
    # Votes within 2 cells of the median are averaged: a line is found to a tenth of a cell, a painted
    # line is 1-2 cells wide, and a line that is not the expected one (a curb 0.5-1 m beyond the edge
    # line) votes further off.
    inlier_m: float = 0.3
    # Floor of a measurement's sigma: the offsets' own accuracy (1-2 cm) is not the map's, whose lane
    # centreline is drawn through surveyed waypoints to about a decimetre.
    measurement_sigma_m: float = 0.1
    min_lines: int = 1
    # Filter. Prior: the map is right to within a metre; it drifts by 5 cm per sqrt(s) (an RNDF's
    # error changes over tens of metres of road, seconds of driving).
    prior_sigma_m: float = 1.0
    process_sigma_m_per_sqrt_s: float = 0.05
    # 3 sigmas: a good measurement is refused 0.3 % of the time; a match one lane over (3-4 m off
    # against sigmas of 0.1-0.15 m) never passes.
    gate_sigmas: float = 3.0
    # Half a second of agreeing refusals at 10 Hz: longer than a wrong match lasts (a frame or two
    # while a line enters the image), short against a road's length.
    reset_after: int = 5
    # Within one road (`OffsetFilter.update`'s `road`) a restart moves the estimate by at most this
    # much: an RNDF's error changes slowly along a road, which the random walk follows through the
    # gate, and "does not exceed one lane width"; a restart of 0.7-1.5 m within a lane was a
    # misreading every time on the DARPA sample (a neighbour's line taken for ours for 0.5-6 s). On
    # another road the error may be another one: any restart.
    max_restart_m: float = 0.5
    # Valid for the route when 1 sigma is under 0.3 m (a tenth of a lane) and fresh within 2 s (20 m at
    # 10 m/s; beyond, the map's error may be another one).
    valid_sigma_m: float = 0.3
    timeout_s: float = 2.0

    def __post_init__(self) -> None:
        if not self.markings_lane_widths:
            raise ValueError("markings_lane_widths: at least one expected marking")
        if not 0.0 < self.max_offset_lane_widths <= 0.5:
            raise ValueError(f"max_offset_lane_widths = {self.max_offset_lane_widths}: must be in (0, 0.5]")
        for name in (
            "inlier_m",
            "measurement_sigma_m",
            "prior_sigma_m",
            "gate_sigmas",
            "max_restart_m",
            "valid_sigma_m",
        ):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"OffsetParams.{name} = {getattr(self, name)}: must be > 0")
        if self.reset_after < 1 or self.min_lines < 1:
            raise ValueError("reset_after and min_lines must be >= 1")


@dataclass(frozen=True)
class OffsetMeasurement:
    """One frame's offset from the marker image (before filtering)."""

    offset_m: float
    variance_m2: float
    lines_m: tuple[float, ...]  # lateral positions of the observed lines that voted (left > 0)
    inliers: int
    angle_error_rad: float  # observed lines' direction minus the map's (counter-clockwise > 0)


@dataclass(frozen=True)
class LaneOffset:
    """The filtered offset: the real lane is `offset_m` left of the map's (see the module docstring)."""

    stamp_s: float
    offset_m: float
    variance_m2: float
    valid: bool
    accepted: bool  # this frame's measurement was taken in (False: none, or rejected by the gate)
    measurement: OffsetMeasurement | None = None

    @property
    def sigma_m(self) -> float:
        return math.sqrt(self.variance_m2)


def lane_frame(
    centreline_xy_m: npt.ArrayLike, x_m: float, y_m: float, window_m: float = 15.0
) -> tuple[float, float, float]:
    """Foot point (x, y) of (x_m, y_m) on the polyline and its local direction psi (rad): the chord from
    `window_m` behind the foot point to `window_m` ahead (clamped to the polyline)."""
    pts = np.asarray(centreline_xy_m, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2 or pts.shape[0] < 2:
        raise ValueError(f"a centreline needs >= 2 points (M, 2), got shape {pts.shape}")
    seg = np.diff(pts, axis=0)
    len2 = np.einsum("ij,ij->i", seg, seg)
    if not np.all(len2 > 0.0):
        raise ValueError("a centreline must not repeat a point")
    q = np.array([x_m, y_m])
    t = np.clip(np.einsum("ij,ij->i", q - pts[:-1], seg) / len2, 0.0, 1.0)
    foot = pts[:-1] + t[:, None] * seg
    i = int(np.argmin(np.einsum("ij,ij->i", foot - q, foot - q)))
    s = np.concatenate(([0.0], np.cumsum(np.sqrt(len2))))
    s_foot = s[i] + t[i] * (s[i + 1] - s[i])
    lo = np.array([np.interp(s_foot - window_m, s, pts[:, 0]), np.interp(s_foot - window_m, s, pts[:, 1])])
    hi = np.array([np.interp(s_foot + window_m, s, pts[:, 0]), np.interp(s_foot + window_m, s, pts[:, 1])])
    d = hi - lo
    return float(foot[i, 0]), float(foot[i, 1]), math.atan2(d[1], d[0])


def _weighted_median(values: FloatArray, weights: FloatArray) -> float:
    order = np.argsort(values)
    v, w = values[order], weights[order]
    cum = np.cumsum(w)
    return float(v[int(np.searchsorted(cum, 0.5 * cum[-1]))])


def measure_offset(
    grid: MarkerGrid,
    centreline_xy_m: npt.ArrayLike,
    lane_width_m: float,
    params: OffsetParams = OffsetParams(),
    *,
    spectrum: RadonSpectrum | None = None,
    markings_m: npt.ArrayLike | None = None,
) -> OffsetMeasurement | None:
    """One frame's offset (see the module docstring); None when no line votes. `markings_m`: where the
    map puts the markings, metres left of the centreline (default `params.markings_lane_widths` x the
    width: lanes that abut, each as wide as this one)."""
    if not (math.isfinite(lane_width_m) and lane_width_m > 0.0):
        raise ValueError(f"lane_width_m = {lane_width_m}: must be finite and > 0")
    cx, cy = grid.centre_xy_m
    fx, fy, psi = lane_frame(centreline_xy_m, cx, cy, params.centreline_window_m)
    spec = spectrum if spectrum is not None else RadonSpectrum(grid.image, grid.cell_m, disc=True)
    normal_map = psi + math.pi / 2.0
    normal = dominant_normal(spec, normal_map, params.max_angle_error_rad, highpass_m=params.highpass_m)
    angle_error = math.remainder(normal - normal_map, 2.0 * math.pi)
    if abs(angle_error) >= params.max_angle_error_rad - 1e-9:
        # the energy still grows at the window's edge: the lines run farther off the map's direction
        # than "close to parallel" (a curve's ends, another road's paint), and the peaks at this angle
        # are not where the lines cross the car's normal (up to 0.5 m off in a synthetic 25-30 m curve)
        return None
    found: LineSet = lines_at(spec, normal, highpass_m=params.highpass_m)
    if len(found.lines) < params.min_lines:
        return None
    n = np.array([math.cos(normal), math.sin(normal)])
    centre_offset = float(n @ np.array([fx - cx, fy - cy]))  # the centreline's p in the Radon plane
    lateral = np.array([ln.offset_m - centre_offset for ln in found.lines])
    strength = np.array([ln.strength for ln in found.lines])
    if markings_m is None:
        expected = np.asarray(params.markings_lane_widths, dtype=np.float64) * lane_width_m
    else:
        expected = np.asarray(markings_m, dtype=np.float64)
        if expected.ndim != 1 or expected.size == 0 or not np.all(np.isfinite(expected)):
            raise ValueError(f"markings_m = {markings_m!r}: expected one or more finite offsets")
    nearest = expected[np.argmin(np.abs(lateral[:, None] - expected[None, :]), axis=1)]
    votes = lateral - nearest
    ok = np.abs(votes) <= params.max_offset_lane_widths * lane_width_m
    if np.count_nonzero(ok) < params.min_lines:
        return None
    votes, strength, lateral = votes[ok], strength[ok], lateral[ok]
    med = _weighted_median(votes, strength)
    inl = np.abs(votes - med) <= params.inlier_m
    w = strength[inl]
    mean = float(np.average(votes[inl], weights=w))
    spread = float(np.average((votes[inl] - mean) ** 2, weights=w))
    k = int(np.count_nonzero(inl))
    variance = params.measurement_sigma_m**2 + spread / k
    return OffsetMeasurement(mean, variance, tuple(float(v) for v in lateral), k, angle_error)


class OffsetFilter:
    """Scalar Kalman filter of the offset with an innovation gate and a restart (see the module docstring)."""

    def __init__(self, params: OffsetParams = OffsetParams()) -> None:
        self.params = params
        self.reset()

    def reset(self) -> None:
        self._x = 0.0
        self._p = self.params.prior_sigma_m**2
        self._stamp_s: float | None = None
        self._accepted_s: float | None = None
        self._accepted_road: Hashable | None = None
        self._rejected: list[OffsetMeasurement] = []

    def update(
        self, measurement: OffsetMeasurement | None, stamp_s: float, road: Hashable | None = None
    ) -> LaneOffset:
        """One frame: `measurement` (None: nothing measured) taken on `road` (the map lane it was
        measured against; None: unknown, every restart allowed), see the module docstring."""
        prm = self.params
        if self._stamp_s is not None:
            dt = max(stamp_s - self._stamp_s, 0.0)
            # no more uncertain than the prior: without markings the map is as good as it ever was
            self._p = min(self._p + prm.process_sigma_m_per_sqrt_s**2 * dt, prm.prior_sigma_m**2)
        self._stamp_s = stamp_s
        accepted = False
        if measurement is not None:
            nu = measurement.offset_m - self._x
            s = self._p + measurement.variance_m2
            if nu * nu <= prm.gate_sigmas**2 * s:
                self._correct(measurement)
                self._rejected.clear()
                accepted = True
            else:
                # the last `reset_after` only: an older one (that did not agree) must not shift the mean
                self._rejected = [*self._rejected, measurement][-prm.reset_after :]
                if len(self._rejected) >= prm.reset_after and self._consistent(self._rejected):
                    restart = float(np.mean([m.offset_m for m in self._rejected]))
                    same_road = road is not None and road == self._accepted_road
                    if not same_road or abs(restart - self._x) <= prm.max_restart_m:
                        # the map's error changed: start again from what the last frames agree on
                        self._x = restart
                        self._p = float(np.max([m.variance_m2 for m in self._rejected]))
                        self._rejected.clear()
                        accepted = True
            if accepted:
                self._accepted_s = stamp_s
                self._accepted_road = road
        valid = (
            self._accepted_s is not None
            and stamp_s - self._accepted_s <= prm.timeout_s
            and self._p <= prm.valid_sigma_m**2
        )
        return LaneOffset(stamp_s, self._x, self._p, valid, accepted, measurement)

    def _correct(self, m: OffsetMeasurement) -> None:
        gain = self._p / (self._p + m.variance_m2)
        self._x += gain * (m.offset_m - self._x)
        self._p *= 1.0 - gain

    def _consistent(self, ms: list[OffsetMeasurement]) -> bool:
        values = np.array([m.offset_m for m in ms])
        return float(values.max() - values.min()) <= 2.0 * self.params.inlier_m


class LaneOffsetEstimator:
    """Scan in, filtered offset out: `LaneMarkerMap` + `measure_offset` + `OffsetFilter`.

    `update(scan, pose, centreline, lane_width_m)` once per revolution, with the car's pose when the scan
    was taken and the map lane it drives in (its centreline as world points in driving order; `road`
    names it for the filter's restart rule).
    """

    def __init__(
        self,
        offset_params: OffsetParams | None = None,
        marker_params: MarkerParams | None = None,
        grid_params: GridParams | None = None,
        sensor_offset_m: tuple[float, float] = (0.0, 0.0),
    ) -> None:
        self.params = offset_params or OffsetParams()
        self.markers = LaneMarkerMap(
            marker_params or MarkerParams(), grid_params or GridParams(), sensor_offset_m
        )
        self.filter = OffsetFilter(self.params)
        self.last: LaneOffset | None = None

    def update(
        self,
        scan: Scan,
        pose: PlanarPose,
        centreline_xy_m: npt.ArrayLike,
        lane_width_m: float,
        ground_mask: BoolArray | None = None,
        markings_m: npt.ArrayLike | None = None,
        road: Hashable | None = None,
    ) -> LaneOffset:
        self.markers.update(scan, pose, ground_mask)
        m = measure_offset(
            self.markers.grid, centreline_xy_m, lane_width_m, self.params, markings_m=markings_m
        )
        self.last = self.filter.update(m, scan.stamp_s, road)
        return self.last


@overload
def apply_offset(path: Path, offset: LaneOffset | float) -> Path: ...
@overload
def apply_offset(path: PathSamples, offset: LaneOffset | float) -> PathSamples: ...
def apply_offset(path: Path | PathSamples, offset: LaneOffset | float) -> Path | PathSamples:
    """The route moved `offset` metres to the left of its heading at every sample (a parallel curve).

    Takes a roadnet `Path` (the route, its stubs) or a `lateral.PathSamples` (what the controller
    tracks); a `LaneOffset` that is not valid leaves the path as it is. Curvature becomes k / (1 - d k)
    and arc length is measured again along the moved samples; ValueError where the offset reaches a
    centre of curvature (the parallel curve has a cusp there). With `PathSamples` the offset is to the
    left of the body heading, which is the lane's direction also when the stub is driven backwards.
    """
    if isinstance(offset, LaneOffset):
        if not offset.valid:
            return path
        d = offset.offset_m
    else:
        d = float(offset)
    if not math.isfinite(d):
        raise ValueError(f"offset {d} m: must be finite")
    if d == 0.0:
        return path
    if isinstance(path, Path):
        return path.offset(d)
    h, k = path.heading_rad, path.curvature_1pm
    scale = 1.0 - d * k
    if np.any(scale <= 1e-6):
        i = int(np.argmax(scale <= 1e-6))
        raise ValueError(
            f"offset {d} m reaches the centre of curvature at s = {path.s_m[i]:.2f} m "
            f"(radius {1.0 / abs(k[i]):.2f} m)"
        )
    x = path.x_m - d * np.sin(h)
    y = path.y_m + d * np.cos(h)
    s = path.s_m[0] + np.concatenate(([0.0], np.cumsum(np.hypot(np.diff(x), np.diff(y)))))
    return replace(path, x_m=x, y_m=y, curvature_1pm=k / scale, s_m=s)
