"""The urban host's control (seed 000 section 11): the orbital lateral controller of section 11.1 and the
longitudinal override strategy of section 11.2 on the behaviour's plan, out to the ECU.

`urban_control` tracks the plan's stub with `lateral_step` (eqs. 18-23, the steering angle goes to the
ECU with the STEER flag) and `longitudinal_step` (following / stopping with hysteresis / velocity,
max/min combination, saturation), the stop distance taken along the stub from the rear axle's projection
at *this* release; our pose is put on the map with the map's offset from the lane markings when the
LIDAR's lane-offset module has a valid one (`/urban/lane_offset`, seed 000 Sec. 6). A backward leg (the
stub's direction -1: leaving a parking spot, the K-turn's backward half) sets `RequestFlags.REVERSE`: the
acceleration request stays along the direction of travel (positive: faster backwards), the ECU shifts at
standstill (brakes, holds, waits for the gateway) and caps the reverse speed (ecu/gear.py). The pose's
speed is signed (negative backwards), so extrapolation runs the right way; the longitudinal controller
sees its magnitude. `reverse_held` (backward legs held at standstill: there is no such case any more, it
stays 0) remains in the summary for the JSON contract. Pure: it replays exactly (`bywire log replay
--check`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any, Literal

import numpy as np

from bywire.host.lateral import LateralParams, PathSamples, VehiclePose, lateral_step
from bywire.host.longitudinal import (
    LeadObservation,
    LongitudinalInputs,
    LongitudinalParams,
    LongitudinalState,
    longitudinal_step,
)
from bywire.host.modules.messages import (
    CONTROL,
    MISSION,
    ControlRequest,
    MissionCommand,
)
from bywire.host.modules.module_params import make_dataclass, number, refuse_unknown
from bywire.host.modules.perception_messages import LANE_OFFSET, LaneOffsetEstimate
from bywire.host.modules.planning.urban_behaviour import extrapolate, on_map
from bywire.host.modules.urban_log import UrbanLog
from bywire.host.modules.urban_messages import (
    URBAN_PLAN,
    URBAN_POSE,
    UrbanPlan,
    UrbanPose,
)
from bywire.host.runtime.module import Module, ModuleContext
from bywire.host.runtime.topics import SAFETY_LIMIT, SafetyLimit
from bywire.protocol.ecu_types import RequestFlags

PLAN_STALE_S = 0.3  # 6 behaviour periods without a plan: hold the car


POSE_STALE_S = 0.2


HOLD_DECEL_MPS2 = -2.0  # what the controller asks without a usable plan or pose (the ECU adds its own)


# Deviation from seed 000 Sec. 11.1 (a kinematic law that assumes the wheels take the angle at once): the
# Passat's steering actuator lags (first order, 0.1 s, and at most 0.7 rad/s; vehicle_models/passat) and a
# request waits up to one control period plus the ECU's cycle. Without compensation the car runs ~0.6 m
# wide in tight RNDF exits. The law is evaluated at the pose predicted this far ahead (constant speed and
# yaw rate), which leads the curvature term by the same amount.
PREVIEW_S = 0.25


class UrbanControl(Module):
    """Lateral (orbital, eqs. 18-23) and longitudinal (override, Sec. 11.2) control on the plan's stub."""

    def __init__(self, params: Mapping[str, Any] | None = None, log: UrbanLog | None = None) -> None:
        params = dict(params or {})
        self.preview_s = number("urban_control", params, "preview_s", PREVIEW_S, 0.0, 5.0)
        params.pop("preview_s", None)
        lat = {k: v for k, v in params.items() if k.startswith("lateral_")}
        lon = {k: v for k, v in params.items() if not k.startswith("lateral_")}
        lat_known = [f"lateral_{f.name}" for f in dataclasses.fields(LateralParams)]
        lon_known = [f.name for f in dataclasses.fields(LongitudinalParams)]
        refuse_unknown("urban_control", params, ["preview_s", *lat_known, *lon_known])
        self.lat = make_dataclass("urban_control", LateralParams, lat, "lateral_")
        self.lon = make_dataclass("urban_control", LongitudinalParams, lon)
        self.state = LongitudinalState()
        self.log = log or UrbanLog()
        self._steer = 0.0
        self._reverse = False  # the last usable plan's leg ran backwards
        self._path_key: float | None = None
        self._path: PathSamples | None = None

    def _samples(self, plan: UrbanPlan) -> PathSamples | None:
        if self._path_key != plan.t_s:
            self._path_key = plan.t_s
            self._path = None
            if len(plan.stub_x_m) >= 2:
                self._path = PathSamples(
                    np.asarray(plan.stub_x_m),
                    np.asarray(plan.stub_y_m),
                    np.asarray(plan.stub_heading_rad),
                    np.asarray(plan.stub_curvature_1pm),
                    np.asarray(plan.stub_s_m),
                )
        return self._path

    def step(self, ctx: ModuleContext) -> None:
        now = ctx.now_s
        plan: UrbanPlan | None = ctx.latest(URBAN_PLAN)
        pose: UrbanPose | None = ctx.latest(URBAN_POSE)
        mission: MissionCommand | None = ctx.latest(MISSION)
        limit: SafetyLimit | None = ctx.latest(SAFETY_LIMIT)
        offset: LaneOffsetEstimate | None = ctx.latest(LANE_OFFSET)
        if pose is not None and offset is not None and offset.valid:
            pose = on_map(pose, offset)
        speed = abs(pose.speed_mps) if pose is not None and pose.valid else 0.0
        accel, controller, v_des, gap = HOLD_DECEL_MPS2, "none", 0.0, math.nan
        reverse = self._reverse
        usable = (
            plan is not None
            and plan.valid
            and now - plan.t_s <= PLAN_STALE_S
            and pose is not None
            and pose.valid
            and now - pose.t_s <= POSE_STALE_S
        )
        applied = offset.offset_m if offset is not None and offset.valid else 0.0
        self.log.lane_offset(now, applied, offset is not None and offset.valid)
        path = self._samples(plan) if usable and plan is not None else None
        if usable and plan is not None and pose is not None and path is not None:
            x, y, h = extrapolate(pose, now - pose.t_s)
            direction: Literal[1, -1] = 1 if plan.direction >= 0 else -1
            lat = lateral_step(path, VehiclePose(x, y, h), direction, self.lat)
            # steer for where the car will be when the steering gets there (see PREVIEW_S)
            px, py, ph = extrapolate(pose, now - pose.t_s + self.preview_s)
            self._steer = lateral_step(path, VehiclePose(px, py, ph), direction, self.lat).steer_rad
            v_des = plan.desired_speed_mps
            if limit is not None:
                v_des = min(v_des, limit.max_speed_mps)
            stop = None if math.isnan(plan.stop_point_s_m) else plan.stop_point_s_m - lat.s_m
            lead = None
            if not math.isnan(plan.lead_gap_m):
                # the gap as the plan saw it, less what we drove since (the lead's motion: its speed)
                dt = max(0.0, now - plan.t_s)
                gap = plan.lead_gap_m - (speed - plan.lead_speed_mps) * dt
                lead = LeadObservation(gap_m=gap, v_lead_mps=plan.lead_speed_mps)
            inputs = LongitudinalInputs(
                v_mps=speed, v_des_mps=max(v_des, 0.0), lead=lead, stop_distance_m=stop
            )
            self.state, accel, controller = longitudinal_step(self.state, inputs, self.lon)
            reverse = direction < 0
        flags = RequestFlags.STEER if mission is None else mission.request_flags(steer=True)
        if reverse:
            # the gear follows the plan's leg; without a usable plan the ECU keeps the gear it has
            flags |= RequestFlags.REVERSE
        self._reverse = reverse
        ctx.publish(
            CONTROL,
            ControlRequest(
                t_s=now,
                accel_mps2=accel,
                steer_rad=self._steer,
                flags=int(flags),
                controller=controller,
                v_des_mps=v_des,
                gap_m=gap,
            ),
        )
