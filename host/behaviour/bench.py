"""`bywire bench urban`: the moving-traffic check, the precedence manager and the lateral controller, timed.

Rows, measured interleaved in one run so that machine load hits all alike; each call is timed alone
with `time.perf_counter_ns` and the distribution reported as p50 / p99 / max in microseconds:

- ``baseline``: an empty Python function called the same way (the floor of the timing method);
- ``mtc_1`` / ``mtc_10``: `moving_traffic_check` with 1 and with 10 vehicles (random but plausible
  scenes: distances, speeds and our own state drawn per call, all five standard parameter sets);
- ``precedence_update``: one `IntersectionPrecedence.update` with three vehicles waiting and one in
  the box (the manager advances 0.1 s per call, as at 10 Hz);
- ``lateral_step``: one `lateral_step` (projection onto a 30 m path stub sampled every 0.25 m, the
  paper's "approximately 30 m ahead", plus eq. 21), with and without the s-hint window.

Each row also gives ``ratio_p50``: its median over the baseline's. Contract (``--json``): ``{"rows":
{name: {"p50_us", "p99_us", "max_us", "n", "ratio_p50"}}, "seconds"}``.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from bywire.host.lateral import LateralParams, PathSamples, VehiclePose, lateral_step

from .mtc import ConflictVehicle, moving_traffic_check
from .precedence import IntersectionPrecedence, StopLine, WaitingVehicle
from .rules import MTC_SITUATIONS

DEFAULT_SECONDS = 5.0
BATCH = 200  # calls of one row before switching to the next (interleaving granularity)


def _noop(*_args: object) -> None:
    return None


def _mtc_cases(rng: np.random.Generator, n_vehicles: int, count: int) -> list[tuple[Any, ...]]:
    params = list(MTC_SITUATIONS.values())
    cases = []
    for _ in range(count):
        own_dist = float(rng.uniform(0.0, 40.0))
        vehicles = [
            ConflictVehicle(
                float(rng.uniform(-30.0, 150.0)), float(rng.uniform(0.0, 15.0)), own_dist, f"b{k}"
            )
            for k in range(n_vehicles)
        ]
        cases.append((float(rng.uniform(0.0, 8.0)), vehicles, params[int(rng.integers(len(params)))]))
    return cases


def _lateral_path() -> PathSamples:
    s = np.arange(0.0, 30.0 + 1e-9, 0.25)
    kappa = 0.05 * np.sin(2.0 * math.pi * s / 30.0)
    heading = np.concatenate(([0.0], np.cumsum(0.5 * (kappa[1:] + kappa[:-1]) * 0.25)))
    x = np.concatenate(([0.0], np.cumsum(0.5 * (np.cos(heading[1:]) + np.cos(heading[:-1])) * 0.25)))
    y = np.concatenate(([0.0], np.cumsum(0.5 * (np.sin(heading[1:]) + np.sin(heading[:-1])) * 0.25)))
    return PathSamples(x, y, heading, kappa, s)


def _stats(samples_ns: list[int], baseline_p50_us: float | None) -> dict[str, float]:
    a = np.asarray(samples_ns, dtype=np.float64) / 1e3
    p50 = float(np.percentile(a, 50))
    out = {"p50_us": p50, "p99_us": float(np.percentile(a, 99)), "max_us": float(a.max()), "n": int(a.size)}
    if baseline_p50_us is not None:
        out["ratio_p50"] = p50 / baseline_p50_us if baseline_p50_us > 0 else math.inf
    return out


def run(seconds: float, seed: int = 7) -> dict[str, Any]:
    rng = np.random.default_rng(seed)
    mtc1 = _mtc_cases(rng, 1, 512)
    mtc10 = _mtc_cases(rng, 10, 512)
    path = _lateral_path()
    lat_params = LateralParams()
    poses = [
        VehiclePose(float(rng.uniform(0.0, 25.0)), float(rng.normal(0.0, 0.5)), float(rng.normal(0.0, 0.1)))
        for _ in range(512)
    ]
    lines = [
        StopLine("S", math.pi / 2),
        StopLine("E", math.pi),
        StopLine("N", -math.pi / 2),
        StopLine("W", 0.0),
    ]
    snapshot = [WaitingVehicle("e", "E", -3.0), WaitingVehicle("n", "N", -2.0), WaitingVehicle("w", "W", 5.0)]
    state: dict[str, Any] = {"pm": None, "t": 0.0}

    def precedence_update(_i: int) -> object:
        if state["pm"] is None or state["t"] > 70.0:  # a fresh intersection every minute of its clock
            state["pm"] = IntersectionPrecedence(lines, "S")
            state["pm"].arrive(10.0)
            state["t"] = 10.0
        state["t"] += 0.1
        return state["pm"].update(state["t"], snapshot, ("x",))

    rows: dict[str, Callable[[int], object]] = {
        "baseline": lambda i: _noop(i),
        "mtc_1": lambda i: moving_traffic_check(*mtc1[i % 512]),
        "mtc_10": lambda i: moving_traffic_check(*mtc10[i % 512]),
        "precedence_update": precedence_update,
        "lateral_step": lambda i: lateral_step(path, poses[i % 512], 1, lat_params),
        "lateral_step_hinted": lambda i: lateral_step(
            path, poses[i % 512], 1, lat_params, s_hint_m=poses[i % 512].x_m, window_m=3.0
        ),
    }
    samples: dict[str, list[int]] = {name: [] for name in rows}
    for fn in rows.values():  # warm-up: imports, caches
        for i in range(20):
            fn(i)
    clock = time.perf_counter_ns
    deadline = time.perf_counter() + seconds
    k = 0
    while time.perf_counter() < deadline or k < 2:
        for name, fn in rows.items():
            bucket = samples[name]
            for i in range(k * BATCH, (k + 1) * BATCH):
                t0 = clock()
                fn(i)
                bucket.append(clock() - t0)
        k += 1
    base = _stats(samples["baseline"], None)
    out_rows = {"baseline": base}
    for name in rows:
        if name != "baseline":
            out_rows[name] = _stats(samples[name], base["p50_us"])
    return {"rows": out_rows, "seconds": seconds}


def _print_table(doc: dict[str, Any]) -> None:
    print(f"{'':22} {'p50 [us]':>10} {'p99 [us]':>10} {'max [us]':>10} {'n':>8} {'p50 / baseline':>15}")
    for name, r in doc["rows"].items():
        ratio = f"{r['ratio_p50']:14.1f}x" if "ratio_p50" in r else f"{'':15}"
        print(f"{name:22} {r['p50_us']:10.2f} {r['p99_us']:10.2f} {r['max_us']:10.1f} {r['n']:8d} {ratio}")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", type=Path, help="write the results as JSON")
    p.add_argument(
        "--seconds",
        type=float,
        default=DEFAULT_SECONDS,
        help=f"roughly how long to measure (default {DEFAULT_SECONDS:.0f})",
    )


def main(args: argparse.Namespace) -> int:
    seconds = DEFAULT_SECONDS if getattr(args, "seconds", None) is None else float(args.seconds)
    if not (math.isfinite(seconds) and seconds > 0.0):
        print(f"bywire bench urban: --seconds {seconds} must be > 0")
        return 2
    doc = run(seconds)
    _print_table(doc)
    if getattr(args, "json", None) is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
    return 0
