"""Tentacles (seed 000 Sec. 7; von Hundelshausen et al., "Tentacles", J. Field Robotics 25(9), 2008):
the reactive layer's precomputed circular arcs from the car's pose, one of which is chosen every
perception cycle when the planned path is blocked close ahead.

The set depends on the speed: `n` arcs with curvatures from -kappa_max(v) to +kappa_max(v), denser
near straight ahead (kappa = kappa_max x u |u|, u evenly spaced in [-1, 1]), kappa_max(v) the
smaller of full lock (`min_radius_m`) and `lateral_accel_mps2` / v² ("at high speeds no dangerous
actions can be taken"), each `base_length_m` + v x `length_time_s` long.

Each arc is judged on the four aspects of the paper, against obstacle points (the corners and edges of
the standing objects, the obstacle cells of the occupancy grid), each placed in the arc's own
coordinates (u along it from the rear axle, d across it):

1. drivable: no obstacle inside the car's corridor (|d| <= half width + `margin_m` ahead of the front
   bumper, + `side_margin_m` beside the car) within the distance the car needs to stop (v x
   `reaction_s` + v² / (2 `brake_mps2`) + `stop_margin_m`, measured from the front bumper);
2. clearance: the nearest obstacle across the arc within `clearance_band_m` outside the corridor (the
   paper's smoothness of the terrain under the arc has no counterpart on a flat road: an occupancy
   grid's cells are obstacles or not);
3. the distance to the first obstacle in the corridor along the arc;
4. how well it follows the planned path: the mean distance of its samples from the path;
plus (von Hundelshausen's) agreement with the arc chosen last cycle, so the choice does not flicker.
The drivable arc with the least weighted cost wins; none drivable: the caller stops.

As in the paper, arcs see obstacles only up to the first tracked vehicle (tracked cars are the following
logic's business): the caller (`behaviour.reactive`) gives the obstacle points accordingly. Deviations:
aspect 2 is the clearance, not the terrain's smoothness, and the arcs are placed in the world frame
from the pose, not looked up in a vehicle-centred grid.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

__all__ = ["TentacleChoice", "TentacleParams", "box_points", "choose_tentacle", "tentacle_curvatures"]

FloatArray = npt.NDArray[np.float64]
Pose = tuple[float, float, float]


@dataclass(frozen=True)
class TentacleParams:
    n: int = 41
    min_radius_m: float = 5.5  # behaviour rules.KTURN_RADIUS_M: 4 deg of steer below the Passat's lock
    lateral_accel_mps2: float = 3.0
    base_length_m: float = 8.0
    length_time_s: float = 2.0
    step_m: float = 0.25
    half_width_m: float = 0.91  # the Passat's half width
    front_m: float = 3.67  # rear axle to front bumper
    rear_m: float = 1.10  # rear axle to rear bumper
    margin_m: float = 0.3  # the corridor beyond the car's sides, ahead of the front bumper
    side_margin_m: float = 0.05  # beside the car: what is passed is passed
    clearance_band_m: float = 1.0
    brake_mps2: float = 6.0  # the stopping distance of aspect 1 (the ECU's emergency braking is harder)
    reaction_s: float = 0.3
    stop_margin_m: float = 1.0
    w_clearance: float = 1.0
    w_distance: float = 3.0
    w_path: float = 1.5
    w_agree: float = 0.3
    path_scale_m: float = 2.0


@dataclass(frozen=True)
class TentacleChoice:
    kappa_1pm: float
    index: int
    free_m: float  # how far the rear axle may go along it before the front touches an obstacle
    poses: FloatArray  # (m, 3) x, y, heading of the rear axle along the arc, world frame
    s_m: FloatArray  # (m,)
    cost: float


def tentacle_curvatures(speed_mps: float, p: TentacleParams) -> FloatArray:
    """The set's curvatures at this speed (see the module docstring)."""
    k_max = 1.0 / p.min_radius_m
    v = abs(speed_mps)
    if v > 0.0:
        k_max = min(k_max, p.lateral_accel_mps2 / (v * v))
    u = np.linspace(-1.0, 1.0, p.n) if p.n > 1 else np.zeros(1)  # one tentacle: straight ahead
    return k_max * u * np.abs(u)


def _arc(pose: Pose, kappa: float, s: FloatArray) -> FloatArray:
    """Rear-axle poses along a circular arc of curvature `kappa` from `pose`, at arc lengths `s`."""
    x0, y0, h0 = pose
    if abs(kappa) < 1e-9:
        lx, ly, lh = s, np.zeros_like(s), np.zeros_like(s)
    else:
        lh = kappa * s
        lx = np.sin(lh) / kappa
        ly = (1.0 - np.cos(lh)) / kappa
    c, sn = math.cos(h0), math.sin(h0)
    return np.column_stack((x0 + c * lx - sn * ly, y0 + sn * lx + c * ly, h0 + lh))


def _arc_coordinates(kappa: float, px: FloatArray, py: FloatArray) -> tuple[FloatArray, FloatArray]:
    """(u along the arc, d to its left) of points given in the start pose's frame."""
    if abs(kappa) < 1e-9:
        return px, py
    r = 1.0 / kappa  # signed: the centre is at (0, r)
    dx, dy = px, py - r
    dist = np.hypot(dx, dy)
    # the angle travelled from the start (the start is at angle -pi/2 seen from a left turn's centre)
    ang = np.arctan2(dx, -dy) if kappa > 0 else np.arctan2(dx, dy)
    u = np.abs(r) * ang
    d = np.abs(r) - dist if kappa > 0 else dist - np.abs(r)
    return u, d


def box_points(
    x: float, y: float, heading: float, length: float, width: float, step: float = 0.2
) -> FloatArray:
    """Points (n, 2) on the outline of a box: what an obstacle's edge looks like to a tentacle."""
    c, s = math.cos(heading), math.sin(heading)
    hl, hw = 0.5 * length, 0.5 * width
    nl = max(2, math.ceil(length / step) + 1)
    nw = max(2, math.ceil(width / step) + 1)
    a = np.linspace(-hl, hl, nl)
    b = np.linspace(-hw, hw, nw)
    local = np.vstack([
        np.column_stack((a, np.full(nl, hw))), np.column_stack((a, np.full(nl, -hw))),
        np.column_stack((np.full(nw, hl), b)), np.column_stack((np.full(nw, -hl), b)),
    ])  # fmt: skip
    return np.column_stack((x + c * local[:, 0] - s * local[:, 1], y + s * local[:, 0] + c * local[:, 1]))


def choose_tentacle(
    pose: Pose,
    speed_mps: float,
    obstacles_xy: FloatArray,
    path_xy: FloatArray,
    previous_kappa: float | None,
    p: TentacleParams | None = None,
) -> TentacleChoice | None:
    """The best drivable tentacle from `pose` at this speed (see the module docstring), None if none
    is drivable. `obstacles_xy` (n, 2) and `path_xy` (m, 2, the planned path ahead) in the world frame."""
    p = p or TentacleParams()
    v = abs(speed_mps)
    kappas = tentacle_curvatures(v, p)
    length = p.base_length_m + v * p.length_time_s
    s = np.arange(0.0, length + 1e-9, p.step_m)
    stop_m = v * p.reaction_s + v * v / (2.0 * p.brake_mps2) + p.stop_margin_m
    corridor = p.half_width_m + p.margin_m
    c, sn = math.cos(pose[2]), math.sin(pose[2])
    obs = np.asarray(obstacles_xy, dtype=float).reshape(-1, 2)
    ox = c * (obs[:, 0] - pose[0]) + sn * (obs[:, 1] - pose[1])
    oy = -sn * (obs[:, 0] - pose[0]) + c * (obs[:, 1] - pose[1])
    path_tree = cKDTree(np.asarray(path_xy, dtype=float).reshape(-1, 2)) if len(path_xy) else None
    k_span = max(float(np.max(np.abs(kappas))), 1e-9)
    best: TentacleChoice | None = None
    for i, k in enumerate(kappas):
        u, d = _arc_coordinates(float(k), ox, oy)
        ahead = (u >= -p.rear_m) & (u <= length + p.front_m)
        # ahead of the front bumper the corridor with its margin; beside the car (a box being passed)
        # only what would touch its side
        across = np.where(u >= p.front_m, corridor, p.half_width_m + p.side_margin_m)
        hits = ahead & (np.abs(d) <= across)
        free = float(np.min(u[hits]) - p.front_m) if hits.any() else math.inf
        if free < stop_m:
            continue  # aspect 1: it runs into something within the distance we need to stop
        band = ahead & ~hits & (np.abs(d) <= corridor + p.clearance_band_m)
        gap = float(np.min(np.abs(d[band]) - corridor)) if band.any() else p.clearance_band_m
        cost = p.w_clearance * (1.0 - gap / p.clearance_band_m)
        if math.isfinite(free):
            cost += p.w_distance * max(0.0, 1.0 - free / (length + p.front_m))
        poses = _arc(pose, float(k), s)
        if path_tree is not None:
            half = poses[s.size // 2 :, :2]
            dist, _ = path_tree.query(half)
            cost += p.w_path * min(float(np.mean(dist)) / p.path_scale_m, 2.0)
        if previous_kappa is not None:
            cost += p.w_agree * abs(float(k) - previous_kappa) / (2.0 * k_span)
        if best is None or cost < best.cost:
            best = TentacleChoice(float(k), i, free, poses, s, cost)
    return best
