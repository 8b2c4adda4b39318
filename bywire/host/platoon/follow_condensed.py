"""The follow QP of seed 003 section V-C (eq. 3, `follow_problem`) condensed onto the planned accelerations.

The paper's variables are the planned positions ``x^1 .. x^{m-1}``; `follow_problem`'s docstring holds the
cost, the constraints and our deviations from the paper. Here the same QP is written in the planned
accelerations ``a = (a^0 .. a^{m-2})`` (the central second differences of the positions, with the ghost
point ``x^{-1} = x^1 - 2 dt v_0``), the positions eliminated ("condensed", as in the MPC literature:
Maciejowski, Predictive Control with Constraints, 2002, section 3.1). The positions follow from the
accelerations by the recurrence the second differences define::

    u^j = v_0 + dt (a^0 / 2 + a^1 + .. + a^j)      mid-step speed (x^{j+1} - x^j) / dt, j = 0..m-2
    x^j = dt (u^0 + .. + u^{j-1})                  j = 1..m-1 (x^0 = 0)
    v^j = (u^{j-1} + u^j) / 2                      central speed, j = 1..m-2

so ``x = L_x a + v_0 dt j`` with ``L_x`` invertible (lower triangular): the change of variables is
exact, the optimum is the same point, and `follow_oracle` (positions, written independently
in cvxpy) is the reference for both.

Why: the cost and the constraints of the position form are second differences, rows spanning
~``1/dt^4`` (its Hessian's condition number is ~3.5e4 at dt 0.2 s), and the command ``a^0 = 2 (x^1 -
v_0 dt) / dt^2`` amplifies position error 50x (dt 0.2 s) to 200x (dt 0.1 s). In accelerations the
Hessian is ``dt (w_acc I + ...)``, condition number ~250, the acceleration limits are simple bounds
and the command is a variable. The matrices are dense (50 x 50 at dt 0.2 s): small, and what a dense
active-set solver wants.

Problem (`CondensedFollow`)::

    minimise  1/2 a' H a + f' a
    subject to  a_min <= a <= a_max                        (bounds)
                v_lo - v_0 <= L_u a <= v_up - v_0          (mid-step speeds, the relaxed envelope)
                L_x a <= x_lead^{1..m-1} - min_gap - v_0 dt j   (only with a hard min_gap_m)

with ``H = 2 dt M'M`` and ``f = 2 dt M'c`` from the cost ``dt ||M a + c||^2`` of eq. 3 (the constant
term is dropped). H and the constraint matrix depend only on `FollowParams`; f and the bounds on the
host's speed and the leader's prediction.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .follow_problem import (
    FloatArray,
    FollowParams,
    FollowResult,
    LeaderPrediction,
    accel_targets,
    targets,
)

NO_BOUND = 1e30  # a row's missing side; solvers take a large finite number where they take no inf


@dataclass(frozen=True)
class CondensedData:
    """One instance's vectors: ``f``, and both sides of the constraints, the bounds on ``a`` first
    (``n_vars`` of them) and then the rows of `CondensedFollow.rows`, in that order."""

    f: FloatArray
    lower: FloatArray
    upper: FloatArray


class CondensedFollow:
    """The matrices of one `FollowParams`, and each instance's vectors (`data`); solver-neutral."""

    def __init__(self, params: FollowParams) -> None:
        self.params = params
        m = params.n_samples
        if m < 4:
            raise ValueError("horizon must span at least 3 steps")
        n = m - 1
        dt = params.dt_s
        self.n_vars = n
        # u = v_0 + L_u a: the first step carries half of a^0 (the ghost point's central difference).
        l_u = np.tril(np.ones((n, n))) * dt
        l_u[:, 0] = 0.5 * dt
        l_x = dt * np.cumsum(l_u, axis=0)  # x^{j+1} = x^j + dt u^j
        l_v = 0.5 * (l_u[1:] + l_u[:-1])
        self.l_x = l_x
        self.x_per_v0 = dt * np.arange(1, m, dtype=np.float64)  # x^j's part from v_0, j = 1..m-1
        sd, sa, sv = math.sqrt(params.w_dist), math.sqrt(params.w_acc), math.sqrt(params.w_vel)
        self._sd, self._sa, self._sv = sd, sa, sv
        host_headway = params.headway_ref == "host"
        dist = l_x[:-1] + params.headway_s * l_v if host_headway else l_x[:-1]
        # Delta d^j's part from v_0: x^j's, and t_h v^j's when the headway is on the host's speed.
        self._dist_per_v0 = self.x_per_v0[:-1] + (params.headway_s if host_headway else 0.0)
        big_m = np.vstack([sd * dist, sa * np.eye(n), sv * l_v])
        self.hessian = 2.0 * dt * (big_m.T @ big_m)
        self._f_map = 2.0 * dt * big_m.T
        rows = [l_u]
        if params.min_gap_m is not None:
            rows.append(l_x)
        self.rows = np.ascontiguousarray(np.vstack(rows))
        self.n_constraints = n + self.rows.shape[0]
        # The speed envelope of `follow_problem.speed_envelope` relative to v_0: what a_min / a_max
        # change the speed by at each mid-step time (the tests hold the two equal through the oracle).
        t_mid = params.time_grid_s()[:-1] + 0.5 * dt
        self._dv_at_min = params.accel_min_mps2 * t_mid
        self._dv_at_max = params.accel_max_mps2 * t_mid
        self._n_cost = 2 * (m - 2) + n

    def data(self, speed_mps: float, leader: LeaderPrediction) -> CondensedData:
        """f and the bounds for the host at ``speed_mps`` behind ``leader``."""
        p = self.params
        n, k = self.n_vars, self.n_vars - 1  # accelerations; Delta d / speed terms (j = 1..m-2)
        g, v_lead = targets(p, leader)
        c = np.empty(self._n_cost)
        c[:k] = self._sd * (self._dist_per_v0 * speed_mps - g)
        c[k : k + n] = -self._sa * accel_targets(p, leader)
        c[k + n :] = self._sv * (speed_mps - v_lead)
        lower = np.empty(self.n_constraints)
        upper = np.empty(self.n_constraints)
        lower[:n] = p.accel_min_mps2
        upper[:n] = p.accel_max_mps2
        upper[n : 2 * n] = np.maximum(p.speed_max_mps - speed_mps, self._dv_at_min)
        lower[n : 2 * n] = np.minimum(p.speed_min_mps - speed_mps, self._dv_at_max)
        if p.min_gap_m is not None:
            lower[2 * n :] = -NO_BOUND
            upper[2 * n :] = leader.positions_m[1:] - p.min_gap_m - self.x_per_v0 * speed_mps
        return CondensedData(f=self._f_map @ c, lower=lower, upper=upper)

    def result(self, speed_mps: float, accels: FloatArray, status: str, iterations: int) -> FollowResult:
        """The `FollowResult` of a solution ``a``: its positions, a^0 the command, a^1 the next."""
        x = np.concatenate(([0.0], self.l_x @ accels + self.x_per_v0 * speed_mps))
        return FollowResult(
            accel_cmd_mps2=float(accels[0]),
            accel_next_mps2=float(accels[1]),
            positions_m=x,
            feasible=True,
            status=status,
            iterations=iterations,
        )
