"""Plant mapping: which variable of a vehicle FMU plays which role in the bywire plant.

The plant talks in roles with fixed SI units (``throttle_pct``, ``brake_bar``, ``speed_mps``, ...).
A TOML file maps each role to the FMU's variable name, with an optional linear conversion, so a
vendor's FMU drops in without code changes::

    [inputs]
    throttle_pct = "throttle_pct"
    brake_bar = { name = "p_brake", scale = 1e-5 }   # FMU in Pa: bar = Pa * 1e-5

    [outputs]
    speed_mps = "v"

    [initial]               # initial conditions -> the FMU's start variables, as [inputs]
    speed_mps = "v_init"

    [parameters]            # optional start values, by FMU variable name
    mass_kg = 1650.0

    [fallback]              # optional, used only by derivations of unmapped outputs
    track_width_m = 1.55

``scale`` and ``offset`` always convert the FMU's value into the role's unit:
``role = fmu * scale + offset`` (for inputs and initial conditions the adapter applies the inverse).

Initial conditions (``[initial]``; role ``speed_mps``, a scenario's ``vehicle.v0_mps``) reach the
FMU only through this table, as start values set before initialisation: the variable is a Real
parameter or input, or any Real the FMU lets be set then (``initial="exact"`` or ``"approx"``,
FMI 2.0 sec. 2.2.7 and the Co-Simulation state machine of sec. 4.2.4). An unmapped initial
condition may only be 0, where the FMU's own start values apply; a non-zero one raises
`MappingError` naming the role and the mapping file. After initialisation the adapter checks the
FMU's speed output against the requested initial speed, so a wrong ``scale`` is caught at once.

Unmapped optional roles fall back as follows (implemented in `fmu_vehicle.FmuVehicle`):

- ``grade_pct``, ``wind_mps`` (inputs): the FMU cannot be told, so only 0 is accepted; a non-zero
  value raises instead of silently simulating a flat road in still air.
- ``gear`` (input, the drive force's direction: +1 drive, -1 reverse, 0 neutral): an FMU without it
  only drives forward, so only +1 is accepted.
- ``wheel_speed_{fl,fr,rl,rr}_mps``: ``speed -/+ yaw_rate * track_width_m / 2`` (left/right, both
  axles; no steering projection).
- ``brake_bar_actual``, ``steer_angle_rad_actual``: the commanded value (ideal actuator).

Not from the papers: this is bywire's seam between the HIL plant (DESIGN.md section 1) and any FMU.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

INPUT_ROLES_REQUIRED = ("throttle_pct", "brake_bar", "steer_angle_rad")
INPUT_ROLES_OPTIONAL = ("grade_pct", "wind_mps", "gear")
OUTPUT_ROLES_REQUIRED = (
    "speed_mps",
    "accel_mps2",
    "yaw_rate_radps",
    "x_m",
    "y_m",
    "heading_rad",
    "distance_m",
)
OUTPUT_ROLES_OPTIONAL = (
    "wheel_speed_fl_mps",
    "wheel_speed_fr_mps",
    "wheel_speed_rl_mps",
    "wheel_speed_rr_mps",
    "brake_bar_actual",
    "steer_angle_rad_actual",
)
INPUT_ROLES = INPUT_ROLES_REQUIRED + INPUT_ROLES_OPTIONAL
OUTPUT_ROLES = OUTPUT_ROLES_REQUIRED + OUTPUT_ROLES_OPTIONAL
INITIAL_ROLES = ("speed_mps",)  # all optional: unmapped, only 0 is accepted

DEFAULT_TRACK_WIDTH_M = 1.55  # VW Passat B6 track; only used to derive unmapped wheel speeds

_TABLES = ("inputs", "outputs", "initial", "parameters", "fallback")
_VARIABLE_KEYS = ("name", "scale", "offset")
_FALLBACK_KEYS = ("track_width_m",)


class MappingError(ValueError):
    """A plant mapping is malformed, or names a variable the FMU does not have."""


@dataclass(frozen=True, slots=True)
class VariableMap:
    """One role's FMU variable and the linear conversion ``role = fmu * scale + offset``."""

    name: str
    scale: float = 1.0
    offset: float = 0.0

    def to_role(self, fmu_value: float) -> float:
        return fmu_value * self.scale + self.offset

    def to_fmu(self, role_value: float) -> float:
        return (role_value - self.offset) / self.scale


@dataclass(frozen=True)
class PlantMapping:
    """Roles -> FMU variables. ``source`` names the file for error messages."""

    inputs: dict[str, VariableMap]
    outputs: dict[str, VariableMap]
    parameters: dict[str, float] = field(default_factory=dict)
    track_width_m: float = DEFAULT_TRACK_WIDTH_M
    source: str = "<mapping>"
    initial: dict[str, VariableMap] = field(default_factory=dict)

    def initial_start_values(self, conditions: dict[str, float]) -> dict[str, tuple[float, str]]:
        """FMU start values for initial conditions given by role in SI units: FMU variable name ->
        (value in the FMU's unit, where it was mapped). A non-zero condition this mapping has no
        variable for raises `MappingError` naming the role and this mapping's file."""
        starts: dict[str, tuple[float, str]] = {}
        for role, value in conditions.items():
            if role not in INITIAL_ROLES:
                raise ValueError(
                    f"unknown initial-condition role {role!r}; expected {', '.join(INITIAL_ROLES)}"
                )
            var = self.initial.get(role)
            if var is not None:
                starts[var.name] = (var.to_fmu(value), f"{self.source}: [initial].{role}")
            elif value != 0.0:
                raise MappingError(
                    f"{self.source}: [initial].{role} is not mapped, so the FMU cannot start at"
                    f" {role} = {value:g}; map it to the FMU's start variable or start at 0"
                )
        return starts


def load_mapping(path: str | Path) -> PlantMapping:
    """Read and check a plant mapping TOML file; `MappingError` names the file and the bad key."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise MappingError(f"{path}: cannot read plant mapping: {exc.strerror or exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise MappingError(f"{path}: not valid TOML: {exc}") from exc
    return parse_mapping(data, source=str(path))


def parse_mapping(data: dict[str, Any], source: str = "<mapping>") -> PlantMapping:
    """Check an already parsed mapping (the TOML document as a dict)."""
    for key in data:
        if key not in _TABLES:
            raise MappingError(f"{source}: [{key}]: unknown table; expected {', '.join(_TABLES)}")
    for key in _TABLES:
        if key in data and not isinstance(data[key], dict):
            raise MappingError(f"{source}: {key}: must be a table ([{key}])")

    inputs = _parse_roles(data.get("inputs", {}), "inputs", INPUT_ROLES, INPUT_ROLES_REQUIRED, source)
    outputs = _parse_roles(data.get("outputs", {}), "outputs", OUTPUT_ROLES, OUTPUT_ROLES_REQUIRED, source)
    initial = _parse_roles(data.get("initial", {}), "initial", INITIAL_ROLES, (), source)
    seen: dict[str, str] = {}
    for role, var in inputs.items():
        if var.name in seen:
            raise MappingError(
                f"{source}: [inputs].{role}: variable {var.name!r} is already driven"
                f" by [inputs].{seen[var.name]}"
            )
        seen[var.name] = role

    parameters: dict[str, float] = {}
    for name, value in data.get("parameters", {}).items():
        parameters[name] = _finite_number(value, f"[parameters].{name}", source)

    fallback = data.get("fallback", {})
    for key in fallback:
        if key not in _FALLBACK_KEYS:
            raise MappingError(
                f"{source}: [fallback].{key}: unknown key; expected {', '.join(_FALLBACK_KEYS)}"
            )
    track_width_m = _finite_number(
        fallback.get("track_width_m", DEFAULT_TRACK_WIDTH_M), "[fallback].track_width_m", source
    )
    if track_width_m <= 0.0:
        raise MappingError(f"{source}: [fallback].track_width_m: must be > 0, got {track_width_m}")

    for role, var in initial.items():
        if var.name in seen:
            raise MappingError(
                f"{source}: [initial].{role}: variable {var.name!r} is an input, driven"
                f" by [inputs].{seen[var.name]}"
            )
        if var.name in parameters:
            raise MappingError(
                f"{source}: [initial].{role}: variable {var.name!r} also has a fixed value in [parameters]"
            )

    return PlantMapping(inputs, outputs, parameters, track_width_m, source, initial)


def _parse_roles(
    table: dict[str, Any],
    table_name: str,
    known: tuple[str, ...],
    required: tuple[str, ...],
    source: str,
) -> dict[str, VariableMap]:
    roles: dict[str, VariableMap] = {}
    for role, spec in table.items():
        where = f"[{table_name}].{role}"
        if role not in known:
            raise MappingError(f"{source}: {where}: unknown role; expected one of {', '.join(known)}")
        roles[role] = _parse_variable(spec, where, source)
    missing = [role for role in required if role not in roles]
    if missing:
        raise MappingError(
            f"{source}: [{table_name}].{missing[0]}: required role is not mapped"
            + (f" (also missing: {', '.join(missing[1:])})" if len(missing) > 1 else "")
        )
    # Keep the canonical role order, whatever the file's order.
    return {role: roles[role] for role in known if role in roles}


def _parse_variable(spec: Any, where: str, source: str) -> VariableMap:
    if isinstance(spec, str):
        return VariableMap(_variable_name(spec, where, source))
    if not isinstance(spec, dict):
        raise MappingError(
            f"{source}: {where}: must be a variable name or {{name, scale, offset}}, got {spec!r}"
        )
    for key in spec:
        if key not in _VARIABLE_KEYS:
            raise MappingError(f"{source}: {where}.{key}: unknown key; expected {', '.join(_VARIABLE_KEYS)}")
    if "name" not in spec:
        raise MappingError(f"{source}: {where}.name: missing")
    name = _variable_name(spec["name"], f"{where}.name", source)
    scale = _finite_number(spec.get("scale", 1.0), f"{where}.scale", source)
    if scale == 0.0:
        raise MappingError(f"{source}: {where}.scale: must not be 0")
    offset = _finite_number(spec.get("offset", 0.0), f"{where}.offset", source)
    return VariableMap(name, scale, offset)


def _variable_name(value: Any, where: str, source: str) -> str:
    if not isinstance(value, str) or not value.strip():
        raise MappingError(f"{source}: {where}: must be a non-empty FMU variable name, got {value!r}")
    return value


def _finite_number(value: Any, where: str, source: str) -> float:
    # bool is an int in Python; `scale = true` is a typo, not 1.0.
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise MappingError(f"{source}: {where}: must be a finite number, got {value!r}")
    return float(value)
