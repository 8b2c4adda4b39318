"""Every shipped scenario passes in SIL, within the bounds on its metrics asserted here; SIL is
deterministic.

These are the acceptance tests of the spine (ECU, FMU plant and host in SIL): acceleration steps,
grade with anti-windup, E-stop PAUSE and DISABLE, driver brake, host heartbeat loss, host freeze,
corrupt and stale frames, bad calibration, and the demo drive. Ground truth comes from the FMU.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from bywire.hil.run import run_scenario
from bywire.hil.scenario import CONTRACT_SCENARIOS, builtin_scenarios, load_scenario
from bywire.hil.sil import run_sil

FAULT_SCENARIOS = (
    "estop_pause",
    "estop_disable",
    "driver_brake",
    "heartbeat_loss",
    "host_freeze",
    "corrupt_frames",
    "stale_frames",
)


# Long runs judged elsewhere in the default suite, in full under -m slow: the heat (bounded SIL runs
# and the 60 s three-process HIL run), the sinusoid (its 60 s string-stability run) and the flood
# (the run compared bit for bit with its quiet twin) in tests/hil/test_platoon_*.py.
LONG_PLATOON_RUNS = ("gcdc_heat", "platoon_sinusoid", "v2v_fuzz")


def _runs_here(name: str, path: Path) -> bool:
    """The spine's scenarios and the short platoon ones; the urban missions (minutes to tens of
    minutes of driving) have their own bounded tests (tests/hil/test_urban_*.py) and a slow campaign."""
    return name not in LONG_PLATOON_RUNS and "urban" not in (yaml.safe_load(path.read_text()) or {})


SCENARIOS = sorted(name for name, path in builtin_scenarios().items() if _runs_here(name, path))


def test_contract_scenarios_are_shipped() -> None:
    assert set(CONTRACT_SCENARIOS) <= set(builtin_scenarios())


@pytest.fixture(scope="module")
def results(tmp_path_factory: pytest.TempPathFactory) -> dict[str, dict]:
    out: dict[str, dict] = {}
    root = tmp_path_factory.mktemp("sil")
    for name in SCENARIOS:
        json_path = root / f"{name}.json"
        out[name] = run_scenario(name, mode="sil", json_path=json_path)
        out[name]["_json_path"] = json_path
    return out


@pytest.mark.parametrize("name", SCENARIOS)
def test_scenario_passes_in_sil(results: dict[str, dict], name: str) -> None:
    result = results[name]
    failed = [c for c in result["checks"] if not c["passed"]]
    assert result["verdict"] == "pass", f"{name}: failed checks {failed}"
    assert result["checks"], "a scenario without checks proves nothing"


def test_json_contract_shape(results: dict[str, dict]) -> None:
    for name, result in results.items():
        doc = json.loads(Path(result["_json_path"]).read_text())
        assert doc["scenario"] == name and doc["mode"] == "sil" and doc["verdict"] in ("pass", "fail")
        for check in doc["checks"]:
            assert {"name", "passed", "value", "limit"} <= set(check)
        assert "final_state" in doc["metrics"] and "real_time_factor" in doc["metrics"]


def test_accel_tracking_rms_error_within_its_bound(results: dict[str, dict]) -> None:
    assert results["accel_steps"]["metrics"]["accel_rms_error_mps2"] <= 0.15


def test_grade_integrator_settles_without_overshoot(results: dict[str, dict]) -> None:
    m = results["grade"]["metrics"]
    assert m["settle_time_s"] is not None and m["settle_time_s"] <= 3.0
    assert m["overshoot_mps2"] <= 0.3


@pytest.mark.parametrize("name", FAULT_SCENARIOS)
def test_fault_scenarios_report_detection_and_stop(results: dict[str, dict], name: str) -> None:
    m = results[name]["metrics"]
    assert m["fault_detect_ms"] is not None and m["fault_detect_ms"] >= 0.0
    assert m["stop_distance_m"] is not None and m["stop_distance_m"] >= 0.0
    assert m["standstill_held"] is True
    assert m["brake_onset_ms"] is not None


def test_bad_calibration_never_engages(results: dict[str, dict]) -> None:
    m = results["bad_calibration"]["metrics"]
    assert m["final_state"] == "OFF" and m["engaged_s"] == 0.0 and "ENGAGED" not in m["states_seen"]


def test_sil_is_deterministic() -> None:
    scenario = dataclasses.replace(load_scenario("corrupt_frames"), duration_s=6.0)
    a = run_sil(scenario)
    b = run_sil(scenario)
    for column in a.plant:
        np.testing.assert_array_equal(a.plant[column], b.plant[column], err_msg=column)
    assert a.host is not None and b.host is not None
    for column in a.host:
        np.testing.assert_array_equal(a.host[column], b.host[column], err_msg=column)


def test_a_failing_check_fails_the_verdict(tmp_path: Path) -> None:
    text = (
        Path(builtin_scenarios()["accel_steps"])
        .read_text()
        .replace("max: 0.15", "max: 0.0001")
        .replace("name: accel_steps", "name: impossible")
    )
    path = tmp_path / "impossible.yaml"
    path.write_text(text)
    result = run_scenario(str(path), mode="sil")
    assert result["verdict"] == "fail"
    assert [c["passed"] for c in result["checks"]] == [False, True, True]


def test_sil_records_every_frame_of_both_buses(tmp_path: Path) -> None:
    record = tmp_path / "frames.asc"
    scenario = dataclasses.replace(load_scenario("estop_disable"), duration_s=5.0)
    run_sil(scenario, record=record)
    text = record.read_text()
    lines = [line for line in text.splitlines() if " Rx " in line]
    ids = {line.split()[2] for line in lines}
    assert {"100", "F0", "120", "121", "122", "123"} <= ids, ids  # DBW_Command, E-stop, gateway reports
    assert {"210", "190", "710", "701"} <= ids, ids  # request RPDO, status TPDO1, both heartbeats
    assert "90" in ids  # the EMCY of the DISABLE


def test_cli_refuses_a_bad_scenario_with_the_field(tmp_path: Path) -> None:
    import subprocess
    import sys

    path = tmp_path / "typo.yaml"
    path.write_text("name: typo\nduration_s: 5\nfualts: []\n")
    proc = subprocess.run(
        [sys.executable, "-m", "bywire", "hil", "run", str(path)], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 2
    assert f"{path}:3: fualts: unknown key" in proc.stderr  # file:line: what


def test_a_ready_made_fmu_without_mapping_is_refused(tmp_path: Path) -> None:
    from bywire.hil.scenario import ScenarioError, parse_scenario

    with pytest.raises(ScenarioError, match=r"vehicle\.mapping: a ready-made FMU"):
        parse_scenario({"name": "x", "duration_s": 1.0, "vehicle": {"model": "car.fmu"}}, "x.yaml")
