"""What the states of the machine see and write each cycle: `BehaviourContext`, `Plan`, the small managers.

Guards read the context (the situation, our place on the route, the objects along it, the managers);
activities write the `Plan` (which path to hand out, speed caps, stop points, why); `Behaviour` turns
the plan into the `BehaviourCommand`. Nothing here does I/O or reads a clock: `t_s` is the behaviour's
clock, the situation's time with every E-stop pause taken out (so that a pause freezes all timers).

`StillnessTracker` is the blockade bookkeeping of AnnieWAY's `aw_BlockadeManager`: since when each
object has stood still (slower than `rules.STILL_SPEED_MPS` and within `rules.STILL_DISPLACEMENT_M` of
where it came to rest). The passing and blockade timers of the Drive family count from when *we*
stopped behind a still lead (`behind_still`, kept by `Behaviour`): a car that came to rest long before
we saw it is still given its seconds once we are behind it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from bywire.host.longitudinal import LongitudinalParams
from bywire.host.roadnet.graph import Edge, RoadGraph
from bywire.host.roadnet.lane_index import LaneIndex
from bywire.host.roadnet.road_area import RoadArea
from bywire.host.roadnet.route import MissionPlanner

from . import rules
from .intersection_map import IntersectionMap
from .lanes import AdjacentLane
from .manoeuvre import STEER_PREVIEW_M, Leg, steering_speed_cap
from .mtc import MtcResult
from .route_view import CheckpointMark, PathObject, RouteView
from .situation import MissionRequest, RequestKind, Situation, TrackedObject

if TYPE_CHECKING:
    from .hsm import Machine
    from .intersection_manager import Crossing, IntersectionManager

__all__ = ["BehaviourContext", "BehaviourParams", "Plan", "StillnessTracker"]


@dataclass(frozen=True)
class BehaviourParams:
    """The vehicle and the cycle-independent knobs (rule values live in `rules`)."""

    rear_axle_to_front_m: float = rules.PASSAT_REAR_AXLE_TO_FRONT_M
    vehicle_length_m: float = rules.PASSAT_VARIANT_LENGTH_M
    vehicle_width_m: float = rules.PASSAT_WIDTH_M
    # c_v of the velocity controller (seed 000 eq. 31): the speed profile's lag compensation and the
    # drive-off shaping (Sec. 9.1 assumption 3) are computed with it.
    velocity_gain_per_s: float = LongitudinalParams().velocity_gain_per_s
    stub_length_m: float = rules.STUB_LENGTH_M
    stub_back_m: float = rules.STUB_BACK_M
    kturn_radius_m: float = rules.KTURN_RADIUS_M

    def __post_init__(self) -> None:
        for name in (
            "rear_axle_to_front_m",
            "vehicle_length_m",
            "vehicle_width_m",
            "velocity_gain_per_s",
            "stub_length_m",
            "kturn_radius_m",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"BehaviourParams.{name} = {value}: must be finite and > 0")
        if not (math.isfinite(self.stub_back_m) and self.stub_back_m >= 0.0):
            raise ValueError(f"BehaviourParams.stub_back_m = {self.stub_back_m}: must be finite and >= 0")


@dataclass
class Plan:
    """One cycle's decision, written by the activities of the active states."""

    leg: Leg | None = None  # None: drive along the route
    leg_s_m: float = 0.0  # our rear axle's arc length on `leg`
    caps: list[tuple[float, str]] = field(default_factory=list)  # speed caps (m/s) and why
    stops: list[tuple[float, str]] = field(default_factory=list)  # rear-axle stop points (route or leg s)
    hold: str | None = None  # stand still here, and why
    follow_lead: bool = True
    profile: bool = True  # apply the route's speed profile (limits, curves)
    drive_off_accel_mps2: float | None = None  # shape the drive-off to this acceleration (MTC assumption 3)
    reasons: list[str] = field(default_factory=list)
    mtc: MtcResult | None = None


class StillnessTracker:
    """Since when each object stands still (see the module docstring); forgets objects no longer seen."""

    def __init__(self) -> None:
        self._rest: dict[str, tuple[float, float, float]] = {}  # id -> (since, x, y)

    def update(self, t_s: float, objects: tuple[TrackedObject, ...]) -> None:
        rest: dict[str, tuple[float, float, float]] = {}
        for obj in objects:
            if obj.speed_mps >= rules.STILL_SPEED_MPS:
                continue
            known = self._rest.get(obj.object_id)
            if (
                known is not None
                and math.hypot(obj.x_m - known[1], obj.y_m - known[2]) <= rules.STILL_DISPLACEMENT_M
            ):
                rest[obj.object_id] = known
            else:
                rest[obj.object_id] = (t_s, obj.x_m, obj.y_m)
        self._rest = rest

    def still_for(self, object_id: str, t_s: float) -> float:
        """Seconds `object_id` has stood still (0 if it moves or is unknown)."""
        known = self._rest.get(object_id)
        return 0.0 if known is None else t_s - known[0]


class BehaviourContext:
    """Everything guards, actions and activities work with (see the module docstring)."""

    def __init__(
        self,
        graph: RoadGraph,
        planner: MissionPlanner,
        lane_index: LaneIndex,
        imap: IntersectionMap,
        params: BehaviourParams,
    ) -> None:
        # where the Zone states' plans are solved (`path_planning.PathPlanner`): None, at once in the
        # cycle; the host module gives a worker process on wall time
        self.path_planner: object | None = None
        self.graph = graph
        self.planner = planner
        self.lane_index = lane_index
        self.imap = imap
        self.params = params
        self.machine: Machine[BehaviourContext] | None = None
        # this cycle
        self.sit: Situation | None = None
        self.t_s = 0.0
        self.plan = Plan()
        self.requests: list[MissionRequest] = []
        # the route and our place on it
        self.route: RouteView | None = None
        self.ego_s_m = 0.0
        self.ego_lateral_m = 0.0
        self.on_route = False  # our place on the route is being tracked (not during off-route legs)
        self.route_objects: list[PathObject] = []
        self.lead: PathObject | None = None
        # since when we stand behind the still lead (its id, the time): the pass and blockade timers
        # count from here, not from when the obstacle came to rest far ahead of us
        self.behind_still: tuple[str, float] | None = None
        self.reports_handled: set[tuple[object, ...]] = set()  # perception's blockades acted upon
        self.next_checkpoint = 0  # mission index
        self.reached: list[int] = []  # checkpoint numbers, in order
        # managers and plans of the families
        self.stillness = StillnessTracker()
        self.intersection: IntersectionManager | None = None
        self.crossing_cache: dict[tuple[object, ...], Crossing] = {}
        self.legs: tuple[Leg, ...] = ()  # the manoeuvre being driven (K-turn, passing, zone)
        self.leg_index = 0
        self.leg_s_m = 0.0
        self.manoeuvre_data: dict[str, object] = {}  # per-manoeuvre facts (pass plan, zone targets)
        self.replan_outcome: str | None = None  # "drive", "kturn", "failed" (Replan / GlobalRecovery)
        self.replan_why = ""
        # the lane a K-turn turns onto (DriveOnLane at a U-turn, Replan at a blockade; None: find one)
        self.kturn_target: AdjacentLane | None = None
        self._road_area: RoadArea | None = None
        self.family_anchor_odometer_m = 0.0  # odometer when a recovery state was entered
        self.odometer_m = 0.0
        self.retrack: Callable[[], None] = lambda: None  # `Behaviour` re-tracks us after a new route

    # ------------------------------------------------------------------------------- facts

    @property
    def situation(self) -> Situation:
        assert self.sit is not None
        return self.sit

    @property
    def speed_mps(self) -> float:
        return abs(self.situation.ego.speed_mps)

    @property
    def stopped(self) -> bool:
        return self.speed_mps < rules.STOPPED_SPEED_MPS

    @property
    def ego_front_s_m(self) -> float:
        return self.ego_s_m + self.params.rear_axle_to_front_m

    @property
    def view(self) -> RouteView:
        assert self.route is not None
        return self.route

    @property
    def road_area(self) -> RoadArea:
        """Where the road is (`roadnet.road_area`), made on first use: the K-turn's map."""
        if self._road_area is None:
            self._road_area = RoadArea.of(self.graph)
        return self._road_area

    def time_in(self, state: str) -> float:
        assert self.machine is not None
        return self.machine.time_in(state, self.t_s)

    def is_active(self, state: str) -> bool:
        return self.machine is not None and self.machine.is_active(state)

    def stood_behind_s(self, object_id: str) -> float:
        """Seconds we have stood behind the still `object_id` as our lead (0 if we do not)."""
        if self.behind_still is None or self.behind_still[0] != object_id:
            return 0.0
        return self.t_s - self.behind_still[1]

    def traffic_moving(self) -> bool:
        """A vehicle near us is moving: we are waiting on traffic, not stuck (excuses no progress)."""
        ego = self.situation.ego
        return any(
            o.speed_mps > rules.STILL_SPEED_MPS
            and math.hypot(o.x_m - ego.x_m, o.y_m - ego.y_m) < rules.TRAFFIC_NEAR_M
            for o in self.situation.objects
        )

    def current_edge(self) -> Edge | None:
        if self.route is None or not self.route.edges:
            return None
        return self.route.edges[self.route.edge_index_at(self.ego_s_m)]

    # ------------------------------------------------------------------------------- checkpoints

    def pending_marks(self) -> list[CheckpointMark]:
        """The route's checkpoints not reached yet, in mission order."""
        if self.route is None:
            return []
        return [m for m in self.route.checkpoints if m.mission_index >= self.next_checkpoint]

    def reach(self, mark: CheckpointMark) -> None:
        self.reached.append(mark.number)
        self.next_checkpoint = mark.mission_index + 1

    # ------------------------------------------------------------------------------- manoeuvres

    def begin_legs(self, legs: tuple[Leg, ...]) -> None:
        """Drive `legs` from now on (a K-turn, a passing shift, the zone stand-in), from the first."""
        self.legs = legs
        self.select_leg(0)

    def select_leg(self, index: int) -> None:
        """Switch to leg `index` and place us on it (entry actions run before this cycle's plan)."""
        self.leg_index = index
        ego = self.situation.ego
        leg = self.legs[index]
        self.leg_s_m = leg.locate(ego.x_m, ego.y_m, 0.0)[0]
        if leg.base_s is not None:
            self.ego_s_m = leg.route_s(self.leg_s_m)
            self.on_route = True
        else:
            self.on_route = False

    def leg_done(self) -> bool:
        """Stopped at the end of the leg being driven (within `rules.KTURN_SWITCH_DISTANCE_M` of it): where
        a manoeuvre's next leg begins, the gear changing at a cusp."""
        if not self.legs:
            return False
        leg = self.legs[self.leg_index]
        return self.leg_s_m >= leg.end_s_m - rules.KTURN_SWITCH_DISTANCE_M and self.stopped

    def drive_to_cusp(self, why: str) -> None:
        """A leg before the last ends in a stop at its end: once stopped there, the next leg begins;
        until then the stop is planned."""
        if self.leg_done():
            self.select_leg(self.leg_index + 1)
        else:
            self.stop_rear_at(self.legs[self.leg_index].end_s_m, why)

    def end_legs(self) -> None:
        """Back to the route (its tracking resumes around `ego_s_m`)."""
        self.legs = ()
        self.leg_index = 0
        self.leg_s_m = 0.0
        self.on_route = self.route is not None

    # ------------------------------------------------------------------------------- plan helpers

    def say(self, reason: str) -> None:
        self.plan.reasons.append(reason)

    def cap(self, speed_mps: float, why: str) -> None:
        self.plan.caps.append((max(speed_mps, 0.0), why))

    def cap_for_steering(self) -> None:
        """Cap this cycle's speed so the wheels keep up with the leg being driven
        (`manoeuvre.steering_speed_cap` with the rules' rate and allowance, `STEER_PREVIEW_M` ahead),
        never below `rules.STEER_CRAWL_MPS`."""
        if not self.legs:
            return
        cap = steering_speed_cap(
            self.legs[self.leg_index], self.leg_s_m, rules.PASSAT_WHEELBASE_M, rules.STEER_PLAN_RATE_RADPS,
            rules.STEER_ALLOW_M, STEER_PREVIEW_M,
        )  # fmt: skip
        if math.isfinite(cap):
            self.cap(max(cap, rules.STEER_CRAWL_MPS), "time to steer")

    def stop_front_at(self, front_s_m: float, why: str) -> None:
        """Stop with the front bumper at `front_s_m` (route or leg arc length, whichever is driven)."""
        self.plan.stops.append((front_s_m - self.params.rear_axle_to_front_m, why))

    def stop_rear_at(self, rear_s_m: float, why: str) -> None:
        self.plan.stops.append((rear_s_m, why))

    def hold(self, why: str) -> None:
        self.plan.hold = why

    def request(self, kind: RequestKind, detail: str, edge: Edge | None = None) -> None:
        self.requests.append(MissionRequest(kind, detail, None if edge is None else edge.key))
