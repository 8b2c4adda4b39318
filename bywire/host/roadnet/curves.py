"""How curves are made and sampled into `Path`s (seed 000 sec. 8, Fig. 10b/c): three kinds.

- `smooth_curve` / `path_through`: the interpolating cubic spline through the points, parameterised by
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
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt
from scipy.interpolate import CubicSpline

from .path import DEFAULT_STEP_M, Path, PathPoint, _from_derivatives, concat

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]

# Two waypoints closer than this are one point for the spline (real RNDFs repeat points; a zero chord
# would make the chord-length parameter non-increasing).
DUPLICATE_M = 1e-3


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


def path_through(
    x_m: npt.ArrayLike,
    y_m: npt.ArrayLike,
    step_m: float = DEFAULT_STEP_M,
    *,
    start_heading_rad: float | None = None,
    end_heading_rad: float | None = None,
) -> Path:
    """The smooth curve through the points (`smooth_curve`), sampled every ~step_m."""
    return smooth_curve(
        x_m, y_m, step_m, start_heading_rad=start_heading_rad, end_heading_rad=end_heading_rad
    )[0]


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
