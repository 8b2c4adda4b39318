"""A simulated revolution to and from the bytes that carry it to the host (`protocol.lidar.scan_message`).

The host's receiver builds its `Scan` from a `ScanPayload` the way `scan_from_payload` does; it is here
so that the simulator's tests cross the wire format with the scan type on both ends.
"""

from __future__ import annotations

import numpy as np

from bywire.host.perception.scan import HDL64E_BEAMS, Scan
from bywire.protocol.lidar.scan_message import ScanPayload, decode, encode


def encode_scan(scan: Scan, beams: int = HDL64E_BEAMS) -> bytes:
    return encode(scan.xyz_m, scan.reflectance, scan.beam, scan.stamp_s, scan.sensor_height_m, beams)


def scan_from_payload(payload: ScanPayload) -> Scan:
    return Scan(
        xyz_m=payload.xyz_m,
        reflectance=payload.reflectance,
        beam=payload.beam.astype(np.int16),
        stamp_s=payload.stamp_s,
        sensor_height_m=payload.sensor_height_m,
    )


def decode_scan(buf: bytes) -> Scan:
    """LidarScanError for bytes that are not a scan message."""
    return scan_from_payload(decode(buf))


__all__ = ["decode_scan", "encode_scan", "scan_from_payload"]
