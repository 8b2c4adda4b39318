"""The candidate solvers of the follow QP (seed 003 V-C, eq. 3) that `bywire bench platoon` times side by
side: each one solves the same condensed problem (`host.platoon.follow_condensed`, accelerations as
variables) with its own direct interface, warm-started from the previous call where it can be; and the
baseline, the position form (the paper's variables) with Clarabel, the fast path before the condensed
form (its settings as they were tuned then).

Every candidate answers ``(a^0 or None when it found no solution, iterations)``. Licences (all
permissive; the benchmark-only ones are in the `bench` extra): DAQP MIT, Clarabel Apache-2.0, OSQP
Apache-2.0, PIQP BSD-2-Clause, ProxSuite BSD-2-Clause.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Protocol

import clarabel
import numpy as np
import scipy.sparse as sp

from bywire.host.platoon.follow_condensed import CondensedFollow
from bywire.host.platoon.follow_problem import (
    FloatArray,
    FollowParams,
    LeaderPrediction,
    accel_targets,
    speed_envelope,
    targets,
)
from bywire.host.platoon.follow_qp import FollowQP

# Where a candidate has tolerances: tight enough that its command agrees with the oracle's within the
# tests' 1e-3 m/s^2 (the bench reports each one's largest difference).
EPS = 1e-9


class Candidate(Protocol):
    name: str

    def solve(self, speed_mps: float, leader: LeaderPrediction) -> tuple[float | None, int]: ...


class DaqpCandidate:
    """The runtime path itself (`FollowQP`), warm-started from the previous working set or cold."""

    def __init__(self, params: FollowParams, warm: bool) -> None:
        self.name = "daqp" if warm else "daqp_cold"
        self._qp = FollowQP(params)
        self._qp.warm_start = warm

    def solve(self, speed_mps: float, leader: LeaderPrediction) -> tuple[float | None, int]:
        r = self._qp.solve(speed_mps, leader)
        return (r.accel_cmd_mps2 if r.feasible else None), r.iterations


class OsqpCandidate:
    """OSQP (ADMM), warm-started from the previous primal and dual iterate, polished."""

    name = "osqp"

    def __init__(self, params: FollowParams) -> None:
        import osqp

        self._cf = CondensedFollow(params)
        n = self._cf.n_vars
        self._p = sp.csc_matrix(np.triu(self._cf.hessian))
        self._a = sp.csc_matrix(np.vstack([np.eye(n), self._cf.rows]))
        self._osqp = osqp
        self._solver: osqp.OSQP | None = None

    def solve(self, speed_mps: float, leader: LeaderPrediction) -> tuple[float | None, int]:
        d = self._cf.data(speed_mps, leader)
        lower, upper = d.lower, d.upper
        if self._solver is None:
            self._solver = self._osqp.OSQP()
            self._solver.setup(
                P=self._p,
                q=d.f,
                A=self._a,
                l=lower,
                u=upper,
                verbose=False,
                eps_abs=EPS,
                eps_rel=EPS,
                polishing=True,
                warm_starting=True,
                max_iter=20000,
            )
        else:
            self._solver.update(q=d.f, l=lower, u=upper)
        res = self._solver.solve(raise_error=False)
        ok = res.info.status_val in (1, 2)  # solved, solved inaccurate
        return (float(res.x[0]) if ok else None), int(res.info.iter)


class ProxsuiteCandidate:
    """ProxSuite's dense ProxQP (proximal augmented Lagrangian), warm-started from the previous result."""

    name = "proxsuite"

    def __init__(self, params: FollowParams) -> None:
        import proxsuite

        self._cf = CondensedFollow(params)
        self._px = proxsuite.proxqp
        self._qp: proxsuite.proxqp.dense.QP | None = None

    def solve(self, speed_mps: float, leader: LeaderPrediction) -> tuple[float | None, int]:
        d = self._cf.data(speed_mps, leader)
        n = self._cf.n_vars
        if self._qp is None:
            cf = self._cf
            self._qp = self._px.dense.QP(cf.n_vars, 0, cf.rows.shape[0], True)
            self._qp.settings.eps_abs = EPS
            self._qp.settings.eps_rel = 0.0
            self._qp.settings.verbose = False
            self._qp.settings.initial_guess = self._px.InitialGuess.WARM_START_WITH_PREVIOUS_RESULT
            self._qp.init(
                cf.hessian, d.f, None, None, cf.rows, d.lower[n:], d.upper[n:], d.lower[:n], d.upper[:n]
            )
        else:
            self._qp.update(g=d.f, l=d.lower[n:], u=d.upper[n:], l_box=d.lower[:n], u_box=d.upper[:n])
        self._qp.solve()
        info = self._qp.results.info
        ok = info.status == self._px.QPSolverOutput.PROXQP_SOLVED
        return (float(self._qp.results.x[0]) if ok else None), int(info.iter)


class PiqpCandidate:
    """PIQP's dense solver (proximal interior point): no warm start, the workspace kept."""

    name = "piqp"

    def __init__(self, params: FollowParams) -> None:
        import piqp

        self._cf = CondensedFollow(params)
        self._piqp = piqp
        self._solver: piqp.DenseSolver | None = None
        self._h = np.asfortranarray(self._cf.hessian)
        self._g = np.asfortranarray(self._cf.rows)

    def solve(self, speed_mps: float, leader: LeaderPrediction) -> tuple[float | None, int]:
        d = self._cf.data(speed_mps, leader)
        n = self._cf.n_vars
        if self._solver is None:
            self._solver = self._piqp.DenseSolver()
            self._solver.settings.eps_abs = EPS
            self._solver.settings.eps_rel = 0.0
            self._solver.setup(
                P=self._h,
                c=d.f,
                G=self._g,
                h_l=d.lower[n:],
                h_u=d.upper[n:],
                x_l=d.lower[:n],
                x_u=d.upper[:n],
            )
        else:
            self._solver.update(c=d.f, h_l=d.lower[n:], h_u=d.upper[n:])
        status = self._solver.solve()
        ok = status == self._piqp.PIQP_SOLVED
        return (float(self._solver.result.x[0]) if ok else None), int(self._solver.result.info.iter)


def _clarabel_settings(tight: bool) -> clarabel.DefaultSettings:
    s = clarabel.DefaultSettings()
    s.verbose = False
    # Data updates (q, b only) are allowed only without presolve/chordal decomposition.
    s.presolve_enable = False
    s.chordal_decomposition_enable = False
    s.max_threads = 1
    if tight:
        # The position form's tuning: its command is 2 x^1 / dt^2, so position error is amplified 50x
        # (dt 0.2 s); equilibration doubled its iterations and iterative refinement cost ~2x per iteration.
        s.equilibrate_enable = False
        s.iterative_refinement_enable = False
        s.tol_gap_abs = s.tol_gap_rel = s.tol_feas = 1e-10
        s.tol_ktratio = 1e-8
    return s


class _ClarabelSolve:
    """Clarabel's direct interface on P, A fixed, q and b updated (an interior point: no warm start)."""

    def __init__(self, p: sp.csc_matrix, a: sp.csc_matrix, settings: clarabel.DefaultSettings) -> None:
        self._p, self._a, self._settings = p, a, settings
        self._solver: clarabel.DefaultSolver | None = None

    def __call__(self, q: FloatArray, b: FloatArray) -> tuple[FloatArray | None, int]:
        if self._solver is None:
            cones = [clarabel.NonnegativeConeT(self._a.shape[0])]
            self._solver = clarabel.DefaultSolver(self._p, q, self._a, b, cones, self._settings)
        else:
            self._solver.update(q=q, b=b)
        sol = self._solver.solve()
        status = str(sol.status)
        ok = status.endswith(("Solved", "AlmostSolved")) and not status.endswith("Unsolved")
        return (np.asarray(sol.x, dtype=np.float64) if ok else None), int(sol.iterations)


class ClarabelCandidate:
    """Clarabel on the condensed problem, its default settings (no warm start)."""

    name = "clarabel"

    def __init__(self, params: FollowParams) -> None:
        self._cf = CondensedFollow(params)
        n = self._cf.n_vars
        rows = self._cf.rows
        a = np.vstack([np.eye(n), -np.eye(n), rows[:n], -rows[:n], rows[n:]])
        self._solve = _ClarabelSolve(
            sp.csc_matrix(np.triu(self._cf.hessian)), sp.csc_matrix(a), _clarabel_settings(tight=False)
        )

    def solve(self, speed_mps: float, leader: LeaderPrediction) -> tuple[float | None, int]:
        d = self._cf.data(speed_mps, leader)
        n = self._cf.n_vars
        lo, up = d.lower, d.upper
        b = np.concatenate((up[:n], -lo[:n], up[n : 2 * n], -lo[n : 2 * n], up[2 * n :]))
        x, iterations = self._solve(d.f, b)
        return (None if x is None else float(x[0])), iterations


class ClarabelPositionsBaseline:
    """The position form (the paper's variables, sparse banded P and A) with Clarabel, tuned: the fast
    path before the condensed form, the baseline every ratio is measured against."""

    name = "clarabel_positions"

    def __init__(self, params: FollowParams) -> None:
        self.params = params
        m = params.n_samples
        n = m - 1
        dt = params.dt_s
        # Extended positions (x^{-1}, x^0, .., x^{m-1}) = E z + e_v0 * v_0.
        rows = np.concatenate(([0], np.arange(2, m + 1)))
        cols = np.concatenate(([0], np.arange(n)))
        ext = sp.csr_matrix((np.ones(n + 1), (rows, cols)), shape=(m + 1, n))
        ext_v0 = np.zeros(m + 1)
        ext_v0[0] = -2.0 * dt
        d1 = sp.diags([-1.0, 1.0], [1, 3], shape=(m - 2, m + 1)) / (2.0 * dt)  # central, j = 1..m-2
        d2 = sp.diags([1.0, -2.0, 1.0], [0, 1, 2], shape=(m - 1, m + 1)) / dt**2  # j = 0..m-2
        sel = sp.eye(m - 2, m + 1, k=2)  # x^j, j = 1..m-2
        fwd_d = sp.diags([-1.0, 1.0], [1, 2], shape=(m - 1, m + 1)) / dt  # mid-step, j = 0..m-2
        fwd = (fwd_d @ ext).tocsc()
        vel = (d1 @ ext).tocsc()
        acc = (d2 @ ext).tocsc()
        self._acc_v0 = d2 @ ext_v0  # only a^0 depends on v_0
        pos_sel = (sel @ ext).tocsc()
        sd, sa, sv = math.sqrt(params.w_dist), math.sqrt(params.w_acc), math.sqrt(params.w_vel)
        dist = pos_sel + params.headway_s * vel if params.headway_ref == "host" else pos_sel
        big_m = sp.vstack([sd * dist, sa * acc, sv * vel]).tocsc()
        self._sd, self._sa, self._sv = sd, sa, sv
        p_full = (2.0 * dt) * (big_m.T @ big_m)
        self._q_map = ((2.0 * dt) * big_m.T).tocsr()
        blocks = [acc, -acc, fwd, -fwd]
        if params.min_gap_m is not None:
            blocks.append(sp.eye(n, format="csc"))  # x^j, j = 1..m-1
        self._solve = _ClarabelSolve(
            sp.triu(p_full, format="csc"), sp.vstack(blocks).tocsc(), _clarabel_settings(tight=True)
        )

    def solve(self, speed_mps: float, leader: LeaderPrediction) -> tuple[float | None, int]:
        p = self.params
        g, vl = targets(p, leader)
        a_ref = accel_targets(p, leader)
        c = np.concatenate((-self._sd * g, self._sa * (self._acc_v0 * speed_mps - a_ref), -self._sv * vl))
        a_v0 = self._acc_v0 * speed_mps
        v_up, v_lo = speed_envelope(p, speed_mps)
        parts = [p.accel_max_mps2 - a_v0, a_v0 - p.accel_min_mps2, v_up, -v_lo]
        if p.min_gap_m is not None:
            parts.append(leader.positions_m[1:] - p.min_gap_m)
        z, iterations = self._solve(np.asarray(self._q_map @ c, dtype=np.float64), np.concatenate(parts))
        if z is None:
            return None, iterations
        return 2.0 * (z[0] - speed_mps * p.dt_s) / p.dt_s**2, iterations


BASELINE = ClarabelPositionsBaseline.name

CANDIDATES: dict[str, Callable[[FollowParams], Candidate]] = {
    BASELINE: ClarabelPositionsBaseline,
    "clarabel": ClarabelCandidate,
    "daqp": lambda p: DaqpCandidate(p, warm=True),
    "daqp_cold": lambda p: DaqpCandidate(p, warm=False),
    "osqp": OsqpCandidate,
    "piqp": PiqpCandidate,
    "proxsuite": ProxsuiteCandidate,
}
"""Every candidate by name; the first is the baseline."""
