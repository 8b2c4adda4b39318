"""Reference solution of the follow QP (seed 003 section V-C, eq. 3; `follow_problem` holds the problem
and our deviations): the problem written directly in the paper's variables, the planned positions, in
cvxpy and solved by Clarabel, independently of `follow_condensed`'s matrices and of `follow_qp`'s
solver. The tests' and `bywire bench platoon`'s reference.

cvxpy is imported only when the oracle runs: it takes a second to import, and a host that drives does
not need it (it is in the `test` and `bench` extras, not the runtime dependencies).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .follow_problem import (
    FloatArray,
    FollowParams,
    FollowResult,
    LeaderPrediction,
    accel_targets,
    braking_result,
    check_shapes,
    speed_envelope,
    targets,
)

if TYPE_CHECKING:
    import cvxpy as cp

ORACLE_TOL = 1e-10


def result_from_positions(
    p: FollowParams, speed_mps: float, z: FloatArray, status: str, iterations: int
) -> FollowResult:
    """The `FollowResult` of planned positions ``z = (x^1 .. x^{m-1})``; the command is the central
    second difference at j = 0 with the ghost point."""
    dt = p.dt_s
    x = np.concatenate(([0.0], z))
    a0 = 2.0 * (x[1] - speed_mps * dt) / dt**2
    a1 = (x[2] - 2.0 * x[1] + x[0]) / dt**2
    return FollowResult(
        accel_cmd_mps2=float(a0),
        accel_next_mps2=float(a1),
        positions_m=x,
        feasible=True,
        status=status,
        iterations=iterations,
    )


@dataclass
class _OracleProblem:
    problem: cp.Problem
    z: cp.Variable
    v0: cp.Parameter
    goal: cp.Parameter
    vlead: cp.Parameter
    aref: cp.Parameter
    v_up: cp.Parameter
    v_lo: cp.Parameter
    x_cap: cp.Parameter | None


@functools.lru_cache(maxsize=64)
def _oracle_problem(p: FollowParams) -> _OracleProblem:
    """Eq. (3) written directly in cvxpy (independent of FollowQP's matrices), parameterised (DPP)."""
    import cvxpy as cp

    m = p.n_samples
    dt = p.dt_s
    z = cp.Variable(m - 1)
    v0 = cp.Parameter()
    goal = cp.Parameter(m - 2)
    vlead = cp.Parameter(m - 2)
    aref = cp.Parameter(m - 1)
    v_up = cp.Parameter(m - 1)
    v_lo = cp.Parameter(m - 1)
    ghost = cp.reshape(z[0] - 2.0 * dt * v0, (1,), order="C")
    ext = cp.hstack([ghost, np.zeros(1), z])  # ext[j + 1] = x^j
    vel = (ext[3 : m + 1] - ext[1 : m - 1]) / (2.0 * dt)  # j = 1..m-2
    acc = (ext[2 : m + 1] - 2.0 * ext[1:m] + ext[0 : m - 1]) / dt**2  # j = 0..m-2
    pos = ext[2:m]  # j = 1..m-2
    fwd = (ext[2 : m + 1] - ext[1:m]) / dt  # j = 0..m-2
    dist = pos + p.headway_s * vel if p.headway_ref == "host" else pos
    cost = dt * (
        p.w_dist * cp.sum_squares(goal - dist)
        + p.w_vel * cp.sum_squares(vlead - vel)
        + p.w_acc * cp.sum_squares(acc - aref)
    )
    cons = [acc >= p.accel_min_mps2, acc <= p.accel_max_mps2, fwd <= v_up, fwd >= v_lo]
    x_cap = None
    if p.min_gap_m is not None:
        x_cap = cp.Parameter(m - 1)
        cons.append(z <= x_cap)
    prob = cp.Problem(cp.Minimize(cost), cons)
    return _OracleProblem(prob, z, v0, goal, vlead, aref, v_up, v_lo, x_cap)


def follow_oracle(params: FollowParams, speed_mps: float, leader: LeaderPrediction) -> FollowResult:
    """Reference solution (cvxpy + Clarabel) of the same QP as `FollowQP.solve`; needs the `test` or
    `bench` extra (cvxpy)."""
    import cvxpy as cp

    check_shapes(params, leader)
    op = _oracle_problem(params)
    g, vl = targets(params, leader)
    v_up, v_lo = speed_envelope(params, speed_mps)
    op.v0.value = speed_mps
    op.goal.value = g
    op.vlead.value = vl
    op.aref.value = accel_targets(params, leader)
    op.v_up.value = v_up
    op.v_lo.value = v_lo
    if op.x_cap is not None and params.min_gap_m is not None:
        op.x_cap.value = leader.positions_m[1:] - params.min_gap_m
    try:
        # Tighter than Clarabel's 1e-8: the command is 2 x^1 / dt^2, and where a limit binds an interior
        # point stops short of it; at 1e-8 a command on a_min came out 5e-4 m/s^2 inside (1e-10: 3e-7).
        tol = {"tol_gap_abs": ORACLE_TOL, "tol_gap_rel": ORACLE_TOL, "tol_feas": ORACLE_TOL}
        op.problem.solve(solver=cp.CLARABEL, **tol)
    except cp.error.SolverError as exc:
        return braking_result(params, speed_mps, f"error: {exc}")
    status = str(op.problem.status)
    if status not in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE) or op.z.value is None:
        return braking_result(params, speed_mps, status)
    return result_from_positions(params, speed_mps, np.asarray(op.z.value, dtype=np.float64), status, 0)
