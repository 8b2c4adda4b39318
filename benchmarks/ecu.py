"""`bywire bench ecu`: the ECU's 1 kHz loop timing with the plant and the host running beside it.

It runs the demo scenario as three real processes (HIL) for the requested time and reads the ECU's
own loop statistics (lateness = wake-up time minus deadline, compute = step duration, overruns).
For scale, the same cyclic executive with an empty step is measured first in this process, on the
same machine, in the same run: the ratio says how much the real ECU work and the load of the other
processes cost on top of the operating system's own wake-up jitter (DESIGN.md section 4: the
ECU's 1 kHz budget, lateness and overruns measured and reported; section 5: ratios from one run).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import os
import tempfile
from pathlib import Path
from typing import Any

from bywire.clock import WallClock
from bywire.ecu.executive import CycleStats, CyclicExecutive
from bywire.hil.report import write_json
from bywire.hil.runner import run_hil
from bywire.hil.scenario import load_scenario
from bywire.realtime import apply_realtime

BASELINE_S = 3.0


def baseline_loop(seconds: float = BASELINE_S) -> dict[str, Any]:
    """The executive with an empty step: the floor set by the OS and Python's wake-up path."""
    clock = WallClock()
    stats = CycleStats()
    executive = CyclicExecutive(0.001, clock, lambda now_s: None, stats)
    executive.run(max_cycles=int(seconds * 1000))
    return stats.snapshot()


def bench_ecu(seconds: float, json_path: Path | None, report_dir: Path | None) -> int:
    rt = apply_realtime(priority=70)
    print(f"baseline: empty 1 kHz loop for {BASELINE_S:.0f} s ({rt.summary()})", flush=True)
    baseline = baseline_loop()
    with contextlib.suppress(OSError, AttributeError):
        # Back to normal scheduling: the runner must not compete with the processes it measures.
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    scenario = dataclasses.replace(load_scenario("demo"), duration_s=seconds)
    with tempfile.TemporaryDirectory(prefix="bywire-bench-") as tmp:
        run_dir = report_dir or Path(tmp)
        print(f"measuring the ECU for {seconds:.0f} s with plant and host running (HIL) ...", flush=True)
        result = run_hil(scenario, run_dir)
        stats_path = run_dir / "ecu_stats.json"
        if not stats_path.exists():
            print("error: the ECU wrote no loop statistics", flush=True)
            return 1
        ecu = json.loads(stats_path.read_text(encoding="utf-8"))
    doc: dict[str, Any] = dict(ecu)
    doc["baseline"] = baseline
    base_p99 = baseline["lateness_us"]["p99"] or 1e-9
    doc["ratio_vs_baseline"] = {
        "lateness_p50": round(ecu["lateness_us"]["p50"] / (baseline["lateness_us"]["p50"] or 1e-9), 2),
        "lateness_p99": round(ecu["lateness_us"]["p99"] / base_p99, 2),
    }
    doc["overruns_per_10k"] = round(10_000 * ecu["overruns"] / max(1, ecu["cycles"]), 3)
    doc["real_time_factor"] = result.extra.get("real_time_factor")
    late, comp = ecu["lateness_us"], ecu["compute_us"]
    print(f"ECU cycles {ecu['cycles']}, overruns {ecu['overruns']} ({doc['overruns_per_10k']} per 10k)")
    print(
        f"lateness us: median {late['p50']:.0f}  p99 {late['p99']:.0f}  p99.9 {late['p999']:.0f}  "
        f"max {late['max']:.0f}   (baseline median {baseline['lateness_us']['p50']:.0f}, "
        f"p99 {baseline['lateness_us']['p99']:.0f}; ratio p99 {doc['ratio_vs_baseline']['lateness_p99']})"
    )
    print(f"compute us:  median {comp['p50']:.0f}  p99 {comp['p99']:.0f}  max {comp['max']:.0f}")
    print(f"scheduler: {ecu.get('scheduler')}")
    if json_path is not None:
        write_json(json_path, doc)
    return 0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--seconds", type=float, default=20.0, help="how long to measure (default 20)")
    p.add_argument("--json", type=Path, help="write the loop statistics as JSON")
    p.add_argument("--report", type=Path, help="directory for the run's logs and traces")


def main(args: argparse.Namespace) -> int:
    return bench_ecu(args.seconds, args.json, args.report)
