"""The localisation's object link as a module of the urban host: our pose and the object list
(`protocol.objects`) in, `/urban/pose` and `/urban/objects` out at 100 Hz; a datagram that is not an
object list is counted and dropped. As `urban_pose` (a host that perceives with its LIDAR) it publishes
the pose alone: the objects are the perception's.
"""

from __future__ import annotations

import math
from typing import Any

from bywire.host.modules.urban_log import UrbanLog
from bywire.host.modules.urban_messages import (
    URBAN_OBJECTS,
    URBAN_POSE,
    UrbanObject,
    UrbanObjects,
    UrbanPose,
)
from bywire.host.runtime.module import Module, ModuleContext
from bywire.protocol.objects import ObjectListError, decode

MAX_DATAGRAMS = 400  # per release: a flood waits in the socket, it does not stall the scheduler


class UrbanIo(Module):
    """Reads the object link (protocol/objects.py) and publishes the newest pose and object list."""

    def __init__(self, link: Any, log: UrbanLog | None = None, objects: bool = True) -> None:
        self.link = link
        self.publish_objects = objects
        self.log = log or UrbanLog()
        self.pose: UrbanPose | None = None
        self.objects: UrbanObjects | None = None
        self.received = 0
        self.rejected = 0

    def step(self, ctx: ModuleContext) -> None:
        now = ctx.now_s
        datagrams = self.link.receive() if self.link is not None else []
        for data in datagrams[-MAX_DATAGRAMS:]:
            self.received += 1
            try:
                msg = decode(data)
            except ObjectListError:
                self.rejected += 1
                continue
            if msg.pose is not None and (self.pose is None or msg.t_s >= self.pose.stamp_s):
                p = msg.pose
                self.pose = UrbanPose(now, True, msg.t_s, p.x_m, p.y_m, p.heading_rad, p.speed_mps,
                                      p.yaw_rate_radps, 0, 0)  # fmt: skip
            if msg.has_objects and (self.objects is None or msg.t_s >= self.objects.stamp_s):
                objs = tuple(
                    UrbanObject(
                        f"v{o.object_id}", o.x_m, o.y_m, o.heading_rad, o.speed_mps, o.length_m, o.width_m
                    )
                    for o in msg.objects
                )
                self.objects = UrbanObjects(now, True, msg.t_s, objs)
        self.log.rejected = self.rejected
        if self.pose is None:
            pose = UrbanPose(now, False, math.nan, 0.0, 0.0, 0.0, 0.0, 0.0, self.received, self.rejected)
        else:
            last = self.pose
            pose = UrbanPose(now, True, last.stamp_s, last.x_m, last.y_m, last.heading_rad, last.speed_mps,
                             last.yaw_rate_radps, self.received, self.rejected)  # fmt: skip
        ctx.publish(URBAN_POSE, pose)
        if not self.publish_objects:
            return
        objs_msg = self.objects or UrbanObjects(now, False, math.nan, ())
        ctx.publish(URBAN_OBJECTS, UrbanObjects(now, objs_msg.valid, objs_msg.stamp_s, objs_msg.objects))
