"""Vehicle plant models as FMI 2.0 Co-Simulation FMUs, built from C sources through fmpy.

- ``passat/``: the VW Passat plant (longitudinal point mass with brake/rolling-resistance
  stiction, blended kinematic/dynamic single track); parameters and their sources in
  ``passat/README.md``. The car is AnnieWAY's base vehicle (seed 000 Sec. 2, seed 003 Sec. II);
  the wheelbase l = 2.72 m and the 30 deg steering limit are from seed 000 Sec. 11.1.
- `build.ensure_fmu`: build-and-cache keyed by the SHA-256 of a model's sources.
- `mapping.load_mapping`: plant roles (inputs, outputs, initial conditions) -> FMU variable names
  (TOML), so vendor FMUs drop in.
- `fmu_vehicle.FmuVehicle` / `open_vehicle`: the fast per-step adapter the plant and SIL use.
"""

from .build import BuildError, default_cache_dir, ensure_fmu
from .fmu_vehicle import (
    FmuError,
    FmuVehicle,
    InitialConditions,
    VehicleInputs,
    VehicleOutputs,
    default_mapping_path,
    open_vehicle,
)
from .mapping import MappingError, PlantMapping, VariableMap, load_mapping, parse_mapping

__all__ = [
    "BuildError",
    "FmuError",
    "FmuVehicle",
    "InitialConditions",
    "MappingError",
    "PlantMapping",
    "VariableMap",
    "VehicleInputs",
    "VehicleOutputs",
    "default_cache_dir",
    "default_mapping_path",
    "ensure_fmu",
    "load_mapping",
    "open_vehicle",
    "parse_mapping",
]
