"""The simulated Velodyne HDL-64E on our car's roof (seed 000 Sec. 2.3 and 4): one `Scan` per revolution.

The paper's sensor: 64 lasers at fixed elevations covering 26.5 deg (about +2 down to -24.8 deg, the
constants of `host.perception.scan`), turning at 600 rpm (10 Hz), 0.09 deg apart in azimuth, range
and reflectivity for every point, ranges to about 100 m with 5 cm resolution. Here:

- elevations evenly spaced over the 64 lasers by default (`hdl64e_elevations_deg`), or the real
  sensor's two blocks of 32 (upper block 1/3 deg apart, lower block 1/2 deg);
- `azimuth_steps` columns per revolution: 2000 (0.18 deg) by default, half the real 4000, which gives
  the 128 k rays the host's perception budget is set for; 4000 is one argument away;
- a ray returns the nearest surface within `max_range_m` (120 m, what KITTI's HDL-64E delivers)
  with Gaussian range noise (`range_noise_m`, 2 cm: the HDL-64E's stated accuracy) and is dropped
  with `dropout_probability` (absorbing, specular or black surfaces); nothing within range is no
  point at all, as the real sensor reports none;
- reflectance: the hit surface's mean (`mesh.REFLECTANCE`) plus Gaussian noise, clipped to 0..1.

Deviations: the whole revolution is cast from one pose (the real sensor sweeps during 0.1 s, and the
paper projects each measurement with the car's motion at its time, Sec. 4; at 10 m/s the skew is at
most 1 m from the first column to the last); no reflectance fall-off with range or incidence angle
(the HDL-64E calibrates its intensities per laser); our own car is not in the scene (a roof mount
sees over it, and KITTI masks it out anyway). Noise is drawn from the sensor's seed and the
revolution's stamp, so a revolution is the same whatever was cast before it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from bywire.hil.lidar.mesh import F32, REFLECTANCE, Ground
from bywire.hil.lidar.scene import LidarScene
from bywire.host.perception.scan import (
    HDL64E_BEAMS,
    HDL64E_ELEVATION_BOTTOM_DEG,
    HDL64E_ELEVATION_TOP_DEG,
    KITTI_SENSOR_HEIGHT_M,
    Scan,
)

DEFAULT_AZIMUTH_STEPS = 2000
MAX_RANGE_M = 120.0
RANGE_NOISE_M = 0.02
REFLECTANCE_NOISE = 0.03
# Roof mount over the middle of the Passat's 2.72 m wheelbase, measured from the rear axle.
MOUNT_FORWARD_M = 1.36


def hdl64e_elevations_deg(layout: str = "even") -> F32:
    """The 64 lasers' elevations, top first (beam 0 = highest). `even`: evenly from +2.0 to -24.8 deg;
    `two_block`: the real head, 32 upper lasers +2.0 .. -8.33 deg and 32 lower ones -8.83 .. -24.33."""
    if layout == "even":
        return np.linspace(HDL64E_ELEVATION_TOP_DEG, HDL64E_ELEVATION_BOTTOM_DEG, HDL64E_BEAMS).astype(
            np.float32
        )
    if layout == "two_block":
        upper = HDL64E_ELEVATION_TOP_DEG - np.arange(32) / 3.0
        lower = -8.83 - 0.5 * np.arange(32)
        return np.concatenate([upper, lower]).astype(np.float32)
    raise ValueError(f"elevation layout {layout!r}: expected 'even' or 'two_block'")


@dataclass(frozen=True)
class EgoPose:
    """Our car's reference point (the rear axle, at road level) and attitude, in the scene's frame.

    Angles are ISO 8855's Z-Y-X (yaw about up, then pitch about the car's left, then roll about its
    forward axis): pitch is positive nose down, roll positive with the left side up.
    `LidarScene.ground` gives all three for a car standing on the road (`on_ground`).
    """

    x_m: float
    y_m: float
    yaw_rad: float
    z_m: float = 0.0
    pitch_rad: float = 0.0
    roll_rad: float = 0.0

    @staticmethod
    def on_ground(ground: Ground, x_m: float, y_m: float, yaw_rad: float) -> EgoPose:
        r = ground.frame(yaw_rad)
        pitch = -math.asin(max(-1.0, min(1.0, float(r[2, 0]))))
        roll = math.atan2(float(r[2, 1]), float(r[2, 2]))
        return EgoPose(x_m, y_m, yaw_rad, float(ground.height_m(x_m, y_m)), pitch, roll)

    def rotation(self) -> npt.NDArray[np.float64]:
        """World-from-car rotation matrix."""
        cy, sy = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        cp, sp = math.cos(self.pitch_rad), math.sin(self.pitch_rad)
        cr, sr = math.cos(self.roll_rad), math.sin(self.roll_rad)
        rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
        ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
        rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
        return rz @ ry @ rx


def _rotate(columns: F32, r: npt.NDArray[np.float64]) -> F32:
    """Directions (3, N) rotated by `r` as (N, 3), without BLAS: Embree's TBB workers, still awake
    after a commit, and OpenBLAS's threads starve each other on 2 cores (a (128 k, 3) @ (3, 3)
    product measured 0.4 ms alone and 44 ms right after a commit)."""
    out = np.empty((columns.shape[1], 3), np.float32)
    rf = r.astype(np.float32)
    for i in range(3):
        out[:, i] = rf[i, 0] * columns[0] + rf[i, 1] * columns[1] + rf[i, 2] * columns[2]
    return out


class SimulatedVelodyne:
    """Casts one revolution into a `LidarScene` (see the module docstring)."""

    def __init__(
        self,
        scene: LidarScene,
        *,
        mount_height_m: float = KITTI_SENSOR_HEIGHT_M,
        mount_forward_m: float = MOUNT_FORWARD_M,
        elevations_deg: npt.ArrayLike | None = None,
        azimuth_steps: int = DEFAULT_AZIMUTH_STEPS,
        range_noise_m: float = RANGE_NOISE_M,
        dropout_probability: float = 0.0,
        max_range_m: float = MAX_RANGE_M,
        reflectance_noise: float = REFLECTANCE_NOISE,
        seed: int = 0,
    ) -> None:
        if not 0.0 <= dropout_probability <= 1.0:
            raise ValueError(f"dropout_probability {dropout_probability} is not a probability")
        if azimuth_steps < 1 or max_range_m <= 0.0 or range_noise_m < 0.0 or reflectance_noise < 0.0:
            raise ValueError("azimuth_steps and max_range_m must be positive, the noises not negative")
        elevations = (
            hdl64e_elevations_deg() if elevations_deg is None else np.asarray(elevations_deg, np.float64)
        )
        if elevations.ndim != 1 or not len(elevations) or len(elevations) > 255:
            raise ValueError(f"expected 1 to 255 elevations, got shape {elevations.shape}")
        self.scene = scene
        self.mount_height_m = float(mount_height_m)
        self.mount_forward_m = float(mount_forward_m)
        self.elevations_deg = np.asarray(elevations, np.float32)
        self.azimuth_steps = int(azimuth_steps)
        self.range_noise_m = float(range_noise_m)
        self.dropout_probability = float(dropout_probability)
        self.max_range_m = float(max_range_m)
        self.reflectance_noise = float(reflectance_noise)
        self.seed = int(seed)
        el = np.radians(np.asarray(elevations, np.float64))[:, None]
        az = (2.0 * np.pi / self.azimuth_steps) * np.arange(self.azimuth_steps)[None, :]
        # row by row (all of beam 0's azimuths, then beam 1's): the order KITTI stores its scans in
        dirs = np.stack(
            np.broadcast_arrays(np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)), axis=-1
        )
        self._dirs_sensor = np.ascontiguousarray(dirs.reshape(-1, 3), dtype=np.float32)
        self._dirs_columns = np.ascontiguousarray(self._dirs_sensor.T)
        self._beam = np.repeat(np.arange(len(elevations), dtype=np.int16), self.azimuth_steps)

    @property
    def rays(self) -> int:
        return len(self._dirs_sensor)

    def sensor_origin_m(self, pose: EgoPose) -> npt.NDArray[np.float64]:
        r = pose.rotation()
        return np.array([pose.x_m, pose.y_m, pose.z_m]) + r @ np.array(
            [self.mount_forward_m, 0.0, self.mount_height_m]
        )

    def scan(self, pose: EgoPose, stamp_s: float) -> Scan:
        """One revolution from `pose` (the scene's moving objects as last set) stamped `stamp_s`."""
        dirs_world = _rotate(self._dirs_columns, pose.rotation())
        rng_m, surface, hit = self.scene.cast(self.sensor_origin_m(pose), dirs_world, self.max_range_m)
        gen = np.random.default_rng(self._seed_sequence(stamp_s))
        keep = hit
        if self.dropout_probability > 0.0:
            keep = hit & (gen.random(self.rays, dtype=np.float32) >= self.dropout_probability)
        idx = np.flatnonzero(keep)
        # float32 draws: half the time of float64 ones, and the scan is float32 anyway
        noise = gen.standard_normal((2, len(idx)), dtype=np.float32)
        measured = rng_m.take(idx)
        measured += np.float32(self.range_noise_m) * noise[0]
        # a return from closer than the noise is still in front of the sensor
        np.maximum(measured, np.float32(0.0), out=measured)
        xyz = self._dirs_sensor.take(idx, axis=0)
        xyz *= measured[:, None]
        refl = REFLECTANCE.take(surface.take(idx))
        refl += np.float32(self.reflectance_noise) * noise[1]
        np.clip(refl, np.float32(0.0), np.float32(1.0), out=refl)
        return Scan(
            xyz_m=xyz,
            reflectance=refl,
            beam=self._beam.take(idx),
            stamp_s=float(stamp_s),
            sensor_height_m=self.mount_height_m,
        )

    def _seed_sequence(self, stamp_s: float) -> np.random.SeedSequence:
        stamp_us = round(stamp_s * 1e6)
        return np.random.SeedSequence([self.seed & 0xFFFFFFFFFFFFFFFF, stamp_us & 0xFFFFFFFFFFFFFFFF])


__all__ = [
    "DEFAULT_AZIMUTH_STEPS",
    "MAX_RANGE_M",
    "MOUNT_FORWARD_M",
    "EgoPose",
    "SimulatedVelodyne",
    "hdl64e_elevations_deg",
]
