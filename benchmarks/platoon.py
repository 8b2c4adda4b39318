"""`bywire bench platoon`: the follow QP of seed 003 V-C (eq. 3) and the V-D platoon step, timed.

Rows, all in one run so that machine load hits both alike:

- one follow QP (10 s horizon) at dt 0.2 s (51 samples) and 0.1 s (101 samples): the fast path
  (`FollowQP`, Clarabel's direct interface, vectors updated in place) and the oracle (`follow_oracle`,
  cvxpy with a cached parameterised problem, solved by Clarabel), interleaved on the same random
  problems; the oracle's command is the reference for ``max_abs_diff_vs_oracle`` (m/s^2, largest
  |a_fast - a_oracle| over the problems both solved).
- the platoon step (`PlatoonStrategy.step`, dt 0.2 s) with 10 vehicles ahead: 10 follow QPs and the
  minimum; also the same step with the oracle for the ratio. Target: p99 <= 10 ms.

Contract (``--json``): ``{"qp_us": {"p50", "p99"}, "oracle_qp_us": {"p50", "p99"}, "step_ms": {"p50",
"p99"}, "leaders": 10, "max_abs_diff_vs_oracle"}`` where the top-level QP rows are for dt 0.2 s (the
step's grid); ``by_dt`` holds both grids, ``oracle_step_ms`` the oracle's step.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from typing import Any

import numpy as np

from benchmarks.timed import add_timed_arguments, run_timed
from bywire.host.platoon.follow_qp import FollowParams, FollowQP, LeaderPrediction, follow_oracle
from bywire.host.platoon.strategy import PlatoonStrategy

DEFAULT_SECONDS = 10.0
LEADERS = 10
STEP_DT_S = 0.2


def random_case(rng: np.random.Generator, params: FollowParams) -> tuple[float, LeaderPrediction]:
    """A host speed and a constant-acceleration leader, covering following, closing in and hard braking."""
    v_max = params.speed_max_mps
    speed = float(rng.uniform(0.0, v_max))
    gap = float(rng.uniform(3.0, 80.0))
    lead_speed = float(np.clip(speed + rng.normal(0.0, 4.0), 0.0, v_max))
    lead_accel = float(rng.uniform(-7.0, 2.0))
    return speed, LeaderPrediction.constant_accel(gap, lead_speed, lead_accel, params)


def random_platoon(
    rng: np.random.Generator, params: FollowParams, n: int, slack_m: float = 2.0
) -> tuple[float, list[LeaderPrediction]]:
    """A host and n vehicles ahead near their platoon positions; sometimes one of them brakes hard."""
    speed = float(rng.uniform(5.0, 25.0))
    hard = int(rng.integers(0, n)) if rng.random() < 0.3 else -1
    leaders = []
    for k in range(n):
        i = k + 1
        gap = i * (params.reserve_m + params.headway_s * speed) + (i - 1) * slack_m + rng.normal(0.0, 3.0)
        accel = -7.0 if k == hard else float(rng.uniform(-1.5, 1.0))
        v = float(np.clip(speed + rng.normal(0.0, 1.0), 0.0, params.speed_max_mps))
        leaders.append(LeaderPrediction.constant_accel(max(gap, 3.0), v, accel, params))
    return speed, leaders


def _pct(samples_s: list[float], scale: float) -> dict[str, float]:
    a = np.asarray(samples_s) * scale
    return {"p50": float(np.percentile(a, 50)), "p99": float(np.percentile(a, 99)), "n": int(a.size)}


def _bench_qp(dt_s: float, seconds: float, seed: int) -> dict[str, Any]:
    params = FollowParams(dt_s=dt_s)
    fast = FollowQP(params)
    rng = np.random.default_rng(seed)
    fast_s: list[float] = []
    oracle_s: list[float] = []
    max_diff = 0.0
    disagree = 0
    follow_oracle(params, *random_case(rng, params))  # warm-up: cvxpy canonicalisation, imports
    fast.solve(*random_case(rng, params))
    deadline = time.perf_counter() + seconds
    while time.perf_counter() < deadline or len(oracle_s) < 5:
        speed, leader = random_case(rng, params)
        t0 = time.perf_counter()
        o = follow_oracle(params, speed, leader)
        t1 = time.perf_counter()
        oracle_s.append(t1 - t0)
        # The fast path is ~10x quicker: time it several times per oracle call for a tighter p99.
        for _ in range(5):
            t0 = time.perf_counter()
            f = fast.solve(speed, leader)
            fast_s.append(time.perf_counter() - t0)
        if f.feasible and o.feasible:
            max_diff = max(max_diff, abs(f.accel_cmd_mps2 - o.accel_cmd_mps2))
        elif f.feasible != o.feasible:
            disagree += 1
    return {
        "dt_s": dt_s,
        "qp_us": _pct(fast_s, 1e6),
        "oracle_qp_us": _pct(oracle_s, 1e6),
        "max_abs_diff_vs_oracle": max_diff,
        "feasibility_disagreements": disagree,
    }


def _bench_step(seconds: float, seed: int) -> dict[str, Any]:
    params = FollowParams(dt_s=STEP_DT_S)
    strat = PlatoonStrategy(params)
    rng = np.random.default_rng(seed)
    step_s: list[float] = []
    oracle_step_s: list[float] = []
    warm = random_platoon(rng, params, LEADERS)
    strat.step(*warm)
    for k, leader in enumerate(warm[1]):  # cvxpy canonicalisation of each of the 10 problems, once
        follow_oracle(strat.params_for(k + 1), warm[0], leader)
    deadline = time.perf_counter() + seconds
    while time.perf_counter() < deadline or len(oracle_step_s) < 2:
        speed, leaders = random_platoon(rng, params, LEADERS)
        for _ in range(3):
            t0 = time.perf_counter()
            strat.step(speed, leaders)
            step_s.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        for k, leader in enumerate(leaders):
            i = k + 1
            follow_oracle(strat.params_for(i), speed, leader)
        oracle_step_s.append(time.perf_counter() - t0)
    return {"step_ms": _pct(step_s, 1e3), "oracle_step_ms": _pct(oracle_step_s, 1e3)}


def run(seconds: float) -> dict[str, Any]:
    by_dt = {
        "0.2": _bench_qp(0.2, 0.3 * seconds, seed=1),
        "0.1": _bench_qp(0.1, 0.3 * seconds, seed=2),
    }
    step = _bench_step(0.4 * seconds, seed=3)
    top = by_dt["0.2"]
    return {
        "qp_us": top["qp_us"],
        "oracle_qp_us": top["oracle_qp_us"],
        "step_ms": step["step_ms"],
        "oracle_step_ms": step["oracle_step_ms"],
        "leaders": LEADERS,
        "max_abs_diff_vs_oracle": max(d["max_abs_diff_vs_oracle"] for d in by_dt.values()),
        "step_target_ms": 10.0,
        "by_dt": by_dt,
        "params": dataclasses.asdict(FollowParams(dt_s=STEP_DT_S)),
    }


def _print_table(doc: dict[str, Any]) -> None:
    print(f"{'':30} {'p50':>10} {'p99':>10} {'oracle p50':>11} {'oracle p99':>11} {'ratio p50':>10}")
    for key, d in doc["by_dt"].items():
        f, o = d["qp_us"], d["oracle_qp_us"]
        print(
            f"{'follow QP dt ' + key + ' s [us]':30} {f['p50']:10.0f} {f['p99']:10.0f} "
            f"{o['p50']:11.0f} {o['p99']:11.0f} {o['p50'] / f['p50']:9.1f}x"
        )
    s, o = doc["step_ms"], doc["oracle_step_ms"]
    label = f"platoon step, {doc['leaders']} ahead [ms]"
    print(
        f"{label:30} {s['p50']:10.2f} {s['p99']:10.2f} "
        f"{o['p50']:11.2f} {o['p99']:11.2f} {o['p50'] / s['p50']:9.1f}x"
    )
    ok = "met" if s["p99"] <= doc["step_target_ms"] else "MISSED"
    print(f"\nstep p99 target {doc['step_target_ms']:.0f} ms: {ok}")
    for key, d in doc["by_dt"].items():
        print(
            f"dt {key} s: max |a_fast - a_oracle| = {d['max_abs_diff_vs_oracle']:.2e} m/s^2, "
            f"feasibility disagreements {d['feasibility_disagreements']}"
        )


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_timed_arguments(p, DEFAULT_SECONDS, "the whole run takes")


def main(args: argparse.Namespace) -> int:
    return run_timed(args, "platoon", DEFAULT_SECONDS, run, _print_table)
