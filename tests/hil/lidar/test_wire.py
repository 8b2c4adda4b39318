"""A simulated revolution crosses the wire (protocol/lidar/scan_message.py) and comes back the same."""

from __future__ import annotations

import numpy as np
import pytest

from bywire.hil.lidar.mesh import Ground
from bywire.hil.lidar.scene import LidarScene
from bywire.hil.lidar.velodyne import EgoPose, SimulatedVelodyne
from bywire.hil.lidar.wire import decode_scan, encode_scan
from bywire.protocol.lidar.scan_message import LidarScanError


def test_a_revolution_round_trips_through_bytes() -> None:
    scene = LidarScene(Ground().mesh(-150.0, 150.0, -150.0, 150.0, 50.0))
    scan = SimulatedVelodyne(scene, azimuth_steps=500, seed=4).scan(EgoPose(0.0, 0.0, 0.0), 3.2)
    back = decode_scan(encode_scan(scan))
    np.testing.assert_array_equal(back.xyz_m, scan.xyz_m)
    np.testing.assert_array_equal(back.beam, scan.beam)
    np.testing.assert_allclose(back.reflectance, scan.reflectance, atol=0.5 / 255.0 + 1e-7)
    assert back.beam.dtype == np.int16
    assert (back.stamp_s, back.sensor_height_m) == (3.2, pytest.approx(scan.sensor_height_m))
    with pytest.raises(LidarScanError):
        decode_scan(encode_scan(scan)[:-1])
