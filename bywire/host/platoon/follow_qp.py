"""The follow QP of seed 003 section V-C (eq. 3) solved each control cycle: `FollowQP`.

`follow_problem` holds the problem (and re-exported here, the names its callers import), its
condensed form onto the accelerations is `follow_condensed`, the reference `follow_oracle`.

Solver: DAQP (Arnström, Bemporad, Axehill, "A dual active-set solver for embedded quadratic
programming using recursive LDL' updates", IEEE TAC 67(8), 2022; MIT), a dual active-set method like
the paper's Goldfarb-Idnani (quadprog is GPL). One DAQP workspace per `FollowQP`: the Hessian is
factorised once per `FollowParams`, each cycle updates only ``f`` and the bounds, and the solve starts
from the previous cycle's working set (the constraints that were active a cycle ago, at the same grid
indices: at the host's 50 ms cycle on the 0.2 s grid a constraint moves by a quarter of a step). In a
closed loop (`bywire bench platoon`'s) that takes 1.9-2.1 iterations on average, 30-34 from the empty
set. Shifting the working set by a step, the textbook's shifted warm start, gained nothing there at
50, 100 or 200 ms cycles: what binds is mostly a run of ``a^j = a_min`` from j = 0 on, which a shift
changes only at its end. An active-set method ends on the exact solution of its working set, so the
command is exact to rounding (no interior-point tolerance amplified by ``2 / dt^2``). `bywire bench
platoon` measures it against Clarabel, OSQP, PIQP and ProxSuite on the same matrices, and against
the position form's Clarabel path that came before (README, "Platoon control").

A warm start that fails (cycling, the iteration limit) is retried once from the empty working set;
infeasibility is DAQP's certificate (the dual is unbounded), the same from any start.
"""

from __future__ import annotations

import math

import daqp
import numpy as np
import numpy.typing as npt

from .follow_condensed import CondensedFollow
from .follow_problem import (
    KMH_TO_MPS,
    AccelRef,
    FloatArray,
    FollowParams,
    FollowResult,
    HeadwayRef,
    LeaderPrediction,
    braking_result,
    check_shapes,
)

# DAQP's exit flags (daqp include/constants.h).
EXIT_OPTIMAL = 1
EXIT_INFEASIBLE = -1
_EXIT_NAMES = {
    1: "optimal",
    2: "soft optimal",
    -1: "infeasible",
    -2: "cycling",
    -3: "unbounded",
    -4: "iteration limit",
}

# Only a cycling solver meets it: measured on random problems, at most ~230 iterations at dt 0.1 s
# (300 constraints) and ~110 at 0.2 s; one iteration costs 2-10 us.
ITER_LIMIT = 2000


class FollowQP:
    """Fast path: DAQP on the condensed problem, its workspace and working set kept between calls."""

    def __init__(self, params: FollowParams) -> None:
        self.params = params
        self.problem = CondensedFollow(params)
        self._model: daqp.Model | None = None
        self.warm_start = True
        """False: every solve from the empty working set (the benchmark's cold rows)."""

    def _cold_sense(self) -> npt.NDArray[np.int32]:
        """DAQP's constraint flags with none active: the empty working set."""
        return np.zeros(self.problem.n_constraints, dtype=np.int32)

    def _solve_data(self, f: FloatArray, lower: FloatArray, upper: FloatArray) -> tuple[FloatArray, int, int]:
        """(a, exit flag, iterations); a cold retry where a warm start failed for a reason of its own."""
        model = self._model
        if model is None:
            model = daqp.Model()
            pr = self.problem
            flag, _ = model.setup(pr.hessian, f, pr.rows, upper, lower, self._cold_sense())
            if flag < 0:
                raise RuntimeError(f"DAQP setup failed ({flag})")
            model.settings = {"iter_limit": ITER_LIMIT}
            self._model = model
            warm = False
        else:
            warm = self.warm_start
            model.update(f=f, bupper=upper, blower=lower, sense=None if warm else self._cold_sense())
        x, _, flag, info = model.solve()
        iterations = int(info["iterations"])
        if warm and flag not in (EXIT_OPTIMAL, EXIT_INFEASIBLE):
            model.update(sense=self._cold_sense())
            x, _, flag, info = model.solve()
            iterations += int(info["iterations"])
        return np.asarray(x, dtype=np.float64), int(flag), iterations

    def solve(self, speed_mps: float, leader: LeaderPrediction) -> FollowResult:
        """One follow solution for the host at ``speed_mps`` behind ``leader``; never raises on data."""
        p = self.params
        check_shapes(p, leader)
        try:
            d = self.problem.data(speed_mps, leader)
            # One sum per vector: a NaN or an inf anywhere makes it non-finite (the finite bounds are
            # at most 1e30, their sums far from overflowing).
            if not math.isfinite(speed_mps + float(d.f.sum()) + float(d.lower.sum()) + float(d.upper.sum())):
                return braking_result(p, speed_mps, "non-finite input")
            accels, flag, iterations = self._solve_data(d.f, d.lower, d.upper)
        except Exception as exc:  # the loop never raises: brake and report, start afresh next time
            self._model = None
            return braking_result(p, speed_mps, f"error: {exc}")
        status = _EXIT_NAMES.get(flag, f"exit {flag}")
        if flag != EXIT_OPTIMAL:
            # An infeasible problem leaves a working set that means nothing for the next one.
            if self._model is not None:
                self._model.update(sense=self._cold_sense())
            return braking_result(p, speed_mps, status)
        return self.problem.result(speed_mps, accels, status, iterations)


__all__ = [
    "KMH_TO_MPS",
    "AccelRef",
    "FollowParams",
    "FollowQP",
    "FollowResult",
    "HeadwayRef",
    "LeaderPrediction",
]
