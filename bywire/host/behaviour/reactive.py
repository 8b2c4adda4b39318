"""The reactive layer (seed 000 Sec. 7): tentacles when the planned path is blocked close ahead.

The states plan to stop for what they see in time (the following logic stops 5-10 m behind a still
obstacle, and passing or a blockade comes after). What appears too close for that — a box dropped just
ahead, an obstacle the perception finds late — is the reactive layer's: every cycle the behaviour drives
the route forward (no manoeuvre's legs, no hold) above `REACT_MIN_SPEED_MPS`, `react` looks along the
path being driven for standing obstacles (objects slower than `rules.STILL_SPEED_MPS`, and on LIDAR the
occupancy grid's obstacle cells) in the car's corridor closer to the front bumper than a comfortable stop
needs (v² / (2 `COMFORT_DECEL_MPS2`) + `REACT_MARGIN_M`). Then it chooses a tentacle
(`navigation.tentacles`: drivable, clear, far from obstacles, near the path, like the last one) and this
cycle drives on it, no faster than now; where no tentacle is drivable it stops before the obstacle at
whatever braking that takes.

It stays engaged while such an obstacle is still beside the car (within the corridor and
`tentacles.TentacleParams.clearance_band_m` of the path, from `REAR_CLEAR_M` behind the rear bumper), so
the car does not swing back onto it with its tail; then the route's tracking brings the car back to the
lane.

As in the paper, obstacles are evaluated up to the first tracked vehicle on the path that moves (the
following logic's business).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from bywire.host.navigation.tentacles import TentacleParams, choose_tentacle

from . import rules
from .context import BehaviourContext
from .manoeuvre import Leg
from .path_planning import standing_points

__all__ = ["react"]

REACT_MIN_SPEED_MPS = 1.0
COMFORT_DECEL_MPS2 = 2.0
REACT_MARGIN_M = 2.0  # below the following logic's standoff (rules.STOPPED_LEAD_STANDOFF_M, 7.5 m)
REAR_CLEAR_M = 2.0
_KEY = "tentacle_kappa"


def _params(ctx: BehaviourContext) -> TentacleParams:
    p = ctx.params
    return TentacleParams(
        half_width_m=0.5 * p.vehicle_width_m,
        front_m=p.rear_axle_to_front_m,
        rear_m=p.vehicle_length_m - p.rear_axle_to_front_m,
        min_radius_m=p.kturn_radius_m,
    )


def react(ctx: BehaviourContext) -> None:
    """The reactive layer's say in this cycle's plan (see the module docstring)."""
    plan = ctx.plan
    engaged = _KEY in ctx.manoeuvre_data
    if (
        ctx.route is None
        or not ctx.on_route
        or ctx.legs
        or plan.leg is not None
        or plan.hold is not None
        or ctx.speed_mps < REACT_MIN_SPEED_MPS
    ):
        ctx.manoeuvre_data.pop(_KEY, None)
        return
    p = _params(ctx)
    view = ctx.view
    v = ctx.speed_mps
    trigger = v * v / (2.0 * COMFORT_DECEL_MPS2) + REACT_MARGIN_M
    s0 = ctx.ego_s_m - p.rear_m - REAR_CLEAR_M
    s1 = ctx.ego_front_s_m + max(trigger, p.base_length_m + v * p.length_time_s)
    lead = ctx.lead
    if lead is not None and abs(lead.obj.speed_mps) >= rules.STILL_SPEED_MPS:
        s1 = min(s1, lead.rear_s_m)  # up to the first tracked vehicle that moves
    w = view.window(s0, s1)
    path_s = view.s[w]
    if path_s.size < 2:
        return
    path_xy = np.column_stack((view.x[w], view.y[w]))
    obstacles = standing_points(ctx)
    if not obstacles.size:
        ctx.manoeuvre_data.pop(_KEY, None)
        return
    dist, j = cKDTree(path_xy).query(obstacles)
    along = path_s[j]
    corridor = p.half_width_m + p.margin_m
    ahead = (along >= ctx.ego_front_s_m) & (along <= ctx.ego_front_s_m + trigger) & (dist <= corridor)
    beside = (along >= s0) & (along <= ctx.ego_front_s_m + trigger) & (dist <= corridor + p.clearance_band_m)
    if not ahead.any() and not (engaged and beside.any()):
        ctx.manoeuvre_data.pop(_KEY, None)
        return
    ego = ctx.situation.ego
    previous = ctx.manoeuvre_data.get(_KEY)
    choice = choose_tentacle(
        (ego.x_m, ego.y_m, ego.heading_rad), v, obstacles, path_xy[path_s >= ctx.ego_s_m],
        previous if isinstance(previous, float) else None, p,
    )  # fmt: skip
    if choice is None:
        first = float(np.min(along[ahead])) if ahead.any() else ctx.ego_front_s_m
        ctx.stop_front_at(first - 0.5, "tentacles: none drivable, stopping before the obstacle")
        ctx.manoeuvre_data[_KEY] = 0.0
        ctx.say("reactive: no tentacle is free, stopping")
        return
    ctx.manoeuvre_data[_KEY] = choice.kappa_1pm
    poses = choice.poses
    leg = Leg(
        poses[:, 0], poses[:, 1], poses[:, 2], np.full(choice.s_m.size, choice.kappa_1pm), choice.s_m, 1,
        float(choice.s_m[-1]),
    )  # fmt: skip
    # the states' stops (route arc length) on the tentacle, which starts at our rear axle
    plan.stops = [(s - ctx.ego_s_m, why) for s, why in plan.stops]
    if math.isfinite(choice.free_m):
        plan.stops.append((choice.free_m - 0.5, "tentacles: the obstacle on the chosen arc"))
    plan.leg, plan.leg_s_m = leg, 0.0
    ctx.cap(v, "tentacles: no faster while swerving")
    side = "left" if choice.kappa_1pm > 0 else "right" if choice.kappa_1pm < 0 else "straight on"
    ctx.say(f"reactive: tentacle {choice.index} ({side}, R {_radius(choice.kappa_1pm)})")


def _radius(kappa: float) -> str:
    return "inf" if abs(kappa) < 1e-9 else f"{1.0 / abs(kappa):.0f} m"
