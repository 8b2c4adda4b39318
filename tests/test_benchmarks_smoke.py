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
