"""Follow QP (seed 003 V-C, eq. 3) fast path vs. cvxpy oracle, limits, closed loop; V-D strategy; bench.
Property tests on drawn problems: test_follow_qp_properties.py."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest

from bywire.cli import benchmark
from bywire.host.platoon.follow_oracle import follow_oracle
from bywire.host.platoon.follow_qp import (
    AccelRef,
    FollowParams,
    FollowQP,
    HeadwayRef,
    LeaderPrediction,
)
from bywire.host.platoon.strategy import PlatoonStrategy

bench = benchmark("platoon")

# Agreement of the fast path with the oracle. The fast path's command is a variable solved exactly for
# its active set; the oracle's is a second difference, 2 x^1 / dt^2 (position error amplified 50x at dt
# 0.2 s, 200x at 0.1 s), solved to 1e-10. Measured max ~2e-8 m/s^2 on hundreds of random problems.
ACCEL_TOL_MPS2 = 1e-4
POS_TOL_M = 1e-3
LIMIT_TOL = 1e-5  # on a^j [m/s^2] and v^j [m/s] from the returned positions (DAQP's primal tolerance 1e-6)


@pytest.mark.parametrize(
    ("dt_s", "headway_ref", "accel_ref"),
    [(0.2, "host", "zero"), (0.1, "host", "zero"), (0.2, "leader", "zero"), (0.2, "host", "leader")],
)
def test_fast_path_agrees_with_oracle_on_random_problems(
    dt_s: float, headway_ref: HeadwayRef, accel_ref: AccelRef
) -> None:
    params = FollowParams(dt_s=dt_s, headway_ref=headway_ref, accel_ref=accel_ref)
    qp = FollowQP(params)
    rng = np.random.default_rng(20110514 + int(dt_s * 10))
    n_infeasible = 0
    for _ in range(40):
        speed, leader = bench.random_case(rng, params)
        f = qp.solve(speed, leader)
        o = follow_oracle(params, speed, leader)
        assert f.feasible == o.feasible, (f.status, o.status)
        if not f.feasible:
            n_infeasible += 1
            assert f.accel_cmd_mps2 == params.accel_min_mps2
            continue
        assert abs(f.accel_cmd_mps2 - o.accel_cmd_mps2) <= ACCEL_TOL_MPS2
        assert np.max(np.abs(f.positions_m - o.positions_m)) <= POS_TOL_M
    assert n_infeasible < 40


def test_a_penalty_relative_to_the_leader_passes_its_acceleration_on() -> None:
    """At the desired gap and speed behind a leader accelerating at 1 m/s^2, the paper's absolute
    penalty plans less than the leader's acceleration; the relative one follows it."""
    base = FollowParams(reserve_m=8.0, min_gap_m=None)
    v0 = 20.0
    gap = base.reserve_m + base.headway_s * v0
    leader = LeaderPrediction.constant_accel(gap, v0, 1.0, base)
    absolute = FollowQP(base).solve(v0, leader).accel_cmd_mps2
    relative = FollowQP(FollowParams(reserve_m=8.0, min_gap_m=None, accel_ref="leader")).solve(v0, leader)
    assert absolute < 0.5 < relative.accel_cmd_mps2 <= 1.0 + 1e-3


def test_bad_references_are_refused() -> None:
    with pytest.raises(ValueError, match="accel_ref"):
        FollowParams(accel_ref="lead")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="headway_ref"):
        FollowParams(headway_ref="ego")  # type: ignore[arg-type]


def test_solution_respects_limits() -> None:
    params = FollowParams(dt_s=0.2)
    qp = FollowQP(params)
    rng = np.random.default_rng(7)
    dt = params.dt_s
    checked = 0
    for _ in range(60):
        speed, leader = bench.random_case(rng, params)
        r = qp.solve(speed, leader)
        if not r.feasible:
            continue
        checked += 1
        x = r.positions_m
        ghost = x[1] - 2.0 * dt * speed
        ext = np.concatenate(([ghost], x))
        acc = (ext[2:] - 2.0 * ext[1:-1] + ext[:-2]) / dt**2  # j = 0..m-2
        vel = np.diff(x) / dt  # mid-step speeds, j = 0..m-2
        assert np.all(acc >= params.accel_min_mps2 - LIMIT_TOL)
        assert np.all(acc <= params.accel_max_mps2 + LIMIT_TOL)
        assert np.all(vel >= params.speed_min_mps - LIMIT_TOL)
        assert np.all(vel <= params.speed_max_mps + LIMIT_TOL)
        assert params.min_gap_m is not None
        assert np.all(x[1:] <= leader.positions_m[1:] - params.min_gap_m + LIMIT_TOL)
        assert abs(acc[0] - r.accel_cmd_mps2) < 1e-9
    assert checked > 30


def test_impossible_braking_gives_full_brake_flagged() -> None:
    params = FollowParams(dt_s=0.2)
    qp = FollowQP(params)
    # 25 m/s, leader 10 m ahead braking at 9 m/s^2: no profile within -4.5 m/s^2 keeps the minimum gap.
    leader = LeaderPrediction.constant_accel(10.0, 25.0, -9.0, params)
    r = qp.solve(25.0, leader)
    assert not r.feasible
    assert r.accel_cmd_mps2 == params.accel_min_mps2
    o = follow_oracle(params, 25.0, leader)
    assert not o.feasible
    # Non-finite input: no exception, full brake.
    bad = qp.solve(float("nan"), leader)
    assert not bad.feasible and bad.accel_cmd_mps2 == params.accel_min_mps2


def test_a_solver_that_gives_up_brakes(monkeypatch: pytest.MonkeyPatch) -> None:
    """DAQP stopped by its iteration limit (here 1: a braking leader needs a few active constraints):
    no exception, full brake, flagged, the reason in the status."""
    from bywire.host.platoon import follow_qp

    monkeypatch.setattr(follow_qp, "ITER_LIMIT", 1)
    params = FollowParams(dt_s=0.2)
    qp = FollowQP(params)
    leader = LeaderPrediction.constant_accel(25.0, 15.0, -3.0, params)
    for _ in range(2):  # cold, then warm (retried cold)
        r = qp.solve(20.0, leader)
        assert not r.feasible and r.accel_cmd_mps2 == params.accel_min_mps2
        assert r.status == "iteration limit"
    monkeypatch.undo()
    assert FollowQP(params).solve(20.0, leader).feasible


def test_speed_above_limit_is_not_infeasible() -> None:
    params = FollowParams(dt_s=0.1)
    leader = LeaderPrediction.constant_accel(60.0, 27.0, 0.0, params)
    r = FollowQP(params).solve(params.speed_max_mps + 2.0, leader)
    assert r.feasible
    assert r.accel_cmd_mps2 < 0.0


@pytest.mark.parametrize("dt_s", [0.2, 0.1])
def test_closed_loop_converges_to_desired_gap(dt_s: float) -> None:
    params = FollowParams(dt_s=dt_s)
    qp = FollowQP(params)
    lead_speed = 20.0
    gap, speed = 55.0, 14.0  # 23 m too far back and 6 m/s slower
    sim_dt = 0.05
    steps_per_cmd = round(dt_s / sim_dt)
    accel = 0.0
    for k in range(round(60.0 / sim_dt)):
        if k % steps_per_cmd == 0:
            leader = LeaderPrediction.constant_accel(gap, lead_speed, 0.0, params)
            r = qp.solve(speed, leader)
            assert r.feasible
            accel = r.accel_cmd_mps2
            assert params.accel_min_mps2 - 1e-6 <= accel <= params.accel_max_mps2 + 1e-6
        # Exact double integrator over the simulation step.
        gap -= speed * sim_dt + 0.5 * accel * sim_dt**2 - lead_speed * sim_dt
        speed += accel * sim_dt
        assert gap > 0.0
    desired = params.reserve_m + params.headway_s * lead_speed
    assert abs(gap - desired) < 0.1
    assert abs(speed - lead_speed) < 0.05


def test_strategy_locks_on_hard_braking_middle_vehicle() -> None:
    params = FollowParams(dt_s=0.2)
    strat = PlatoonStrategy(params, slack_m=2.0)
    v = 20.0
    d = params.reserve_m + params.headway_s * v

    def platoon(accels: list[float]) -> list[LeaderPrediction]:
        return [
            LeaderPrediction.constant_accel(i * d + (i - 1) * strat.slack_m, v, a, params)
            for i, a in enumerate(accels, start=1)
        ]

    calm = strat.step(v, platoon([0.0, 0.0, 0.0, 0.0]))
    assert calm.feasible and abs(calm.accel_cmd_mps2) < 1e-2
    braking = strat.step(v, platoon([0.0, -6.0, 0.0, 0.0]))
    assert braking.binding_index == 2
    assert braking.accel_cmd_mps2 == min(r.accel_cmd_mps2 for r in braking.per_leader)
    assert braking.accel_cmd_mps2 < -1.0
    # The slack makes the farther vehicle ask for more room: with vehicle 2 a metre too close to
    # vehicle 1 (it follows its own leader loosely), the lock moves to it, not to vehicle 1.
    close = platoon([0.0, 0.0])
    close[1] = LeaderPrediction.constant_accel(2 * d + strat.slack_m - 3.0, v, 0.0, params)
    assert strat.step(v, close).binding_index == 2
    assert strat.step(v, []).binding_index == 0


def test_bench_main_writes_contract_json(tmp_path: Path) -> None:
    out = tmp_path / "platoon.json"
    rc = bench.main(argparse.Namespace(json=out, seconds=0.2))
    assert rc == 0
    doc = json.loads(out.read_text(encoding="utf-8"))
    for key in ("qp_us", "oracle_qp_us", "step_ms"):
        assert {"p50", "p99"} <= set(doc[key])
        assert doc[key]["p50"] > 0.0
    assert doc["leaders"] == 10
    assert doc["max_abs_diff_vs_oracle"] <= ACCEL_TOL_MPS2
    # every candidate solver, side by side on the same closed-loop problems, the baseline among them
    assert set(doc["solvers"]) == set(bench.CANDIDATES)
    assert doc["solver_baseline"] in doc["solvers"] and doc["solver_runtime"] in doc["solvers"]
    for row in doc["solvers"].values():
        assert row["p50"] > 0.0 and row["p99"] >= row["p50"]
        assert row["max_abs_diff_vs_oracle"] <= 1e-2  # a candidate fed the wrong data is off by metres/s^2
    runtime = doc["solvers"][doc["solver_runtime"]]
    assert runtime["max_abs_diff_vs_oracle"] <= ACCEL_TOL_MPS2
    assert runtime["feasibility_disagreements"] == 0


def test_bench_platoon_runs_as_a_user_runs_it(tmp_path: Path) -> None:
    """`bywire bench platoon --json FILE` (its JSON contract), a very short run."""
    import subprocess
    import sys

    out = tmp_path / "bp.json"
    proc = subprocess.run(
        [sys.executable, "-m", "bywire", "bench", "platoon", "--seconds", "0.3", "--json", str(out)],
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(out.read_text())
    assert {"qp_us", "oracle_qp_us", "step_ms", "leaders", "max_abs_diff_vs_oracle", "solvers"} <= set(doc)
    assert all({"p50", "p99"} <= set(row) for row in doc["solvers"].values())
    assert doc["leaders"] == 10 and {"p50", "p99"} <= set(doc["step_ms"])
