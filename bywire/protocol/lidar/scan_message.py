"""One LIDAR revolution as bytes: the points a Velodyne HDL-64E delivers per turn (seed 000 Sec. 2.3),
plant -> host.

The paper's car moved its scans through a shared-memory database (KogMo-RTDB, Sec. 3); ours go over
the host runtime's transport as one message per revolution. Little-endian, planar, version 1:

    header  "<4sBBHIdf"   magic b"BWLS", version 1, beams (lasers of the sensor, 1..255), flags (0:
                          none defined), point count n (<= MAX_POINTS), stamp_s (the revolution's
                          time, s), sensor_height_m (the sensor over the road under the car)
    n x 3   float32       x, y, z (m) in the sensor frame: x forward, y left, z up
    n       uint8         reflectance * 255, rounded (0..1 in steps of 1/255)
    n       uint8         beam (laser row, 0 = highest elevation), < beams

14 bytes a point: 114 k points (64 beams x 2000 azimuths on an open road) are 1.6 MB. No checksum:
the message crosses between processes on one machine over a reliable, ordered transport, and a
checksum would cost a pass over 1.6 MB at 10 Hz to guard against nothing that transport does.

This layer knows arrays, not the host's `Scan` (`bywire.protocol` imports no host code): the receiver
builds its scan from `ScanPayload`. `decode` refuses anything but a well-formed revolution with
`LidarScanError` naming the field, and never raises another exception (fuzzed in
tests/protocol/lidar/test_scan_message.py); its xyz and beam arrays are views of the buffer, not copies.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

MAGIC = b"BWLS"
VERSION = 1
# 4000 azimuths x 64 beams, the HDL-64E's full resolution, is 256 k; four times that is no sensor of ours.
MAX_POINTS = 1 << 20
_HEADER = struct.Struct("<4sBBHIdf")
HEADER_BYTES = _HEADER.size
POINT_BYTES = 3 * 4 + 1 + 1


class LidarScanError(ValueError):
    """Bytes that are not a valid scan message, or arrays that cannot be one; the message says which
    field and why."""


@dataclass(frozen=True)
class ScanPayload:
    """A decoded revolution: xyz_m (n, 3) float32, reflectance (n,) float32 in 0..1, beam (n,) uint8."""

    xyz_m: npt.NDArray[np.float32]
    reflectance: npt.NDArray[np.float32]
    beam: npt.NDArray[np.uint8]
    stamp_s: float
    sensor_height_m: float
    beams: int

    def __len__(self) -> int:
        return int(self.xyz_m.shape[0])


def encode(
    xyz_m: npt.ArrayLike,
    reflectance: npt.ArrayLike,
    beam: npt.ArrayLike,
    stamp_s: float,
    sensor_height_m: float,
    beams: int = 64,
) -> bytes:
    """The message of one revolution; LidarScanError for arrays that do not make one."""
    xyz = np.asarray(xyz_m, dtype=np.float32)
    refl = np.asarray(reflectance, dtype=np.float32)
    rows = np.asarray(beam)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise LidarScanError(f"xyz_m: expected (n, 3), got {xyz.shape}")
    n = xyz.shape[0]
    if refl.shape != (n,) or rows.shape != (n,):
        raise LidarScanError(f"{n} points but reflectance {refl.shape} and beam {rows.shape}")
    if n > MAX_POINTS:
        raise LidarScanError(f"count: {n} points, more than {MAX_POINTS}")
    if not 1 <= beams <= 255:
        raise LidarScanError(f"beams: {beams} is not 1..255")
    if not (np.isfinite(stamp_s) and np.isfinite(sensor_height_m)):
        raise LidarScanError(f"stamp_s {stamp_s} and sensor_height_m {sensor_height_m} must be finite")
    if not np.isfinite(xyz).all():
        raise LidarScanError(
            f"xyz_m: point {int(np.flatnonzero(~np.isfinite(xyz).all(axis=1))[0])} is not finite"
        )
    if n and not (np.all(refl >= 0.0) and np.all(refl <= 1.0)):
        raise LidarScanError("reflectance: expected values in 0..1")
    if n and not (np.issubdtype(rows.dtype, np.integer) and rows.min() >= 0 and rows.max() < beams):
        raise LidarScanError(f"beam: expected integers 0..{beams - 1}")
    header = _HEADER.pack(MAGIC, VERSION, beams, 0, n, float(stamp_s), float(sensor_height_m))
    return b"".join(
        (
            header,
            np.ascontiguousarray(xyz, dtype="<f4").tobytes(),
            np.rint(refl * 255.0).astype(np.uint8).tobytes(),
            rows.astype(np.uint8).tobytes(),
        )
    )


def decode(buf: bytes | bytearray | memoryview) -> ScanPayload:
    """The revolution in `buf`; LidarScanError naming the field for anything else."""
    try:
        data = memoryview(buf).cast("B")
    except (TypeError, ValueError) as e:
        raise LidarScanError(f"buffer: not a flat run of bytes ({e})") from e
    if len(data) < HEADER_BYTES:
        raise LidarScanError(f"length: {len(data)} bytes, shorter than the {HEADER_BYTES}-byte header")
    magic, version, beams, flags, n, stamp_s, height_m = _HEADER.unpack_from(data)
    if magic != MAGIC:
        raise LidarScanError(f"magic: {bytes(magic)!r}, expected {MAGIC!r}")
    if version != VERSION:
        raise LidarScanError(f"version: {version}, this reader knows {VERSION}")
    if flags != 0:
        raise LidarScanError(f"flags: {flags:#06x}, none are defined")
    if beams == 0:
        raise LidarScanError("beams: 0, a sensor has at least one")
    if n > MAX_POINTS:
        raise LidarScanError(f"count: {n} points, more than {MAX_POINTS}")
    expected = HEADER_BYTES + n * POINT_BYTES
    if len(data) != expected:
        raise LidarScanError(f"length: {len(data)} bytes, but {n} points take {expected}")
    if not (np.isfinite(stamp_s) and np.isfinite(height_m)):
        raise LidarScanError(f"stamp_s {stamp_s} / sensor_height_m {height_m}: not finite")
    xyz = np.frombuffer(data, dtype="<f4", count=3 * n, offset=HEADER_BYTES).reshape(n, 3)
    finite = np.isfinite(xyz).all(axis=1)
    if not finite.all():
        raise LidarScanError(f"xyz_m: point {int(np.flatnonzero(~finite)[0])} is not finite")
    q = np.frombuffer(data, dtype=np.uint8, count=n, offset=HEADER_BYTES + 12 * n)
    rows = np.frombuffer(data, dtype=np.uint8, count=n, offset=HEADER_BYTES + 13 * n)
    if n and int(rows.max()) >= beams:
        bad = int(np.flatnonzero(rows >= beams)[0])
        raise LidarScanError(f"beam: point {bad} is on beam {int(rows[bad])} of a {beams}-beam sensor")
    return ScanPayload(
        xyz_m=xyz.astype(np.float32, copy=False),
        reflectance=q.astype(np.float32) / np.float32(255.0),
        beam=rows,
        stamp_s=float(stamp_s),
        sensor_height_m=float(height_m),
        beams=int(beams),
    )


__all__ = [
    "HEADER_BYTES",
    "MAGIC",
    "MAX_POINTS",
    "POINT_BYTES",
    "VERSION",
    "LidarScanError",
    "ScanPayload",
    "decode",
    "encode",
]
