"""The lead vehicle tracked from the radar's target: gap and speed (v_lead = v_own + range rate). It touches
no bus, so it can run in a worker process of its own (crash-isolated perception, DESIGN section 1).
"""

from __future__ import annotations

import math

from bywire.host.modules.messages import LEAD, ODOMETRY, RADAR, LeadTrack, Odometry, RadarReport
from bywire.host.runtime.module import Module, ModuleContext


class LeadTracker(Module):
    def step(self, ctx: ModuleContext) -> None:
        radar: RadarReport | None = ctx.latest(RADAR)
        odo: Odometry | None = ctx.latest(ODOMETRY)
        v_own = odo.speed_mps if odo is not None else 0.0
        if radar is None or not radar.valid:
            track = LeadTrack(ctx.now_s, False, math.nan, math.nan)
        else:
            track = LeadTrack(ctx.now_s, True, radar.range_m, v_own + radar.range_rate_mps)
        ctx.publish(LEAD, track)
