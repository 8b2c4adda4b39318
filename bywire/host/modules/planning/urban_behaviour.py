"""The behaviour of seed 000 sections 8-9 as a module of the urban host: `host.behaviour.Behaviour.step` on a
`Situation` made of the newest pose (the rear axle, extrapolated to the release with its speed and yaw
rate), the objects (matched to lanes by the behaviour's own `LaneIndex`; a standing box the way round
that fits its lane), both put on the map by its offset from the lane markings when the LIDAR's
`lane_offset` module has one (seed 000 Sec. 6), and the E-stop as the ECU
reports it: ENGAGED is RUN, DISABLED is DISABLE, anything else PAUSE (before the ECU engages, and while
it stops for a fault, the behaviour's clock stands still: nothing times out). Its planner is built from
the mission's RNDF/MDF once per host (`HostResources.urban_network`, ~1.5 s on the DARPA sample network;
before the runtime starts). A replan takes ~30 ms: the module's deadline (45 ms of its 50 ms period)
tolerates it, and "slow" needs 8 misses in 10 releases. The path planner (zones, K-turns, exit turns)
is a worker process on wall time; in lockstep it steps inline, one step of its search per poll, marked
`background()`: on wall time it would run beside the behaviour, so its cost is not the behaviour's
(see `runtime.inline_worker`). Pure: it replays exactly.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from bywire.host.behaviour.behaviour import Behaviour
from bywire.host.behaviour.path_planning import InlinePathPlanner, PlanReply, PlanRequest
from bywire.host.behaviour.situation import EgoState, EStop, Situation, TrackedObject, match_objects
from bywire.host.modules.messages import (
    ECU_STATUS,
    EcuStatusReport,
)
from bywire.host.modules.perception_messages import (
    LANE_OFFSET,
    PERCEPTION_OBSTACLES,
    LaneOffsetEstimate,
    ObstacleCells,
)
from bywire.host.modules.urban_log import UrbanLog
from bywire.host.modules.urban_messages import (
    URBAN_OBJECTS,
    URBAN_PLAN,
    URBAN_POSE,
    UrbanObject,
    UrbanObjects,
    UrbanPlan,
    UrbanPose,
)
from bywire.host.runtime.inline_worker import background
from bywire.host.runtime.module import Module, ModuleContext
from bywire.protocol.ecu_types import EcuState

STANDING_MPS = 0.5  # slower: the LIDAR's tracker calls a track static and knows no front


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


def _score(obj: TrackedObject) -> float:
    """How far an object stands from its lane's centre line (lower: fits better)."""
    assert obj.lane is not None
    return abs(obj.lane.lateral_m)


def on_map(pose: UrbanPose, offset: LaneOffsetEstimate) -> UrbanPose:
    """Our pose moved onto the map by its offset from the lane markings (perception.lane_offset)."""
    dx, dy = offset.correction()
    return replace(pose, x_m=pose.x_m - dx, y_m=pose.y_m - dy)


def objects_on_map(objs: UrbanObjects, offset: LaneOffsetEstimate) -> UrbanObjects:
    """The objects, seen from our position fix, moved onto the map with it."""
    dx, dy = offset.correction()
    moved = tuple(replace(o, x_m=o.x_m - dx, y_m=o.y_m - dy) for o in objs.objects)
    return replace(objs, objects=moved)


class BackgroundPathPlanner(InlinePathPlanner):
    """The lockstep planner: `InlinePathPlanner`, its steps marked as background work of the step."""

    def poll(self, ticket: int) -> PlanReply | None:
        with background():
            return super().poll(ticket)

    def submit(self, request: PlanRequest) -> int:
        with background():
            return super().submit(request)


class UrbanBehaviour(Module):
    """`Behaviour.step` on the store's pose and objects (see the module docstring)."""

    def __init__(
        self, behaviour: Behaviour, log: UrbanLog | None = None, path_planner_process: bool = False
    ) -> None:
        self.behaviour = behaviour
        self.log = log or UrbanLog()
        self._path_planner_process = path_planner_process
        self._path_planner: Any = None
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
        if o.speed_mps < STANDING_MPS:
            # A box seen standing has an orientation but no front (the LIDAR's tracks): it stands the
            # way round that fits a lane better.
            turned = replace(obj, heading_rad=math.remainder(o.heading_rad + math.pi, 2.0 * math.pi))
            flipped = match_objects(self.behaviour.ctx.lane_index, (turned,))[0]
            if flipped.lane is not None and (matched.lane is None or _score(flipped) < _score(matched)):
                matched = flipped
        self._matches[o.object_id] = (key, matched)
        return matched

    def start(self, ctx: ModuleContext) -> None:
        if self._path_planner_process and self._path_planner is None:
            from bywire.host.modules.planning.path_planner_process import ProcessPathPlanner

            self._path_planner = ProcessPathPlanner()
            self.behaviour.ctx.path_planner = self._path_planner
        elif self.behaviour.ctx.path_planner is None:
            self.behaviour.ctx.path_planner = BackgroundPathPlanner()

    def close(self) -> None:
        if self._path_planner is not None:
            self._path_planner.close()
            self._path_planner = None

    def step(self, ctx: ModuleContext) -> None:
        now = ctx.now_s
        pose: UrbanPose | None = ctx.latest(URBAN_POSE)
        objs: UrbanObjects | None = ctx.latest(URBAN_OBJECTS)
        status: EcuStatusReport | None = ctx.latest(ECU_STATUS)
        offset: LaneOffsetEstimate | None = ctx.latest(LANE_OFFSET)
        cells_msg: ObstacleCells | None = ctx.latest(PERCEPTION_OBSTACLES)
        if objs is not None and objs.valid:
            self.log.perceive(objs.stamp_s, tuple((o.object_id, o.x_m, o.y_m) for o in objs.objects))
        if offset is not None and offset.valid:
            pose = on_map(pose, offset) if pose is not None else None
            objs = objects_on_map(objs, offset) if objs is not None else None
        if pose is None or not pose.valid:
            ctx.publish(URBAN_PLAN, _hold_plan(now, "no pose yet"))
            return
        x, y, h = extrapolate(pose, now - pose.t_s)
        objects = tuple(self._matched(o) for o in (objs.objects if objs is not None and objs.valid else ()))
        cells = None
        if cells_msg is not None and cells_msg.valid:
            east, north = offset.correction() if offset is not None else (0.0, 0.0)
            xy = np.asarray(cells_msg.xy_m, dtype=np.float64) - np.array([east, north])
            cells = np.column_stack((xy, np.asarray(cells_msg.size_m, dtype=np.float64)))
        sit = Situation(
            t_s=now,
            ego=EgoState(x, y, math.atan2(math.sin(h), math.cos(h)), pose.speed_mps),
            objects=objects,
            estop=estop_of(status),
            obstacle_cells=cells,
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
