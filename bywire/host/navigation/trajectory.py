"""A planned path made a trajectory: each stretch driven in one direction gets a jerk-limited speed profile
from standstill to standstill, computed by ruckig (Berscheid & Kroeger 2021: time-optimal, jerk-limited,
one degree of freedom: the arc length), and the stretches follow each other with the car standing at
each cusp for `cusp_pause_s` (the gear change).

A stretch's speed limit is the zone's, and on a stretch that turns, what `lateral_accel_mps2` allows on
its tightest curvature (a conservative whole-stretch limit: zone paths are short and slow). Speeds are
signed in the result: negative while reversing. SI units throughout.

`launch_profile` is the part the behaviour drives with: each leg of a manoeuvre (a zone stretch, a
K-turn leg, an exit turn's move) starts from standstill, and the acceleration it asks for on the way
to the leg's speed follows ruckig's jerk-limited drive-off, looked up by the speed reached rather than
by time (the ECU may hold the car a moment at a gear change: a clock would run ahead of the car). The
arrival at a leg's end stays with the paper's stop-point controllers (seed 000 Sec. 11.2), which at
these speeds is the critically damped position controller: smooth already, and exact at the point.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from ruckig import ControlInterface, InputParameter, Result, Ruckig, Trajectory

from .smoothing import split_at_cusps

__all__ = ["LaunchProfile", "SpeedLimits", "ZoneTrajectory", "launch_profile", "speed_profile"]


@dataclass(frozen=True)
class SpeedLimits:
    speed_mps: float = 3.0  # rules.ZONE_SPEED_MAX_MPS's order; the caller passes the zone's limit
    accel_mps2: float = 1.0
    jerk_mps3: float = 2.0
    lateral_accel_mps2: float = 1.0
    cusp_pause_s: float = 1.0


@dataclass(frozen=True)
class ZoneTrajectory:
    t_s: np.ndarray  # sample times
    x_m: np.ndarray
    y_m: np.ndarray
    heading_rad: np.ndarray
    speed_mps: np.ndarray  # signed: < 0 reversing
    accel_mps2: np.ndarray  # along the motion, signed like the speed
    duration_s: float


def _stretch_profile(length_m: float, v_max: float, lim: SpeedLimits, dt_s: float) -> tuple[np.ndarray, ...]:
    """(t, s, v, a) of a rest-to-rest drive over `length_m`, sampled every `dt_s` and at the end."""
    inp = InputParameter(1)
    inp.current_position, inp.current_velocity, inp.current_acceleration = [0.0], [0.0], [0.0]
    inp.target_position, inp.target_velocity, inp.target_acceleration = [length_m], [0.0], [0.0]
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = [v_max], [lim.accel_mps2], [lim.jerk_mps3]
    traj = Trajectory(1)
    result = Ruckig(1).calculate(inp, traj)
    if result not in (Result.Working, Result.Finished):
        raise ValueError(
            f"speed_profile: ruckig found no profile for {length_m:.2f} m at {v_max:.2f} m/s ({result})"
        )
    t, s, v, a = _sampled(traj, dt_s)
    return t, np.clip(s, 0.0, length_m), v, a


def _sampled(traj: Trajectory, dt_s: float) -> tuple[np.ndarray, ...]:
    """(t, position, velocity, acceleration) of a one-axis ruckig trajectory every `dt_s` and at its end."""
    t = np.append(np.arange(0.0, traj.duration, dt_s), traj.duration)
    out = np.array([np.concatenate(traj.at_time(float(ti))) for ti in t])
    return t, out[:, 0], out[:, 1], out[:, 2]


def speed_profile(
    poses: np.ndarray, directions: np.ndarray, limits: SpeedLimits | None = None, dt_s: float = 0.05
) -> ZoneTrajectory:
    """The trajectory along `poses` (N x 3) driven in `directions` (N, +-1), see the module docstring."""
    lim = limits or SpeedLimits()
    for name in ("speed_mps", "accel_mps2", "jerk_mps3", "lateral_accel_mps2"):
        value = getattr(lim, name)
        if not (math.isfinite(value) and value > 0.0):
            raise ValueError(f"speed_profile: {name} = {value} must be finite and > 0")
    if poses.shape[0] < 2:
        raise ValueError(f"speed_profile: a path needs at least 2 poses, not {poses.shape[0]}")
    parts: list[tuple[np.ndarray, ...]] = []
    t0 = 0.0
    for i0, i1 in split_at_cusps(directions):
        part = poses[i0 : i1 + 1]
        d = float(directions[i1])
        seg = np.hypot(*np.diff(part[:, :2], axis=0).T)
        s_path = np.concatenate([[0.0], np.cumsum(seg)])
        length = float(s_path[-1])
        if length < 1e-6:
            continue
        turn = np.abs(np.diff(np.unwrap(part[:, 2])))
        kappa = float(np.max(turn / np.maximum(seg, 1e-9))) if seg.size else 0.0
        v_turn = math.sqrt(lim.lateral_accel_mps2 / kappa) if kappa > 1e-6 else math.inf
        v_max = min(lim.speed_mps, v_turn)
        t, s, v, a = _stretch_profile(length, v_max, lim, dt_s)
        x = np.interp(s, s_path, part[:, 0])
        y = np.interp(s, s_path, part[:, 1])
        th = np.interp(s, s_path, np.unwrap(part[:, 2]))
        if parts:
            t0 += lim.cusp_pause_s
        parts.append((t + t0, x, y, th, d * v, d * a))
        t0 += float(t[-1])
    if not parts:
        raise ValueError("speed_profile: the path has no length")
    t, x, y, th, v, a = (np.concatenate([p[k] for p in parts]) for k in range(6))
    return ZoneTrajectory(t, x, y, th, v, a, duration_s=float(t[-1]))


@dataclass(frozen=True)
class LaunchProfile:
    """A jerk-limited drive-off from standstill to `target_mps` as (time, speed, acceleration) samples
    (speed non-decreasing), asked by speed reached: see the module docstring."""

    target_mps: float
    t_s: np.ndarray
    speed_mps: np.ndarray
    accel_mps2: np.ndarray

    def accel_at(self, speed_mps: float, lead_s: float) -> float:
        """The acceleration the profile asks for `lead_s` after the instant it reaches `speed_mps`
        (>= 0; 0 at and above the target). The lead is the command's way to the wheels (a cycle of
        the behaviour and the actuator's lag): at standstill the profile's own value is 0."""
        if speed_mps >= self.target_mps:
            return 0.0
        t = float(np.interp(max(speed_mps, 0.0), self.speed_mps, self.t_s)) + lead_s
        return float(np.interp(t, self.t_s, self.accel_mps2, right=0.0))


@lru_cache(maxsize=256)
def _launch(target_mps: float, accel_mps2: float, jerk_mps3: float, dt_s: float) -> LaunchProfile:
    inp = InputParameter(1)
    inp.control_interface = ControlInterface.Velocity
    inp.current_position, inp.current_velocity, inp.current_acceleration = [0.0], [0.0], [0.0]
    inp.target_velocity, inp.target_acceleration = [target_mps], [0.0]
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = [target_mps], [accel_mps2], [jerk_mps3]
    traj = Trajectory(1)
    result = Ruckig(1).calculate(inp, traj)
    if result not in (Result.Working, Result.Finished):
        raise ValueError(f"launch_profile: ruckig found no drive-off to {target_mps:.2f} m/s ({result})")
    t, _, v, a = _sampled(traj, dt_s)
    return LaunchProfile(target_mps, t, np.maximum.accumulate(v), a)


def launch_profile(target_mps: float, limits: SpeedLimits | None = None, dt_s: float = 0.02) -> LaunchProfile:
    """ruckig's time-optimal drive-off from rest to `target_mps` within the limits' acceleration and jerk
    (cached: the target is rounded to 0.05 m/s, the resolution of the behaviour's speed caps)."""
    lim = limits or SpeedLimits()
    if not (math.isfinite(target_mps) and target_mps > 0.0):
        raise ValueError(f"launch_profile: target_mps = {target_mps} must be finite and > 0")
    return _launch(max(round(target_mps / 0.05) * 0.05, 0.05), lim.accel_mps2, lim.jerk_mps3, dt_s)
