"""Both vehicle profiles run the spine: every contract scenario passes in SIL with the plant and the ECU
speaking a VW PQ Passat's own messages (`vehicle_profile: pq`), as it does on our gateway's.

The frame faults of the scenarios name the bywire gateway's reports; on pq they hit the PQ messages
that carry the same (protocol.vehicle_pq.REPORT_MESSAGES), so the same checks judge the same failures.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import yaml

from bywire.ecu.app import EcuApp, vehicle_reports
from bywire.hil.run import run_scenario
from bywire.hil.scenario import CONTRACT_SCENARIOS, ScenarioError, load_scenario, parse_scenario
from bywire.protocol.vehicle_can import VehicleCodec

# The spine's frame faults beyond the contract: late, repeated and frozen reports, and the re-arm.
MORE_FAULTS = ("stale_frames", "estop_stuck_sender", "driver_override_rearm")


@pytest.mark.parametrize("name", [*CONTRACT_SCENARIOS, *MORE_FAULTS])
def test_scenario_passes_on_the_pq_profile(name: str) -> None:
    result = run_scenario(dataclasses.replace(load_scenario(name), vehicle_profile="pq"), mode="sil")
    failed = [c for c in result["checks"] if not c["passed"]]
    assert result["verdict"] == "pass", f"{name} on pq: failed checks {failed}"
    assert result["checks"], "a scenario without checks proves nothing"


def test_corruption_on_pq_is_caught_by_the_cars_checksums() -> None:
    """corrupt_frames spoils GW_WheelSpeeds and GW_Motion: on pq Bremse_3 (no checksum: it goes out
    unchanged), GW_Inertial (our CRC), Bremse_5 (the car's XOR) and Getriebe_1 (no checksum)."""
    result = run_scenario(
        dataclasses.replace(load_scenario("corrupt_frames"), vehicle_profile="pq"), mode="sil"
    )
    rx = result["metrics"]["ecu_vehicle_rx"]
    # 0.3 s of GW_Inertial at 100 Hz and Bremse_5 at 50 Hz, nothing else
    assert rx["corrupt"] == 30 + 15
    assert rx["unexpected_exceptions"] == 0


def test_the_ecu_judges_the_car_by_every_report_of_its_profile() -> None:
    assert vehicle_reports(VehicleCodec()) == ("GW_WheelSpeeds", "GW_Motion", "GW_Driver", "GW_Steer")
    assert set(vehicle_reports(VehicleCodec(profile="pq"))) == {
        "Lenkhilfe_3",
        "Motor_2",
        "Motor_3",
        "Getriebe_1",
        "Bremse_3",
        "Bremse_5",
        "GW_Inertial",
        "GW_Arm",
    }


def test_an_ecu_without_a_report_for_an_input_refuses_to_start(monkeypatch: pytest.MonkeyPatch) -> None:
    import bywire.ecu.app as app

    monkeypatch.setattr(app, "vehicle_reports", lambda codec: ("Bremse_3", "Bremse_5"))
    with pytest.raises(ValueError, match="no vehicle report to the ECU carries long_accel_mps2"):
        EcuApp(None, None, None, None, vehicle_profile="pq")  # type: ignore[arg-type]


def _doc(name: str = "grade", **changes: object) -> dict[str, object]:
    """A shipped scenario's YAML document, with `changes`."""
    doc = yaml.safe_load(Path(load_scenario(name).source).read_text(encoding="utf-8"))
    doc.update(changes)
    return doc


def test_a_scenario_names_its_profile() -> None:
    assert parse_scenario(_doc(vehicle_profile="pq"), "grade.yaml").vehicle_profile == "pq"
    assert parse_scenario(_doc(), "grade.yaml").vehicle_profile == "bywire"


def test_an_unknown_profile_is_refused_with_where() -> None:
    with pytest.raises(ScenarioError, match=r"grade\.yaml: vehicle_profile: .*bywire, pq"):
        parse_scenario(_doc(vehicle_profile="mqb"), "grade.yaml")


def test_a_world_runs_on_the_bywire_profile_only() -> None:
    with pytest.raises(ScenarioError, match="vehicle_profile: pq: a scenario with a world"):
        parse_scenario(_doc("platoon_braking", vehicle_profile="pq"), "platoon_braking.yaml")
