"""One simulated revolution as a callable, for `benchmarks/perception.py` to time.

`cast_benchmark(scenario)` builds the scenario's world and scene once (not timed: a scenario's
static scene is built at its start) and returns a `CastBench`. Each call is what the simulator pays
per revolution for its LIDAR: the moving cars set where the world has them, one revolution cast
from our car's pose, noise and all. `advance()` moves the world one revolution on (our car standing
at its start, the traffic driving as the scenario has it): traffic simulation, not LIDAR, so it is
outside the call and a benchmark leaves it out of its clock.
"""

from __future__ import annotations

from dataclasses import dataclass

from bywire.hil.lidar.urban_scene import UrbanLidar, urban_lidar_for_scenario
from bywire.hil.lidar.velodyne import DEFAULT_AZIMUTH_STEPS
from bywire.host.perception.scan import HDL64E_REVOLUTION_S, Scan

DEFAULT_SCENARIO = "lane_change"  # a car overtaking beside ours: a moving box in range all along


@dataclass
class CastBench:
    """Call it for one revolution's `Scan`, `advance()` between calls to move the traffic on; `rays` and
    the triangle counts describe what it casts."""

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
        return self.lidar.revolution(self.t_s)

    def advance(self) -> None:
        self.t_s += HDL64E_REVOLUTION_S
        # the FMU's frame: our car stands at its origin, which the world places on the start waypoint
        self.lidar.world.step(self.t_s, 0.0, 0.0, 0.0, 0.0, 0.0)


def cast_benchmark(
    scenario: str = DEFAULT_SCENARIO, azimuth_steps: int = DEFAULT_AZIMUTH_STEPS, seed: int = 1
) -> CastBench:
    """The scenario's scene, built; each call of the result casts one revolution (see the module)."""
    return CastBench(scenario, urban_lidar_for_scenario(scenario, seed=seed, azimuth_steps=azimuth_steps))


__all__ = ["DEFAULT_SCENARIO", "CastBench", "cast_benchmark"]
