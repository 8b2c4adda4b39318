"""Urban driving scenarios (seed 000) in the three-process HIL, through `bywire hil run --mode hil` as a user
runs it: bus servers, ECU, plant (with the urban world, its object list on loopback UDP) and host (the `urban`
configuration) as separate processes. A four-way stop with a car waiting (also on LIDAR: the plant's sensor
process casts, the host's perception process tracks), the host frozen mid-turn (SIGSTOP), the DARPA sample
mission's first 90 s (also on LIDAR) and the whole mission, the parking lot (the zone planner in its
worker process); behaviour is judged, never timing."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml
from hil_process_run import run_in_hil
from shared_data import shared_data_dir

from bywire.hil.hil_variants import four_way_stop_hil
from bywire.hil.scenario import builtin_scenarios

pytestmark = pytest.mark.hil


def _builtin_hil_doc(name: str) -> dict[str, Any]:
    """A shipped urban scenario as a document for a HIL run: named NAME_hil, its network files by path."""
    path = builtin_scenarios()[name]
    doc: dict[str, Any] = yaml.safe_load(path.read_text())
    doc["name"] = f"{name}_hil"
    for key in ("rndf", "mdf"):
        doc["urban"][key] = str(path.parent / doc["urban"][key])
    return doc


def _run_hil(doc: dict[str, Any], tmp_path: Path, timeout_s: float = 400.0) -> dict[str, Any]:
    result, report = run_in_hil(doc, tmp_path, timeout_s)
    assert (report / f"{doc['name']}_urban.png").stat().st_size > 20_000
    return result


def _sample_mission(name: str) -> dict[str, Any]:
    """The shipped sample mission's scenario document under another name (skips without the shared data)."""
    if not (shared_data_dir() / "rndf" / "darpa_sample" / "Sample_RNDF.txt").is_file():
        pytest.skip(f"DARPA sample RNDF not found at {shared_data_dir() / 'rndf' / 'darpa_sample'}")
    doc: dict[str, Any] = yaml.safe_load(builtin_scenarios()["darpa_sample_mission"].read_text())
    doc["name"] = name
    return doc


def test_four_way_stop_in_three_processes(tmp_path: Path) -> None:
    result = _run_hil(four_way_stop_hil(), tmp_path)
    m = result["metrics"]
    assert m["checkpoints_reached_list"] == [1, 2] and m["precedence_violations"] == 0
    assert m["collisions"] == 0 and m["final_state"] == "ENGAGED"
    states = [s for _, s in result["state_history"]]
    assert states[1:4] == [
        "Intersection/IntersectionStop",
        "Intersection/IntersectionWait",
        "Intersection/IntersectionDriveInside",
    ]
    east = next(a for a in result["urban"]["arrivals"] if a["vehicle"] == "east")
    ours = next(a for a in result["urban"]["arrivals"] if a["vehicle"] == "ego")
    assert east["departure_s"] < ours["departure_s"]


# In the slow set for its cost (a sensor process and a perception process beside the run's five; the
# default run's urban HIL test is the same stop on the perfect list). Its one host crash, "deque
# mutated during iteration", was the health topic reading a module's execution history while the
# module's thread appended (fixed: the runtime reads a snapshot).
@pytest.mark.slow
def test_four_way_stop_on_lidar_in_three_processes(tmp_path: Path) -> None:
    """The plant's sensor process casts the Velodyne and sends each revolution over the scan link; the
    host's perception runs in a worker process of its own; the behaviour waits for the car it sees."""
    doc = four_way_stop_hil()
    doc["name"] = "four_way_stop_lidar_hil"
    doc["perception"] = "lidar"
    result = _run_hil(doc, tmp_path)
    m = result["metrics"]
    assert m["perception"] == "lidar" and m["lidar_revolutions"] > 0
    assert m["checkpoints_reached_list"] == [1, 2] and m["precedence_violations"] == 0
    assert m["collisions"] == 0 and m["final_state"] == "ENGAGED"
    east = next(a for a in result["urban"]["arrivals"] if a["vehicle"] == "east")
    ours = next(a for a in result["urban"]["arrivals"] if a["vehicle"] == "ego")
    assert east["departure_s"] < ours["departure_s"]
    assert m["perception_missed_objects"] < 0.2


@pytest.mark.slow
def test_darpa_sample_mission_first_90_s_on_lidar_in_three_processes(tmp_path: Path) -> None:
    doc = _sample_mission("darpa_sample_mission_lidar_hil")
    doc["duration_s"] = 90.0
    doc["perception"] = "lidar"
    doc["checks"] = [c for c in doc["checks"] if c["metric"] not in ("checkpoints_reached", "time_s")]
    doc["checks"].append({"name": "first checkpoints", "metric": "checkpoints_reached", "min": 2})
    result = _run_hil(doc, tmp_path)
    assert result["verdict"] == "pass", [c for c in result["checks"] if not c["passed"]]


@pytest.mark.slow  # 90 s of driving; the default run's urban HIL test is the four-way stop
def test_darpa_sample_mission_first_90_s_in_three_processes(tmp_path: Path) -> None:
    doc = _sample_mission("darpa_sample_mission_hil")
    doc["duration_s"] = 90.0
    doc["checks"] = [c for c in doc["checks"] if c["metric"] not in ("checkpoints_reached", "time_s")]
    doc["checks"].append({"name": "first checkpoints", "metric": "checkpoints_reached", "min": 2})
    result = _run_hil(doc, tmp_path)
    m = result["metrics"]
    assert m["checkpoints_reached_list"][:2] == [1, 2]
    assert m["lateral_error_rms_m"] <= 0.2 and m["lateral_error_max_m"] <= 0.5
    assert m["collisions"] == 0 and m["stop_line_stops"] >= 1


@pytest.mark.slow  # ~33 min of wall time: the whole mission, every check of the scenario
def test_darpa_sample_mission_whole_in_three_processes(tmp_path: Path) -> None:
    doc = _sample_mission("darpa_sample_mission_hil_whole")
    result = _run_hil(doc, tmp_path, timeout_s=float(doc["duration_s"]) + 600.0)
    assert result["verdict"] == "pass", [c for c in result["checks"] if not c["passed"]]
    m = result["metrics"]
    assert m["mission_complete"] and m["checkpoints_reached"] == m["checkpoints_total"] == 18
    assert m["lateral_error_max_m"] <= 0.5 and m["collisions"] == 0 and m["reverse_held"] == 0


@pytest.mark.slow  # the default run has the spine's SIGSTOP test in HIL and this scenario in SIL
def test_host_frozen_mid_turn_the_ecu_stops_the_car(tmp_path: Path) -> None:
    """SIGSTOP of the host process while it turns left inside the intersection: the ECU's watchdog brings
    the car to a standstill (SAFE_STOP) and holds it."""
    doc = _builtin_hil_doc("host_freeze_in_turn")
    result = _run_hil(doc, tmp_path)
    m = result["metrics"]
    assert m["hsm_state_at_fault"] == "Intersection/IntersectionDriveInside"
    assert m["final_state"] == "SAFE_STOP" and m["standstill_held"] is True and m["collisions"] == 0


# In the slow set for its cost (80 s of wall time, the longest of the HIL stage); the planner's worker
# process is tested in the default run by tests/host/modules/test_path_planner_process.py, and the lot
# itself in SIL by tests/hil/test_urban_scenarios.py.
@pytest.mark.slow
def test_the_parking_lot_in_three_processes(tmp_path: Path) -> None:
    """The zone planner on wall time: each plan is solved in the behaviour's worker process while the
    car holds, the host keeps its rhythm (no stale request, no stop), and the car parks between the two
    parked cars, backs out and leaves by the exit."""
    doc = _builtin_hil_doc("zone_park_between_cars")
    doc["duration_s"] = 80.0  # done in about 70 s; the suite's time is counted
    doc["checks"] = [c for c in doc["checks"] if c["metric"] != "time_s"]
    result = _run_hil(doc, tmp_path)
    m = result["metrics"]
    assert (
        m["checkpoints_reached_list"] == [1, 2, 3] and m["collisions"] == 0 and m["final_state"] == "ENGAGED"
    )
    leaves = [s.rsplit("/", 1)[-1] for _, s in result["state_history"]]
    assert leaves[1:5] == ["ZoneApproach", "ZoneEnter", "ZonePark", "ZoneLeave"]
    assert "ZoneRecovery" not in leaves and m["min_speed_mps"] < -0.2


@pytest.mark.slow  # ~70 s of wall time, as the parking lot above
def test_the_dead_end_kturn_in_three_processes(tmp_path: Path) -> None:
    """The K-turn planned on the road on wall time: the plan is solved in the worker process while the
    car holds at the dead end, then three legs within the 9.1 m street, no curb touched, and back."""
    doc = _builtin_hil_doc("kturn_narrow_road")
    result = _run_hil(doc, tmp_path)
    m = result["metrics"]
    assert result["verdict"] == "pass", result["checks"]
    assert m["checkpoints_reached_list"] == [1, 2, 3] and m["final_state"] == "ENGAGED"
    leaves = [s.rsplit("/", 1)[-1] for _, s in result["state_history"]]
    turn = [s for s in leaves if s.startswith("DriveKTurn")]
    assert turn[0] == "DriveKTurnPlanning" and turn[-1] == "DriveKTurnFinish"
    assert m["road_departure_m"] < 0.3 and m["direction_changes"] <= 4
