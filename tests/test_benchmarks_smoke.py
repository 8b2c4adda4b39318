"""The benchmark script runs and reports what the README quotes (no timing is asserted: the
figures belong to a benchmark run, not a unit test on a shared machine)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).resolve().parents[1]


def load_benchmarks() -> ModuleType:
    spec = importlib.util.spec_from_file_location("bywire_benchmarks_run", ROOT / "benchmarks" / "run.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def test_sil_spine_benchmark_reports_every_scenario_and_the_slowest() -> None:
    bench = load_benchmarks()
    assert "demo" in bench.SPINE_SCENARIOS and "bad_calibration" in bench.SPINE_SCENARIOS
    out = bench.bench_sil_spine(("bad_calibration", "heartbeat_loss"))
    assert set(out["real_time_factor"]) == {"bad_calibration", "heartbeat_loss"}
    assert all(v > 0 for v in out["real_time_factor"].values())
    assert out["min"] == min(out["real_time_factor"].values())
    assert out["real_time_factor"][out["slowest"]] == out["min"]
    assert out["ratio_min_to_target"] == round(out["min"] / 20.0, 2)
    assert out["baseline_fmu_alone_real_time_factor"]["before"] > 0


def test_perception_benchmark_reports_its_contract_rows() -> None:
    from bywire.cli import import_command_module

    doc = import_command_module("benchmarks.perception").run(1.0)
    rows = ("grid_ms", "frame_ms", "baseline_ms", "frame_cpu_ms") if "grid_ms" in doc else ()  # KITTI data
    for row in (*rows, "cast_ms"):
        assert {"p50", "p99"} <= set(doc[row]) and 0 < doc[row]["p50"] <= doc[row]["p99"], row
    if rows:
        assert set(doc["parts_ms"]) == {"grid", "segmentation", "tracker", "lane_markers"}
    assert doc["cast"]["rays"] > 100_000


def test_the_load_benchmark_calls_any_safe_stop_spurious_and_merges_rhythms(tmp_path: Path) -> None:
    """How `bench hil` judges a run, on a made-up one: the ECU engaged, then stopped for a late heartbeat."""
    import csv

    from bywire.cli import import_command_module
    from bywire.host.trace import HOST_COLUMNS
    from bywire.protocol.ecu_types import EcuState, Fault
    from bywire.rhythm import GapHistogram

    bench = import_command_module("benchmarks.hil_load")
    with open(tmp_path / "host.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(HOST_COLUMNS)
        for k in range(30):
            state = EcuState.READY if k < 5 else EcuState.ENGAGED if k < 20 else EcuState.SAFE_STOP
            faults = int(Fault.HOST_HEARTBEAT) if k >= 20 else 0
            row = dict.fromkeys(HOST_COLUMNS, 0.0) | {"t_s": 100 + 0.1 * k, "ecu_state": int(state)}
            w.writerow([faults if c == "ecu_faults" else row[c] for c in HOST_COLUMNS])
    link = GapHistogram()
    for gap_ms in (20.0, 20.0, 61.0):
        link.add(gap_ms / 1e3)
    result = {
        "verdict": "fail",
        "checks": [{"name": "still_engaged", "passed": False}],
        "stalls": {"host": {"rhythm_ms": {"ecu_link": link.to_json()}}},
        "metrics": {"ecu_loop": {"host_link": {"heartbeat_gap_ms": link.to_json()}}},
    }
    assert bench.judge_run(result, tmp_path, duration_s=1.9)["spurious_stop"] is None  # after the end
    run = bench.judge_run(result, tmp_path)
    assert run["spurious_stop"]["at_s"] == 2.0 and run["spurious_stop"]["faults"] == ["HOST_HEARTBEAT"]
    assert run["faults"] == ["HOST_HEARTBEAT"] and run["failed_checks"] == ["still_engaged"]
    tally = bench.Tally()
    tally.add(run)
    tally.add(run)
    doc = tally.doc()
    assert doc["runs"] == 2 and doc["spurious_stops"] == 2 and doc["ecu_faults"] == {"HOST_HEARTBEAT": 2}
    assert doc["heartbeat_gap_max_ms"] == 61.0 and doc["host_gap_ms"]["count"] == 6
    assert {"p99", "p999", "max"} <= set(doc["host_gap_ms"])


def test_the_partitioned_load_stays_off_the_ecus_cpu(tmp_path: Path) -> None:
    """`bench hil --load --partition`: the load's processes may run only on the housekeeping CPUs, and
    the machine's floor is measured on the ECU's CPU."""
    import os

    from bywire.cli import import_command_module

    bench = import_command_module("benchmarks.hil_load")
    part = bench.Partition.of_this_machine()
    assert part.ecu_cpu not in part.housekeeping and part.ecu_cpu == max(os.sched_getaffinity(0))
    with bench.background_load(tmp_path, disk=True, cpus=part.housekeeping) as procs:
        assert len(procs) == 2
        assert all(os.sched_getaffinity(p.pid) == set(part.housekeeping) for p in procs)
    floor = bench.bare_loop_lateness_ms(0.2, cpu=part.ecu_cpu)
    assert {"p50", "p99", "p999", "max"} <= set(floor)


def test_sil_benchmark_reports_a_factor_per_scenario_beside_the_fmu_alone() -> None:
    from bywire.cli import import_command_module

    bench = import_command_module("benchmarks.sil")
    doc = bench.bench(["demo"], repeats=2, duration_s=1.5)
    row = doc["sil_factor"]["demo"]
    assert row["n"] == 2 and len(row["runs"]) == 2 and row["simulated_s"] == 1.5
    assert 0 < row["min"] <= row["median"] <= row["p99"] <= row["max"]
    assert row["per_second"]["min"] > 0 and row["target"] == bench.TARGETS["demo"]
    assert row["cpu_factor"]["median"] > 0 and len(row["cpu_factor"]["runs"]) == 2
    assert doc["baseline_fmu_alone_factor"]["before"] > 0 and doc["baseline_fmu_alone_factor"]["after"] > 0
