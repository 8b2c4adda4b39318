"""The urban world as the simulated Velodyne sees it: lane paint, curbs, buildings, parked and moving cars,
a shipped scenario cast end to end, and the benchmark's entry."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from bywire.hil.lidar.bench import cast_benchmark
from bywire.hil.lidar.mesh import REFLECTANCE, Surface
from bywire.hil.lidar.road_marks import SIDEWALK_M
from bywire.hil.lidar.urban_scene import VEHICLE_HEIGHT_M, UrbanLidar, urban_lidar_for_scenario
from bywire.hil.world.urban import UrbanWorld
from bywire.hil.world.urban_spec import UrbanSpecError, parse_urban
from bywire.host.perception.scan import Scan

# networks/ring.rndf, segment 1: lane 1.1 eastbound on y = -2, lane 1.2 westbound on y = +2, 12 ft wide
LANE_HALF_M = 0.5 * 12 * 0.3048
EDGE_Y_M = -2.0 - LANE_HALF_M
EXACT: dict[str, Any] = {"range_noise_m": 0.0, "seed": 3}


def _ring(**urban: Any) -> UrbanWorld:
    data = {"rndf": "networks/ring.rndf", "mdf": "networks/ring_pass.mdf", **urban}
    return UrbanWorld(parse_urban(data, "lidar_test.yaml"))


def _world_points(lidar: UrbanLidar, scan: Scan) -> np.ndarray:
    pose = lidar.ego_pose()
    return lidar.sensor.sensor_origin_m(pose) + scan.xyz_m.astype(np.float64) @ pose.rotation().T


def _band(xyz: np.ndarray, y_lo: float, y_hi: float, x_lo: float = 20.0, x_hi: float = 80.0) -> np.ndarray:
    return (xyz[:, 1] > y_lo) & (xyz[:, 1] < y_hi) & (xyz[:, 0] > x_lo) & (xyz[:, 0] < x_hi)


def test_lane_paint_is_brighter_than_the_asphalt_beside_it() -> None:
    lidar = UrbanLidar.build(_ring(), **EXACT)
    scan = lidar.revolution(0.0)
    xyz = _world_points(lidar, scan)
    edge = _band(xyz, EDGE_Y_M - 0.04, EDGE_Y_M + 0.04)  # solid white: nothing beside lane 1.1 there
    centre = _band(xyz, 0.11 - 0.04, 0.11 + 0.04)  # one of the double yellow's two lines
    gap = _band(xyz, -0.03, 0.03)  # between them
    asphalt = _band(xyz, EDGE_Y_M + 0.3, -0.3)
    for band, surface in (
        (edge, Surface.PAINT_WHITE),
        (centre, Surface.PAINT_YELLOW),
        (gap, Surface.ASPHALT),
    ):
        assert band.sum() >= 20
        assert float(scan.reflectance[band].mean()) == pytest.approx(float(REFLECTANCE[surface]), abs=0.02)
    assert scan.reflectance[edge].mean() > scan.reflectance[asphalt].mean() + 0.3
    # the paint is a film on the road, not a step in it
    np.testing.assert_allclose(xyz[edge | asphalt, 2], 0.0, atol=0.005)


def test_a_curb_is_a_height_step_at_the_road_edge() -> None:
    lidar = UrbanLidar.build(_ring(scenery={"curb_height_m": 0.15}), **EXACT)
    xyz = _world_points(lidar, lidar.revolution(0.0))
    road = _band(xyz, EDGE_Y_M + 0.1, -0.3)
    face_y = EDGE_Y_M - 0.3
    sidewalk = _band(xyz, face_y - SIDEWALK_M + 0.05, face_y - 0.05)
    assert road.sum() > 100 and sidewalk.sum() > 100
    np.testing.assert_allclose(xyz[road, 2], 0.0, atol=0.005)
    np.testing.assert_allclose(xyz[sidewalk, 2], 0.15, atol=0.005)
    # the same on the far side of the street, along lane 1.2
    far = _band(xyz, -face_y + 0.05, -face_y + SIDEWALK_M - 0.05)
    assert far.sum() > 100
    np.testing.assert_allclose(xyz[far, 2], 0.15, atol=0.005)
    assert scan_has_face(xyz, face_y)


def scan_has_face(xyz: np.ndarray, face_y: float) -> bool:
    """Returns on the curb's vertical face: at its line, between the road and the curb's top."""
    on = _band(xyz, face_y - 0.01, face_y + 0.01, 0.0, 120.0) & (xyz[:, 2] > 0.01) & (xyz[:, 2] < 0.14)
    return bool(on.any())


def test_an_open_street_with_buildings_and_cars_gives_100_to_130k_points() -> None:
    buildings = [
        {"x_m": x, "y_m": side * 14.0, "length_m": 36.0, "width_m": 10.0, "height_m": 12.0}
        for x in (30.0, 70.0, 110.0, 150.0)
        for side in (-1.0, 1.0)
    ]
    parked = [{"name": f"p{i}", "driver": "parked", "x_m": 60.0 + 12 * i, "y_m": -3.0} for i in range(4)]
    lidar = UrbanLidar.build(
        _ring(start="1.1.3", vehicles=parked, scenery={"buildings": buildings, "curb_height_m": 0.12})
    )
    scan = lidar.revolution(0.0)
    assert 100_000 <= len(scan) <= 130_000
    xyz = _world_points(lidar, scan)
    walls = np.abs(np.abs(xyz[:, 1]) - 9.0) < 0.1
    assert walls.sum() > 5000 and set(scan.beam[walls].tolist()) >= set(range(7))
    on_cars = (np.abs(xyz[:, 1] + 3.0) < 0.85) & (xyz[:, 2] > 0.3) & (xyz[:, 2] < VEHICLE_HEIGHT_M + 0.05)
    assert on_cars.sum() > 500


def test_a_shipped_scenario_builds_and_casts_one_revolution() -> None:
    lidar = urban_lidar_for_scenario("pass_parked_car")
    scan = lidar.revolution(0.0)
    assert len(scan) >= 100_000 and scan.sensor_height_m == pytest.approx(1.73)
    assert scan.xyz_m.dtype == np.float32 and scan.beam.dtype == np.int16
    xyz = _world_points(lidar, scan)
    # the parked car, 88 m ahead: (100, -2), 4.5 x 1.8 m
    on_car = (np.abs(xyz[:, 0] - 100.0) < 2.3) & (np.abs(xyz[:, 1] + 2.0) < 0.95) & (xyz[:, 2] > 0.2)
    assert on_car.sum() >= 5


def test_moving_cars_are_where_the_world_has_them_at_each_revolution() -> None:
    bench = cast_benchmark("lane_change")
    car = bench.lidar.world.cars[0]
    seen = []
    for _ in range(3):
        bench.advance()
        scan = bench()
        xyz = _world_points(bench.lidar, scan)
        c, s = np.cos(car.heading_rad), np.sin(car.heading_rad)
        along = (xyz[:, 0] - car.x_m) * c + (xyz[:, 1] - car.y_m) * s
        across = -(xyz[:, 0] - car.x_m) * s + (xyz[:, 1] - car.y_m) * c
        seen.append(int(((np.abs(along) < 2.3) & (np.abs(across) < 0.95) & (xyz[:, 2] > 0.2)).sum()))
    assert bench.moving_triangles == 10 and bench.rays == 128_000 and bench.static_triangles > 1000
    assert min(seen) > 100
    assert car.x_m > bench.lidar.world.ego[0] + 1.0  # it drove on from beside us


def test_scenery_is_parsed_strictly() -> None:
    world = _ring(scenery={"buildings": [{"x_m": 1, "y_m": 2, "length_m": 3, "width_m": 4}]})
    b = world.spec.scenery.buildings[0]
    assert (b.height_m, b.heading_deg, world.spec.scenery.curb_height_m) == (10.0, 0.0, 0.0)
    base = {"rndf": "networks/ring.rndf", "mdf": "networks/ring_pass.mdf"}
    for scenery, path in (
        ({"walls": []}, "urban.scenery.walls"),
        ({"buildings": [{"x_m": 1}]}, "urban.scenery.buildings[0].y_m"),
        ({"curb_height_m": 2.0}, "urban.scenery.curb_height_m"),
        ({"buildings": {"x_m": 1}}, "urban.scenery.buildings"),
    ):
        with pytest.raises(UrbanSpecError) as err:
            parse_urban({**base, "scenery": scenery}, "lidar_test.yaml")
        assert err.value.path == path


def test_stop_bars_are_painted_and_intersections_are_not() -> None:
    lidar = urban_lidar_for_scenario("four_way_stop_0", range_noise_m=0.0)
    line = next(ln for ln in lidar.world.lines if ln.vertex == "1.1.4")  # (-8, -2), heading east
    lidar.world.ego = (line.x_m - 12.0, line.y_m, 0.0, 0.0, 0.0)
    scan = lidar.revolution(0.0)
    xyz = _world_points(lidar, scan)
    bar = _band(xyz, line.y_m - 1.5, line.y_m + 1.5, line.x_m - 0.4, line.x_m - 0.05)
    assert bar.sum() >= 20
    assert float(scan.reflectance[bar].mean()) == pytest.approx(
        float(REFLECTANCE[Surface.PAINT_WHITE]), abs=0.02
    )
    box = _band(xyz, -5.0, 5.0, -5.0, 5.0)
    assert box.sum() > 200 and float(scan.reflectance[box].max()) < 0.45
