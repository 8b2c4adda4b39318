"""The LIDAR's link as a module of the urban host: the sensor's revolutions (`protocol.lidar.scan_link`,
`protocol.lidar.scan_message`) in, the newest one out on `/perception/scan` for the perception to take.

Only the newest revolution of a release is decoded and published (the link keeps two at most: a host
that fell behind skips to the present, it never works through a backlog). A release that finds no new
revolution publishes nothing: a 1.6 MB object is not sent on to a process-isolated perception twice.
Messages the decoder refuses are counted and dropped.
"""

from __future__ import annotations

import math
from typing import Any

from bywire.host.modules.perception_messages import PERCEPTION_SCAN, PerceptionScan
from bywire.host.runtime.module import Module, ModuleContext
from bywire.protocol.lidar.scan_message import LidarScanError, decode


class LidarIo(Module):
    """Reads the scan link and publishes each new revolution once (see the module docstring)."""

    def __init__(self, link: Any) -> None:
        self.link = link
        self.received = 0
        self.rejected = 0
        self._stamp_s = -math.inf

    def step(self, ctx: ModuleContext) -> None:
        messages = self.link.receive() if self.link is not None else []
        self.received += len(messages)
        for data in reversed(messages):
            try:
                scan = decode(data)
            except LidarScanError:
                self.rejected += 1
                continue
            if scan.stamp_s <= self._stamp_s:
                return  # a revolution older than one already published: the sensor restarted or lies
            self._stamp_s = scan.stamp_s
            ctx.publish(
                PERCEPTION_SCAN,
                PerceptionScan(ctx.now_s, True, scan.stamp_s, scan.sensor_height_m, scan.xyz_m,
                               scan.reflectance, scan.beam, self.received, self.rejected),
            )  # fmt: skip
            return
