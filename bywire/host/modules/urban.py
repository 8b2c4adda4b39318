"""The urban host (issue 5): pose and object list in, the behaviour of seed 000 Sec. 8-9, the orbital
lateral controller of Sec. 11.1 and the longitudinal override strategy of Sec. 11.2 out to the ECU.

    urban_io          (the object link)          -> /urban/pose, /urban/objects
    urban_behaviour   /urban/pose, /urban/objects, /ecu/status -> /urban/plan       20 Hz
    urban_control     /urban/plan, /urban/pose, /mission/command, /supervisor/limit -> /control/request  50 Hz

`urban_behaviour` runs `host.behaviour.Behaviour.step` on a `Situation` made of the newest pose (the
rear axle, extrapolated to the release with its speed and yaw rate), the objects (matched to lanes by the
behaviour's own `LaneIndex`) and the E-stop as the ECU reports it: ENGAGED is RUN, DISABLED is DISABLE,
anything else PAUSE (before the ECU engages, and while it stops for a fault, the behaviour's clock stands
still: nothing times out). Its planner is built from the scenario's RNDF/MDF once per host
(`HostResources.urban_network`, ~1.5 s on the DARPA sample network; before the runtime starts). A replan
takes ~30 ms: the module's deadline (45 ms of its 50 ms period) tolerates it, and "slow" needs 8 misses
in 10 releases.

`urban_control` tracks the plan's stub with `lateral_step` (eqs. 18-23, the steering angle goes to the
ECU with the STEER flag) and `longitudinal_step` (following / stopping with hysteresis / velocity,
max/min combination, saturation), the stop distance taken along the stub from the rear axle's projection
at *this* release. A backward leg (the stub's direction -1: leaving a parking spot, the K-turn's
backward half) sets `RequestFlags.REVERSE`: the acceleration request stays along the direction of travel
(positive: faster backwards), the ECU shifts at standstill (brakes, holds, waits for the gateway) and
caps the reverse speed (ecu/gear.py). The pose's speed is signed (negative backwards), so extrapolation
runs the right way; the longitudinal controller sees its magnitude. `reverse_held` (backward legs held at
standstill: there is no such case any more, it stays 0) remains in the summary for the JSON contract.

Both computing modules are pure functions of their inputs (replayable, `bywire log replay --check`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np

from bywire.host.behaviour.behaviour import Behaviour
from bywire.host.behaviour.situation import EgoState, EStop, Situation, TrackedObject, match_objects
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
    ECU_STATUS,
    MISSION,
    ControlRequest,
    EcuStatusReport,
    MissionCommand,
)
from bywire.host.modules.urban_messages import (
    URBAN_OBJECTS,
    URBAN_PLAN,
    URBAN_POSE,
    UrbanObject,
    UrbanObjects,
    UrbanPlan,
    UrbanPose,
)
from bywire.host.runtime.module import Module, ModuleContext
from bywire.host.runtime.topics import SAFETY_LIMIT, SafetyLimit
from bywire.protocol.ecu_types import EcuState, RequestFlags
from bywire.protocol.objects import ObjectListError, decode

PLAN_STALE_S = 0.3  # 6 behaviour periods without a plan: hold the car
POSE_STALE_S = 0.2
HOLD_DECEL_MPS2 = -2.0  # what the controller asks without a usable plan or pose (the ECU adds its own)
# Deviation from seed 000 Sec. 11.1 (a kinematic law that assumes the wheels take the angle at once): the
# Passat's steering actuator lags (first order, 0.1 s, and at most 0.7 rad/s; vehicle_models/passat) and a
# request waits up to one control period plus the ECU's cycle. Without compensation the car runs ~0.6 m
# wide in tight RNDF exits. The law is evaluated at the pose predicted this far ahead (constant speed and
# yaw rate), which leads the curvature term by the same amount.
PREVIEW_S = 0.25
MAX_DATAGRAMS = 400  # per release: a flood waits in the socket, it does not stall the scheduler


@dataclass
class UrbanLog:
    """What the urban modules tell the run's summary: the state history and the faults (not data flow)."""

    states: list[tuple[float, str]] = field(default_factory=list)
    faults: list[tuple[float, str]] = field(default_factory=list)
    checkpoints_reached: tuple[int, ...] = ()
    reverse_held: int = 0
    rejected: int = 0

    def summary(self) -> dict[str, Any]:
        return {
            "states": [[round(t, 3), s] for t, s in self.states],
            "faults": [[round(t, 3), f] for t, f in self.faults],
            "behaviour_checkpoints": list(self.checkpoints_reached),
            "reverse_held": self.reverse_held,
            "object_datagrams_rejected": self.rejected,
        }


def estop_of(status: EcuStatusReport | None) -> EStop:
    """The E-stop as the behaviour should see it, from the ECU's state (see the module docstring)."""
    if status is None or not status.valid:
        return EStop.PAUSE
    if status.state == int(EcuState.ENGAGED):
        return EStop.RUN
    if status.state == int(EcuState.DISABLED):
        return EStop.DISABLE
    return EStop.PAUSE


def extrapolate(pose: UrbanPose, dt_s: float) -> tuple[float, float, float]:
    """The rear axle `dt_s` after the pose (constant speed and yaw rate, exact arc)."""
    if dt_s <= 0.0:
        return pose.x_m, pose.y_m, pose.heading_rad
    v, r, h = pose.speed_mps, pose.yaw_rate_radps, pose.heading_rad
    if abs(r) < 1e-6:
        return pose.x_m + v * dt_s * math.cos(h), pose.y_m + v * dt_s * math.sin(h), h
    h1 = h + r * dt_s
    rad = v / r
    return pose.x_m + rad * (math.sin(h1) - math.sin(h)), pose.y_m - rad * (math.cos(h1) - math.cos(h)), h1


class UrbanIo(Module):
    """Reads the object link (protocol/objects.py) and publishes the newest pose and object list."""

    def __init__(self, link: Any, log: UrbanLog | None = None) -> None:
        self.link = link
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
        objs_msg = self.objects or UrbanObjects(now, False, math.nan, ())
        ctx.publish(URBAN_OBJECTS, UrbanObjects(now, objs_msg.valid, objs_msg.stamp_s, objs_msg.objects))


class UrbanBehaviour(Module):
    """`Behaviour.step` on the store's pose and objects (see the module docstring)."""

    def __init__(self, behaviour: Behaviour, log: UrbanLog | None = None) -> None:
        self.behaviour = behaviour
        self.log = log or UrbanLog()
        self._last_state = ""
        self._matches: dict[str, tuple[tuple[float, float, float], TrackedObject]] = {}

    def _matched(self, o: UrbanObject) -> TrackedObject:
        """The object with its lane match (the world model's job, seed 000 Sec. 8); an object that has not
        moved keeps its match (the same pose gives the same match: a cache, not a change of result)."""
        key = (round(o.x_m, 3), round(o.y_m, 3), round(o.heading_rad, 4))
        obj = TrackedObject(o.object_id, o.x_m, o.y_m, o.heading_rad, o.speed_mps, o.length_m, o.width_m)
        hit = self._matches.get(o.object_id)
        if hit is not None and hit[0] == key:
            return replace(hit[1], speed_mps=o.speed_mps, length_m=o.length_m, width_m=o.width_m)
        matched = match_objects(self.behaviour.ctx.lane_index, (obj,))[0]
        self._matches[o.object_id] = (key, matched)
        return matched

    def step(self, ctx: ModuleContext) -> None:
        now = ctx.now_s
        pose: UrbanPose | None = ctx.latest(URBAN_POSE)
        objs: UrbanObjects | None = ctx.latest(URBAN_OBJECTS)
        status: EcuStatusReport | None = ctx.latest(ECU_STATUS)
        if pose is None or not pose.valid:
            ctx.publish(URBAN_PLAN, _hold_plan(now, "no pose yet"))
            return
        x, y, h = extrapolate(pose, now - pose.t_s)
        objects = tuple(self._matched(o) for o in (objs.objects if objs is not None and objs.valid else ()))
        sit = Situation(
            t_s=now,
            ego=EgoState(x, y, math.atan2(math.sin(h), math.cos(h)), pose.speed_mps),
            objects=objects,
            estop=estop_of(status),
        )
        cmd = self.behaviour.step(sit)
        if cmd.state != self._last_state:
            self._last_state = cmd.state
            self.log.states.append((now, cmd.state))
        if cmd.fault:
            self.log.faults.append((now, cmd.fault))
        self.log.checkpoints_reached = tuple(cmd.checkpoints_reached)
        stub = cmd.stub
        ctx.publish(
            URBAN_PLAN,
            UrbanPlan(
                t_s=now,
                valid=True,
                state=cmd.state,
                direction=int(stub.direction),
                desired_speed_mps=float(cmd.desired_speed_mps),
                stop_point_s_m=math.nan if cmd.stop_point_s_m is None else float(cmd.stop_point_s_m),
                ego_s_m=float(cmd.ego_s_m),
                lead_id="" if cmd.lead is None else cmd.lead.object_id,
                lead_gap_m=math.nan if cmd.lead is None else float(cmd.lead.gap_m),
                lead_speed_mps=math.nan if cmd.lead is None else float(cmd.lead.speed_mps),
                paused=bool(cmd.paused),
                next_checkpoint=int(cmd.next_checkpoint),
                checkpoints_reached=tuple(int(c) for c in cmd.checkpoints_reached),
                fault=cmd.fault or "",
                reason=cmd.reason,
                requests=tuple(f"{r.kind.value}: {r.detail}" for r in cmd.requests),
                stub_x_m=tuple(float(v) for v in stub.x_m),
                stub_y_m=tuple(float(v) for v in stub.y_m),
                stub_heading_rad=tuple(float(v) for v in stub.heading_rad),
                stub_curvature_1pm=tuple(float(v) for v in stub.curvature_1pm),
                stub_s_m=tuple(float(v) for v in stub.s_m),
            ),
        )


def _hold_plan(now: float, why: str) -> UrbanPlan:
    return UrbanPlan(now, False, "", 1, 0.0, math.nan, 0.0, "", math.nan, math.nan, False, 0, (), "", why,
                     (), (), (), (), (), ())  # fmt: skip


class UrbanControl(Module):
    """Lateral (orbital, eqs. 18-23) and longitudinal (override, Sec. 11.2) control on the plan's stub."""

    def __init__(self, params: Mapping[str, Any] | None = None, log: UrbanLog | None = None) -> None:
        params = dict(params or {})
        self.preview_s = float(params.pop("preview_s", PREVIEW_S))
        lat = {k[len("lateral_") :]: float(v) for k, v in params.items() if k.startswith("lateral_")}
        lon = {k: v for k, v in params.items() if not k.startswith("lateral_")}
        self.lat = LateralParams(**lat)
        self.lon = LongitudinalParams(**lon)
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


__all__ = ["UrbanBehaviour", "UrbanControl", "UrbanIo", "UrbanLog", "estop_of", "extrapolate"]
