"""The urban host's LIDAR perception (seed 000 sections 4-5) as a module: each new revolution into the
occupancy grid at the sensor's pose, the grid's obstacle cells segmented into objects, the objects that
have a road user's shape tracked, and the published tracks out as the object list the behaviour reads
(`/urban/objects`, the same topic and type the perfect object link fills); the grid's obstacle cells go
out too (`/perception/obstacles`: the zone planner's map).

The sensor's pose is the rear axle's (the pose link's) moved to the scan's stamp with its speed and yaw
rate, then forward by the roof mount (`sensor_forward_m`); the revolution itself is taken as seen from
that one pose (the simulated sensor casts it so; the paper also de-skews the sweep, Sec. 4).

A track's heading: its velocity's direction while it moves, and once it stands the box orientation
nearest the last heading it moved with (a box has no front). A track never seen moving has only its box
orientation; the behaviour matches such an object to a lane either way round.

Pure: the same revolutions and poses give the same objects, so a recording replays exactly.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from bywire.host.modules.module_params import integer, number, refuse_unknown
from bywire.host.modules.perception_messages import (
    PERCEPTION_OBSTACLES,
    PERCEPTION_SCAN,
    PERCEPTION_STATUS,
    ObstacleCells,
    PerceptionScan,
    PerceptionStatus,
)
from bywire.host.modules.planning.urban_behaviour import extrapolate
from bywire.host.modules.urban_messages import (
    URBAN_OBJECTS,
    URBAN_POSE,
    UrbanObject,
    UrbanObjects,
    UrbanPose,
)
from bywire.host.perception.ego_pose import EgoPose
from bywire.host.perception.grid import OccupancyGrid, warm_up
from bywire.host.perception.scan import Scan
from bywire.host.perception.segmentation import ParticipantShape, SegmentationParams, segment
from bywire.host.perception.tracker import Detection, Track, Tracker, TrackerParams
from bywire.host.runtime.module import Module, ModuleContext

SENSOR_FORWARD_M = 1.36  # the roof mount ahead of the rear axle (hil.lidar.velodyne.MOUNT_FORWARD_M)
# A pose older than this at the scan's stamp is no pose for it: the frame waits for a fresh one.
MAX_POSE_AGE_S = 0.2


def sensor_pose(pose: UrbanPose, stamp_s: float, forward_m: float) -> EgoPose:
    """The sensor's pose at `stamp_s` from the rear axle's pose (moved with its speed and yaw rate)."""
    x, y, h = extrapolate(pose, stamp_s - pose.stamp_s)
    return EgoPose(x + forward_m * math.cos(h), y + forward_m * math.sin(h), h)


def scan_of(msg: PerceptionScan) -> Scan:
    """The revolution of a `/perception/scan` message, as the perception's functions take it."""
    return Scan(msg.xyz_m, msg.reflectance, msg.beam, msg.stamp_s, msg.sensor_height_m)


def _flip_towards(yaw_rad: float, reference_rad: float) -> float:
    """`yaw_rad` or `yaw_rad + pi`, whichever is nearer `reference_rad`."""
    d = math.remainder(yaw_rad - reference_rad, 2.0 * math.pi)
    return yaw_rad if abs(d) <= math.pi / 2 else math.remainder(yaw_rad + math.pi, 2.0 * math.pi)


class LidarPerception(Module):
    """Grid, segmentation and tracking on the newest revolution (see the module docstring)."""

    def __init__(self, params: Mapping[str, Any] | None = None) -> None:
        params = dict(params or {})
        kind = "lidar_perception"
        refuse_unknown(kind, params, ("sensor_forward_m", "join_distance_m", "min_cells"))
        self.forward_m = number(kind, params, "sensor_forward_m", SENSOR_FORWARD_M, -10.0, 10.0)
        self.grid = OccupancyGrid()
        self.segmentation = SegmentationParams(
            join_distance_m=number(kind, params, "join_distance_m", 0.5, 0.0, 10.0),
            min_cells=integer(kind, params, "min_cells", 3, 1, 10_000),
        )
        self.shape = ParticipantShape()
        # A car waiting at a stop line, hidden by one crossing between us: 3 s before it is given up.
        self.tracker = Tracker(TrackerParams(standing_miss_loss=0.1, standing_max_misses=30))
        self._stamp_s = math.nan
        self._headings: dict[int, float] = {}
        self._objects: UrbanObjects | None = None
        self._status: PerceptionStatus | None = None
        self._cells: ObstacleCells | None = None

    def start(self, ctx: ModuleContext) -> None:
        warm_up()  # the grid's compiled kernels: about a second, before the first release

    def step(self, ctx: ModuleContext) -> None:
        now = ctx.now_s
        scan: PerceptionScan | None = ctx.latest(PERCEPTION_SCAN)
        pose: UrbanPose | None = ctx.latest(URBAN_POSE)
        fresh = scan is not None and scan.valid and not scan.stamp_s <= self._stamp_s
        if (
            fresh
            and scan is not None
            and pose is not None
            and pose.valid
            and abs(scan.stamp_s - pose.stamp_s) <= MAX_POSE_AGE_S
        ):
            self._frame(now, scan, pose)
        objects = self._objects or UrbanObjects(now, False, math.nan, ())
        ctx.publish(URBAN_OBJECTS, UrbanObjects(now, objects.valid, objects.stamp_s, objects.objects))
        cells, self._cells = self._cells, None
        if cells is not None:  # once per frame: a few thousand cells, recorded
            ctx.publish(
                PERCEPTION_OBSTACLES, ObstacleCells(now, True, cells.stamp_s, cells.xy_m, cells.size_m)
            )
        status = self._status or PerceptionStatus(now, False, math.nan, 0, 0, 0, 0, 0, 0)
        ctx.publish(
            PERCEPTION_STATUS,
            PerceptionStatus(now, status.valid, status.stamp_s, status.points, status.obstacle_cells,
                             status.segments, status.tracks, status.published, status.moving),
        )  # fmt: skip

    def _frame(self, now: float, msg: PerceptionScan, pose: UrbanPose) -> None:
        self._stamp_s = msg.stamp_s
        scan = scan_of(msg)
        self.grid.update(scan, sensor_pose(pose, msg.stamp_s, self.forward_m))
        seg = segment(self.grid.snapshot(), self.segmentation)
        self._cells = ObstacleCells(
            now, True, msg.stamp_s, seg.cells.xy_m.astype(np.float32), seg.cells.size_m.astype(np.float32)
        )
        found = [o for o in seg.objects if self.shape.accepts(o)]
        detections = [Detection(o.x_m, o.y_m, o.length_m, o.width_m, o.yaw_rad) for o in found]
        tracks = self.tracker.update(detections, msg.stamp_s)
        alive = {t.id for t in self.tracker.all_tracks()}
        self._headings = {k: v for k, v in self._headings.items() if k in alive}
        objects = tuple(self._object(t) for t in tracks)
        self._objects = UrbanObjects(now, True, msg.stamp_s, objects)
        self._status = PerceptionStatus(
            now,
            True,
            msg.stamp_s,
            len(scan),
            len(seg.cells),
            len(found),
            len(self.tracker),
            len(tracks),
            sum(1 for t in tracks if t.moving),
        )

    def _object(self, t: Track) -> UrbanObject:
        if t.moving:
            heading = math.atan2(t.vy_mps, t.vx_mps)
            self._headings[t.id] = heading
            speed = t.speed_mps
        else:
            last = self._headings.get(t.id)
            heading = t.yaw_rad if last is None else _flip_towards(t.yaw_rad, last)
            speed = 0.0
        return UrbanObject(f"t{t.id}", t.x_m, t.y_m, heading, speed, max(t.length_m, 0.5),
                           max(t.width_m, 0.5))  # fmt: skip


__all__ = ["LidarPerception", "scan_of", "sensor_pose"]
