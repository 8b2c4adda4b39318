"""Follow controller of seed 003 (Team AnnieWAY, GCDC 2011), section V-C, eqs. (1)-(3), as a QP: the
problem (parameters, the leader's prediction, cost, constraints and our deviations); `follow_qp` solves
it, `follow_oracle` is the test's reference.

The paper's variables: the host's planned positions ``z = (x^1 .. x^{m-1})`` on the grid ``t_j = j*dt``,
``m = horizon_s/dt + 1`` samples, everything relative to the host at ``t_0`` (``x^0 = 0`` is pinned).
The leader trajectory comes from the vehicle manager's prediction (`LeaderPrediction`; the paper
assumes constant acceleration except where velocity limits bind: `LeaderPrediction.constant_accel`).

Cost (eq. 3, each term times ``dt`` so that it approximates the integral of eq. 2 and the weights mean
the same at every ``dt``)::

    J = dt * [ sum_{j=1}^{m-2} w_dist (Delta d^j)^2 + w_vel (v_lead^j - v^j)^2
             + sum_{j=0}^{m-2} w_acc (a^j - a_ref^j)^2 ],     Delta d^j = x_lead^j - r - t_h * v^j - x^j

(a_ref = 0 in the paper; ``accel_ref="leader"`` penalises the difference to the leader's predicted
acceleration instead, see below.)

with central differences ``v^j = (x^{j+1} - x^{j-1}) / (2 dt)`` and
``a^j = (x^{j+1} - 2 x^j + x^{j-1}) / dt^2``.

Linear inequalities (the paper's conditions 2 and 3): ``a_min <= a^j <= a_max`` for j = 0..m-2 and
``v_min <= (x^{j+1} - x^j) / dt <= v_max`` for j = 0..m-2; optionally (deviation, see below)
``x^j <= x_lead^j - min_gap``.

Fixes of the garbled PDF extraction (derived, not guessed from the layout):

- Safety distance (condition 1 and the Delta d of eq. 3): the extraction reads ``x_0 < x_1 r + t_h v_1``
  and ``Delta d = x_lead - r + t_h v_lead - x_0``. The gap ``x_lead - x_0`` must *exceed* ``r + t_h v``,
  so the condition is ``x_0 < x_1 - r - t_h v_1`` and ``Delta d = x_lead - r - t_h v_lead - x_0``. With
  the extracted ``+ t_h v`` the desired gap would shrink with speed.
- Finite differences: the extraction labels the first difference ``Delta_c^2`` and the second one
  ``Delta_c`` and then uses ``u_j = Delta_c^2 x^j`` (a velocity) as the acceleration and
  ``Delta v_j = v_lead - Delta_c x^j`` (an acceleration) as the velocity error. The two labels are
  swapped; here velocity = central first difference, acceleration = central second difference.
- The paper reads the command as ``a = Delta_c^2 x^1``, i.e. the second difference at j = 1, which is
  what one gets if both ``x^0`` and ``x^1 = x^0 + v_0 dt`` are pinned by the state. That pins the
  first step at zero acceleration (a one-step delay). Deviation: we pin only ``x^0`` and impose the
  current speed through the central difference at j = 0 with a ghost point
  ``x^{-1} = x^1 - 2 dt v_0``. Then ``a^0 = 2 (x^1 - v_0 dt) / dt^2`` is exact for constant
  acceleration over the first step and is the command (``accel_cmd_mps2``); ``a^1`` (the paper's
  reading) is reported as ``accel_next_mps2``. Because the command is free, ``a^0`` enters the
  acceleration penalty (the paper's sum starts at j = 1).

Further deviations:

- Velocity limits on the forward (mid-step) differences, not the central ones: the central ``v^j``
  only sees ``(a^{j-1} + a^j) / 2``-type sums, so with central limits a host above ``v_max`` could
  plan ``a^0 > 0, a^1 << 0`` (odd/even decoupling) and command an acceleration while over the limit.
  The forward difference at j = 0 is ``v_0 + a^0 dt / 2``, which pins the sign of the command. The
  cost keeps the paper's central differences.

- Headway on the host's speed (``headway_ref="host"``, default): ``Delta d`` uses the host's planned
  speed ``v^j`` (still linear in z, so still a QP). The paper's eq. 3 multiplies t_h by the leader's
  speed (``headway_ref="leader"`` keeps that): then a braking leader first moves the desired position
  *ahead* (its velocity is ``v_lead - t_h a_lead``, e.g. 27 m/s for a leader at 20 m/s braking at
  6 m/s^2 with the V-D headway 2 t_h), and the host's first command came out slightly positive in
  that case. Both agree in steady state (``v = v_lead``); the host form is the usual constant time gap.
  The headway is therefore in P: one `FollowQP` per headway (the strategy keeps one per vehicle).

- Acceleration penalty relative to the leader (``accel_ref="leader"``, off by default): the paper's
  ``w_acc a^2`` pulls every planned acceleration toward zero, so the plan passes on only part of a
  leader's predicted acceleration and the follower acts like a constant-time-gap PD on the gap error,
  which at h = 0.6 s amplifies low-frequency disturbances (host/modules/control/platoon.py). ``w_acc (a -
  a_lead)^2`` keeps the smoothing but around the leader's predicted profile (the cooperative
  feed-forward of CACC, inside the QP, with the prediction's own limits). Still a QP: only q changes.
- Velocity limits are relaxed to what the acceleration limits can reach from the current speed
  (mid-step speed ``<= max(v_max, v_0 + a_min (t_j + dt/2))``, symmetric below), so a measured speed
  slightly outside ``[v_min, v_max]`` (noise, a downhill) does not make the QP infeasible. Forward
  differences are exact sums of the step accelerations, so braking at a_min and then landing on the
  limit in one step is always a feasible profile.
- An optional hard no-collision bound ``x^j <= x_lead^j - min_gap_m`` (j = 1..m-1). The paper keeps
  the safety distance only through the cost. With it, a leader braking harder than our limits allow
  makes the QP infeasible: the controller then commands ``a_min`` and sets ``feasible = False``;
  it never raises in the loop (solver errors and non-finite inputs are treated the same way).
- Solver: the paper uses Goldfarb-Idnani's active set method (as in quadprog, GPL: not used here).
  `follow_qp.FollowQP` solves the problem condensed onto the accelerations (`follow_condensed`) with
  DAQP, a dual active-set method of the same family (MIT), warm-started from the previous cycle's
  active set; `follow_oracle` is the problem in these positions, written independently in cvxpy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt

from bywire.host.limits import ACCEL_MAX_MPS2, ACCEL_MIN_MPS2

FloatArray = npt.NDArray[np.float64]
HeadwayRef = Literal["host", "leader"]
AccelRef = Literal["zero", "leader"]

KMH_TO_MPS = 1.0 / 3.6


@dataclass(frozen=True)
class FollowParams:
    """Parameters of one follow QP; defaults are the GCDC 2011 rules (seed 003 V-A)."""

    headway_s: float = 0.6
    # Paper V-A: "0.6 s and 20 m" (headway and reserve required during the competition).
    reserve_m: float = 20.0
    horizon_s: float = 10.0
    dt_s: float = 0.2
    w_dist: float = 1.0
    w_vel: float = 1.0
    # w_acc = 4 gives, for the unconstrained infinite-horizon analogue (LQR on the double integrator),
    # gap/speed gains of 0.5 1/s^2 and 1.1 1/s: damping ~0.8, no overshoot worth mentioning.
    w_acc: float = 4.0
    accel_min_mps2: float = ACCEL_MIN_MPS2  # host.limits
    accel_max_mps2: float = ACCEL_MAX_MPS2
    speed_min_mps: float = 0.0
    speed_max_mps: float = 100.0 * KMH_TO_MPS
    # Hard no-collision bound to the predicted leader; None: the cost alone keeps the distance (paper).
    min_gap_m: float | None = 2.0
    # Whose speed the headway multiplies: "host" (default, deviation) or "leader" (the paper's eq. 3).
    headway_ref: HeadwayRef = "host"
    # What the acceleration penalty measures from: "zero" (the paper's eq. 3: w_acc a^2) or "leader"
    # (deviation: w_acc (a - a_lead)^2, a_lead from the leader's predicted speeds).
    accel_ref: AccelRef = "zero"

    def __post_init__(self) -> None:
        if self.headway_ref not in ("host", "leader"):
            raise ValueError(f"headway_ref must be 'host' or 'leader', got {self.headway_ref!r}")
        if self.accel_ref not in ("zero", "leader"):
            raise ValueError(f"accel_ref must be 'zero' or 'leader', got {self.accel_ref!r}")

    @property
    def n_samples(self) -> int:
        """m: samples on the grid including t_0."""
        return round(self.horizon_s / self.dt_s) + 1

    def time_grid_s(self) -> FloatArray:
        return np.arange(self.n_samples, dtype=np.float64) * self.dt_s


@dataclass(frozen=True)
class LeaderPrediction:
    """A leader's predicted positions/speeds on the horizon grid t_j = j*dt, j = 0..m-1.

    Positions are relative to the host's position at t_0 (host at 0, leader ahead > 0).
    """

    positions_m: FloatArray
    speeds_mps: FloatArray

    @staticmethod
    def constant_accel(
        gap_m: float,
        speed_mps: float,
        accel_mps2: float,
        params: FollowParams,
    ) -> LeaderPrediction:
        """The paper's prediction: constant acceleration until a velocity limit, then constant speed."""
        t = params.time_grid_s()
        v0 = min(max(speed_mps, params.speed_min_mps), params.speed_max_mps)
        if accel_mps2 > 0.0:
            t_sat = (params.speed_max_mps - v0) / accel_mps2
        elif accel_mps2 < 0.0:
            t_sat = (params.speed_min_mps - v0) / accel_mps2
        else:
            t_sat = math.inf
        t_eff = np.minimum(t, t_sat)
        v_end = v0 + accel_mps2 * t_eff
        pos = gap_m + v0 * t_eff + 0.5 * accel_mps2 * t_eff**2 + v_end * (t - t_eff)
        return LeaderPrediction(positions_m=pos, speeds_mps=v_end)


@dataclass(frozen=True)
class FollowResult:
    accel_cmd_mps2: float
    """a^0: the command for the coming step."""
    accel_next_mps2: float
    """a^1 (the paper's a = Delta^2 x^1)."""
    positions_m: FloatArray
    """x^0 .. x^{m-1}, relative to the host at t_0."""
    feasible: bool
    status: str = ""
    iterations: int = 0


def braking_result(params: FollowParams, speed_mps: float, status: str) -> FollowResult:
    """Most braking command (a_min until standstill): the answer when the QP has none."""
    t = params.time_grid_s()
    v0 = max(speed_mps, 0.0) if math.isfinite(speed_mps) else 0.0
    a = params.accel_min_mps2
    t_eff = np.minimum(t, v0 / -a) if a < 0 else t
    pos = v0 * t_eff + 0.5 * a * t_eff**2
    return FollowResult(
        accel_cmd_mps2=a,
        accel_next_mps2=a,
        positions_m=pos,
        feasible=False,
        status=status,
    )


def speed_envelope(params: FollowParams, speed_mps: float) -> tuple[FloatArray, FloatArray]:
    """Bounds of the mid-step speeds, j = 0..m-2: the limits relaxed to what a_min/a_max reach."""
    t = params.time_grid_s()[:-1] + 0.5 * params.dt_s
    v_up = np.maximum(params.speed_max_mps, speed_mps + params.accel_min_mps2 * t)
    v_lo = np.minimum(params.speed_min_mps, speed_mps + params.accel_max_mps2 * t)
    return v_up, v_lo


def targets(params: FollowParams, leader: LeaderPrediction) -> tuple[FloatArray, FloatArray]:
    """The constant part of x^j (+ t_h v^j for "host") in the corrected Delta d of eq. 3, and v_lead^j.

    j = 1..m-2. "leader": g^j = x_lead^j - r - t_h v_lead^j; "host": g^j = x_lead^j - r (the t_h v^j term
    is in the matrix).
    """
    xl = leader.positions_m[1:-1]
    vl = leader.speeds_mps[1:-1]
    if params.headway_ref == "leader":
        return xl - params.reserve_m - params.headway_s * vl, vl
    return xl - params.reserve_m, vl


def accel_targets(params: FollowParams, leader: LeaderPrediction) -> FloatArray:
    """The acceleration a^j (j = 0..m-2) is penalised against: zero, or the leader's predicted
    acceleration (central differences of its predicted speeds, one-sided at j = 0)."""
    m = params.n_samples
    if params.accel_ref == "zero":
        return np.zeros(m - 1)
    v = leader.speeds_mps
    a = np.empty(m - 1)
    a[0] = (v[1] - v[0]) / params.dt_s
    a[1:] = (v[2:] - v[:-2]) / (2.0 * params.dt_s)
    return a


def check_shapes(params: FollowParams, leader: LeaderPrediction) -> None:
    m = params.n_samples
    if leader.positions_m.shape != (m,) or leader.speeds_mps.shape != (m,):
        raise ValueError(f"leader prediction must have {m} samples (horizon/dt + 1)")
