"""The urban host's world as a Foxglove 3D scene: each message decodes, with the schema Foxglove is given,
into what the host published (protobuf from the message's own FileDescriptorSet: an independent reader).
The recording's `bywire log scene` and the live view carry the same messages."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

from bywire.host.modules.perception_messages import (
    PERCEPTION_OBSTACLES,
    PERCEPTION_SCAN,
    ObstacleCells,
    PerceptionScan,
)
from bywire.host.modules.scene_view import SceneConverter
from bywire.host.modules.urban_messages import (
    URBAN_OBJECTS,
    URBAN_PLAN,
    URBAN_POSE,
    UrbanObject,
    UrbanObjects,
    UrbanPlan,
    UrbanPose,
)


def decode(msg: Any) -> Any:
    schema = msg.get_schema()
    pool = descriptor_pool.DescriptorPool()
    for f in descriptor_pb2.FileDescriptorSet.FromString(schema.data).file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name)).FromString(msg.encode())


def pose(t: float = 1.5, valid: bool = True) -> UrbanPose:
    return UrbanPose(t, valid, t, 10.0, -5.0, math.pi / 2, 3.0, 0.0, 1, 0)


def test_the_pose_places_our_car_in_the_map() -> None:
    (tf_topic, tf), (ego_topic, ego) = SceneConverter().convert(URBAN_POSE, pose())
    assert (tf_topic, ego_topic) == ("/scene/tf", "/scene/ego")
    t = decode(tf)
    assert (t.parent_frame_id, t.child_frame_id) == ("map", "base_link")
    assert (t.translation.x, t.translation.y) == (10.0, -5.0)
    assert 2.0 * math.atan2(t.rotation.z, t.rotation.w) == pytest.approx(math.pi / 2)
    assert t.timestamp.seconds == 1 and t.timestamp.nanos == 500_000_000
    e = decode(ego).entities[0]
    assert e.frame_id == "base_link" and len(e.cubes) == 1 and e.cubes[0].size.x == pytest.approx(4.77)


def test_tracks_cells_and_the_path_are_where_the_host_has_them() -> None:
    conv = SceneConverter()
    objs = UrbanObjects(
        2.0, True, 2.0,
        (UrbanObject("t1", 5.0, 6.0, 0.3, 4.0, 4.5, 1.8), UrbanObject("t2", -3.0, 1.0, 0.0, 0.0, 1.0, 0.6)),
    )  # fmt: skip
    ((topic, tracks),) = conv.convert(URBAN_OBJECTS, objs)
    e = decode(tracks).entities[0]
    assert topic == "/scene/tracks" and e.frame_id == "map" and len(e.cubes) == 2 == len(e.texts)
    c = e.cubes[0]
    assert (c.pose.position.x, c.pose.position.y, c.size.x, c.size.y) == (5.0, 6.0, 4.5, 1.8)
    assert 2.0 * math.atan2(c.pose.orientation.z, c.pose.orientation.w) == pytest.approx(0.3)
    assert c.color.b > c.color.r and e.cubes[1].color.r == e.cubes[1].color.b  # moving blue, still grey
    assert e.texts[0].text.startswith("t1 4.0")
    cells = ObstacleCells(
        2.0, True, 2.0, np.array([[1.0, 2.0], [3.0, 4.0]], np.float32), np.array([0.2, 0.4], np.float32)
    )
    ((_, grid),) = conv.convert(PERCEPTION_OBSTACLES, cells)
    cubes = decode(grid).entities[0].cubes
    got = [(q.pose.position.x, q.pose.position.y, q.size.x) for q in cubes]
    assert np.allclose(got, [(1.0, 2.0, 0.2), (3.0, 4.0, 0.4)])
    plan = UrbanPlan(
        2.0, True, "Drive/DriveOnLane", 1, 5.0, math.nan, 0.0, "", math.nan, math.nan, False, 1, (), "", "",
        (), (0.0, 1.0, 2.0), (0.0, 0.5, 1.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 1.0, 2.0),
    )  # fmt: skip
    ((_, path),) = conv.convert(URBAN_PLAN, plan)
    line = decode(path).entities[0].lines[0]
    assert [(p.x, p.y) for p in line.points] == [(0.0, 0.0), (1.0, 0.5), (2.0, 1.0)]


def test_a_revolution_is_a_point_cloud_on_the_sensor() -> None:
    xyz = np.array([[1.0, 2.0, -1.5], [10.0, -3.0, 0.2]], np.float32)
    scan = PerceptionScan(
        3.0, True, 2.95, 1.73, xyz, np.array([0.1, 0.9], np.float32), np.array([0, 63], np.uint8), 7, 0
    )
    (_, tf), (topic, cloud) = SceneConverter().convert(PERCEPTION_SCAN, scan)
    t = decode(tf)
    assert (t.parent_frame_id, t.child_frame_id, t.translation.z) == (
        "base_link",
        "lidar",
        pytest.approx(1.73),
    )
    c = decode(cloud)
    assert topic == "/scene/scan" and c.frame_id == "lidar" and c.point_stride == 16
    assert [f.name for f in c.fields] == ["x", "y", "z", "reflectance"]
    points = np.frombuffer(c.data, dtype="<f4").reshape(-1, 4)
    assert np.array_equal(points[:, :3], xyz) and np.allclose(points[:, 3], [0.1, 0.9])


def test_what_the_scene_does_not_show_gives_nothing() -> None:
    conv = SceneConverter()
    assert conv.convert(URBAN_POSE, pose(valid=False)) == []
    assert conv.convert("/control/request", pose()) == []


def test_the_live_view_carries_the_scene_on_typed_channels() -> None:
    from bywire.host.runtime.live_view import LiveView

    with LiveView(0) as view:
        for topic, msg in SceneConverter().convert(URBAN_POSE, pose()):
            view.publish_message(topic, msg, 1_500_000_000)
        schemas = {t: s.name for t, s in view.topics().items()}
    assert schemas == {"/scene/tf": "foxglove.FrameTransform", "/scene/ego": "foxglove.SceneUpdate"}
