"""Scenario files: what the plant, the ECU and the host do in one HIL/SIL run, and how it is judged.

A scenario is a YAML (or TOML) file with the schema documented in `docs/scenarios.md`. Parsing is
strict: an unknown key, a wrong type or an impossible value is refused with the file and the path of
the bad field (`grade.yaml: faults[1].at_s: expected a number >= 0, got 'soon'`), because a typo in a
safety scenario that silently does nothing is worse than no scenario.
"""

from __future__ import annotations

import dataclasses
import re
import tomllib
from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml

from bywire.hil.world.spec import WorldSpec, parse_world
from bywire.hil.world.urban_spec import UrbanSpec, parse_urban
from bywire.profiles import ramp_value, step_value
from bywire.protocol.ecu_types import EcuState, EstopMode
from bywire.protocol.vehicle_can import VEHICLE_PROFILES
from bywire.schema import Reader, SchemaError, yaml_line

if TYPE_CHECKING:
    from bywire.host.config import HostConfig

SCENARIO_SUFFIXES = (".yaml", ".yml", ".toml")

FAULT_KINDS = (
    "estop",  # E-stop radio mode change: mode = RUN | PAUSE | DISABLE
    "driver_brake",  # driver presses the brake pedal: pedal_pct, duration_s
    "driver_steer",  # driver steering torque: torque_nm, duration_s
    "corrupt",  # vehicle frames sent with a bad CRC: frames, duration_s
    "drop",  # vehicle frames not sent at all: frames, duration_s
    "delay",  # vehicle frames held back: frames, delay_ms, duration_s
    "repeat",  # vehicle frames sent with a frozen alive counter: frames, duration_s
    "stuck",  # a frozen transmitter: its last frame again, byte for byte: frames, duration_s
    "heartbeat_mute",  # the host stops its CANopen heartbeat but keeps sending requests
    "host_freeze",  # the host stops (SIL: stops stepping; HIL: SIGSTOP)
    "host_kill",  # the host dies (SIL: stops stepping; HIL: SIGKILL)
    "host_stop",  # the host asks the ECU for a controlled stop (request flag STOP)
    "unlatch",  # a service tool on the host link writes the DISABLE unlatch (SDO 0x2300sub1 = 1)
    "arm_button",  # the safety driver presses the arm button on the car (GW_Driver.SafetyArm)
    "engage_press",  # the mission lets go of ENGAGE for a moment and asks anew (a new engage wish)
    "rearm",  # the host sends a REARM pulse
    "loop_stall",  # the ECU's loop stops for duration_s (SIL: not stepped; HIL: SIGSTOP .. SIGCONT)
    # Host runtime faults (for the runtime's supervisor), injected into one module of the host: module = NAME
    "module_exception",  # the module's next step raises
    "module_hang",  # the module's next step never returns (an endless loop)
    "module_deadlock",  # the module's next step blocks forever on a lock
    "module_slow",  # every step takes slow_ms longer, for duration_s (0: to the end)
    "module_kill",  # the module's worker process is killed (SIGKILL)
)
MODULE_FAULTS = ("module_exception", "module_hang", "module_deadlock", "module_slow", "module_kill")

CHECK_OPS = ("max", "min", "equals", "includes")


# The metric family `state_at_<T>s`: the ECU's state (name) at scenario time T.
STATE_AT = re.compile(r"state_at_(\d+(?:\.\d+)?)s")


class ScenarioError(SchemaError):
    """A scenario file that cannot be run, with the file and the path of the bad field."""


class _Reader(Reader):
    error_type = ScenarioError


@dataclass(frozen=True)
class FaultEvent:
    at_s: float
    kind: str
    duration_s: float = 0.0
    frames: tuple[str, ...] = ()
    mode: EstopMode = EstopMode.RUN
    pedal_pct: float = 0.0
    torque_nm: float = 0.0
    delay_ms: float = 0.0
    module: str = ""  # module faults: which host module
    slow_ms: float = 0.0

    def active(self, t_s: float) -> bool:
        """In effect at t_s: from at_s for duration_s, or to the end of the run when duration_s is 0."""
        return self.at_s <= t_s and (self.duration_s == 0.0 or t_s < self.at_s + self.duration_s)


@dataclass(frozen=True)
class LeadCar:
    gap0_m: float
    speed_profile: tuple[tuple[float, float], ...]
    length_m: float = 4.8
    leaves_at_s: float | None = None  # turns off the road: the radar loses it


@dataclass(frozen=True)
class Check:
    name: str
    metric: str
    op: str
    limit: float | bool | str
    # The limit in a HIL run, where it differs: real processes on a shared machine add the operating
    # system's scheduling latency to every timing (None: the same limit as in SIL).
    hil_limit: float | bool | str | None = None

    def limit_for(self, mode: str) -> float | bool | str:
        return self.hil_limit if mode == "hil" and self.hil_limit is not None else self.limit


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    source: str
    duration_s: float
    v0_mps: float
    model: str
    plant_mapping: str | None
    calibration: str | None  # None: the ECU's default calibration
    corrupt_calibration: bool
    host_mode: str  # "script": accel_profile; "drive": longitudinal override controller
    host_config: str  # the host configuration (modules, policies): a shipped name or a file
    engage_at_s: float
    accel_profile: tuple[tuple[float, float], ...]
    speed_profile: tuple[tuple[float, float], ...]
    steer_profile: tuple[tuple[float, float], ...]
    stop_line_m: float | None
    lead: LeadCar | None
    grade_pct: tuple[tuple[float, float], ...]
    wind_mps: tuple[tuple[float, float], ...]
    accel_noise_mps2: float
    wheel_speed_noise_mps: float
    radar_range_noise_m: float
    actuator_delay_ms: float
    faults: tuple[FaultEvent, ...]
    checks: tuple[Check, ...]
    fault_ref_s: float | None
    hold_until_s: float | None
    seed: int
    hil_timeout_s: float = 0.0
    extra: dict[str, Any] = field(default_factory=dict)
    world: WorldSpec | None = None  # cooperative driving: roads, traffic, radar, GPS, V2V (hil.world.spec)
    urban: UrbanSpec | None = None  # urban: RNDF/MDF network, traffic, object list (hil.world.urban_spec)
    # What the vehicle CAN speaks (protocol.vehicle_can.VEHICLE_PROFILES): our gateway's reports, or a
    # VW PQ car's own messages (the plant and the ECU both speak it).
    vehicle_profile: str = "bywire"
    # host.params: module name -> parameters set over the host configuration's (a campaign's headway)
    host_params: dict[str, dict[str, Any]] = field(default_factory=dict)

    def faults_of(self, *kinds: str) -> tuple[FaultEvent, ...]:
        return tuple(f for f in self.faults if f.kind in kinds)


def _parse_fault(item: Any, source: str, path: str) -> FaultEvent:
    r = _Reader(item, source, path)
    kind = r.string("kind", choices=FAULT_KINDS)
    at_s = r.number("at_s", lo=0.0)
    # A button press and a moment's release have a length of their own; a stall must have one.
    default_duration = {"arm_button": 0.2, "engage_press": 0.1}.get(kind, 0.0)
    duration_s = r.number("duration_s", default=default_duration, lo=0.0)
    if kind in ("arm_button", "engage_press", "loop_stall") and duration_s <= 0.0:
        raise r.error("duration_s", f"a '{kind}' fault needs a duration > 0 s")
    frames_raw = r.raw("frames", [])
    if not isinstance(frames_raw, list) or not all(isinstance(f, str) for f in frames_raw):
        raise r.error("frames", f"expected a list of DBC message names, got {frames_raw!r}")
    mode = EstopMode.RUN
    if kind == "estop":
        mode_name = r.string("mode", choices=("RUN", "PAUSE", "DISABLE", "INVALID"))
        mode = EstopMode[mode_name]
    pedal = r.number("pedal_pct", default=30.0, lo=0.0, hi=100.0) if kind == "driver_brake" else 0.0
    torque = r.number("torque_nm", default=5.0, lo=-20.0, hi=20.0) if kind == "driver_steer" else 0.0
    delay = r.number("delay_ms", default=0.0, lo=0.0, hi=10_000.0) if kind == "delay" else 0.0
    module = r.string("module") if kind in MODULE_FAULTS else ""
    slow_ms = r.number("slow_ms", lo=0.0, hi=10_000.0) if kind == "module_slow" else 0.0
    if kind in ("corrupt", "drop", "delay", "repeat", "stuck") and not frames_raw:
        raise r.error("frames", f"a '{kind}' fault needs the list of frames it affects")
    r.finish()
    return FaultEvent(
        at_s=at_s,
        kind=kind,
        duration_s=duration_s,
        frames=tuple(frames_raw),
        mode=mode,
        pedal_pct=pedal,
        torque_nm=torque,
        delay_ms=delay,
        module=module,
        slow_ms=slow_ms,
    )


def parse_check(item: Any, source: str, path: str) -> Check:
    """One check (`{name, metric, max|min|equals|includes, hil}`), `path` naming it in errors."""
    r = _Reader(item, source, path)
    metric = r.string("metric")
    ops = [op for op in CHECK_OPS if r.has(op)]
    if len(ops) != 1:
        raise ScenarioError(source, path, f"a check needs exactly one of {', '.join(CHECK_OPS)}")
    op = ops[0]
    limit = r.raw(op)
    if op in ("max", "min") and (isinstance(limit, bool) or not isinstance(limit, int | float)):
        raise r.error(op, f"expected a number, got {limit!r}")
    if op in ("equals", "includes") and not isinstance(limit, bool | str | int | float):
        raise r.error(op, f"expected a value, got {limit!r}")
    if STATE_AT.fullmatch(metric) is None and re.match(r"state_at_\d", metric):
        raise r.error("metric", f"expected state_at_<seconds>s (e.g. state_at_12.5s), got {metric!r}")
    hil_limit = r.raw("hil")
    if hil_limit is not None:
        if op in ("equals", "includes"):
            raise r.error("hil", "a HIL limit applies to max and min checks only")
        if isinstance(hil_limit, bool) or not isinstance(hil_limit, int | float):
            raise r.error("hil", f"expected a number, got {hil_limit!r}")
        if (op == "max" and hil_limit < limit) or (op == "min" and hil_limit > limit):  # type: ignore[operator]
            raise r.error("hil", f"a HIL limit may only be looser than the SIL one ({op} {limit})")
    name = r.string("name", default=f"{metric}_{op}")
    r.finish()
    return Check(name=name, metric=metric, op=op, limit=limit, hil_limit=hil_limit)


def _relative_to(source: str, path: str) -> str:
    """Paths in a scenario file are relative to the file's folder (absolute ones stay as they are)."""
    p = Path(path).expanduser()
    if p.is_absolute() or not Path(source).is_file():
        return str(p)
    return str(Path(source).parent / p)


def parse_scenario(data: Any, source: str) -> Scenario:
    """Build a `Scenario` from parsed YAML/TOML data; `source` names the file in errors."""
    r = _Reader(data, source, "")
    name = r.string("name")
    if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}", name):
        # The name becomes file names in reports: keep it to a safe, non-empty identifier.
        raise r.error("name", f"expected 1-64 letters, digits, '_', '-' or '.', got {name!r}")
    description = r.string("description", default="")
    duration_s = r.number("duration_s", lo=0.1, hi=24 * 3600.0)
    seed = int(r.number("seed", default=1.0, lo=0.0))
    hil_timeout_s = r.number("hil_timeout_s", default=0.0, lo=0.0)

    vehicle = r.sub("vehicle")
    model = vehicle.string("model", default="passat")
    plant_mapping = vehicle.raw("mapping")
    if plant_mapping is not None and not isinstance(plant_mapping, str):
        raise vehicle.error("mapping", "expected a path to a plant mapping TOML file")
    if model.endswith(".fmu"):
        # A vendor's FMU: the plant needs to know which of its variables play which role.
        if plant_mapping is None:
            raise vehicle.error("mapping", f"a ready-made FMU ({model}) needs a plant mapping TOML file")
        model = _relative_to(source, model)
    if plant_mapping is not None:
        plant_mapping = _relative_to(source, plant_mapping)
    v0 = vehicle.number("v0_mps", default=0.0, lo=0.0, hi=70.0)
    vehicle.finish()
    vehicle_profile = r.string("vehicle_profile", default="bywire", choices=VEHICLE_PROFILES)

    ecu = r.sub("ecu")
    calibration = ecu.raw("calibration")
    if calibration is not None and not isinstance(calibration, str):
        raise ecu.error("calibration", "expected a path to a calibration file")
    if calibration is not None:
        calibration = _relative_to(source, calibration)
    corrupt_cal = ecu.boolean("corrupt_calibration", False)
    ecu.finish()

    host = r.sub("host")
    mode = host.string("mode", default="script", choices=("script", "drive"))
    engage_at = host.number("engage_at_s", default=0.5, lo=0.0)
    accel_profile = host.profile("accel_profile")
    speed_profile = host.profile("speed_profile")
    steer_profile = host.profile("steer_profile")
    stop_line = host.opt_number("stop_line_m", lo=0.0)
    host_config = host.string("config", default="default")
    if Path(host_config).suffix in (".yaml", ".yml", ".toml"):
        host_config = _relative_to(source, host_config)
    host_params = host.raw("params", {}) or {}
    if not isinstance(host_params, dict) or not all(isinstance(v, dict) for v in host_params.values()):
        raise host.error("params", f"expected module name -> mapping of parameters, got {host_params!r}")
    for i, (_, a) in enumerate(accel_profile):
        if not -10.0 <= a <= 10.0:
            raise host.error(f"accel_profile[{i}]", f"acceleration {a} m/s^2 is not physical")
    if mode == "drive" and not speed_profile:
        raise host.error("speed_profile", "drive mode needs a speed profile")
    lead = None
    if host.has("lead"):
        lr = host.sub("lead")
        lead = LeadCar(
            gap0_m=lr.number("gap0_m", lo=1.0),
            speed_profile=lr.profile("speed_profile"),
            length_m=lr.number("length_m", default=4.8, lo=1.0, hi=20.0),
            leaves_at_s=lr.opt_number("leaves_at_s", lo=0.0),
        )
        lr.finish()
    host.finish()

    plant = r.sub("plant")
    grade = plant.profile("grade_pct")
    wind = plant.profile("wind_mps")
    noise = plant.sub("noise")
    accel_noise = noise.number("accel_mps2", default=0.03, lo=0.0, hi=5.0)
    wheel_noise = noise.number("wheel_speed_mps", default=0.02, lo=0.0, hi=5.0)
    radar_noise = noise.number("radar_range_m", default=0.1, lo=0.0, hi=10.0)
    noise.finish()
    delay = plant.number("actuator_delay_ms", default=10.0, lo=0.0, hi=1000.0)
    plant.finish()

    raw_faults = r.raw("faults", []) or []
    if not isinstance(raw_faults, list):
        raise ScenarioError(source, "faults", "expected a list of fault events")
    faults = tuple(_parse_fault(item, source, f"faults[{i}]") for i, item in enumerate(raw_faults))
    raw_checks = r.raw("checks", []) or []
    if not isinstance(raw_checks, list):
        raise ScenarioError(source, "checks", "expected a list of checks")
    checks = tuple(parse_check(item, source, f"checks[{i}]") for i, item in enumerate(raw_checks))
    fault_ref = r.opt_number("fault_ref_s", lo=0.0)
    hold_until = r.opt_number("hold_until_s", lo=0.0)
    extra = r.raw("extra", {}) or {}
    world = None
    if r.has("world"):
        world = parse_world(r.raw("world"), source, "world", ScenarioError)
        if lead is not None:
            raise ScenarioError(
                source, "host.lead", "give the lead car as a world vehicle when there is a world"
            )
    perception = r.string("perception", default="perfect", choices=PERCEPTION_MODES)
    if r.has("perception") and not r.has("urban"):
        raise r.error("perception", "only an urban scenario has a perception mode (no urban: section)")
    urban = None
    if r.has("urban"):
        urban = parse_urban(r.raw("urban"), source, "urban", ScenarioError)
        if world is not None or lead is not None:
            raise ScenarioError(
                source,
                "urban",
                "an urban scenario has its traffic in urban.vehicles (no world, no host.lead)",
            )
    if vehicle_profile != "bywire" and world is not None:
        # A world's host reads its odometry from our gateway's reports (GW_WheelSpeeds, GW_Motion,
        # host.modules.io.vehicle_sensors): on a PQ bus it would run blind.
        raise r.error(
            "vehicle_profile",
            f"{vehicle_profile}: a scenario with a world: section runs on the bywire profile only "
            "(the host's odometry reads the gateway's reports)",
        )
    r.finish()
    if fault_ref is None and faults:
        fault_ref = min(f.at_s for f in faults)
    scenario = Scenario(
        name=name,
        description=description,
        source=source,
        duration_s=duration_s,
        v0_mps=v0,
        model=model,
        plant_mapping=plant_mapping,
        calibration=calibration,
        corrupt_calibration=corrupt_cal,
        host_mode=mode,
        host_config=host_config,
        engage_at_s=engage_at,
        accel_profile=accel_profile,
        speed_profile=speed_profile,
        steer_profile=steer_profile,
        stop_line_m=stop_line,
        lead=lead,
        grade_pct=grade,
        wind_mps=wind,
        accel_noise_mps2=accel_noise,
        wheel_speed_noise_mps=wheel_noise,
        radar_range_noise_m=radar_noise,
        actuator_delay_ms=delay,
        faults=faults,
        checks=checks,
        fault_ref_s=fault_ref,
        hold_until_s=hold_until,
        seed=seed,
        hil_timeout_s=hil_timeout_s,
        extra=dict(extra),
        world=world,
        urban=urban,
        vehicle_profile=vehicle_profile,
        host_params={str(k): dict(v) for k, v in host_params.items()},
    )
    return with_perception(scenario, perception) if urban is not None else scenario


def scenario_host_config(scenario: Scenario, name_or_file: str | None = None) -> HostConfig:
    """The host configuration a run of `scenario` uses (`name_or_file`, default the scenario's), with
    the scenario's `host.params` set over it: the one place SIL, the HIL host and the evaluation read it."""
    from bywire.host.config import load_host_config  # the module registry: not for `hil list`

    return load_host_config(
        name_or_file or scenario.host_config, scenario.host_params, (scenario.source, "host.params")
    )


# What an urban host perceives the other cars by: the world's object list, or the simulated LIDAR.
PERCEPTION_MODES = ("perfect", "lidar")
# The host configuration that perceives with the LIDAR, per configuration that takes the object list.
LIDAR_HOST_CONFIGS = {"urban": "urban_lidar"}


def with_perception(scenario: Scenario, mode: str) -> Scenario:
    """`scenario` with its host perceiving by `mode` (`perfect` | `lidar`): the world's setting and the
    host configuration that goes with it (`urban` <-> `urban_lidar`; a scenario's own file is kept)."""
    if mode not in PERCEPTION_MODES:
        raise ValueError(f"perception {mode!r}: expected one of {', '.join(PERCEPTION_MODES)}")
    if scenario.urban is None:
        raise ValueError(f"{scenario.name}: only an urban scenario has a perception mode")
    config = scenario.host_config
    to_lidar = dict(LIDAR_HOST_CONFIGS)
    to_perfect = {v: k for k, v in to_lidar.items()}
    config = (to_lidar if mode == "lidar" else to_perfect).get(config, config)
    return dataclasses.replace(
        scenario, host_config=config, urban=dataclasses.replace(scenario.urban, perception=mode)
    )


# The hand-made urban scenarios (seed 000; not the DARPA missions, which take tens of minutes): the
# tests run each with the object list and with the LIDAR.
URBAN_HAND_MADE = (
    "four_way_stop_0",
    "four_way_stop_1",
    "four_way_stop_2",
    "four_way_stop_3",
    "four_way_stop_stuck_car",
    "left_turn_oncoming",
    "merge_moving_traffic",
    "lane_change",
    "pass_parked_car",
    "blocked_road_replan",
    "estop_in_intersection",
    "host_freeze_in_turn",
    "zone_park_between_cars",
    "maze_zone",
    "kturn_narrow_road",
    "blocked_road_no_uturn_edge",
    "obstacle_appears_close",
)

# The scenarios of the spine's contract (ECU, plant and host), runnable by bare name: the tests run
# each, the benchmarks time each.
CONTRACT_SCENARIOS = (
    "accel_steps",
    "grade",
    "estop_pause",
    "estop_disable",
    "driver_brake",
    "heartbeat_loss",
    "host_freeze",
    "corrupt_frames",
    "bad_calibration",
)


def shipped_files(folder: str, suffixes: Collection[str]) -> dict[str, Path]:
    """The files of the package folder `hil/<folder>/` with one of `suffixes`, by bare name, sorted."""
    found: dict[str, Path] = {}
    for entry in (resources.files("bywire.hil") / folder).iterdir():
        path = Path(str(entry))
        if path.suffix in suffixes:
            found[path.stem] = path
    return dict(sorted(found.items()))


def resolve_shipped(
    name_or_file: str,
    suffixes: Collection[str],
    shipped: Callable[[], dict[str, Path]],
    error: type[SchemaError],
    what: str,
) -> Path:
    """A file by path (its suffix one of `suffixes`) or a shipped one by bare name (`shipped()`, looked
    at only then); else `error`."""
    path = Path(name_or_file)
    if path.suffix in suffixes:
        if not path.is_file():
            raise error(name_or_file, "", f"no such {what} file")
        return path
    known = shipped()
    if name_or_file not in known:
        raise error(name_or_file, "", f"unknown {what}; shipped ones: {', '.join(known)}")
    return known[name_or_file]


def builtin_scenarios() -> dict[str, Path]:
    """Scenarios shipped in hil/scenarios/, by bare name."""
    return shipped_files("scenarios", SCENARIO_SUFFIXES)


def resolve_scenario_path(name_or_file: str) -> Path:
    return resolve_shipped(name_or_file, SCENARIO_SUFFIXES, builtin_scenarios, ScenarioError, "scenario")


def load_scenario(name_or_file: str, overrides: Mapping[str, Any] | None = None) -> Scenario:
    """Load a shipped scenario by bare name, or any scenario file by path; `overrides` sets fields of
    it first (`{"vehicle.v0_mps": 25.0}`, `hil.scenario_overrides`)."""
    path = resolve_scenario_path(name_or_file)
    text = path.read_text(encoding="utf-8")
    try:
        data = tomllib.loads(text) if path.suffix == ".toml" else yaml.safe_load(text)
    except (yaml.YAMLError, tomllib.TOMLDecodeError) as exc:
        raise ScenarioError(str(path), "", f"not valid {path.suffix[1:].upper()}: {exc}") from exc
    if overrides:
        from bywire.hil.scenario_overrides import OverrideError, apply_overrides

        try:
            data = apply_overrides(data, overrides)
        except OverrideError as exc:
            raise ScenarioError(str(path), "", str(exc)) from None
    try:
        return parse_scenario(data, str(path))
    except SchemaError as exc:
        if exc.source != str(path) or path.suffix == ".toml":  # tomllib keeps no positions
            raise
        if overrides and any(exc.path == k or exc.path.startswith((f"{k}.", f"{k}[")) for k in overrides):
            raise ScenarioError(exc.source, exc.path, f"{exc.message} (as set)") from None
        raise exc.at_line(yaml_line(text, exc.path)) from None


__all__ = [
    "PERCEPTION_MODES",
    "URBAN_HAND_MADE",
    "Check",
    "EcuState",
    "FaultEvent",
    "LeadCar",
    "Scenario",
    "ScenarioError",
    "builtin_scenarios",
    "load_scenario",
    "parse_check",
    "parse_scenario",
    "ramp_value",
    "step_value",
    "with_perception",
]
