"""Synthetic Velodyne revolutions of simple scenes (a road with a grade, walls, boxes) for the occupancy
grid, segmentation and registration tests: 64 beams from +2 to -24.8 deg, cast against the scene."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from bywire.host.perception.ego_pose import EgoPose
from bywire.host.perception.scan import HDL64E_BEAMS, KITTI_SENSOR_HEIGHT_M, Scan

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Box:
    """An upright box in the world: centre (x, y), size along x and y, top height over the road."""

    x_m: float
    y_m: float
    size_x_m: float
    size_y_m: float
    height_m: float = 1.5
    yaw_rad: float = 0.0


def cast(
    boxes: tuple[Box, ...] = (),
    pose: EgoPose | None = None,
    grade: float = 0.0,
    azimuth_step_deg: float = 0.4,
    max_range_m: float = 100.0,
    sensor_height_m: float = KITTI_SENSOR_HEIGHT_M,
    range_noise_m: float = 0.0,
    seed: int = 0,
) -> Scan:
    """One revolution from a sensor at `pose` (world frame) over a road z = grade * x_world (road
    height 0 under the world origin), in the sensor frame, rows top beam first; Gaussian range noise
    of `range_noise_m` (the HDL-64E's is under 2 cm, 1 sigma)."""
    pose = pose if pose is not None else EgoPose()
    elev = np.radians(np.linspace(2.0, -24.8, HDL64E_BEAMS))
    az = np.radians(np.arange(-180.0, 180.0, azimuth_step_deg))
    e, a = np.meshgrid(elev, az, indexing="ij")
    if range_noise_m > 0.0:
        # a real head's lasers fire at their own azimuths: their samples do not line up column by column
        a = a + np.radians(np.random.default_rng(seed + 1).uniform(0.0, azimuth_step_deg, (HDL64E_BEAMS, 1)))
    beam = np.repeat(np.arange(HDL64E_BEAMS, dtype=np.int16), len(az))
    # Ray directions in the world (sensor yaw applied), origin at the sensor.
    yaw = a.ravel() + pose.yaw_rad
    d = np.column_stack((np.cos(e.ravel()) * np.cos(yaw), np.cos(e.ravel()) * np.sin(yaw), np.sin(e.ravel())))
    origin = np.array([pose.x_m, pose.y_m, grade * pose.x_m + sensor_height_m])
    t = np.full(len(d), np.inf)
    # Road: origin_z + t d_z = grade (origin_x + t d_x).
    denom = d[:, 2] - grade * d[:, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t_road = (grade * origin[0] - origin[2]) / denom
    t = np.where((t_road > 0) & np.isfinite(t_road), t_road, t)
    for b in boxes:
        t = np.minimum(t, _box_hit(b, origin, d, grade))
    hit = t <= max_range_m
    if range_noise_m > 0.0:
        t = t + np.random.default_rng(seed).normal(0.0, range_noise_m, len(t))
    world = origin + d[hit] * t[hit, None]
    rel = world - origin
    c, s = math.cos(-pose.yaw_rad), math.sin(-pose.yaw_rad)
    xyz = np.column_stack((c * rel[:, 0] - s * rel[:, 1], s * rel[:, 0] + c * rel[:, 1], rel[:, 2]))
    return Scan(
        xyz.astype(np.float32),
        np.full(len(xyz), 0.2, np.float32),
        beam[hit],
        sensor_height_m=sensor_height_m,
    )


def _box_hit(b: Box, origin: F64, d: F64, grade: float) -> F64:
    """Distance along each ray to the box (slab method in the box's own axes), inf if missed."""
    c, s = math.cos(-b.yaw_rad), math.sin(-b.yaw_rad)
    ox, oy = origin[0] - b.x_m, origin[1] - b.y_m
    o = np.array([c * ox - s * oy, s * ox + c * oy, origin[2]])
    dd = np.column_stack((c * d[:, 0] - s * d[:, 1], s * d[:, 0] + c * d[:, 1], d[:, 2]))
    base = grade * b.x_m
    lo = np.array([-b.size_x_m / 2, -b.size_y_m / 2, base - 1.0])
    hi = np.array([b.size_x_m / 2, b.size_y_m / 2, base + b.height_m])
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lo - o) / dd
        t2 = (hi - o) / dd
    t_near = np.nanmax(np.minimum(t1, t2), axis=1)
    t_far = np.nanmin(np.maximum(t1, t2), axis=1)
    ok = (t_far >= t_near) & (t_far > 0)
    return np.where(ok, np.maximum(t_near, 0.0), np.inf)


def write_kitti_bin(path: str, scan: Scan) -> None:
    np.column_stack((scan.xyz_m, scan.reflectance)).astype(np.float32).tofile(path)
