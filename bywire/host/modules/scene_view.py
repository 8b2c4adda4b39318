"""The urban host's world as a Foxglove 3D scene: what the perception made of the LIDAR (seed 000 Secs. 4-5:
the occupancy grid's obstacle cells, the tracked objects), the revolution's points, our car and the
stub the behaviour drives, in Foxglove's own schemas (`SceneUpdate`, `PointCloud`, `FrameTransform`), so
that its 3D panel shows them as they are, live or from a recording.

One converter (`SceneConverter`), two sinks: the host's live view (`bywire host run --live-view PORT`
publishes these beside every topic) and `bywire log scene RUN.mcap -o SCENE.mcap` (a recording's scene,
opened beside the recording itself). Frames:

- `map`: the position fix's east/north frame, metres (the poses, cells and tracks are given in it);
- `base_link`: our pose's reference point (the rear axle's centre), x forward, from `/urban/pose`;
- `lidar`: the sensor, `sensor_height_m` above `base_link` (the points of `/perception/scan`).

A revolution is placed with the newest pose at hand, not one interpolated to its stamp (at 10 m/s the
points of one revolution are up to 1 m apart anyway: a view, not a measurement). The converter keeps only
that pose. Not from the papers: the field's viewer, shown what the papers' figures 5-8 show.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from bywire.host.modules.perception_messages import (
    PERCEPTION_OBSTACLES,
    PERCEPTION_SCAN,
    ObstacleCells,
    PerceptionScan,
)
from bywire.host.modules.urban_messages import (
    URBAN_OBJECTS,
    URBAN_PLAN,
    URBAN_POSE,
    UrbanObjects,
    UrbanPlan,
    UrbanPose,
)

__all__ = ["SCENE_TOPICS", "SOURCE_TOPICS", "SceneConverter"]

SCENE_OBSTACLES = "/scene/obstacles"
SCENE_TRACKS = "/scene/tracks"
SCENE_EGO = "/scene/ego"
SCENE_PATH = "/scene/path"
SCENE_SCAN = "/scene/scan"
SCENE_TF = "/scene/tf"
SCENE_TOPICS = (SCENE_OBSTACLES, SCENE_TRACKS, SCENE_EGO, SCENE_PATH, SCENE_SCAN, SCENE_TF)
SOURCE_TOPICS = (PERCEPTION_OBSTACLES, PERCEPTION_SCAN, URBAN_OBJECTS, URBAN_PLAN, URBAN_POSE)

CELL_HEIGHT_M = 0.5
TRACK_HEIGHT_M = 1.5
EGO_LENGTH_M = 4.77  # the Passat's outline, for the picture only
EGO_WIDTH_M = 1.82
EGO_REAR_OVERHANG_M = 1.1
MOVING_MPS = 0.5

_OBSTACLE_RGBA = (0.9, 0.3, 0.1, 0.8)
_MOVING_RGBA = (0.1, 0.5, 1.0, 0.6)
_STILL_RGBA = (0.6, 0.6, 0.6, 0.6)
_EGO_RGBA = (0.1, 0.8, 0.2, 0.7)
_PATH_RGBA = (1.0, 0.9, 0.1, 1.0)


def _fm() -> Any:
    import foxglove.messages as fm  # the live extra: imported where a scene is made

    return fm


def _stamp(fm: Any, t_s: float) -> Any:
    ns = max(round(t_s * 1e9), 0)
    return fm.Timestamp(sec=ns // 1_000_000_000, nsec=ns % 1_000_000_000)


def _yaw(fm: Any, heading_rad: float) -> Any:
    return fm.Quaternion(x=0.0, y=0.0, z=math.sin(0.5 * heading_rad), w=math.cos(0.5 * heading_rad))


def _pose(fm: Any, x: float, y: float, z: float, heading_rad: float = 0.0) -> Any:
    return fm.Pose(position=fm.Vector3(x=x, y=y, z=z), orientation=_yaw(fm, heading_rad))


def _color(fm: Any, rgba: tuple[float, float, float, float]) -> Any:
    return fm.Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])


class SceneConverter:
    """Host objects in, Foxglove scene messages out (see the module docstring)."""

    def __init__(self) -> None:
        self.fm = _fm()
        self._pose: UrbanPose | None = None

    def convert(self, topic: str, obj: object) -> list[tuple[str, Any]]:
        """The scene messages `obj` (published on `topic`) makes, as (scene topic, message); none for
        what the scene does not show or for an invalid object."""
        if not getattr(obj, "valid", False):
            return []
        if topic == URBAN_POSE and isinstance(obj, UrbanPose):
            self._pose = obj
            return self._ego(obj)
        if topic == PERCEPTION_OBSTACLES and isinstance(obj, ObstacleCells):
            return [(SCENE_OBSTACLES, self._cells(obj))]
        if topic == URBAN_OBJECTS and isinstance(obj, UrbanObjects):
            return [(SCENE_TRACKS, self._tracks(obj))]
        if topic == URBAN_PLAN and isinstance(obj, UrbanPlan):
            return [(SCENE_PATH, self._path(obj))]
        if topic == PERCEPTION_SCAN and isinstance(obj, PerceptionScan):
            return self._scan(obj)
        return []

    def _entity(self, t_s: float, frame: str, entity_id: str, **primitives: Any) -> Any:
        fm = self.fm
        return fm.SceneUpdate(
            entities=[fm.SceneEntity(timestamp=_stamp(fm, t_s), frame_id=frame, id=entity_id, **primitives)]
        )

    def _ego(self, pose: UrbanPose) -> list[tuple[str, Any]]:
        fm = self.fm
        centre = 0.5 * EGO_LENGTH_M - EGO_REAR_OVERHANG_M  # ahead of the rear axle
        tf = fm.FrameTransform(
            timestamp=_stamp(fm, pose.t_s), parent_frame_id="map", child_frame_id="base_link",
            translation=fm.Vector3(x=pose.x_m, y=pose.y_m, z=0.0), rotation=_yaw(fm, pose.heading_rad),
        )  # fmt: skip
        car = fm.CubePrimitive(
            pose=_pose(fm, centre, 0.0, 0.75),
            size=fm.Vector3(x=EGO_LENGTH_M, y=EGO_WIDTH_M, z=1.5),
            color=_color(fm, _EGO_RGBA),
        )
        return [(SCENE_TF, tf), (SCENE_EGO, self._entity(pose.t_s, "base_link", "ego", cubes=[car]))]

    def _cells(self, cells: ObstacleCells) -> Any:
        fm = self.fm
        color = _color(fm, _OBSTACLE_RGBA)
        cubes = [
            fm.CubePrimitive(
                pose=_pose(fm, float(x), float(y), 0.5 * CELL_HEIGHT_M),
                size=fm.Vector3(x=float(sz), y=float(sz), z=CELL_HEIGHT_M),
                color=color,
            )
            for (x, y), sz in zip(np.asarray(cells.xy_m), np.asarray(cells.size_m), strict=True)
        ]
        return self._entity(cells.t_s, "map", "obstacle_cells", cubes=cubes)

    def _tracks(self, objects: UrbanObjects) -> Any:
        fm = self.fm
        cubes, texts = [], []
        for o in objects.objects:
            rgba = _MOVING_RGBA if abs(o.speed_mps) >= MOVING_MPS else _STILL_RGBA
            cubes.append(
                fm.CubePrimitive(
                    pose=_pose(fm, o.x_m, o.y_m, 0.5 * TRACK_HEIGHT_M, o.heading_rad),
                    size=fm.Vector3(x=o.length_m, y=o.width_m, z=TRACK_HEIGHT_M),
                    color=_color(fm, rgba),
                )
            )
            texts.append(
                fm.TextPrimitive(
                    pose=_pose(fm, o.x_m, o.y_m, TRACK_HEIGHT_M + 0.5), billboard=True, font_size=14.0,
                    scale_invariant=True, color=_color(fm, (1.0, 1.0, 1.0, 1.0)),
                    text=f"{o.object_id} {o.speed_mps:.1f} m/s",
                )
            )  # fmt: skip
        return self._entity(objects.t_s, "map", "tracks", cubes=cubes, texts=texts)

    def _path(self, plan: UrbanPlan) -> Any:
        fm = self.fm
        points = [fm.Point3(x=x, y=y, z=0.05) for x, y in zip(plan.stub_x_m, plan.stub_y_m, strict=True)]
        line = fm.LinePrimitive(
            type=fm.LinePrimitiveLineType.LineStrip, pose=_pose(fm, 0.0, 0.0, 0.0), thickness=0.15,
            points=points, color=_color(fm, _PATH_RGBA),
        )  # fmt: skip
        return self._entity(plan.t_s, "map", "stub", lines=[line] if len(points) >= 2 else [])

    def _scan(self, scan: PerceptionScan) -> list[tuple[str, Any]]:
        fm = self.fm
        xyz = np.asarray(scan.xyz_m, dtype=np.float32).reshape(-1, 3)
        refl = np.asarray(scan.reflectance, dtype=np.float32).reshape(-1, 1)
        data = np.hstack((xyz, refl)).astype("<f4").tobytes()
        f32 = fm.PackedElementFieldNumericType.Float32
        fields = [fm.PackedElementField(name=n, offset=4 * i, type=f32) for i, n in enumerate("xyz")]
        fields.append(fm.PackedElementField(name="reflectance", offset=12, type=f32))
        cloud = fm.PointCloud(
            timestamp=_stamp(fm, scan.t_s), frame_id="lidar", pose=_pose(fm, 0.0, 0.0, 0.0),
            point_stride=16, fields=fields, data=data,
        )  # fmt: skip
        mount = fm.FrameTransform(
            timestamp=_stamp(fm, scan.t_s), parent_frame_id="base_link", child_frame_id="lidar",
            translation=fm.Vector3(x=0.0, y=0.0, z=scan.sensor_height_m), rotation=_yaw(fm, 0.0),
        )  # fmt: skip
        return [(SCENE_TF, mount), (SCENE_SCAN, cloud)]
