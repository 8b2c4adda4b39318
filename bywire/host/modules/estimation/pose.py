"""The pose server as a module (seed 003 section II-h): NMEA and odometry in (`host.world.pose.PoseServer`),
`/ego/pose` out, dead reckoning through dropouts and frozen fixes. Pure: it replays exactly.
"""

from __future__ import annotations

import math

from bywire.host.geo import LocalFrame
from bywire.host.modules.gcdc_messages import (
    EGO_MOTION,
    GPS_NMEA,
    POSE,
    PoseReport,
)
from bywire.host.runtime.module import Module, ModuleContext
from bywire.host.world.pose import PoseServer, PoseServerConfig


class PoseModule(Module):
    """NMEA bytes and odometry -> our pose on the local plane (`host.world.pose.PoseServer`)."""

    def __init__(self, frame: LocalFrame, config: PoseServerConfig | None = None) -> None:
        self.server = PoseServer(frame, config)
        self._last_motion_s = -math.inf

    def step(self, ctx: ModuleContext) -> None:
        now = ctx.now_s
        srv = self.server
        for m in ctx.new(EGO_MOTION):
            if m.valid and m.rx_s > self._last_motion_s:
                srv.odometry(m.rx_s, m.speed_mps, m.yaw_rate_radps, m.accel_mps2)
                self._last_motion_s = m.rx_s
        for chunk in ctx.new(GPS_NMEA):
            if chunk.data:
                srv.feed(chunk.data, chunk.rx_s)
        p = srv.pose(now)
        nan = math.nan
        dropped = sum(srv.stream.drops.values())
        frozen = srv.counts.get("fix_frozen", 0) + srv.counts.get("fix_repeated", 0)
        if p is None:
            ctx.publish(
                POSE,
                PoseReport(
                    now,
                    False,
                    nan,
                    nan,
                    nan,
                    nan,
                    nan,
                    nan,
                    nan,
                    nan,
                    nan,
                    False,
                    False,
                    False,
                    True,
                    0,
                    dropped,
                    frozen,
                ),
            )
            return
        ctx.publish(
            POSE,
            PoseReport(
                now, True, p.x_m, p.y_m, p.heading_rad, p.speed_mps, p.accel_mps2, p.yaw_rate_radps,
                p.lat_deg, p.lon_deg, p.position_std_m, p.rtk, p.gnss, p.dead_reckoning, p.stale,
                p.fix_quality, dropped, frozen,
            ),
        )  # fmt: skip
