"""The urban host's LIDAR modules on revolutions cast by the simulated Velodyne (`hil.lidar`), stepped by
hand on a private store: the perception finds the cars where the world has them, in the host's frame;
the lane offset finds a map that is 1.5 m off and says by how much, as a translation."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from module_harness import Harness

from bywire.hil.lidar.urban_scene import UrbanLidar
from bywire.hil.perception_eval import MATCH_M
from bywire.hil.scenario import load_scenario
from bywire.hil.world.urban import UrbanWorld
from bywire.host.modules.estimation.lane_offset import LaneOffsetModule, expected_markings
from bywire.host.modules.estimation.lidar_perception import LidarPerception
from bywire.host.modules.perception_messages import (
    LANE_OFFSET,
    PERCEPTION_OBSTACLES,
    PERCEPTION_SCAN,
    PerceptionScan,
)
from bywire.host.modules.urban_messages import URBAN_OBJECTS, URBAN_POSE, UrbanPose
from bywire.host.perception.scan import Scan
from bywire.host.roadnet.lane_index import LaneIndex


def _scan_msg(scan: Scan, t_s: float, k: int) -> PerceptionScan:
    return PerceptionScan(t_s, True, scan.stamp_s, scan.sensor_height_m, scan.xyz_m, scan.reflectance,
                          scan.beam.astype(np.uint8), k, 0)  # fmt: skip


def _pose(t_s: float, x: float, y: float, h: float, v: float) -> UrbanPose:
    return UrbanPose(t_s, True, t_s, x, y, h, v, 0.0, 0, 0)


def test_the_perception_finds_the_waiting_cars_where_they_stand() -> None:
    world = UrbanWorld(load_scenario("four_way_stop_2").urban, 1)  # type: ignore[arg-type]
    lidar = UrbanLidar.build(world, seed=3)
    x, y, h = world.ego[0] + 130.0, world.ego[1], world.ego[2]  # 20 m before the intersection
    world.ego = (x, y, h, 0.0, 0.0)
    h_mod = Harness("lidar_perception", LidarPerception())
    for k in range(6):
        t = 0.1 * k
        h_mod.publish(URBAN_POSE, _pose(t, x, y, h, 0.0))
        h_mod.publish(PERCEPTION_SCAN, _scan_msg(lidar.revolution(t), t, k))
        h_mod.step(t)
    objs = h_mod.latest(URBAN_OBJECTS)
    assert objs.valid and objs.stamp_s == 0.5
    cars = [c for c in world.cars if math.hypot(c.x_m - x, c.y_m - y) < 40.0]
    assert cars
    for c in cars:
        # a car seen from one side is the box of its visible faces: its centre lies up to half a car
        # length towards us (the evaluation's match distance, hil.perception_eval.MATCH_M)
        d = min(math.hypot(o.x_m - c.x_m, o.y_m - c.y_m) for o in objs.objects)
        assert d < MATCH_M, (c.name, d, objs.objects)
    assert all(o.object_id.startswith("t") and o.speed_mps == 0.0 for o in objs.objects)
    # the grid's obstacle cells go out too (the zone planner's map): some on every car, in the host's frame
    cells = h_mod.latest(PERCEPTION_OBSTACLES)
    assert cells.valid and cells.stamp_s == 0.5 and cells.xy_m.shape == (cells.size_m.shape[0], 2)
    for c in cars:
        near = np.hypot(cells.xy_m[:, 0] - c.x_m, cells.xy_m[:, 1] - c.y_m) < 0.5 * math.hypot(
            c.length_m, c.width_m
        )
        assert near.sum() >= 3, c.name


def test_the_lane_offset_finds_a_map_that_is_off_by_a_translation() -> None:
    world = UrbanWorld(load_scenario("rndf_offset").urban, 1)  # type: ignore[arg-type]
    world.cars.clear()
    lidar = UrbanLidar.build(world, seed=5)
    module = LaneOffsetModule(LaneIndex(world.graph))
    h_mod = Harness("lane_offset", module)
    y_true, offset_north = 0.0, 1.5
    for k in range(25):
        t = 0.1 * k
        x = 20.0 + 1.0 * k  # 10 m/s along lane 1.1, in the middle of the real lane
        world.ego = (x, y_true, 0.0, 10.0, 0.0)
        # the position fix is off from the map by the map's error: the host believes y = 1.5
        h_mod.publish(URBAN_POSE, _pose(t, x, y_true + offset_north, 0.0, 10.0))
        h_mod.publish(PERCEPTION_SCAN, _scan_msg(lidar.revolution(t), t, k))
        h_mod.step(t)
    est = h_mod.latest(LANE_OFFSET)
    assert est.valid
    assert abs(est.north_m - offset_north) < 0.3 and abs(est.east_m) < 1e-6
    assert est.correction() == (est.east_m, est.north_m)


def test_the_lane_offset_expects_the_markings_where_the_map_puts_them() -> None:
    """cross.rndf's lane centres lie 4 m apart for 12 ft lanes: the line between them is 2 m from each
    centre, not half a width (1.83 m). Expected where the map puts it, a map that is right reads ~0;
    expected as abutting lanes, it read that 0.17 m as the map's error."""
    world = UrbanWorld(load_scenario("four_way_stop_0").urban, 1)  # type: ignore[arg-type]
    world.cars.clear()
    lidar = UrbanLidar.build(world, seed=5)
    index = LaneIndex(world.graph)
    lane = index.match(-120.0, -2.0, 0.0)
    assert lane is not None
    assert expected_markings(index, lane.edge, lane.s_m, 3.6576) == pytest.approx((-1.8288, 2.0, 5.8288))
    module = LaneOffsetModule(index)
    h_mod = Harness("lane_offset", module)
    for k in range(25):
        t = 0.1 * k
        x = -140.0 + 1.0 * k  # 10 m/s along lane 1.1, on its centre, the map right
        world.ego = (x, -2.0, 0.0, 10.0, 0.0)
        h_mod.publish(URBAN_POSE, _pose(t, x, -2.0, 0.0, 10.0))
        h_mod.publish(PERCEPTION_SCAN, _scan_msg(lidar.revolution(t), t, k))
        h_mod.step(t)
    est = h_mod.latest(LANE_OFFSET)
    assert est.valid and abs(est.estimate_m) < 0.06, est


def test_the_sensor_process_casts_what_the_plant_snapshots_and_sends_it_to_the_host() -> None:
    """HIL's sensor: a process of its own, fed the stamp, our pose and the moving cars; the host reads
    whole revolutions off the scan link, stamped as the plant asked."""
    from bywire.hil.lidar.sensor_link import LidarProcess
    from bywire.hil.lidar.wire import decode_scan
    from bywire.hil.runner import free_port
    from bywire.protocol.lidar.scan_link import open_scan_link

    spec = load_scenario("four_way_stop_1").urban
    assert spec is not None
    world = UrbanWorld(spec, 1)
    url = f"tcp://127.0.0.1:{free_port()}"
    host = open_scan_link(url, receiver=True)
    sensor = LidarProcess(spec, 1, url)
    try:
        got = []
        for k in range(200):
            t = 0.1 * k
            if sensor.due(t):
                sensor.revolution(world, t)
            got += [decode_scan(m) for m in host.receive()]
            if len(got) >= 3:
                break
            time.sleep(0.1)
        assert len(got) >= 3
        assert [s.stamp_s for s in got] == sorted(s.stamp_s for s in got)
        assert all(len(s) > 50_000 for s in got)
    finally:
        summary = sensor.summary()
        host.close()
    assert summary["revolutions"] >= 3 and summary["points_per_revolution"] > 50_000
