"""A scenario's plant model: its FMU, its role mapping and its initial conditions (DESIGN section 1).

The SIL run and the HIL plant process open the vehicle here, so a scenario's ``vehicle.v0_mps``
reaches any FMU the same way: as the ``speed_mps`` initial condition, through the mapping's
``[initial]`` table (`bywire.vehicle_models.mapping`), never by a variable name of our own model.
`check_initial_conditions` answers before any process starts whether the mapping can start the
scenario at all.
"""

from __future__ import annotations

from bywire.hil.scenario import Scenario
from bywire.vehicle_models.fmu_vehicle import (
    FmuVehicle,
    InitialConditions,
    default_mapping_path,
    open_vehicle,
)
from bywire.vehicle_models.mapping import PlantMapping, load_mapping


def scenario_mapping(scenario: Scenario) -> PlantMapping:
    """The scenario's plant mapping: its own file, else the bundled model's mapping.toml."""
    return load_mapping(scenario.plant_mapping or default_mapping_path(scenario.model))


def initial_conditions(scenario: Scenario) -> InitialConditions:
    return InitialConditions(speed_mps=scenario.v0_mps)


def check_initial_conditions(scenario: Scenario) -> None:
    """`MappingError` (one line: the role and the mapping file) when the scenario starts in a state
    its mapping cannot give the FMU."""
    scenario_mapping(scenario).initial_start_values(initial_conditions(scenario).by_role())


def open_scenario_vehicle(scenario: Scenario) -> FmuVehicle:
    """The scenario's plant model: a bundled model by name, or any FMU with its role mapping."""
    return open_vehicle(
        scenario.model, mapping=scenario_mapping(scenario), initial=initial_conditions(scenario)
    )
