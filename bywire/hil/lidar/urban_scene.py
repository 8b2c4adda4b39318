"""The urban world (`hil.world.urban`) as the simulated Velodyne sees it (seed 000 Sec. 4 and 6).

Static, built once per scenario (`urban_static_mesh`): the ground plane (level, or on a constant
grade given as a `Ground`) reaching `GROUND_MARGIN_M` past everything in the network, so that every
beam pointing down lands within range; the lane paint, stop bars and curbs (`road_marks`); the
scenario's buildings (`urban.scenery`); and the cars that never move (`parked`, `stuck`), as
oriented boxes `VEHICLE_HEIGHT_M` high. Per revolution (`UrbanLidar.revolution`): the cars that
drive (`lane`), as boxes where the world has them now, and our pose from the world's ego (its rear
axle, standing on the ground).

Deviation: cars are boxes down to the road (no wheels, no ground clearance, no windows).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from bywire.hil.lidar.mesh import Ground, Mesh, Surface, box_mesh
from bywire.hil.lidar.road_marks import road_marks_mesh
from bywire.hil.lidar.scene import LidarScene
from bywire.hil.lidar.velodyne import MAX_RANGE_M, EgoPose, SimulatedVelodyne
from bywire.hil.scenario import load_scenario
from bywire.hil.world.urban import Car, UrbanWorld
from bywire.host.perception.scan import Scan
from bywire.host.roadnet.graph import EdgeKind

VEHICLE_HEIGHT_M = 1.5  # a saloon's roof; the Passat's is 1.47 m
GROUND_MARGIN_M = MAX_RANGE_M + 10.0
GROUND_TILE_M = 50.0
STANDING_DRIVERS = ("parked", "stuck")


def vehicle_mesh(ground: Ground, car: Car) -> Mesh:
    return box_mesh(
        ground,
        car.x_m,
        car.y_m,
        car.heading_rad,
        car.length_m,
        car.width_m,
        VEHICLE_HEIGHT_M,
        Surface.VEHICLE,
    )


def _extent(world: UrbanWorld) -> tuple[float, float, float, float]:
    """x min, x max, y min, y max of the lanes, exits, cars, buildings and our start."""
    pts = [np.array([world.start[:2]])]
    for edge in world.graph.edges((EdgeKind.LANE, EdgeKind.EXIT)):
        pts.append(edge.path.xy)
    pts.append(np.array([[c.x_m, c.y_m] for c in world.cars]).reshape(-1, 2))
    pts.append(np.array([[b.x_m, b.y_m] for b in world.spec.scenery.buildings]).reshape(-1, 2))
    xy = np.concatenate(pts)
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    return float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1])


def urban_static_mesh(world: UrbanWorld, ground: Ground, margin_m: float = GROUND_MARGIN_M) -> Mesh:
    """Everything of the world's that does not move, on `ground` (see the module docstring)."""
    x0, x1, y0, y1 = _extent(world)
    scenery = world.spec.scenery
    parts = [
        ground.mesh(x0 - margin_m, x1 + margin_m, y0 - margin_m, y1 + margin_m, GROUND_TILE_M),
        road_marks_mesh(world.graph, ground, scenery.curb_height_m),
    ]
    for b in scenery.buildings:
        parts.append(
            box_mesh(
                ground,
                b.x_m,
                b.y_m,
                math.radians(b.heading_deg),
                b.length_m,
                b.width_m,
                b.height_m,
                Surface.BUILDING,
            )
        )
    parts += [vehicle_mesh(ground, c) for c in world.cars if c.spec.driver in STANDING_DRIVERS]
    return Mesh.concat(parts)


def moving_vehicle_meshes(world: UrbanWorld, ground: Ground) -> list[Mesh]:
    return [vehicle_mesh(ground, c) for c in moving_cars(world.cars)]


def moving_cars(cars: Iterable[Car]) -> list[Car]:
    """The cars cast every revolution: the traffic, and what appears later (not in the static scene)."""
    return [c for c in cars if c.spec.driver not in STANDING_DRIVERS or c.spec.appears_ahead_m > 0.0]


@dataclass
class UrbanLidar:
    """A simulated Velodyne in an urban world: `revolution(t)` scans from where the world has our car
    and the traffic now. `sensor` holds the sensor's settings (`SimulatedVelodyne`)."""

    world: UrbanWorld
    scene: LidarScene
    sensor: SimulatedVelodyne

    @classmethod
    def build(cls, world: UrbanWorld, ground: Ground | None = None, **sensor: Any) -> UrbanLidar:
        """Scene and sensor for `world`; `sensor` are `SimulatedVelodyne`'s keyword arguments."""
        ground = ground if ground is not None else Ground()
        scene = LidarScene(urban_static_mesh(world, ground), ground)
        return cls(world, scene, SimulatedVelodyne(scene, **sensor))

    def ego_pose(self) -> EgoPose:
        x, y, heading = self.world.ego[0], self.world.ego[1], self.world.ego[2]
        return EgoPose.on_ground(self.scene.ground, x, y, heading)

    def update_moving(self) -> None:
        self.scene.set_moving(moving_vehicle_meshes(self.world, self.scene.ground))

    def revolution(self, stamp_s: float) -> Scan:
        """One revolution at the world's present state, stamped `stamp_s`."""
        self.update_moving()
        return self.sensor.scan(self.ego_pose(), stamp_s)


def urban_lidar_for_scenario(name_or_file: str, seed: int = 1, **sensor: Any) -> UrbanLidar:
    """The world of a shipped (bare name) or any urban scenario at its start, with its sensor."""
    scenario = load_scenario(name_or_file)
    if scenario.urban is None:
        raise ValueError(f"{name_or_file}: not an urban scenario (no urban: section)")
    sensor.setdefault("seed", seed)
    return UrbanLidar.build(UrbanWorld(scenario.urban, seed), **sensor)


__all__ = [
    "VEHICLE_HEIGHT_M",
    "UrbanLidar",
    "moving_cars",
    "moving_vehicle_meshes",
    "urban_lidar_for_scenario",
    "urban_static_mesh",
    "vehicle_mesh",
]
