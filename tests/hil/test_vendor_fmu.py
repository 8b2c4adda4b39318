"""The shipped scenarios on an FMU that is not ours, through its plant mapping file, in SIL.

The vendor car (tests/vendor_fmu.py) has its own code, names and units (km/h, Pa, degrees, a pedal
fraction; its initial speed is ``vx_init`` in km/h): a scenario's ``vehicle.v0_mps`` reaches it
only through the mapping's ``[initial]`` table. The spine's scenarios and the platoon's braking test
(starting at 100 km/h) must pass on it as on the bundled passat.
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import pytest
from vendor_fmu import VENDOR_MAPPING, mapping_without_initial, vendor_fmu

from bywire.hil.run import run_scenario
from bywire.hil.scenario import CONTRACT_SCENARIOS, Scenario, load_scenario
from bywire.hil.scenario_vehicle import open_scenario_vehicle
from bywire.vehicle_models import MappingError

# The platoon's braking test (V2X, GPS, a world of cars; 5-10 s here) only with -m slow.
SCENARIOS = (
    *CONTRACT_SCENARIOS,
    "demo",
    pytest.param("platoon_braking", marks=pytest.mark.slow),
)


def on_vendor_car(name: str, mapping: Path = VENDOR_MAPPING) -> Scenario:
    """A shipped scenario with its vehicle replaced by the vendor car (the rest, and the relative
    paths of its own files, unchanged)."""
    return dataclasses.replace(load_scenario(name), model=str(vendor_fmu()), plant_mapping=str(mapping))


@pytest.mark.parametrize("name", SCENARIOS)
def test_shipped_scenario_passes_on_the_vendor_car(name: str) -> None:
    result = run_scenario(on_vendor_car(name), mode="sil")
    failed = [c for c in result["checks"] if not c["passed"]]
    assert result["verdict"] == "pass", f"{name}: failed checks {failed}"
    assert result["checks"], "a scenario without checks proves nothing"


def test_the_scenarios_initial_speed_reaches_the_vendor_car_in_its_unit() -> None:
    scenario = on_vendor_car("grade")
    with open_scenario_vehicle(scenario) as car:
        assert scenario.v0_mps == 24.0
        assert car.read("vx_init") == pytest.approx(24.0 * 3.6)
        assert car.outputs().speed_mps == pytest.approx(24.0)


def test_a_scenario_at_rest_needs_no_initial_table(tmp_path: Path) -> None:
    scenario = on_vendor_car("bad_calibration", mapping_without_initial(tmp_path))
    assert scenario.v0_mps == 0.0
    assert run_scenario(scenario, mode="sil")["verdict"] == "pass"


def test_a_moving_start_without_initial_stops_before_the_run(tmp_path: Path) -> None:
    mapping = mapping_without_initial(tmp_path)
    with pytest.raises(MappingError, match=r"\[initial\]\.speed_mps is not mapped"):
        run_scenario(on_vendor_car("accel_steps", mapping), mode="sil")


def test_cli_names_the_role_and_the_mapping_file_in_one_line(tmp_path: Path) -> None:
    """A scenario file of the user's, pointing at the vendor FMU and a mapping without [initial]."""
    mapping = mapping_without_initial(tmp_path)
    path = tmp_path / "vendor_steps.yaml"
    path.write_text(
        "name: vendor_steps\nduration_s: 5\n"
        f"vehicle: {{v0_mps: 10.0, model: '{vendor_fmu()}', mapping: {mapping.name}}}\n"
        "checks:\n  - {name: stays_engaged, metric: final_state, equals: ENGAGED}\n"
    )
    proc = subprocess.run(
        [sys.executable, "-m", "bywire", "hil", "run", str(path), "--mode", "sil", "--quiet"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.splitlines() == [
        f"error: {mapping}: [initial].speed_mps is not mapped, so the FMU cannot start at speed_mps = 10;"
        " map it to the FMU's start variable or start at 0"
    ]
