"""The simulated Velodyne on hand-made scenes: the ground rings each beam draws, a box ahead, drop-outs,
determinism, a graded road, and moving objects cast like static ones."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bywire.hil.lidar.mesh import REFLECTANCE, Ground, Mesh, Surface, box_mesh
from bywire.hil.lidar.scene import LidarScene
from bywire.hil.lidar.velodyne import EgoPose, SimulatedVelodyne, hdl64e_elevations_deg
from bywire.host.perception.scan import HDL64E_BEAMS, Scan

H = 1.73
EXACT = {"range_noise_m": 0.0, "reflectance_noise": 0.0, "mount_forward_m": 0.0, "mount_height_m": H}


def _ground(ground: Ground | None = None, half_m: float = 200.0) -> Mesh:
    return (ground or Ground()).mesh(-half_m, half_m, -half_m, half_m, 50.0)


def _sensor(scene: LidarScene, **kw: object) -> SimulatedVelodyne:
    return SimulatedVelodyne(scene, **{**EXACT, **kw})  # type: ignore[arg-type]


def _ring_radius_m(elevation_deg: float) -> float:
    return H / math.tan(math.radians(-elevation_deg))


def test_flat_road_gives_each_beam_its_ground_ring() -> None:
    scan = _sensor(LidarScene(_ground())).scan(EgoPose(0.0, 0.0, 0.3), 0.0)
    el = hdl64e_elevations_deg()
    radius = np.hypot(scan.xyz_m[:, 0], scan.xyz_m[:, 1])
    np.testing.assert_allclose(scan.xyz_m[:, 2], -H, atol=0.005)
    for b in range(HDL64E_BEAMS):
        mine = scan.beam == b
        if el[b] >= 0.0 or _ring_radius_m(float(el[b])) > 120.0:
            assert not mine.any(), f"beam {b} at {el[b]:.2f} deg reaches no ground within 120 m"
            continue
        assert mine.sum() == 2000
        np.testing.assert_allclose(radius[mine], _ring_radius_m(float(el[b])), rtol=1e-4, atol=0.01)
    # the top seven beams (+2.0 .. -0.57 deg) see the ground beyond 120 m
    assert len(scan) == 57 * 2000


def test_range_noise_has_its_sigma() -> None:
    scan = _sensor(LidarScene(_ground()), range_noise_m=0.02).scan(EgoPose(0.0, 0.0, 0.0), 0.0)
    el = np.radians(hdl64e_elevations_deg()[scan.beam])
    measured = np.linalg.norm(scan.xyz_m.astype(np.float64), axis=1)
    error = measured - H / np.sin(-el)
    assert abs(float(error.mean())) < 0.001
    assert float(error.std()) == pytest.approx(0.02, rel=0.05)


def test_a_box_ten_metres_ahead_is_seen_at_ten_metres_by_the_right_beams() -> None:
    ground = Ground()
    box = box_mesh(ground, 10.0 + 2.25, 0.0, 0.0, 4.5, 2.0, 1.5, Surface.VEHICLE)
    scan = _sensor(LidarScene(Mesh.concat([_ground(), box]))).scan(EgoPose(0.0, 0.0, 0.0), 0.0)
    ahead = (np.abs(scan.xyz_m[:, 1]) < 0.02) & (scan.xyz_m[:, 0] > 0.0)  # the column at azimuth 0
    on_face = ahead & (np.abs(scan.xyz_m[:, 0] - 10.0) < 0.005)
    el = hdl64e_elevations_deg()
    # the face spans the road (z = -H) to the roof (z = 1.5 - H) at 10 m
    expected = {
        b for b in range(64) if math.atan2(-H, 10.0) < math.radians(el[b]) < math.atan2(1.5 - H, 10.0)
    }
    assert set(scan.beam[on_face].tolist()) == expected
    assert len(expected) == 20
    np.testing.assert_allclose(scan.reflectance[on_face], REFLECTANCE[Surface.VEHICLE])
    # behind the face nothing of those beams: no ground return shows through the box
    hidden = ahead & np.isin(scan.beam, list(expected)) & (scan.xyz_m[:, 0] > 10.01)
    assert not hidden.any()


def test_moving_objects_are_cast_as_if_they_were_static() -> None:
    ground = Ground()
    cars = [
        box_mesh(ground, 10.0, 3.0, 0.4, 4.5, 1.8, 1.5, Surface.VEHICLE),
        box_mesh(ground, -25.0, -6.0, 2.0, 4.5, 1.8, 1.5, Surface.VEHICLE),
        box_mesh(ground, 2.0, 0.0, 0.0, 1.0, 1.0, 1.0, Surface.VEHICLE),  # under the sensor's nose
    ]
    close = box_mesh(ground, 1.0, 1.9, 0.0, 4.5, 1.8, 1.5, Surface.VEHICLE)  # the sensor is in its sphere
    cars.append(close)
    pose = EgoPose(0.0, 0.0, 0.1)
    reference = _sensor(LidarScene(Mesh.concat([_ground(), *cars]))).scan(pose, 0.0)
    scene = LidarScene(_ground())
    scene.set_moving(cars)
    moving = _sensor(scene).scan(pose, 0.0)
    np.testing.assert_array_equal(moving.beam, reference.beam)
    np.testing.assert_allclose(moving.xyz_m, reference.xyz_m, atol=1e-4)
    np.testing.assert_array_equal(moving.reflectance, reference.reflectance)
    scene.set_moving([])
    assert len(_sensor(scene).scan(pose, 0.0)) == 57 * 2000


def test_drop_out_rate_matches_its_setting() -> None:
    scene = LidarScene(_ground())
    hits = len(_sensor(scene).scan(EgoPose(0.0, 0.0, 0.0), 0.0))
    p = 0.3
    kept = len(_sensor(scene, dropout_probability=p).scan(EgoPose(0.0, 0.0, 0.0), 0.0))
    sigma = math.sqrt(p * (1.0 - p) / hits)
    assert abs(kept / hits - (1.0 - p)) < 4.0 * sigma


def _same(a: Scan, b: Scan) -> bool:
    return (
        np.array_equal(a.xyz_m, b.xyz_m)
        and np.array_equal(a.reflectance, b.reflectance)
        and np.array_equal(a.beam, b.beam)
    )


def test_a_revolution_depends_only_on_the_seed_and_the_stamp() -> None:
    scene = LidarScene(_ground())
    noisy = {"range_noise_m": 0.02, "reflectance_noise": 0.03, "dropout_probability": 0.1}
    a, b = _sensor(scene, seed=7, **noisy), _sensor(scene, seed=7, **noisy)
    pose = EgoPose(1.0, 2.0, 0.5)
    first = a.scan(pose, 0.1)
    a.scan(pose, 0.2)  # another revolution in between changes nothing
    assert _same(first, a.scan(pose, 0.1))
    assert _same(first, b.scan(pose, 0.1))
    assert not _same(first, b.scan(pose, 0.2))
    assert not _same(first, _sensor(scene, seed=8, **noisy).scan(pose, 0.1))


def test_on_a_grade_the_road_is_still_z_minus_the_mount_height() -> None:
    ground = Ground(grade_pct=6.0, uphill_heading_rad=0.7, origin_xy_m=(5.0, -3.0))
    pose = EgoPose.on_ground(ground, 20.0, 10.0, 1.9)
    assert pose.z_m == pytest.approx(float(ground.height_m(20.0, 10.0)))
    np.testing.assert_allclose(pose.rotation(), ground.frame(1.9), atol=1e-12)
    scan = _sensor(LidarScene(_ground(ground, 300.0), ground)).scan(pose, 0.0)
    np.testing.assert_allclose(scan.xyz_m[:, 2], -H, atol=0.005)
    el = hdl64e_elevations_deg()
    radius = np.hypot(scan.xyz_m[:, 0], scan.xyz_m[:, 1])
    for b in (20, 40, 63):
        np.testing.assert_allclose(radius[scan.beam == b], _ring_radius_m(float(el[b])), rtol=1e-4)


def test_a_level_car_on_a_grade_sees_the_road_rise_ahead() -> None:
    ground = Ground(grade_pct=5.0)
    scan = _sensor(LidarScene(_ground(ground), ground)).scan(EgoPose(0.0, 0.0, 0.0), 0.0)
    ahead = (np.abs(scan.xyz_m[:, 1]) < 0.05) & (scan.xyz_m[:, 0] > 5.0)
    behind = (np.abs(scan.xyz_m[:, 1]) < 0.05) & (scan.xyz_m[:, 0] < -5.0)
    np.testing.assert_allclose(scan.xyz_m[ahead, 2], -H + 0.05 * scan.xyz_m[ahead, 0], atol=0.005)
    np.testing.assert_allclose(scan.xyz_m[behind, 2], -H + 0.05 * scan.xyz_m[behind, 0], atol=0.005)


def test_elevation_layouts() -> None:
    even, blocks = hdl64e_elevations_deg(), hdl64e_elevations_deg("two_block")
    for el in (even, blocks):
        assert el.shape == (64,) and np.all(np.diff(el) < 0.0) and el[0] == pytest.approx(2.0)
    assert even[-1] == pytest.approx(-24.8) and blocks[-1] == pytest.approx(-24.33)
    np.testing.assert_allclose(np.diff(blocks[:32]), -1.0 / 3.0, rtol=1e-5)
    np.testing.assert_allclose(np.diff(blocks[32:]), -0.5, rtol=1e-5)
    with pytest.raises(ValueError, match="layout"):
        hdl64e_elevations_deg("three_block")
    scan = _sensor(LidarScene(_ground()), elevations_deg=blocks, azimuth_steps=360).scan(
        EgoPose(0, 0, 0), 0.0
    )
    assert scan.beam.max() == 63 and len(scan) == 360 * int(
        np.sum(H / np.tan(np.radians(-blocks[blocks < 0])) <= 120)
    )


def test_settings_are_checked() -> None:
    scene = LidarScene(_ground())
    with pytest.raises(ValueError, match="probability"):
        SimulatedVelodyne(scene, dropout_probability=1.5)
    with pytest.raises(ValueError, match="positive"):
        SimulatedVelodyne(scene, azimuth_steps=0)
    with pytest.raises(ValueError, match="elevations"):
        SimulatedVelodyne(scene, elevations_deg=np.zeros((2, 2)))
