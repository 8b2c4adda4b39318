"""Ego-motion between consecutive LIDAR scans by scan registration (2-D ICP), for seed 000 section 4's
projection of each revolution "under consideration of the vehicle's motion" when no pose source is at
hand (on KITTI the listed poses do not fit the shared scans; registration does).

Point-to-line ICP in the ground plane (the 2-D form of point-to-plane): the points of both scans in a
height band over the ground (0.3 to 2.5 m: vertical structure, not road, not treetops), thinned to one
per `voxel_m` square, the target's local line normals from the principal axes of its `normal_neighbours`
nearest points. Each iteration pairs every source point with its nearest target point (scipy's
cKDTree) within a gate that shrinks from `max_pair_m` to `min_pair_m`, and solves the linearised
least squares for (dx, dy, dyaw) with Huber weights; it stops when the step is below 0.1 mm and
1e-5 rad. Only x, y and yaw: roll, pitch and height changes between revolutions are not modelled.
Scans are not motion-compensated (KITTI's are not): the rolling shutter of one revolution is left in.
Every paired point counts, corners and clutter too: dropping the points whose neighbours are not on a
line removed the few that fix the motion along a street (its fronts are all parallel). Surfaces seen
from above (car roofs below the sensor) sample differently from two poses; on the synthetic street of
the tests they bias the result by 2-3 cm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from bywire.host.perception.ego_pose import EgoPose
from bywire.host.perception.scan import Scan

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class RegistrationParams:
    min_height_m: float = 0.3  # over the ground plane under the sensor
    max_height_m: float = 2.5
    min_range_m: float = 3.0
    max_range_m: float = 40.0  # farther, a yaw error moves points more than the gate
    voxel_m: float = 0.2
    normal_neighbours: int = 8
    max_pair_m: float = 1.5
    min_pair_m: float = 0.3
    huber_m: float = 0.1
    max_iterations: int = 60


@dataclass(frozen=True)
class Registration:
    """The pose of the moving scan's frame in the fixed scan's frame, with the fit's quality."""

    pose: EgoPose
    rms_m: float  # point-to-line residual of the paired points
    pairs: int
    iterations: int
    converged: bool


def registration_points(scan: Scan, params: RegistrationParams | None = None) -> F64:
    """The scan's vertical structure in the ground plane (K, 2), one point per voxel."""
    p = params if params is not None else RegistrationParams()
    xyz = scan.xyz_m
    height = xyz[:, 2] + scan.sensor_height_m
    r2 = xyz[:, 0] ** 2 + xyz[:, 1] ** 2
    keep = (height >= p.min_height_m) & (height <= p.max_height_m)
    keep &= (r2 >= p.min_range_m**2) & (r2 <= p.max_range_m**2)
    xy = xyz[keep, :2].astype(np.float64)
    key = np.floor(xy / p.voxel_m).astype(np.int64)
    _, first = np.unique(key[:, 0] * (1 << 32) + key[:, 1], return_index=True)
    return xy[np.sort(first)]


def register(
    moving: Scan | F64,
    fixed: Scan | F64,
    initial: EgoPose | None = None,
    params: RegistrationParams | None = None,
) -> Registration:
    """The pose of `moving`'s frame in `fixed`'s frame (for consecutive scans: the motion of the car
    from `fixed` to `moving`). Scans or their `registration_points`."""
    p = params if params is not None else RegistrationParams()
    src = registration_points(moving, p) if isinstance(moving, Scan) else np.asarray(moving, np.float64)
    dst = registration_points(fixed, p) if isinstance(fixed, Scan) else np.asarray(fixed, np.float64)
    pose = initial if initial is not None else EgoPose()
    if len(src) < 3 or len(dst) < p.normal_neighbours:
        return Registration(pose, math.nan, 0, 0, False)
    tree = cKDTree(dst)
    normals = _line_normals(dst, tree, p.normal_neighbours)
    x, y, yaw = pose.x_m, pose.y_m, pose.yaw_rad
    rms, pairs = math.nan, 0
    for it in range(1, p.max_iterations + 1):
        gate = max(p.min_pair_m, p.max_pair_m * (1.0 - it / (0.5 * p.max_iterations)))
        c, s = math.cos(yaw), math.sin(yaw)
        moved = np.column_stack((c * src[:, 0] - s * src[:, 1] + x, s * src[:, 0] + c * src[:, 1] + y))
        dist, j = tree.query(moved, distance_upper_bound=gate)
        ok = np.isfinite(dist)
        pairs = int(ok.sum())
        if pairs < 3:
            return Registration(EgoPose(x, y, yaw), math.nan, pairs, it, False)
        q, n, m = dst[j[ok]], normals[j[ok]], moved[ok]
        r = np.einsum("ij,ij->i", m - q, n)
        # d r / d(dx, dy, dyaw) for a small rotation about the fixed frame's origin after the pose.
        jac = np.column_stack((n[:, 0], n[:, 1], n[:, 1] * m[:, 0] - n[:, 0] * m[:, 1]))
        w = np.minimum(1.0, p.huber_m / np.maximum(np.abs(r), 1e-12))
        a = jac.T @ (jac * w[:, None])
        b = -jac.T @ (w * r)
        try:
            dx, dy, dyaw = np.linalg.solve(a, b)
        except np.linalg.LinAlgError:
            return Registration(EgoPose(x, y, yaw), math.nan, pairs, it, False)
        cd, sd = math.cos(dyaw), math.sin(dyaw)
        x, y = cd * x - sd * y + dx, sd * x + cd * y + dy
        yaw += dyaw
        rms = float(np.sqrt(np.mean(r * r)))
        if gate <= p.min_pair_m and abs(dx) < 1e-4 and abs(dy) < 1e-4 and abs(dyaw) < 1e-5:
            return Registration(EgoPose(x, y, yaw), rms, pairs, it, True)
    return Registration(EgoPose(x, y, yaw), rms, pairs, p.max_iterations, False)


def _line_normals(points: F64, tree: cKDTree, k: int) -> F64:
    """Unit normal of the line through each point's k nearest neighbours (the minor principal axis)."""
    _, idx = tree.query(points, k=k)
    nb = points[idx]
    d = nb - nb.mean(axis=1, keepdims=True)
    sxx = (d[:, :, 0] ** 2).mean(axis=1)
    syy = (d[:, :, 1] ** 2).mean(axis=1)
    sxy = (d[:, :, 0] * d[:, :, 1]).mean(axis=1)
    major = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
    return np.column_stack((-np.sin(major), np.cos(major)))
