"""Smoothing a searched path (after Dolgov et al. 2010, the planner of seed 000's rival Junior; seed 000
Sec. 10 hands its raw A* paths to the controller): the hybrid A* path is made of arcs joined with
steering jumps; a controller follows a path whose curvature changes gently.

Each stretch between direction changes (the cusps stay where they are, as do the start and the goal)
is smoothed by nonlinear conjugate gradient (`scipy.optimize.minimize`, method "CG") on the sum of

- smoothness: w_s * sum |x[i+1] - 2 x[i] + x[i-1]|^2 (the discrete second derivative);
- obstacles: w_o * sum (d_max - d(x[i]))^2 where the clearance d (the distance transform of the map,
  interpolated) is under d_max;
- fidelity: w_f * sum |x[i] - x0[i]|^2 (stay near the searched path, which is known to be free).

Dolgov's curvature term is left out of the objective (its gradient is long and the smoothness term
already lowers curvature); it is a check instead. The result is checked against the same configuration-
space table the search used, at the headings of its tangent, and its discrete curvature against the
car's smallest turning radius (5 % tolerance): a stretch that fails either keeps its searched poses, so
smoothing never moves a path into collision or into a turn the car cannot drive.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage, optimize

from .cspace import CSpace

__all__ = ["SmoothingParams", "smooth_path", "split_at_cusps"]


@dataclass(frozen=True)
class SmoothingParams:
    w_smooth: float = 1.0
    w_obstacle: float = 2.0
    w_fidelity: float = 0.05
    clearance_m: float = 1.5  # d_max: closer than this to an obstacle is penalised
    resample_m: float = 0.25  # the smoothed path's spacing
    max_iterations: int = 200


def split_at_cusps(directions: np.ndarray) -> list[tuple[int, int]]:
    """Index ranges [i0, i1] (inclusive) of the stretches driven in one direction."""
    n = directions.size
    if n == 0:
        return []
    cuts = [0]
    for i in range(1, n):
        if directions[i] != directions[i - 1]:
            cuts.append(i - 1)
    cuts.append(n - 1)
    return [(a, b) for a, b in itertools.pairwise(cuts) if b > a]


def _resample(xy: np.ndarray, step_m: float) -> np.ndarray:
    seg = np.hypot(*np.diff(xy, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if s[-1] < 1e-9:
        return xy[:1].copy()
    n = max(2, math.ceil(s[-1] / step_m) + 1)
    t = np.linspace(0.0, s[-1], n)
    return np.column_stack((np.interp(t, s, xy[:, 0]), np.interp(t, s, xy[:, 1])))


def _curvature(xy: np.ndarray) -> np.ndarray:
    a, b, c = xy[:-2], xy[1:-1], xy[2:]
    ab, bc, ac = np.hypot(*(b - a).T), np.hypot(*(c - b).T), np.hypot(*(c - a).T)
    cross = (b - a)[:, 0] * (c - b)[:, 1] - (b - a)[:, 1] * (c - b)[:, 0]
    return 2.0 * np.abs(cross) / np.maximum(ab * bc * ac, 1e-12)


class _Clearance:
    """The distance to the nearest obstacle cell (metres), bilinear, with its gradient."""

    def __init__(self, cs: CSpace) -> None:
        grid = cs.grid
        self.res = grid.resolution_m
        self.origin = grid.origin_xy_m
        self.dist = ndimage.distance_transform_edt(~grid.occupied) * self.res
        gy, gx = np.gradient(self.dist, self.res)
        self.gx, self.gy = gx, gy

    def __call__(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cols = (xy[:, 0] - self.origin[0]) / self.res - 0.5
        rows = (xy[:, 1] - self.origin[1]) / self.res - 0.5
        coords = np.vstack((rows, cols))
        d = ndimage.map_coordinates(self.dist, coords, order=1, mode="nearest")
        gx = ndimage.map_coordinates(self.gx, coords, order=1, mode="nearest")
        gy = ndimage.map_coordinates(self.gy, coords, order=1, mode="nearest")
        return d, np.column_stack((gx, gy))


def _objective(
    flat: np.ndarray, fixed0: np.ndarray, fixed1: np.ndarray, x0: np.ndarray, clearance: _Clearance,
    p: SmoothingParams,
) -> tuple[float, np.ndarray]:  # fmt: skip
    inner = flat.reshape(-1, 2)
    x = np.vstack((fixed0, inner, fixed1))
    grad = np.zeros_like(x)
    # smoothness
    dd = x[:-2] - 2.0 * x[1:-1] + x[2:]
    f = p.w_smooth * float(np.sum(dd * dd))
    g2 = 2.0 * p.w_smooth * dd
    grad[:-2] += g2
    grad[1:-1] -= 2.0 * g2
    grad[2:] += g2
    # obstacles
    d, gd = clearance(inner)
    near = d < p.clearance_m
    pen = np.where(near, p.clearance_m - d, 0.0)
    f += p.w_obstacle * float(np.sum(pen * pen))
    grad[1:-1] += (-2.0 * p.w_obstacle * pen)[:, None] * gd
    # fidelity
    dev = inner - x0
    f += p.w_fidelity * float(np.sum(dev * dev))
    grad[1:-1] += 2.0 * p.w_fidelity * dev
    return f, grad[1:-1].ravel()


def smooth_path(
    cs: CSpace,
    poses: np.ndarray,
    directions: np.ndarray,
    turn_radius_m: float,
    params: SmoothingParams | None = None,
) -> tuple[np.ndarray, np.ndarray, dict[str, int]]:
    """The smoothed path (N x 3 poses, N directions) and counts: stretches smoothed, kept as searched."""
    p = params or SmoothingParams()
    if poses.shape[0] < 3:
        return poses.copy(), directions.copy(), {"smoothed": 0, "kept": 0}
    clearance = _Clearance(cs)
    kappa_max = 1.0 / turn_radius_m
    out_poses: list[np.ndarray] = []
    out_dirs: list[np.ndarray] = []
    counts = {"smoothed": 0, "kept": 0}
    for i0, i1 in split_at_cusps(directions):
        part = poses[i0 : i1 + 1]
        d = float(directions[i1])
        xy0 = _resample(part[:, :2], p.resample_m)
        candidate = part
        if xy0.shape[0] >= 4:
            res = optimize.minimize(
                _objective, xy0[1:-1].ravel(), jac=True, method="CG",
                args=(xy0[0], xy0[-1], xy0[1:-1], clearance, p),
                options={"maxiter": p.max_iterations},
            )  # fmt: skip
            xy = np.vstack((xy0[0], res.x.reshape(-1, 2), xy0[-1]))
            th = _stretch_headings(xy, d, float(part[0, 2]), float(part[-1, 2]))
            sm = np.column_stack((xy, th))
            ok = not cs.collides(sm[:, 0], sm[:, 1], sm[:, 2]).any()
            ok &= bool(np.all(_curvature(xy) <= 1.05 * kappa_max + 1e-9)) if xy.shape[0] >= 3 else True
            if ok:
                candidate = sm
        counts["smoothed" if candidate is not part else "kept"] += 1
        start = 1 if out_poses else 0
        out_poses.append(candidate[start:])
        out_dirs.append(np.full(candidate.shape[0] - start, d))
    return np.vstack(out_poses), np.concatenate(out_dirs), counts


def _stretch_headings(xy: np.ndarray, direction: float, first: float, last: float) -> np.ndarray:
    """Heading of the car at each point: along the tangent (against it reversing), the ends as given."""
    d = np.diff(xy, axis=0)
    th = np.arctan2(d[:, 1], d[:, 0]) + (math.pi if direction < 0 else 0.0)
    th = np.unwrap(np.concatenate([[first], th]))
    mid = th[1:]
    heads = np.empty(xy.shape[0])
    heads[0] = first
    heads[1:-1] = 0.5 * (mid[:-1] + mid[1:])
    heads[-1] = _near(last, heads[-2])
    return heads


def _near(angle: float, ref: float) -> float:
    """`angle` moved by whole turns to the nearest of `ref`."""
    return ref + math.remainder(angle - ref, 2.0 * math.pi)
