"""What the behaviour layer takes in each cycle (`Situation`) and what it gives out (`BehaviourCommand`).

Seed 000 Sec. 8: "When all situation assessment has taken place and all state transitions are made,
the reached state generates a path stub that is input to the closed-loop control module (Section 11).
It reaches approximately 30 m ahead and consists of densely sampled way points combined with heading
and curvature information." Sec. 11.2: the longitudinal controllers take a desired speed, a lead
vehicle and a stop point. So the command carries exactly those, plus what the mission layer must hear
(replan requests, blocked edges) and why.

Conventions (all SI, ENU local metres of the road network's frame):

- The ego pose is the **rear axle** (the reference point of the orbital controller, Sec. 11.1); the
  rules judge the front bumper (`rules.PASSAT_REAR_AXLE_TO_FRONT_M` ahead of it). `speed_mps` is
  signed: negative while reversing.
- Objects are boxes: centre, heading, `length_m` x `width_m`, speed >= 0 along their heading (a
  tracker's negative speed is a heading flipped by pi). `lane` is the world model's match of the
  object to a lane edge of the graph (`LaneIndex.match`, seed 000 Sec. 8: "Dynamic objects [...] are
  matched to the most probable edge"); `match_objects` fills it. Objects without one still count as
  obstacles on our path and at stop lines, but not as priority traffic on a lane (the MTC needs the
  lane to know the vehicle's way to the merge point).
- `estop`: PAUSE and DISABLE make the behaviour hold (stop and stay) in its current state; RUN again
  resumes there (DARPA rules 3.3: "ready to resume forward motion when the E-stop re-enters RUN").
- `progress` is optional: the mission layer's own tracking of the behaviour's route; by default
  (None) the behaviour tracks its route itself, which it owns (it replans).

Output: `BehaviourCommand.stub` is densely sampled (0.25 m) in the order it is driven, heading = the
body's heading (nose direction, also reversing), curvature = the steering curvature tan(delta)/l, as
`host/lateral.PathSamples` wants; `path_samples()` makes one. `stop_point_s_m` and `ego_s_m` are arc
lengths along the stub, so `stop_distance_m` = their difference is what `longitudinal_step` wants
(`longitudinal_inputs(v)`). In reverse the longitudinal controller (forward only) is fed the speed's
magnitude and the distance along the reversing stub.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from enum import StrEnum
from typing import Literal

import numpy as np
import numpy.typing as npt

from bywire.host.lateral import PathSamples
from bywire.host.longitudinal import LeadObservation, LongitudinalInputs
from bywire.host.roadnet.ids import WaypointId
from bywire.host.roadnet.lane_index import LaneIndex, LaneMatch
from bywire.host.roadnet.route import Route

from .mtc import MtcResult

__all__ = [
    "BehaviourCommand",
    "BlockedRoad",
    "Direction",
    "EStop",
    "EdgeKey",
    "EgoState",
    "LaneRef",
    "LeadObject",
    "MissionRequest",
    "PathStub",
    "RequestKind",
    "RouteProgress",
    "Situation",
    "TrackedObject",
    "match_objects",
    "stub_from_arrays",
]

FloatArray = npt.NDArray[np.float64]
Direction = Literal[1, -1]
EdgeKey = tuple[WaypointId, WaypointId]


class EStop(StrEnum):
    """The E-stop / ECU state as far as behaviour cares (DARPA rules 3.3: RUN, PAUSE, DISABLE)."""

    RUN = "run"
    PAUSE = "pause"
    DISABLE = "disable"


@dataclass(frozen=True)
class EgoState:
    """Our vehicle: rear-axle position, heading (rad, ENU), signed speed (m/s), acceleration (m/s²)."""

    x_m: float
    y_m: float
    heading_rad: float
    speed_mps: float
    accel_mps2: float = 0.0


@dataclass(frozen=True)
class LaneRef:
    """An object matched to a graph edge: arc length along the edge and signed offset (left > 0)."""

    edge: EdgeKey
    s_m: float
    lateral_m: float = 0.0

    @classmethod
    def from_match(cls, match: LaneMatch) -> LaneRef:
        return cls(match.edge.key, match.s_m, match.lateral_offset_m)


@dataclass(frozen=True)
class TrackedObject:
    """Another traffic participant or obstacle: box centre, heading, speed along it, size, lane match."""

    object_id: str
    x_m: float
    y_m: float
    heading_rad: float
    speed_mps: float
    length_m: float
    width_m: float
    lane: LaneRef | None = None


@dataclass(frozen=True)
class BlockedRoad:
    """Perception's verdict that the road is blocked at (x, y), on `edge` if it knows which."""

    x_m: float
    y_m: float
    edge: EdgeKey | None = None
    detail: str = ""


@dataclass(frozen=True)
class RouteProgress:
    """The mission layer's tracking of a route: drive piece index, arc length and offset on its path."""

    route: Route
    piece_index: int
    s_m: float
    lateral_m: float


@dataclass(frozen=True)
class Situation:
    """One cycle's input. `t_s` is monotonic (may not go backwards between calls)."""

    t_s: float
    ego: EgoState
    objects: tuple[TrackedObject, ...] = ()
    blocked: tuple[BlockedRoad, ...] = ()
    estop: EStop = EStop.RUN
    progress: RouteProgress | None = None
    # the perception's obstacle cells (k x 3: centre x, y and size, metres), where it has a grid (LIDAR)
    obstacle_cells: np.ndarray | None = field(default=None, compare=False)

    def validate(self) -> None:
        """ValueError naming the field of the first bad value (non-finite, negative size, ...)."""
        _finite("Situation.t_s", self.t_s)
        if not isinstance(self.ego, EgoState):
            raise ValueError(f"Situation.ego: expected an EgoState, got {type(self.ego).__name__}")
        _position("Situation.ego", self.ego.x_m, self.ego.y_m)
        for name in ("heading_rad", "speed_mps", "accel_mps2"):
            _finite(f"Situation.ego.{name}", getattr(self.ego, name))
        if not isinstance(self.estop, EStop):
            raise ValueError(f"Situation.estop = {self.estop!r}: expected one of {[e.value for e in EStop]}")
        seen: set[str] = set()
        for i, obj in enumerate(self.objects):
            if not isinstance(obj, TrackedObject):
                raise ValueError(
                    f"Situation.objects[{i}]: expected a TrackedObject, got {type(obj).__name__}"
                )
            where = f"Situation.objects[{i}] ({obj.object_id!r})"
            if not isinstance(obj.object_id, str) or not obj.object_id:
                raise ValueError(f"{where}.object_id: must be a non-empty string")
            if obj.object_id in seen:
                raise ValueError(f"{where}.object_id: listed twice in one situation")
            seen.add(obj.object_id)
            _position(where, obj.x_m, obj.y_m)
            _finite(f"{where}.heading_rad", obj.heading_rad)
            if not (math.isfinite(obj.speed_mps) and obj.speed_mps >= 0.0):
                raise ValueError(
                    f"{where}.speed_mps = {obj.speed_mps}: must be finite and >= 0 along the heading "
                    "(a negative tracker speed is the heading turned by pi)"
                )
            for name in ("length_m", "width_m"):
                value = getattr(obj, name)
                if not (math.isfinite(value) and value > 0.0):
                    raise ValueError(f"{where}.{name} = {value}: must be finite and > 0")
            if obj.lane is not None:
                _finite(f"{where}.lane.s_m", obj.lane.s_m)
                _finite(f"{where}.lane.lateral_m", obj.lane.lateral_m)
        for i, b in enumerate(self.blocked):
            _position(f"Situation.blocked[{i}]", b.x_m, b.y_m)
        if self.progress is not None:
            _finite("Situation.progress.s_m", self.progress.s_m)
            _finite("Situation.progress.lateral_m", self.progress.lateral_m)


def _finite(name: str, value: float) -> None:
    if not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{name} = {value!r}: must be a finite number")


# Positions are metres in the network's local frame; one farther out than a quarter of the Earth's
# circumference is no place on the map (and 1e300 m overflowed the lane index's kd-tree query).
MAX_COORDINATE_M = 1.0e7


def _position(where: str, x_m: float, y_m: float) -> None:
    for name, value in (("x_m", x_m), ("y_m", y_m)):
        _finite(f"{where}.{name}", value)
        if abs(value) > MAX_COORDINATE_M:
            raise ValueError(
                f"{where}.{name} = {value!r}: beyond {MAX_COORDINATE_M:g} m from the local frame's origin"
            )


def match_objects(index: LaneIndex, objects: Iterable[TrackedObject]) -> tuple[TrackedObject, ...]:
    """The objects with their `lane` filled from `index.match` (position and heading), as the world
    model does it (seed 000 Sec. 8). Objects already matched keep their match."""
    out = []
    for obj in objects:
        if obj.lane is None:
            m = index.match(obj.x_m, obj.y_m, obj.heading_rad)
            if m is not None:
                obj = replace(obj, lane=LaneRef.from_match(m))
        out.append(obj)
    return tuple(out)


# ------------------------------------------------------------------------------------------- output


@dataclass(frozen=True, eq=False)
class PathStub:
    """The path stub (seed 000 Sec. 8): samples in driving order, body heading, steering curvature."""

    x_m: FloatArray
    y_m: FloatArray
    heading_rad: FloatArray
    curvature_1pm: FloatArray
    s_m: FloatArray
    direction: Direction = 1

    def __post_init__(self) -> None:
        n = self.x_m.shape[0]
        if n < 2 or any(a.shape != (n,) for a in (self.y_m, self.heading_rad, self.curvature_1pm, self.s_m)):
            raise ValueError(f"PathStub: needs >= 2 samples in equal 1-D arrays, got {n}")
        for a in (self.x_m, self.y_m, self.heading_rad, self.curvature_1pm, self.s_m):
            a.setflags(write=False)

    @property
    def length_m(self) -> float:
        return float(self.s_m[-1] - self.s_m[0])

    def to_path_samples(self) -> PathSamples:
        """`host/lateral.PathSamples` of the stub (with `direction` for `lateral_step`)."""
        return PathSamples(self.x_m, self.y_m, self.heading_rad, self.curvature_1pm, self.s_m)


@dataclass(frozen=True)
class LeadObject:
    """The vehicle to follow: bumper-to-bumper gap along our path and its speed along it (>= 0)."""

    object_id: str
    gap_m: float
    speed_mps: float


class RequestKind(StrEnum):
    """What the behaviour tells the mission layer."""

    REPLAN = "replan"  # we planned a new route from here (the behaviour did it, this says so)
    EDGE_BLOCKED = "edge_blocked"  # we marked `edge` blocked in the road graph
    BLOCKADES_FORGOTTEN = "blockades_forgotten"  # a checkpoint was unreachable: all blockades cleared
    CHECKPOINT_UNREACHABLE = "checkpoint_unreachable"  # even without blockades: skipped


@dataclass(frozen=True)
class MissionRequest:
    kind: RequestKind
    detail: str
    edge: EdgeKey | None = None


@dataclass(frozen=True, eq=False)
class BehaviourCommand:
    """One cycle's output (see the module docstring for the conventions)."""

    t_s: float
    state: str  # active state path, e.g. "Intersection/IntersectionWait"
    stub: PathStub
    desired_speed_mps: float  # >= 0, magnitude (also reversing)
    stop_point_s_m: float | None  # where the rear axle must stop, arc length along the stub
    ego_s_m: float  # the rear axle's projection onto the stub when this command was made
    lead: LeadObject | None
    reason: str
    requests: tuple[MissionRequest, ...] = ()
    paused: bool = False
    next_checkpoint: int = 0  # mission index of the next checkpoint to reach (len(mission): done)
    checkpoints_reached: tuple[int, ...] = ()  # checkpoint numbers passed so far, in order
    mtc: MtcResult | None = None  # the moving-traffic check that decided this cycle, if any
    fault: str | None = None  # an internal error this cycle (we went to the global recovery)
    transitions: tuple[str, ...] = field(default=())  # "A -> B (why)" fired this cycle

    @property
    def direction(self) -> Direction:
        return self.stub.direction

    @property
    def stop_distance_m(self) -> float | None:
        """Distance from the rear axle to its stop point along the stub (negative once past it)."""
        if self.stop_point_s_m is None:
            return None
        return self.stop_point_s_m - self.ego_s_m

    def longitudinal_inputs(self, v_mps: float) -> LongitudinalInputs:
        """`host/longitudinal.LongitudinalInputs` for our measured speed `v_mps` (its magnitude is used:
        the controller drives forward along whichever way the stub goes)."""
        lead = None if self.lead is None else LeadObservation(self.lead.gap_m, self.lead.speed_mps)
        return LongitudinalInputs(
            v_mps=abs(v_mps),
            v_des_mps=self.desired_speed_mps,
            lead=lead,
            stop_distance_m=self.stop_distance_m,
        )

    def path_samples(self) -> PathSamples:
        return self.stub.to_path_samples()

    def summary(self) -> tuple[object, ...]:
        """The decision in comparable form (determinism checks, replay diffs)."""
        return (
            round(self.t_s, 9),
            self.state,
            self.direction,
            round(self.desired_speed_mps, 9),
            None if self.stop_point_s_m is None else round(self.stop_point_s_m, 9),
            None if self.lead is None else (self.lead.object_id, round(self.lead.gap_m, 9)),
            tuple(r.kind.value for r in self.requests),
            self.next_checkpoint,
        )


def stub_from_arrays(
    x: Sequence[float] | FloatArray,
    y: Sequence[float] | FloatArray,
    heading: Sequence[float] | FloatArray,
    curvature: Sequence[float] | FloatArray,
    direction: Direction = 1,
) -> PathStub:
    """A `PathStub` from samples in driving order; repeated points are dropped, s is recomputed."""
    xa = np.asarray(x, dtype=np.float64)
    ya = np.asarray(y, dtype=np.float64)
    ha = np.asarray(heading, dtype=np.float64)
    ka = np.asarray(curvature, dtype=np.float64)
    if xa.size == 0 or not (xa.shape == ya.shape == ha.shape == ka.shape):
        raise ValueError(f"stub_from_arrays: needs equal non-empty arrays, got {xa.shape}, {ya.shape}")
    step = np.hypot(np.diff(xa), np.diff(ya))
    keep = np.concatenate(([True], step > 1e-6))
    xa, ya, ha, ka = xa[keep], ya[keep], ha[keep], ka[keep]
    if xa.size < 2:  # a degenerate stub: a 1 cm stub along the heading keeps the controllers defined
        h = float(ha[0]) if ha.size else 0.0
        sign = 1.0 if direction == 1 else -1.0
        xa = np.array([xa[0], xa[0] + sign * 0.01 * math.cos(h)])
        ya = np.array([ya[0], ya[0] + sign * 0.01 * math.sin(h)])
        ha = np.array([h, h])
        ka = np.zeros(2)
    s = np.concatenate(([0.0], np.cumsum(np.hypot(np.diff(xa), np.diff(ya)))))
    return PathStub(
        np.ascontiguousarray(xa),
        np.ascontiguousarray(ya),
        np.ascontiguousarray(np.arctan2(np.sin(ha), np.cos(ha))),
        np.ascontiguousarray(ka),
        s,
        direction,
    )
