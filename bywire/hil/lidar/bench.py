"""One simulated revolution as a callable, for `benchmarks/perception.py` to time.

`cast_benchmark(scenario)` builds the scenario's world and scene once (not timed: a scenario's
static scene is built at its start) and returns a `CastBench`: each call moves the traffic one
revolution on, sets the moving cars and casts one revolution from our car's start pose. The world
is stepped with our car standing, so the cars drive past it as the scenario has them.
"""

from __future__ import annotations

from dataclasses import dataclass

from bywire.hil.lidar.urban_scene import UrbanLidar, urban_lidar_for_scenario
from bywire.hil.lidar.velodyne import DEFAULT_AZIMUTH_STEPS
from bywire.host.perception.scan import HDL64E_REVOLUTION_S, Scan

DEFAULT_SCENARIO = "lane_change"  # a car overtaking beside ours: a moving box in range all along


@dataclass
class CastBench:
    """Call it for one revolution's `Scan`; `rays` and the triangle counts describe what it casts."""

    scenario: str
    lidar: UrbanLidar
    t_s: float = 0.0

    @property
    def rays(self) -> int:
        return self.lidar.sensor.rays

    @property
    def static_triangles(self) -> int:
        return self.lidar.scene.static_triangles

    @property
    def moving_triangles(self) -> int:
        return self.lidar.scene.moving_triangles

    def __call__(self) -> Scan:
        self.t_s += HDL64E_REVOLUTION_S
        world = self.lidar.world
        # the FMU's frame: our car stands at its origin, which the world places on the start waypoint
        world.step(self.t_s, 0.0, 0.0, 0.0, 0.0, 0.0)
        return self.lidar.revolution(self.t_s)


def cast_benchmark(
    scenario: str = DEFAULT_SCENARIO, azimuth_steps: int = DEFAULT_AZIMUTH_STEPS, seed: int = 1
) -> CastBench:
    """The scenario's scene, built; each call of the result casts one revolution (see the module)."""
    return CastBench(scenario, urban_lidar_for_scenario(scenario, seed=seed, azimuth_steps=azimuth_steps))


__all__ = ["DEFAULT_SCENARIO", "CastBench", "cast_benchmark"]
