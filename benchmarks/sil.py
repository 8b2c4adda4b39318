"""`bywire bench sil`: how fast SIL runs whole scenarios, beside the FMU stepped alone in the same run.

    bywire bench sil [--scenario NAME ...] [--repeats N] [--duration S] [--json FILE]

SIL (DESIGN section 1) steps plant, ECU and host in lockstep every simulated millisecond; its
real-time factor (simulated seconds per wall second of the stepping loop, start-up excluded, as
`run_sil` reports it) is what makes campaigns of many runs affordable. Per scenario it prints the
factor's median / p99 / max / min over the repeats, and within each run the factor of every
simulated second (median, 1st percentile, min: where a run slows down), and the factor on the loop's
CPU time (simulated seconds per CPU second of the stepping thread: what other processes on a shared
machine take away from the wall-clock factor, it leaves out). The machine's baseline is the
vehicle FMU stepped alone at 1 kHz for 5 s, before the scenarios and after them: on a shared machine
an absolute factor from another day says little, its ratio to this baseline more.

Contract (``--json FILE``): ``{"sil_factor": {NAME: {"median", "p99", "max", "min", "n", "runs",
"per_second": {"median", "p01", "min"}, "cpu_factor": {"median", "runs"}, "simulated_s", "target",
"ratio_to_baseline"}},
"baseline_fmu_alone_factor": {"before", "after"}}``. Targets are printed, never asserted.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

# The scenarios the simulator's speed is judged on, and the factor each should reach on these
# 2-core machines: the spine's demo, the 10-vehicle GCDC heat, the DARPA sample mission.
TARGETS: dict[str, float] = {"demo": 50.0, "gcdc_heat": 25.0, "darpa_sample_mission": 30.0}
FMU_BASELINE_S = 5.0


def fmu_alone_factor(seconds: float = FMU_BASELINE_S) -> float:
    """The vehicle FMU stepped alone at 1 kHz: the machine's speed today, the floor of SIL's cost."""
    from bywire.vehicle_models.fmu_vehicle import VehicleInputs, open_vehicle

    vehicle = open_vehicle("passat", start_values={"v0_mps": 10.0})
    inputs = VehicleInputs(throttle_pct=20.0)
    try:
        t0 = time.perf_counter()
        for _ in range(round(seconds * 1000)):
            vehicle.step(0.001, inputs)
        wall = time.perf_counter() - t0
    finally:
        vehicle.close()
    return round(seconds / wall, 1)


def run_once(name: str, duration_s: float | None) -> tuple[float, list[float], float, float]:
    """One SIL run: its real-time factor, the factor of each simulated second, the simulated time,
    and the simulated time per second of this thread's CPU time over the same loop."""
    from bywire.hil.scenario import load_scenario
    from bywire.hil.sil import run_sil

    scenario = load_scenario(name)
    if duration_s is not None:
        scenario = dataclasses.replace(scenario, duration_s=min(duration_s, scenario.duration_s))
    simulated_s = scenario.duration_s
    marks: list[tuple[float, float]] = []  # (simulated s, wall s), every simulated 0.1 s
    cpu: list[float] = []

    def progress(fraction: float) -> None:
        marks.append((fraction * simulated_s, time.perf_counter()))
        cpu.append(time.thread_time())

    result = run_sil(scenario, progress=progress)
    per_second: list[float] = []
    last_sim, last_wall = marks[0] if marks else (0.0, 0.0)
    for sim, wall in marks[1:]:
        if sim - last_sim >= 1.0 - 1e-9 and wall > last_wall:
            per_second.append((sim - last_sim) / (wall - last_wall))
            last_sim, last_wall = sim, wall
    loop_cpu_s = cpu[-1] - cpu[0] if len(cpu) > 1 else 0.0
    cpu_factor = (marks[-1][0] - marks[0][0]) / loop_cpu_s if loop_cpu_s > 0.0 else float("nan")
    return float(result.extra["real_time_factor"]), per_second, simulated_s, cpu_factor


def bench(names: list[str], repeats: int, duration_s: float | None) -> dict[str, Any]:
    before = fmu_alone_factor()
    out: dict[str, Any] = {}
    for name in names:
        factors: list[float] = []
        cpu_factors: list[float] = []
        seconds: list[float] = []
        simulated_s = 0.0
        for _ in range(repeats):
            factor, per_second, simulated_s, cpu_factor = run_once(name, duration_s)
            factors.append(factor)
            cpu_factors.append(round(cpu_factor, 2))
            seconds.extend(per_second)
            print(f"  {name}: {factor:.2f}x ({simulated_s:g} s simulated)", file=sys.stderr, flush=True)
        per = np.asarray(seconds) if seconds else np.asarray(factors)
        out[name] = {
            "median": round(statistics.median(factors), 2),
            "p99": round(float(np.percentile(factors, 99)), 2),
            "max": round(max(factors), 2),
            "min": round(min(factors), 2),
            "n": len(factors),
            "runs": factors,
            "per_second": {
                "median": round(float(np.median(per)), 2),
                "p01": round(float(np.percentile(per, 1)), 2),
                "min": round(float(per.min()), 2),
            },
            "cpu_factor": {"median": round(statistics.median(cpu_factors), 2), "runs": cpu_factors},
            "simulated_s": simulated_s,
            "target": TARGETS.get(name),
        }
    after = fmu_alone_factor()
    for row in out.values():
        row["ratio_to_baseline"] = round(row["median"] / max(statistics.mean((before, after)), 1e-9), 4)
    return {"sil_factor": out, "baseline_fmu_alone_factor": {"before": before, "after": after}}


def print_table(doc: dict[str, Any]) -> None:
    base = doc["baseline_fmu_alone_factor"]
    print(f"FMU alone at 1 kHz: {base['before']}x before, {base['after']}x after")
    head = f"{'scenario':24s} {'median':>8s} {'p99':>8s} {'max':>8s} {'min':>8s} {'n':>3s}"
    print(f"{head}  per s: p01/min  CPU  target")
    for name, row in doc["sil_factor"].items():
        target = row["target"]
        verdict = "" if target is None else f"{target:g}x {'met' if row['median'] >= target else 'not met'}"
        print(
            f"{name:24s} {row['median']:8.2f} {row['p99']:8.2f} {row['max']:8.2f} {row['min']:8.2f} "
            f"{row['n']:3d}  {row['per_second']['p01']:6.2f}/{row['per_second']['min']:<6.2f} "
            f"{row['cpu_factor']['median']:6.2f} {verdict}"
        )


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--scenario",
        action="append",
        help=f"a scenario to run (repeatable; default: {', '.join(TARGETS)})",
    )
    p.add_argument("--repeats", type=int, default=1, help="runs of each scenario (default 1)")
    p.add_argument(
        "--duration", type=float, help="simulate at most this long per run (default: each scenario's own)"
    )
    p.add_argument("--json", type=Path, metavar="FILE", help="write the results as JSON")


def main(args: argparse.Namespace) -> int:
    if args.repeats < 1:
        print(f"bywire bench sil: --repeats {args.repeats} must be >= 1", file=sys.stderr)
        return 2
    if args.duration is not None and not args.duration > 0.0:
        print(f"bywire bench sil: --duration {args.duration:g} must be > 0", file=sys.stderr)
        return 2
    doc = bench(args.scenario or list(TARGETS), args.repeats, args.duration)
    print_table(doc)
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
    return 0
