"""The host's topics and their objects: what the modules of the spine's host say to each other.

Every object is a frozen dataclass with `t_s`, the time it is valid for on the runtime clock (the
release time of the module that made it, unless the field says otherwise). Times of reception
(`rx_s`) are kept separately so a consumer can judge freshness itself: a module publishes every
release, also when its input is missing, and says so (`valid`, `fresh`), so that silence always
means the module is in trouble, never that the world is quiet.
"""

from __future__ import annotations

from dataclasses import dataclass

from bywire.host.runtime.log_schema import register_type
from bywire.host.runtime.store import linear_interpolation
from bywire.protocol.ecu_types import RequestFlags

MISSION = "/mission/command"
ECU_STATUS = "/ecu/status"
ECU_REQUEST = "/ecu/request"
RADAR = "/radar/target"
LEAD = "/perception/lead"
ODOMETRY = "/ego/odometry"
CONTROL = "/control/request"
RUN_INFO = "/run/info"


@register_type(retired=("heartbeat_mute",))
@dataclass(frozen=True)
class MissionCommand:
    """What the mission wants now: the driver's command script (`host.command_script`)."""

    t_s: float
    mode: str  # "script": follow accel_mps2; "drive": the longitudinal override controller
    v_des_mps: float
    accel_mps2: float  # script mode's request
    steer_rad: float
    steer: bool
    engage: bool
    rearm: bool
    stop: bool  # ask the ECU for a controlled stop
    stop_line_m: float  # along the path from the start (nan: no stop line)

    def request_flags(self, steer: bool | None = None) -> RequestFlags:
        """The ECU request flags this command asks for; `steer` overrides the mission's own STEER
        (a controller that steers by itself)."""
        flags = RequestFlags.NONE
        if self.engage:
            flags |= RequestFlags.ENGAGE
        if self.steer if steer is None else steer:
            flags |= RequestFlags.STEER
        if self.rearm:
            flags |= RequestFlags.REARM
        if self.stop:
            flags |= RequestFlags.STOP
        return flags


@register_type
@dataclass(frozen=True)
class EcuStatusReport:
    """The ECU's latest status as the host received it (`fresh`: a new one arrived this release)."""

    t_s: float
    valid: bool
    fresh: bool
    rx_s: float  # reception time of the status (nan: none yet)
    state: int  # EcuState
    faults: int  # Fault bits
    nmt_operational: bool
    speed_mps: float
    accel_mps2: float
    throttle_pct: float
    brake_bar: float
    steer_angle_rad: float


@register_type
@linear_interpolation("odometer_m", "speed_mps")
@dataclass(frozen=True)
class Odometry:
    """Distance driven since the start (from the ECU's measured speed) and the speed."""

    t_s: float
    odometer_m: float
    speed_mps: float
    valid: bool


@register_type
@dataclass(frozen=True)
class RadarReport:
    """The radar's newest target (`valid` false: no target, or none received for too long)."""

    t_s: float
    valid: bool
    rx_s: float
    range_m: float
    range_rate_mps: float


@register_type
@dataclass(frozen=True)
class LeadTrack:
    """The vehicle ahead in our lane, as the perception believes it."""

    t_s: float
    valid: bool
    gap_m: float
    v_lead_mps: float


@register_type
@dataclass(frozen=True)
class ControlRequest:
    """The longitudinal (and scripted lateral) request for the ECU, with why it was chosen."""

    t_s: float
    accel_mps2: float
    steer_rad: float
    flags: int  # RequestFlags
    controller: str  # one of hil.trace.CONTROLLERS
    v_des_mps: float
    gap_m: float  # nan: no lead


@register_type
@dataclass(frozen=True)
class EcuRequestSent:
    """What actually went to the ECU this release (after the link's own freshness check)."""

    t_s: float
    accel_mps2: float
    steer_rad: float
    flags: int
    counter: int
    request_age_ms: float  # age of the control request sent (-1: none, a stop was sent instead)
    heartbeat: bool


@register_type
@dataclass(frozen=True)
class RunInfo:
    """What a recording needs to be replayed on its own: the scenario and host configuration as run.

    Published once, when the runtime starts (`t_s` = the start of its release grid).
    """

    t_s: float
    scenario_source: str
    scenario_text: str  # the scenario file as it was (YAML or TOML, by the source's suffix)
    host_config_source: str
    host_config_json: str  # the configuration after `extends`, as parsed
    lockstep: bool  # SIL (simulated time) or wall time
