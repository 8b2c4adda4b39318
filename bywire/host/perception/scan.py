"""One LIDAR revolution as the perception modules take it, and the reader of KITTI's Velodyne files.

A scan is in the sensor frame (x forward, y left, z up, metres) with each point's reflectance
(0..1) and beam (laser row, 0 = the highest elevation). The Velodyne HDL-64E that AnnieWAY and
KITTI carried (seed 000 section 4) has 64 beams from about +2 deg down to about -24.8 deg and turns
at 10 Hz. KITTI's files carry no beam id; the rows are recovered from the azimuth's zero crossings
(the files are stored laser row by laser row), as the shared data's note describes.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

HDL64E_BEAMS = 64
HDL64E_ELEVATION_TOP_DEG = 2.0
HDL64E_ELEVATION_BOTTOM_DEG = -24.8
HDL64E_REVOLUTION_S = 0.1
KITTI_SENSOR_HEIGHT_M = 1.73


class ScanFormatError(ValueError):
    """A scan file that is not what its reader expects; the message names the file and why."""


@dataclass(frozen=True)
class Scan:
    """One revolution in the sensor frame.

    xyz_m: (N, 3) float32 points, metres; reflectance: (N,) float32 in 0..1; beam: (N,) int16 laser
    row, 0 = top; stamp_s: the revolution's time on the host clock (seconds); sensor_height_m: the
    sensor's height over the road under the car (the ground plane is z = -sensor_height_m).
    """

    xyz_m: npt.NDArray[np.float32]
    reflectance: npt.NDArray[np.float32]
    beam: npt.NDArray[np.int16]
    stamp_s: float = 0.0
    sensor_height_m: float = KITTI_SENSOR_HEIGHT_M

    def __post_init__(self) -> None:
        n = self.xyz_m.shape[0]
        if self.xyz_m.ndim != 2 or self.xyz_m.shape[1] != 3:
            raise ValueError(f"scan points must be (N, 3), got {self.xyz_m.shape}")
        if self.reflectance.shape != (n,) or self.beam.shape != (n,):
            raise ValueError(f"{n} points but reflectance {self.reflectance.shape}, beam {self.beam.shape}")

    def __len__(self) -> int:
        return int(self.xyz_m.shape[0])


def kitti_beam_rows(xyz_m: npt.NDArray[np.floating]) -> npt.NDArray[np.int16]:
    """The laser row of each point of a KITTI scan stored row by row: a new row starts where the
    azimuth crosses zero from below (a small step: a jump of more than pi/2 is noise, not a turn)."""
    if len(xyz_m) == 0:
        return np.zeros(0, np.int16)
    az = np.arctan2(xyz_m[:, 1], xyz_m[:, 0])
    starts = (az[1:] >= 0.0) & (az[:-1] < 0.0) & (np.abs(np.diff(az)) < np.pi / 2)
    rows = np.concatenate(([0], np.cumsum(starts)))
    return np.minimum(rows, HDL64E_BEAMS - 1).astype(np.int16)


def read_kitti_bin(path: Path, stamp_s: float = 0.0) -> Scan:
    """A KITTI Velodyne `.bin` (float32 N x 4: x, y, z, reflectance) as a Scan with recovered beams."""
    path = Path(path)
    try:
        raw = np.fromfile(path, dtype=np.float32)
        size = path.stat().st_size  # fromfile drops a tail shorter than one float
    except OSError as e:
        raise ScanFormatError(f"{path}: cannot read: {e.strerror or e}") from e
    if size % 16:
        raise ScanFormatError(
            f"{path}: {size} bytes is not a whole number of 16-byte points (x, y, z, reflectance)"
        )
    pts = raw.reshape(-1, 4)
    finite = np.isfinite(pts).all(axis=1)
    if not finite.all():
        bad = int(np.flatnonzero(~finite)[0])
        raise ScanFormatError(f"{path}: point {bad} (byte {bad * 16}) is not finite: {pts[bad].tolist()}")
    xyz = np.ascontiguousarray(pts[:, :3])
    return Scan(
        xyz_m=xyz,
        reflectance=np.ascontiguousarray(np.clip(pts[:, 3], 0.0, 1.0)),
        beam=kitti_beam_rows(xyz),
        stamp_s=stamp_s,
    )
