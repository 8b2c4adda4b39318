"""`Behaviour`: the manoeuvre planner of seed 000 Sec. 8 - the hierarchical state machine, one call a cycle.

    behaviour = Behaviour(planner)              # plans the mission route (or takes one)
    command = behaviour.step(situation)         # every 20-50 ms
    lateral_step(command.path_samples(), pose, command.direction, lateral_params)
    longitudinal_step(state, command.longitudinal_inputs(v), longitudinal_params)

The statechart (`build_statechart`, Fig. 11's main level): Drive (initial), Intersection, Zone, Replan,
GlobalRecovery, MissionComplete; the families are the packages drive/, intersection/ and zone/ (one module
per state), the top-level recovery states are in recovery/, the core in hsm.py. A cycle:

1. Check the situation (ValueError naming the field; time may not run backwards).
2. E-stop PAUSE or DISABLE: hold. The machine does not step, no manager sees the cycle, and the
   behaviour's clock stops (it is the situation's time minus every pause), so nothing times out while
   paused and everything resumes in the state it was in (DARPA rules 3.3). Moved more than
   `PAUSE_MOVED_RESET_M` while paused: resume in the GlobalRecovery (re-localise, replan).
3. Track: the rear axle on the route (a window around the last arc length; or the mission layer's
   `Situation.progress` when it tracks this very route) or on the manoeuvre leg being driven; the
   odometer; the objects along the route ahead and the lead among those in our lane; stillness of
   every object and since when we stand behind a still lead; checkpoints passed (front bumper within
   `CHECKPOINT_TOLERANCE_M`; the last one once we stand on it); the intersection manager's view.
4. Step the machine (top-down guarded transitions, no-progress timers), then run the active states'
   activities, which write the `Plan`.
5. Compose the `BehaviourCommand`: the stub (30 m of route or leg from 2 m behind the rear axle), the
   desired speed (the lowest cap; on the route also the speed profile: MDF limits, curves, anticipated
   at 1 m/s²; after an MTC go the drive-off ramp a_sat the check assumed; on a manoeuvre's leg ruckig's
   jerk-limited drive-off, `navigation.trajectory.launch_profile`), the nearest stop point
   (a state's, the final checkpoint's, and 7.5 m behind a still lead), the lead, the requests to the
   mission layer, and why.

Seed 000 Sec. 12's lesson ("a software exception [...] was caught by an error handler. The result was a
hanging process"): an exception inside a state's guard or action does not stop the behaviour, nor is it
hidden. The cycle still returns a command - hold, in the GlobalRecovery, with `fault` set to the error -
and the next cycles try to get back on track (`Behaviour.faults` counts them; a host module should log
every `fault` and may escalate). Two guards that keep undoing each other are such an error too
(`HsmLivelockError` after `rules.MAX_MICROSTEPS` transitions in one cycle). Bad *input* is the caller's
error and raises ValueError.

Costs: one `step` takes about 0.4 ms at a four-way stop with four vehicles (`bywire bench urban`, row
``hsm_step``); entering an intersection computes its conflict geometry once (~3 ms, then cached per
crossing), and a replan with its new route view takes ~30 ms on the DARPA sample network: a host
module at 20-50 Hz sees such a cycle as one late output, never a hang.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from bywire.host.navigation.trajectory import launch_profile
from bywire.host.roadnet.lane_index import LaneIndex
from bywire.host.roadnet.route import MissionPlanner, Route

from . import rules
from .context import BehaviourContext, BehaviourParams, Plan
from .drive import drive_family
from .drive.common import report_key
from .hsm import Fired, Machine, State
from .intersection import intersection_family
from .intersection_map import IntersectionMap
from .reactive import react
from .recovery import global_recovery_state, mission_complete_state, replan_state
from .route_view import PathObject, RouteView, objects_on_path
from .situation import BehaviourCommand, EStop, LeadObject, PathStub, Situation, stub_from_arrays
from .zone import zone_family

__all__ = ["Behaviour", "build_machine", "build_statechart"]

FloatArray = npt.NDArray[np.float64]
_PROFILE_MIN_HORIZON_M = 30.0
# how far ahead of the speed reached a leg's drive-off asks (two behaviour periods: at standstill the
# jerk-limited profile's own acceleration is 0, and the command takes that long to reach the wheels)
LAUNCH_LEAD_S = 0.1
_PROFILE_MAX_HORIZON_M = 200.0


def build_statechart() -> State[BehaviourContext]:
    """The whole state tree (a fresh one: states hold no per-run data, but parents are set on use)."""
    return State(
        "Behaviour",
        doc="seed 000 Fig. 11: the HSM's main level",
        initial="Drive",
        children=(
            drive_family(),
            intersection_family(),
            zone_family(),
            replan_state(),
            global_recovery_state(),
            mission_complete_state(),
        ),
    )


def build_machine() -> Machine[BehaviourContext]:
    return Machine(
        build_statechart(), max_microsteps=rules.MAX_MICROSTEPS, progress_m=rules.PROGRESS_DISTANCE_M
    )


class Behaviour:
    """The behaviour layer for one mission (see the module docstring). Not thread-safe; no I/O."""

    def __init__(
        self,
        planner: MissionPlanner,
        route: Route | None = None,
        *,
        params: BehaviourParams | None = None,
        lane_index: LaneIndex | None = None,
        intersections: IntersectionMap | None = None,
    ) -> None:
        graph = planner.graph
        self.params = params or BehaviourParams()
        self.imap = intersections or IntersectionMap(graph)
        self.ctx = BehaviourContext(graph, planner, lane_index or LaneIndex(graph), self.imap, self.params)
        self.ctx.route = RouteView(graph, route if route is not None else planner.plan(), self.imap)
        self.machine = build_machine()
        self.ctx.machine = self.machine
        self.ctx.retrack = self._track
        self.faults = 0
        self._last_t: float | None = None
        self._paused_total_s = 0.0
        self._was_paused = False
        self._pause_xy: tuple[float, float] | None = None
        self._last_xy: tuple[float, float] | None = None
        self._located = False

    # ------------------------------------------------------------------------------- public

    @property
    def route(self) -> Route:
        return self.ctx.view.route

    @property
    def route_view(self) -> RouteView:
        return self.ctx.view

    @property
    def state(self) -> str:
        return self.machine.path if self.machine.started else ""

    @property
    def clock_s(self) -> float:
        """The behaviour's clock: the last situation's time minus all E-stop pauses."""
        return (self._last_t or 0.0) - self._paused_total_s

    def step(self, situation: Situation) -> BehaviourCommand:
        """One cycle (see the module docstring)."""
        situation.validate()
        if self._last_t is not None and situation.t_s < self._last_t:
            raise ValueError(
                f"Situation.t_s = {situation.t_s}: before the previous cycle's {self._last_t} "
                "(time runs forward)"
            )
        if self._last_t is not None and self._was_paused:
            self._paused_total_s += situation.t_s - self._last_t
        self._last_t = situation.t_s
        ctx = self.ctx
        ctx.sit = situation
        ctx.t_s = situation.t_s - self._paused_total_s
        ctx.plan = Plan()
        ctx.requests = []
        ego = situation.ego

        if situation.estop != EStop.RUN:
            if not self._was_paused:
                self._pause_xy = (ego.x_m, ego.y_m)
            self._was_paused = True
            self._track()
            ctx.hold(f"E-stop {situation.estop.value.upper()}: holding in {self.state or 'start'}")
            return self._compose((), None, paused=True)

        resumed_far = None
        if self._was_paused:
            self._was_paused = False
            self._last_xy = (ego.x_m, ego.y_m)  # movement while paused is no progress
            if self._pause_xy is not None:
                moved = math.hypot(ego.x_m - self._pause_xy[0], ego.y_m - self._pause_xy[1])
                if moved > rules.PAUSE_MOVED_RESET_M and self.machine.started:
                    resumed_far = moved
        if self._last_xy is not None:
            ctx.odometer_m += math.hypot(ego.x_m - self._last_xy[0], ego.y_m - self._last_xy[1])
        self._last_xy = (ego.x_m, ego.y_m)
        fired: tuple[Fired, ...] = ()
        fault = None
        try:
            ctx.stillness.update(ctx.t_s, situation.objects)
            self._track()
            self._checkpoints()
            if ctx.intersection is not None:  # the guards must see this cycle's vehicles
                ctx.intersection.update(ctx.t_s, situation.objects)
            if ctx.reports_handled:  # a blockade report that went away may come back as a new one
                ctx.reports_handled &= {report_key(b) for b in situation.blocked}
            if not self.machine.started:
                self.machine.start(ctx, ctx.t_s, ctx.odometer_m)
            if resumed_far is not None:
                ctx.replan_why = f"moved {resumed_far:.0f} m during the E-stop pause"
                f, _ = self.machine.force("GlobalRecovery", ctx, ctx.t_s, ctx.odometer_m, ctx.replan_why)
                fired = (f,)
            fired += self.machine.step(ctx, ctx.t_s, ctx.odometer_m)
            self.machine.run_activities(ctx)
            react(ctx)  # the reactive layer over the states' plan (Sec. 7: tentacles)
        except Exception as exc:  # seed 000 Sec. 12: never hang, never hide (see the module docstring)
            self.faults += 1
            fault = f"{type(exc).__name__}: {exc}"
            ctx.plan = Plan()
            ctx.legs = ()
            ctx.on_route = ctx.route is not None
            ctx.replan_why = f"internal error: {fault}"
            if self.machine.started:
                f, _ = self.machine.force("GlobalRecovery", ctx, ctx.t_s, ctx.odometer_m, ctx.replan_why)
                fired += (f,)
            else:
                self.machine = build_machine()
                ctx.machine = self.machine
            ctx.hold(f"internal error, holding: {fault}")
        return self._compose(fired, fault)

    # ------------------------------------------------------------------------------- tracking

    def _track(self) -> None:
        ctx = self.ctx
        ego = ctx.situation.ego
        if ctx.legs:
            leg = ctx.legs[ctx.leg_index]
            ctx.leg_s_m, _ = leg.locate(ego.x_m, ego.y_m, ctx.leg_s_m)
            if leg.base_s is not None:
                ctx.ego_s_m = leg.route_s(ctx.leg_s_m)
                ctx.on_route = True
            else:
                ctx.on_route = False
        elif ctx.route is not None:
            view = ctx.view
            progress = ctx.situation.progress
            if progress is not None and progress.route is view.route and view.lead_in is None:
                ctx.ego_s_m, ctx.ego_lateral_m = progress.s_m, progress.lateral_m
            elif not self._located:
                ctx.ego_s_m, ctx.ego_lateral_m, _ = view.locate(ego.x_m, ego.y_m, 0.0, 0.0, view.length_m)
            else:
                ctx.ego_s_m, ctx.ego_lateral_m, _ = view.locate(ego.x_m, ego.y_m, ctx.ego_s_m)
            self._located = True
            ctx.on_route = True
        if ctx.route is not None and ctx.on_route:
            half = 0.5 * self.params.vehicle_width_m
            ctx.route_objects = ctx.view.project_objects(
                ctx.situation.objects, ctx.ego_s_m - 10.0, ctx.ego_s_m + rules.LEAD_HORIZON_M, half
            )
            ctx.lead = _nearest_ahead(ctx.route_objects, ctx.ego_s_m)
        else:
            ctx.route_objects = []
            ctx.lead = None
        lead = ctx.lead
        behind = (
            lead is not None
            and ctx.stopped
            and lead.obj.speed_mps < rules.STILL_SPEED_MPS
            and ctx.stillness.still_for(lead.obj.object_id, ctx.t_s) > 0.0
            and lead.rear_s_m - ctx.ego_front_s_m <= rules.STOOD_BEHIND_MAX_GAP_M
        )
        if not behind or lead is None:
            ctx.behind_still = None
        elif ctx.behind_still is None or ctx.behind_still[0] != lead.obj.object_id:
            ctx.behind_still = (lead.obj.object_id, ctx.t_s)

    def _checkpoints(self) -> None:
        ctx = self.ctx
        if not ctx.on_route or ctx.route is None:
            return
        for mark in ctx.pending_marks():
            if mark.spot or ctx.ego_front_s_m < mark.s_m - rules.CHECKPOINT_TOLERANCE_M:
                break
            if mark.final and not ctx.stopped:
                break  # the finish: reached once we stand on it
            ctx.reach(mark)

    # ------------------------------------------------------------------------------- output

    def _compose(self, fired: tuple[Fired, ...], fault: str | None, paused: bool = False) -> BehaviourCommand:
        ctx = self.ctx
        plan = ctx.plan
        p = self.params
        stops = list(plan.stops)
        if plan.leg is not None:
            leg = plan.leg
            stub, ego_stub_s = leg.stub(plan.leg_s_m, p.stub_length_m, p.stub_back_m)
            shift = plan.leg_s_m - ego_stub_s
            here = plan.leg_s_m
            w = slice(
                max(int(leg.s.searchsorted(here - 5.0)) - 1, 0),
                int(leg.s.searchsorted(here + rules.LEAD_HORIZON_M)) + 1,
            )
            on_leg = objects_on_path(
                leg.x[w],
                leg.y[w],
                _wrap(leg.travel_heading[w]),
                leg.s[w],
                ctx.situation.objects,
                0.5 * p.vehicle_width_m,
            )
            lead = _nearest_ahead(on_leg, here)
            front = here + p.rear_axle_to_front_m
        elif ctx.route is not None:
            view = ctx.view
            stub, ego_stub_s = view.stub(ctx.ego_s_m, p.stub_length_m, p.stub_back_m)
            shift = ctx.ego_s_m - ego_stub_s
            here = ctx.ego_s_m
            lead = ctx.lead
            front = ctx.ego_front_s_m
            if view.finish_s_m is not None:  # the finish, also once reached: we stay there
                stops.append((view.finish_s_m - p.rear_axle_to_front_m, "the mission's last checkpoint"))
        else:  # cannot happen after construction; keeps the command defined
            ego = ctx.situation.ego
            stub = _point_stub(ego.x_m, ego.y_m, ego.heading_rad)
            shift, here, lead, front, ego_stub_s = 0.0, 0.0, None, p.rear_axle_to_front_m, 0.0
        lead_out = None
        if plan.follow_lead and lead is not None and not paused:
            gap = max(lead.rear_s_m - front, 0.0)
            lead_out = LeadObject(lead.obj.object_id, gap, lead.speed_along_mps)
            if lead.speed_along_mps < rules.STILL_SPEED_MPS:
                stops.append(
                    (lead.rear_s_m - rules.STOPPED_LEAD_STANDOFF_M - p.rear_axle_to_front_m, "still lead")
                )
        speed = min((v for v, _ in plan.caps), default=rules.SPEED_LIMIT_MAX_MPS)
        if plan.leg is None and plan.profile and ctx.route is not None:
            v_now = ctx.speed_mps
            b = rules.SPEED_ANTICIPATION_DECEL_MPS2
            horizon = min(
                max(v_now * v_now / (2.0 * b) + 20.0, _PROFILE_MIN_HORIZON_M), _PROFILE_MAX_HORIZON_M
            )
            profile, _ = ctx.view.speed_profile(here, b, horizon, 1.0 / p.velocity_gain_per_s)
            speed = min(speed, profile)
        if plan.drive_off_accel_mps2 is not None:
            speed = min(speed, ctx.speed_mps + plan.drive_off_accel_mps2 / p.velocity_gain_per_s)
        elif plan.leg is not None and speed > rules.STOPPED_SPEED_MPS:
            # a manoeuvre's leg drives off along ruckig's jerk-limited profile to the leg's speed;
            # asked as v + a / c_v, the velocity controller's exact feed-forward of a
            launch = launch_profile(speed).accel_at(ctx.speed_mps, LAUNCH_LEAD_S)
            speed = min(speed, ctx.speed_mps + launch / p.velocity_gain_per_s)
        reasons = list(plan.reasons)
        if plan.hold is not None:
            speed = 0.0
            stops.append((here, plan.hold))
            reasons.insert(0, plan.hold)
        stop_point = min((s for s, _ in stops), default=None)
        return BehaviourCommand(
            t_s=ctx.situation.t_s,
            state=self.state,
            stub=stub,
            desired_speed_mps=max(speed, 0.0),
            stop_point_s_m=None if stop_point is None else stop_point - shift,
            ego_s_m=ego_stub_s,
            lead=lead_out,
            reason="; ".join(reasons),
            requests=tuple(ctx.requests),
            paused=paused,
            next_checkpoint=ctx.next_checkpoint,
            checkpoints_reached=tuple(ctx.reached),
            mtc=plan.mtc,
            fault=fault,
            transitions=tuple(f"{f.leaf} -> {f.target} ({f.label})" for f in fired),
        )


def _nearest_ahead(objects: list[PathObject], here_s_m: float) -> PathObject | None:
    ahead = [p for p in objects if p.in_corridor and p.s_m > here_s_m]
    return min(ahead, key=lambda p: p.rear_s_m, default=None)


def _wrap(a: FloatArray) -> FloatArray:
    return np.asarray((a + np.pi) % (2.0 * np.pi) - np.pi, dtype=np.float64)


def _point_stub(x_m: float, y_m: float, heading_rad: float) -> PathStub:
    return stub_from_arrays([x_m], [y_m], [heading_rad], [0.0])
