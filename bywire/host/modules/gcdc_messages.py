"""Topics and objects of the cooperative-driving host (seed 003 Sec. II): GPS, pose, V2V, world,
platoon. Same rules as `messages`: frozen dataclasses stamped `t_s` on the runtime clock, published every
release (also when there is nothing new, saying so), times of reception kept apart (`rx_s`).

V2V generation times arrive as UNIX seconds; the receiving module converts them onto the runtime clock
(`t_gen_s`), so every computing module downstream works on one clock and replays exactly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from bywire.host.runtime.log_schema import register_type
from bywire.host.runtime.store import linear_interpolation

GPS_NMEA = "/gps/nmea"
EGO_MOTION = "/ego/motion"
POSE = "/ego/pose"
V2V_RECEIVED = "/v2v/received"
V2V_SENT = "/v2v/sent"
V2V_ICLCM_SENT = "/v2v/iclcm_sent"
WORLD_LEADS = "/world/leads"
PLATOON = "/platoon/status"


@register_type
@dataclass(frozen=True)
class NmeaChunk:
    """Bytes read from the GPS/INS serial line since the last release (empty: nothing arrived)."""

    t_s: float
    rx_s: float  # when they were read
    data: bytes


@register_type
@dataclass(frozen=True)
class EgoMotion:
    """The car's odometry from vehicle CAN (GW_WheelSpeeds, GW_Motion): the pose server's inputs."""

    t_s: float
    valid: bool
    rx_s: float
    speed_mps: float  # mean of the four wheel speeds
    yaw_rate_radps: float
    accel_mps2: float
    samples: int  # frames folded into this report


@register_type
@linear_interpolation("x_m", "y_m", "speed_mps")
@dataclass(frozen=True)
class PoseReport:
    """Our pose (`host.world.pose.Pose`) at t_s on the local plane, and the pose server's health."""

    t_s: float
    valid: bool
    x_m: float
    y_m: float
    heading_rad: float
    speed_mps: float
    accel_mps2: float
    yaw_rate_radps: float
    lat_deg: float
    lon_deg: float
    position_std_m: float
    rtk: bool
    gnss: bool
    dead_reckoning: bool
    stale: bool
    fix_quality: int
    nmea_dropped: int  # sentences dropped by the NMEA decoder since the start (checksum, partial, ...)
    frozen_fixes: int  # fixes dropped as frozen or repeated (a receiver under a bridge)


@register_type
@dataclass(frozen=True)
class V2vVehicle:
    station_id: int
    t_gen_s: float  # generation time on the runtime clock
    t_rx_s: float
    lat_deg: float
    lon_deg: float
    heading_true_deg: float  # clockwise from true north
    speed_mps: float
    yaw_rate_radps: float  # nan: not sent
    accel_mps2: float  # nan: not sent
    length_m: float
    width_m: float


@register_type
@dataclass(frozen=True)
class V2vLight:
    station_id: int
    t_gen_s: float
    intersection_id: int
    signal_group: int
    lat_deg: float
    lon_deg: float
    phase: str  # red, redAmber, green, amber, or "" (unknown)
    time_to_change_s: float  # nan: unknown


@register_type
@dataclass(frozen=True)
class V2vLimit:
    station_id: int
    t_gen_s: float
    zone_id: int
    lat_deg: float
    lon_deg: float
    limit_mps: float


@register_type
@dataclass(frozen=True)
class ReasonCount:
    reason: str
    count: int


@register_type
@dataclass(frozen=True)
class V2vCooperative:
    """One vehicle's GCDC 2016 iCLCM (`protocol.v2x.iclcm.CooperativeState`) on the runtime clock: what its
    cooperative controller says beyond its CAM. nan: unavailable. The merge and intersection objects of
    the GCDC 2016 scenarios, which our platoon does not drive, are not carried."""

    station_id: int
    t_gen_s: float  # generation time on the runtime clock
    t_rx_s: float  # nan: our own
    controller_type: str  # manual, cc, acc, cacc
    target_accel_mps2: float  # what its controller requests (a CACC follower's feed-forward)
    time_headway_s: float
    cruise_speed_mps: float
    rear_axle_m: float  # front bumper (the CAM's reference point) to the rear axle
    mio_station_id: int  # the most important object: the vehicle it follows (0: none or no id)
    mio_range_m: float
    mio_bearing_rad: float  # counter-clockwise positive
    mio_range_rate_mps: float
    lane: int  # GCDC lane 1..3 (0: unavailable)
    platoon_id: int  # 1 platoon A, 2 platoon B (0: none)


@register_type
@dataclass(frozen=True)
class V2vBatch:
    """The plausible V2V/V2I messages received since the last release, and the receiver's counters."""

    t_s: float
    vehicles: tuple[V2vVehicle, ...]
    lights: tuple[V2vLight, ...]
    limits: tuple[V2vLimit, ...]
    received: int  # since the start
    accepted: int
    rejected: tuple[ReasonCount, ...]  # `v2v_rejected` by reason, since the start
    cooperative: tuple[V2vCooperative, ...] = ()  # iCLCMs, one per message


@register_type
@dataclass(frozen=True)
class CamSent:
    t_s: float
    sent: bool
    station_id: int
    generation_unix_s: float
    count: int


@register_type
@dataclass(frozen=True)
class IclcmSent:
    """Our iCLCM of this release, sent beside our CAM (None: none this release)."""

    t_s: float
    sent: bool
    count: int  # since the start
    iclcm: V2vCooperative | None


@register_type
@dataclass(frozen=True)
class Lead:
    """One vehicle ahead in our lane (`host.world.radar_fusion.LeadEstimate`), with its prediction."""

    station_id: int  # -1: radar only
    source: str  # v2v, radar, fused
    confidence: str  # high, medium, low
    gap_m: float
    speed_mps: float
    accel_mps2: float
    length_m: float
    # Tuples, not arrays: a replay compares every field exactly, element by element.
    grid_s: tuple[float, ...]  # prediction times relative to t_s
    positions_m: tuple[float, ...]  # its rear bumper relative to our front bumper at t_s
    speeds_mps: tuple[float, ...]


@register_type
@dataclass(frozen=True)
class RoadsideItem:
    """A traffic light's stop line or a speed-limit zone on our lane, ahead (distance > 0) or passed."""

    kind: str  # traffic_light, speed_limit
    station_id: int
    distance_m: float  # along our lane from our front bumper
    phase: str
    time_to_change_s: float
    limit_mps: float


@register_type
@dataclass(frozen=True)
class LeadSet:
    """The world model's view for the platoon controller (seed 003 IV): the vehicles ahead in our lane,
    sorted by gap (index k = vehicle k + 1 ahead), and the road side on our lane."""

    t_s: float
    valid: bool  # false: no usable pose (off the map, stale)
    host_lane: int  # -1: off the map
    host_s_m: float
    leads: tuple[Lead, ...]
    roadside: tuple[RoadsideItem, ...]
    radar_gap_m: float  # nan: no radar track
    associated_station: int  # -1: none
    confident: bool
    tracked: int  # stations in the vehicle manager
    frozen: int
    silent: int


@register_type
@dataclass(frozen=True)
class PlatoonStatus:
    t_s: float
    accel_cmd_mps2: float
    mode: str  # cruise, platoon, stop_line, emergency, hold, blind, script, none
    binding_index: int  # 1-based vehicle ahead whose follow QP bound (0: none)
    binding_station: int  # -1: none or radar only
    leaders: int
    feasible: bool
    v_des_mps: float  # after speed limits and the supervisor's limit
    speed_limit_mps: float  # nan: none
    stop_distance_m: float  # nan: no red light ahead that we stop for
    time_headway_s: float = math.nan  # the time gap the follow QPs keep (FollowParams.headway_s)


__all__ = [
    "EGO_MOTION",
    "GPS_NMEA",
    "PLATOON",
    "POSE",
    "V2V_ICLCM_SENT",
    "V2V_RECEIVED",
    "V2V_SENT",
    "WORLD_LEADS",
    "CamSent",
    "EgoMotion",
    "IclcmSent",
    "Lead",
    "LeadSet",
    "NmeaChunk",
    "PlatoonStatus",
    "PoseReport",
    "ReasonCount",
    "RoadsideItem",
    "V2vBatch",
    "V2vCooperative",
    "V2vLight",
    "V2vLimit",
    "V2vVehicle",
]
