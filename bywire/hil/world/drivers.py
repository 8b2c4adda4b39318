"""Driver models of the simulated traffic: what acceleration each car asks for, from what it perceives.

All are pure, clock-injected and deterministic for a seed. A car's longitudinal dynamics (in `traffic`)
are a first-order actuator lag from the commanded acceleration u to the actual one a, ``lag a' + a = u``,
bounded by the car's own limits (emergency braking capability, not the GCDC comfort limits).

- `ScriptedSpeed` (kinematic: speed and acceleration are the script's, exactly; no lag): a piecewise-linear
  speed profile (the spine's `host.lead`), Plexe's sinusoidal leader ``v = mean + A sin(2 pi f (t - t0))``,
  Plexe's emergency braking (from `at_s` at a constant deceleration down to `to_mps`), or a replayed real
  leader (a profile from the OpenACC / CARMA files).
- `AccDriver`: a plain radar ACC, constant time gap ``u = kp (g - s0 - h v) + kd (v_pred - v)`` while a car
  is within its radar range, else (and never above) cruise ``u = k_v (v_set - v)``. With the typical
  h = 1.2 s and the lag it is string unstable at some frequencies, as the real strings of OpenACC show.
- `CaccDriver`: Ploeg et al. (IEEE T-ITS 15(2), 2014) one-vehicle look-ahead CACC with the predecessor's
  broadcast command as feed-forward: ``h xi' = -xi + kp e + kd e' + u_pred``, ``u = xi``, with
  ``e = g - s0 - h v``, ``e' = v_pred - v - h a`` (the simulated cars broadcast their command u, as
  Ploeg's do; our own car's CAM carries its measured acceleration).
- `IdmDriver`: the Intelligent Driver Model (Treiber et al. 2000) as the human: ``a = a_max (1 - (v/v0)^4 -
  (s*/g)^2)``, ``s* = s0 + max(0, v T + v dv / (2 sqrt(a_max b)))``, on what the driver saw `reaction_s` ago
  (a perception delay line), plus an Ornstein-Uhlenbeck acceleration noise (sigma `noise_mps2`, tau 2 s).
"""

from __future__ import annotations

import bisect
import itertools
import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bywire.hil.world.spec import DriverSpec

CRUISE_GAIN_PER_S = 0.4  # speed error to acceleration when nobody is ahead: ~2.5 s time constant
NOISE_TAU_S = 2.0
DIFF_STEP_S = 0.05  # central difference for a profile's acceleration


@dataclass(frozen=True)
class Ahead:
    """What a driver perceives of the car ahead on its lane (None: nobody within its range)."""

    gap_m: float  # its rear bumper to our front bumper, along the lane
    speed_mps: float
    accel_mps2: float  # as broadcast (CACC) or measured; delayed by the sender's latency


def ramp(profile: Sequence[tuple[float, float]], t_s: float, times: Sequence[float] | None = None) -> float:
    """Linear interpolation of [(t, v), ...], held outside (like `hil.scenario.ramp_value`); `times` (the
    profile's t column) makes it a bisection, for the long profiles of a replayed recording."""
    if not profile:
        return 0.0
    if t_s <= profile[0][0]:
        return profile[0][1]
    if t_s >= profile[-1][0]:
        return profile[-1][1]
    if times is not None:
        i = bisect.bisect_left(times, t_s)
        (t0, v0), (t1, v1) = profile[i - 1], profile[i]
        return v0 + (v1 - v0) * (t_s - t0) / (t1 - t0)
    for (t0, v0), (t1, v1) in itertools.pairwise(profile):
        if t_s <= t1:
            return v0 + (v1 - v0) * (t_s - t0) / (t1 - t0)
    return profile[-1][1]


class ScriptedSpeed:
    """The script's speed at any time; see the module docstring. `replay` replaces the profile."""

    kinematic = True

    def __init__(self, spec: DriverSpec, replay: Sequence[tuple[float, float]] = ()) -> None:
        self.spec = spec
        self.profile = tuple(replay) if spec.replay and replay else spec.speed_profile
        self._times = [t for t, _ in self.profile]

    def _base(self, t_s: float) -> float:
        sin = self.spec.sinusoid
        if sin is not None:
            if t_s < sin.start_s:
                return sin.mean_mps
            return sin.mean_mps + sin.amplitude_mps * math.sin(
                2.0 * math.pi * sin.freq_hz * (t_s - sin.start_s)
            )
        return ramp(self.profile, t_s, self._times)

    def speed(self, t_s: float) -> float:
        brake = self.spec.brake
        v = self._base(t_s)
        if brake is not None and t_s > brake.at_s:
            v_at = self._base(brake.at_s)
            v = max(min(brake.to_mps, v_at), v_at - brake.decel_mps2 * (t_s - brake.at_s))
        return max(0.0, v)

    def accel(self, t_s: float) -> float:
        brake = self.spec.brake
        if brake is not None and t_s > brake.at_s:
            v = self.speed(t_s)
            return -brake.decel_mps2 if v > min(brake.to_mps, self._base(brake.at_s)) + 1e-9 else 0.0
        sin = self.spec.sinusoid
        if sin is not None:
            if t_s < sin.start_s:
                return 0.0
            w = 2.0 * math.pi * sin.freq_hz
            return sin.amplitude_mps * w * math.cos(w * (t_s - sin.start_s))
        h = DIFF_STEP_S
        return (self.speed(t_s + h) - self.speed(max(0.0, t_s - h))) / (t_s + h - max(0.0, t_s - h))

    def distance(self, t0_s: float, t1_s: float) -> float:
        """Distance driven in [t0, t1]: trapezoid, exact for a piecewise-linear profile between events."""
        return 0.5 * (self.speed(t0_s) + self.speed(t1_s)) * (t1_s - t0_s)


class AccDriver:
    kinematic = False

    def __init__(self, spec: DriverSpec) -> None:
        self.spec = spec

    def command(self, t_s: float, v_mps: float, a_mps2: float, ahead: Ahead | None, dt_s: float) -> float:
        sp = self.spec
        u = CRUISE_GAIN_PER_S * (sp.v_set_mps - v_mps)
        if ahead is not None:
            e = ahead.gap_m - sp.standstill_m - sp.headway_s * v_mps
            u = min(u, sp.kp * e + sp.kd * (ahead.speed_mps - v_mps))
        return u


class CaccDriver:
    kinematic = False

    def __init__(self, spec: DriverSpec) -> None:
        self.spec = spec
        self.xi = 0.0

    def command(self, t_s: float, v_mps: float, a_mps2: float, ahead: Ahead | None, dt_s: float) -> float:
        sp = self.spec
        cruise = CRUISE_GAIN_PER_S * (sp.v_set_mps - v_mps)
        if ahead is None:
            self.xi = cruise
            return cruise
        h = sp.headway_s
        e = ahead.gap_m - sp.standstill_m - h * v_mps
        de = ahead.speed_mps - v_mps - h * a_mps2
        target = sp.kp * e + sp.kd * de + ahead.accel_mps2
        # Exact discretisation of h xi' = target - xi over dt (target held).
        self.xi = target + (self.xi - target) * math.exp(-dt_s / h)
        # Cruise caps the follower (a CACC car never drives faster than its set speed); the filter state
        # is clamped to the command so that it does not wind up while cruising.
        if cruise < self.xi:
            self.xi = cruise
        return self.xi


class IdmDriver:
    kinematic = False

    def __init__(self, spec: DriverSpec, seed: int) -> None:
        self.spec = spec
        self.rng = np.random.default_rng(seed)
        self.noise = 0.0
        self._seen: deque[tuple[float, Ahead | None]] = deque()

    def _perceived(self, t_s: float, ahead: Ahead | None) -> Ahead | None:
        self._seen.append((t_s, ahead))
        delay = self.spec.reaction_s
        while len(self._seen) > 1 and self._seen[1][0] <= t_s - delay:
            self._seen.popleft()
        return self._seen[0][1]

    def command(self, t_s: float, v_mps: float, a_mps2: float, ahead: Ahead | None, dt_s: float) -> float:
        sp = self.spec
        seen = self._perceived(t_s, ahead)
        free = 1.0 - (v_mps / max(sp.v_set_mps, 0.1)) ** 4
        interaction = 0.0
        if seen is not None:
            dv = v_mps - seen.speed_mps
            s_star = sp.standstill_m + max(
                0.0,
                v_mps * sp.headway_s + v_mps * dv / (2.0 * math.sqrt(sp.accel_mps2 * sp.comfort_decel_mps2)),
            )
            interaction = (s_star / max(seen.gap_m, 0.1)) ** 2
        if sp.noise_mps2 > 0.0 and dt_s > 0.0:
            phi = math.exp(-dt_s / NOISE_TAU_S)
            self.noise = phi * self.noise + math.sqrt(1.0 - phi * phi) * sp.noise_mps2 * float(
                self.rng.standard_normal()
            )
        return sp.accel_mps2 * (free - interaction) + self.noise


Driver = ScriptedSpeed | AccDriver | CaccDriver | IdmDriver


def make_driver(spec: DriverSpec, seed: int, replay: Sequence[tuple[float, float]] = ()) -> Driver:
    if spec.kind == "scripted":
        return ScriptedSpeed(spec, replay)
    if spec.kind == "acc":
        return AccDriver(spec)
    if spec.kind == "cacc":
        return CaccDriver(spec)
    if spec.kind == "idm":
        return IdmDriver(spec, seed)
    raise ValueError(f"unknown driver kind {spec.kind!r}")


__all__ = ["AccDriver", "Ahead", "CaccDriver", "Driver", "IdmDriver", "ScriptedSpeed", "make_driver", "ramp"]
