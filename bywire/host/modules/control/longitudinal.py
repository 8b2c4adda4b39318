"""The longitudinal control module: seed 000 section 11.2's override controller on the store's data.

The controller itself is the pure `host.longitudinal` (tested on its own); this module feeds it the
mission's desired speed and stop line, the odometry and the lead track, and obeys the supervisor:
a `SafetyLimit` caps the desired speed (approached at `DEGRADE_DECEL_MPS2`, not as a step), and a
lead track that has gone silent (the perception restarting, say) is not read as a free lane — the
car does not accelerate blind (`PERCEPTION_STALE_S`).
"""

from __future__ import annotations

import math
from typing import Any

from bywire.host.longitudinal import (
    LeadObservation,
    LongitudinalInputs,
    LongitudinalParams,
    LongitudinalState,
    longitudinal_step,
)
from bywire.host.modules.messages import (
    CONTROL,
    LEAD,
    MISSION,
    ODOMETRY,
    ControlRequest,
    LeadTrack,
    MissionCommand,
    Odometry,
)
from bywire.host.modules.module_params import make_dataclass
from bywire.host.runtime.module import Module, ModuleContext
from bywire.host.runtime.topics import SAFETY_LIMIT, SafetyLimit
from bywire.protocol.ecu_types import RequestFlags

PERCEPTION_STALE_S = 0.1  # 5 periods without a lead track: the perception is down, not the lane free
DEGRADE_DECEL_MPS2 = 1.5  # how fast a supervisor's speed limit is approached: firm, not an emergency


class LongitudinalModule(Module):
    def __init__(self, params: dict[str, Any] | None = None) -> None:
        self.params = make_dataclass("longitudinal", LongitudinalParams, params or {})
        self.state = LongitudinalState()
        self._limit_start: tuple[float, float] | None = None  # (limit's t_s, our speed when we saw it)

    def _limited_speed(self, limit: SafetyLimit, now_s: float, speed_mps: float) -> float:
        """The limit, reached from the speed we had at a steady `DEGRADE_DECEL_MPS2`: a step in the
        desired speed would make the velocity controller brake at its limit (-c_v * dv)."""
        if self._limit_start is None or self._limit_start[0] != limit.t_s:
            self._limit_start = (limit.t_s, speed_mps)
        seen_s, v0 = self._limit_start
        return max(limit.max_speed_mps, v0 - DEGRADE_DECEL_MPS2 * max(0.0, now_s - seen_s))

    def step(self, ctx: ModuleContext) -> None:
        now = ctx.now_s
        mission: MissionCommand | None = ctx.latest(MISSION)
        odo: Odometry | None = ctx.latest(ODOMETRY)
        track: LeadTrack | None = ctx.latest(LEAD)
        limit: SafetyLimit | None = ctx.latest(SAFETY_LIMIT)
        speed = odo.speed_mps if odo is not None else 0.0
        v_des = mission.v_des_mps if mission is not None else 0.0
        if limit is not None:
            v_des = min(v_des, self._limited_speed(limit, now, speed))
        blind = track is None or now - track.t_s > PERCEPTION_STALE_S
        lead = (
            LeadObservation(gap_m=track.gap_m, v_lead_mps=track.v_lead_mps)
            if track is not None and track.valid and not blind
            else None
        )
        flags = RequestFlags.NONE
        if mission is None:
            accel, controller = 0.0, "none"
        elif mission.mode == "script":
            accel, controller = mission.accel_mps2, "script"
        else:
            stop_distance = None
            if not math.isnan(mission.stop_line_m) and odo is not None:
                stop_distance = mission.stop_line_m - odo.odometer_m
            inputs = LongitudinalInputs(
                v_mps=speed, v_des_mps=v_des, lead=lead, stop_distance_m=stop_distance
            )
            self.state, accel, controller = longitudinal_step(self.state, inputs, self.params)
            if blind:
                accel = min(accel, 0.0)
        if mission is not None:
            flags |= mission.request_flags()
        ctx.publish(
            CONTROL,
            ControlRequest(
                t_s=now,
                accel_mps2=accel,
                steer_rad=mission.steer_rad if mission is not None else 0.0,
                flags=int(flags),
                controller=controller,
                v_des_mps=v_des,
                gap_m=lead.gap_m if lead is not None else math.nan,
            ),
        )
