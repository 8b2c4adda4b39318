"""Topics and objects of the urban host's LIDAR perception (seed 000 sections 4-6): the revolutions off the
sensor link, what the perception made of each, and the map's lateral offset from the lane markings.

Every object is a frozen dataclass with `t_s` (the publishing module's release time on the runtime clock)
and a `valid` flag, registered for MCAP recording and replay. The tracked objects themselves go out on
`/urban/objects` (`urban_messages.UrbanObjects`), where the behaviour reads them whoever made them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from bywire.host.runtime.log_schema import register_type

PERCEPTION_SCAN = "/perception/scan"
PERCEPTION_STATUS = "/perception/status"
PERCEPTION_OBSTACLES = "/perception/obstacles"
LANE_OFFSET = "/urban/lane_offset"


@register_type
@dataclass(frozen=True)
class PerceptionScan:
    """The newest revolution as the sensor sent it (`protocol.lidar.scan_message`): points in the sensor
    frame (x forward, y left, z up; metres), reflectance 0..1, laser row (0 = highest), stamped with the
    revolution's time on the scenario's clock. Recorded whole: a recording replays the perception."""

    t_s: float
    valid: bool
    stamp_s: float
    sensor_height_m: float
    xyz_m: np.ndarray = field(compare=False)  # (n, 3) float32
    reflectance: np.ndarray = field(compare=False)  # (n,) float32
    beam: np.ndarray = field(compare=False)  # (n,) uint8
    received: int  # revolutions so far
    rejected: int  # messages the decoder refused so far


@register_type
@dataclass(frozen=True)
class PerceptionStatus:
    """What one perception frame found: obstacle cells of the grid, segmented objects, tracks (all and
    published), and the frame's scan stamp (nan: no scan yet)."""

    t_s: float
    valid: bool
    stamp_s: float
    points: int
    obstacle_cells: int
    segments: int
    tracks: int
    published: int
    moving: int


@register_type
@dataclass(frozen=True)
class ObstacleCells:
    """The occupancy grid's obstacle cells of one perception frame (seed 000 Sec. 4, eqs. 1-5): each cell's
    centre in the position fix's frame and its size, metres. What the zone planner's map is built from
    on LIDAR (seed 000 Sec. 10.1: "an obstacle map obtained from a 360-deg laser range scanner"): a wall,
    and the whole outline of a car seen from one side, which no track's box holds."""

    t_s: float
    valid: bool
    stamp_s: float
    xy_m: np.ndarray = field(compare=False)  # (k, 2) float32
    size_m: np.ndarray = field(compare=False)  # (k,) float32


@register_type
@dataclass(frozen=True)
class LaneOffsetEstimate:
    """The map lane's lateral offset from the observed markings (`perception.lane_offset`) as applied:
    positive, the real lane lies to the left of the map's (0 below the module's smallest correction;
    `estimate_m` the filter's value); as a vector (`east_m`, `north_m`), what to subtract from positions
    in the position fix's frame to put them on the map. `valid` only while the filter is sure."""

    t_s: float
    valid: bool
    stamp_s: float
    offset_m: float
    sigma_m: float
    measured: bool  # this revolution gave an accepted measurement
    east_m: float
    north_m: float
    estimate_m: float

    def correction(self) -> tuple[float, float]:
        """(east, north) to subtract from a position: nothing unless valid."""
        return (self.east_m, self.north_m) if self.valid else (0.0, 0.0)
