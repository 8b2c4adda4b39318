"""Topics and objects of the urban host (seed 000 sections 8-11): pose and object list in, the
behaviour's plan out.

Every object is a frozen dataclass with `t_s` (the publishing module's release time on the runtime clock)
and a `valid` flag, registered for MCAP recording and replay.
"""

from __future__ import annotations

from dataclasses import dataclass

from bywire.host.runtime.log_schema import register_type

URBAN_POSE = "/urban/pose"
URBAN_OBJECTS = "/urban/objects"
URBAN_PLAN = "/urban/plan"


@register_type
@dataclass(frozen=True)
class UrbanPose:
    """Our rear axle on the road network (local metres, ENU heading) as the pose link last reported it."""

    t_s: float
    valid: bool
    stamp_s: float  # the snapshot's scenario time (nan: none yet)
    x_m: float
    y_m: float
    heading_rad: float
    speed_mps: float  # signed
    yaw_rate_radps: float
    received: int  # datagrams so far
    rejected: int  # datagrams the decoder refused so far


@register_type
@dataclass(frozen=True)
class UrbanObject:
    object_id: str
    x_m: float  # centre of its box
    y_m: float
    heading_rad: float
    speed_mps: float  # >= 0 along the heading
    length_m: float
    width_m: float


@register_type
@dataclass(frozen=True)
class UrbanObjects:
    """The newest object list (the simulator's perfect perception with optional noise: the host has no
    perception of its own yet)."""

    t_s: float
    valid: bool
    stamp_s: float
    objects: tuple[UrbanObject, ...]


@register_type
@dataclass(frozen=True)
class UrbanPlan:
    """One behaviour cycle's command (host.behaviour.BehaviourCommand, flattened for the store).

    `valid` false: no pose yet, the controller holds. NaN marks an absent stop point or lead."""

    t_s: float
    valid: bool
    state: str
    direction: int  # 1 forward, -1 backward
    desired_speed_mps: float
    stop_point_s_m: float  # along the stub (nan: none)
    ego_s_m: float
    lead_id: str
    lead_gap_m: float
    lead_speed_mps: float
    paused: bool
    next_checkpoint: int
    checkpoints_reached: tuple[int, ...]
    fault: str
    reason: str
    requests: tuple[str, ...]
    stub_x_m: tuple[float, ...]
    stub_y_m: tuple[float, ...]
    stub_heading_rad: tuple[float, ...]
    stub_curvature_1pm: tuple[float, ...]
    stub_s_m: tuple[float, ...]
