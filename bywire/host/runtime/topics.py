"""The runtime's own topics: what the supervisor reports and asks for, and the modules' health.

These are ordinary store objects, so they are recorded, replayed and shown live like any other
topic; the host modules that must obey them (the longitudinal controller, the ECU link) read them
as declared inputs.
"""

from __future__ import annotations

from dataclasses import dataclass

from bywire.host.runtime.log_schema import register_type

SUPERVISOR_EVENTS = "/supervisor/events"
SAFETY_LIMIT = "/supervisor/limit"
STOP_REQUEST = "/supervisor/stop"
MODULE_HEALTH = "/runtime/health"


@register_type
@dataclass(frozen=True)
class SupervisorEvent:
    """One detection or action of the supervisor, with its cause and how long detection took.

    `onset_s` is the supervisor's own estimate of when the failure began (the release that never
    ended, the exception's time, the first of the deadline misses); `detect_ms` = t_s - onset_s.
    """

    t_s: float
    module: str
    generation: int
    cause: str  # exception | crashed | hang | deadlock | slow | stale | dependant | recovered | escalated
    detail: str
    action: str  # restart | degrade | stop | none
    onset_s: float
    detect_ms: float


@register_type
@dataclass(frozen=True)
class SafetyLimit:
    """A limit every motion module must respect from `t_s` on (the supervisor's "degrade")."""

    t_s: float
    max_speed_mps: float
    reason: str


@register_type
@dataclass(frozen=True)
class StopRequest:
    """Ask the ECU for a controlled stop (request flag STOP), with why."""

    t_s: float
    reason: str


@register_type
@dataclass(frozen=True)
class ModuleHealth:
    """A module's state and timing, published by the runtime every `health_period_s`."""

    t_s: float
    module: str
    generation: int
    state: str  # starting | running | restarting | degraded | stopped | failed
    releases: int
    completed: int
    misses: int
    skipped: int
    restarts: int
    exec_ms_p50: float
    exec_ms_p99: float
    exec_ms_max: float
    output_age_ms: float  # newest output's age (-1: nothing published yet)
