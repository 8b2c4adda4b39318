"""Fast FMI 2.0 Co-Simulation adapter for vehicle plants: `FmuVehicle` and `open_vehicle`.

The HIL plant process and the in-process SIL step the vehicle at 1 kHz, so `FmuVehicle.step` is
a thin path: value references and ctypes buffers are prepared once, and each step is exactly
three calls into the FMU (fmi2SetReal, fmi2DoStep, fmi2GetReal) plus a few float operations —
no numpy, no dicts, no allocation beyond the returned `VehicleOutputs`.

Roles, units and the fallbacks for unmapped optional roles are defined in `mapping.py`. The
FMU's own log messages (e.g. a rejected parameter) are collected per instance and quoted in
`FmuError`. fmpy's native log formatter keeps a single process-wide logger, so this module
routes messages by instance name; each `FmuVehicle` gets a unique one.

Not thread-safe: one `FmuVehicle` belongs to one loop. Not from the papers: the plant of
DESIGN.md section 1.
"""

from __future__ import annotations

import collections
import contextlib
import ctypes
import itertools
import shutil
import sys
import tempfile
import weakref
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType

import fmpy
from fmpy import read_model_description
from fmpy.fmi2 import (
    FMU2Slave,
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CallbackFunctions,
    fmi2CallbackLoggerTYPE,
)
from fmpy.model_description import ModelDescription, ScalarVariable

from .build import ensure_fmu, model_dir
from .mapping import (
    INPUT_ROLES,
    OUTPUT_ROLES,
    MappingError,
    PlantMapping,
    VariableMap,
    load_mapping,
)

_FMI2_WARNING = 1
# How far the speed right after initialisation may be from the requested initial speed: float
# round-off of a unit conversion, far below any scale error (km/h for m/s is 3.6x).
_INITIAL_SPEED_TOLERANCE_MPS = 1e-3
_LOG_LABELS = ("OK", "WARNING", "DISCARD", "ERROR", "FATAL", "PENDING")
_LOG_LINES_KEPT = 20


class FmuError(RuntimeError):
    """An FMI call failed; the message quotes the FMU's own log lines."""


@dataclass(slots=True)
class VehicleInputs:
    """Actuator requests and environment for one step (bywire plant roles, SI units)."""

    throttle_pct: float = 0.0  # accelerator pedal, 0..100 %
    brake_bar: float = 0.0  # commanded brake pressure
    steer_angle_rad: float = 0.0  # road-wheel angle request, + left
    grade_pct: float = 0.0  # road grade, + uphill
    wind_mps: float = 0.0  # wind along the car's axis, + head wind
    gear: float = 1.0  # direction of the drive force: +1 drive, -1 reverse, 0 neutral


@dataclass(frozen=True, slots=True)
class InitialConditions:
    """The plant's state at t = 0 (bywire initial-condition roles, SI units); mapped by ``[initial]``."""

    speed_mps: float = 0.0  # along the car's axis, + forward

    def by_role(self) -> dict[str, float]:
        return {"speed_mps": self.speed_mps}


@dataclass(slots=True)
class VehicleOutputs:
    """Plant state after a step. Speeds, wheel speeds and the acceleration are signed in the vehicle
    frame (negative when rolling backwards)."""

    speed_mps: float
    accel_mps2: float
    yaw_rate_radps: float
    x_m: float
    y_m: float
    heading_rad: float
    distance_m: float
    wheel_speed_fl_mps: float
    wheel_speed_fr_mps: float
    wheel_speed_rl_mps: float
    wheel_speed_rr_mps: float
    brake_bar_actual: float
    steer_angle_rad_actual: float


# ---- FMU log routing -------------------------------------------------------------------------

_log_sinks: dict[str, collections.deque[str]] = {}
_instance_ids = itertools.count(1)


def _route_log(
    env: object, instance: bytes | None, status: int, category: bytes | None, message: bytes
) -> None:
    name = instance.decode("utf-8", "replace") if instance else ""
    label = _LOG_LABELS[status] if 0 <= status < len(_LOG_LABELS) else str(status)
    text = f"[{label}] {message.decode('utf-8', 'replace')}"
    sink = _log_sinks.get(name)
    if sink is None:
        print(f"{name}: {text}", file=sys.stderr)
    else:
        sink.append(text)


_LOGGER = fmi2CallbackLoggerTYPE(_route_log)
_CALLBACKS = fmi2CallbackFunctions()
_CALLBACKS.allocateMemory = fmi2CallbackAllocateMemoryTYPE(fmpy.calloc)
_CALLBACKS.freeMemory = fmi2CallbackFreeMemoryTYPE(fmpy.free)


def _install_logger() -> None:
    # fmpy's native proxy formats the variadic message and forwards it to one global logger; any
    # later fmpy user can replace that logger, so claim it again before each instantiation. The
    # proxy saves the struct's current logger, hence the reset (else it would forward to itself).
    from fmpy.logging import addLoggerProxy

    _CALLBACKS.logger = _LOGGER
    addLoggerProxy(ctypes.byref(_CALLBACKS))


# ---- the adapter -----------------------------------------------------------------------------


class FmuVehicle:
    """One instance of a vehicle FMU, stepped on its own time from t = 0.

    ``fmu_path`` is a ``.fmu`` file or an extracted FMU directory. Start values come from
    ``mapping.parameters``, then ``initial`` through ``mapping.initial`` (roles, SI units), then
    ``start_values`` (FMU variable names, unconverted: for the bundled model's own tests).
    ``initial_inputs`` are applied before initialisation, so a model that settles its actuators
    at initialisation (the bundled passat does) starts e.g. held on a grade. With ``initial``
    given, the speed after initialisation must be ``initial.speed_mps`` (`MappingError` if not).
    """

    def __init__(
        self,
        fmu_path: str | Path,
        mapping: PlantMapping,
        start_values: dict[str, float] | None = None,
        *,
        initial_inputs: VehicleInputs | None = None,
        initial: InitialConditions | None = None,
    ) -> None:
        self._fmu_path = Path(fmu_path)
        self._mapping = mapping
        self._slave: FMU2Slave | None = None
        # Deletes the extracted copy of a .fmu even if the caller forgets close().
        self._cleanup: Callable[[], object] | None = None
        self._log: collections.deque[str] = collections.deque(maxlen=_LOG_LINES_KEPT)
        self._t_s = 0.0
        self._instance_name = ""
        try:
            self._open(start_values or {}, initial_inputs or VehicleInputs(), initial)
        except BaseException:
            self.close()
            raise

    # -- setup (not on the hot path) --

    def _open(
        self, start_values: dict[str, float], initial_inputs: VehicleInputs, initial: InitialConditions | None
    ) -> None:
        # Before the FMU is opened: the one-line answer to a scenario the mapping cannot start.
        initial_starts = self._mapping.initial_start_values(initial.by_role()) if initial is not None else {}
        if not self._fmu_path.exists():
            raise FileNotFoundError(f"{self._fmu_path}: no such FMU")
        try:
            md = read_model_description(str(self._fmu_path))
        except Exception as exc:
            raise FmuError(f"{self._fmu_path}: cannot read modelDescription.xml: {exc}") from exc
        if md.fmiVersion != "2.0" or md.coSimulation is None:
            raise FmuError(f"{self._fmu_path}: not an FMI 2.0 Co-Simulation FMU (fmiVersion {md.fmiVersion})")
        self._variables = {v.name: v for v in md.modelVariables}
        in_vars = self._resolve(self._mapping.inputs, "inputs", ("input",))
        out_vars = self._resolve(self._mapping.outputs, "outputs", ("output", "local"))
        starts = self._resolve_starts(initial_starts, start_values)

        if self._fmu_path.is_dir():
            unzipdir = str(self._fmu_path)
        else:
            tmpdir = tempfile.mkdtemp(prefix="bywire-fmu-")
            self._cleanup = weakref.finalize(self, shutil.rmtree, tmpdir, ignore_errors=True)
            unzipdir = fmpy.extract(str(self._fmu_path), tmpdir)
        self._instance_name = f"{md.coSimulation.modelIdentifier}#{next(_instance_ids)}"
        _log_sinks[self._instance_name] = self._log
        _install_logger()
        slave = FMU2Slave(
            guid=md.guid,
            unzipDirectory=unzipdir,
            modelIdentifier=md.coSimulation.modelIdentifier,
            instanceName=self._instance_name,
        )
        self._slave = slave
        self._prepare_buffers(md, in_vars, out_vars)
        try:
            slave.instantiate(callbacks=_CALLBACKS)
        except Exception as exc:
            raise self._error("fmi2Instantiate", exc) from exc
        self._component = ctypes.c_void_p(slave.component)
        try:
            slave.setupExperiment(startTime=0.0)
            for var, value in starts:
                slave.setReal([var.valueReference], [value])
            self._write_inputs(initial_inputs)
            self._check(self._set_real(self._component, self._u_vr, self._n_u, self._u), "fmi2SetReal")
            slave.enterInitializationMode()
            slave.exitInitializationMode()
        except FmuError:
            raise
        except Exception as exc:
            raise self._error("initialisation", exc) from exc
        self._check(self._get_real(self._component, self._y_vr, self._n_y, self._y), "fmi2GetReal")
        self._last = self._read_outputs(initial_inputs)
        if initial is not None:
            self._check_initial_speed(initial.speed_mps)

    def _check_initial_speed(self, requested_mps: float) -> None:
        started_mps = self._last.speed_mps
        if abs(started_mps - requested_mps) <= _INITIAL_SPEED_TOLERANCE_MPS * max(1.0, abs(requested_mps)):
            return
        var = self._mapping.initial.get("speed_mps")
        hint = (
            f"check [initial].speed_mps ({var.name!r}) and its scale"
            if var is not None
            else "map [initial].speed_mps to the FMU's start variable"
        )
        raise MappingError(
            f"{self._mapping.source}: {self._fmu_path.name} starts at speed_mps = {started_mps:g},"
            f" not the requested {requested_mps:g}; {hint}"
        )

    def _resolve(
        self, roles: dict[str, VariableMap], table: str, causalities: tuple[str, ...]
    ) -> dict[str, ScalarVariable]:
        resolved: dict[str, ScalarVariable] = {}
        for role, var_map in roles.items():
            where = f"{self._mapping.source}: [{table}].{role}"
            var = self._variables.get(var_map.name)
            if var is None:
                raise MappingError(f"{where}: FMU {self._fmu_path.name} has no variable {var_map.name!r}")
            if var.type != "Real" or var.causality not in causalities:
                raise MappingError(
                    f"{where}: FMU variable {var_map.name!r} is a {var.type} {var.causality};"
                    f" expected a Real {' or '.join(causalities)}"
                )
            resolved[role] = var
        return resolved

    def _resolve_starts(
        self, initial_starts: dict[str, tuple[float, str]], start_values: dict[str, float]
    ) -> list[tuple[ScalarVariable, float]]:
        merged: dict[str, tuple[float, str]] = {
            name: (value, f"{self._mapping.source}: [parameters].{name}")
            for name, value in self._mapping.parameters.items()
        }
        merged.update(initial_starts)
        merged.update({name: (value, f"start_values[{name!r}]") for name, value in start_values.items()})
        starts = []
        for name, (value, where) in merged.items():
            var = self._variables.get(name)
            if var is None:
                raise MappingError(f"{where}: FMU {self._fmu_path.name} has no variable {name!r}")
            # FMI 2.0 sec. 4.2.4: before initialisation fmi2SetReal may set any non-constant
            # variable with initial = exact or approx (parameters and inputs are such variables).
            settable = var.causality in ("parameter", "input") or var.initial in ("exact", "approx")
            if var.type != "Real" or var.variability == "constant" or not settable:
                raise MappingError(
                    f"{where}: FMU variable {name!r} ({var.type} {var.causality} {var.variability})"
                    " cannot take a start value; expected a Real parameter, input or a variable"
                    ' with initial="exact" or "approx"'
                )
            starts.append((var, float(value)))
        return starts

    def _prepare_buffers(
        self, md: ModelDescription, in_vars: dict[str, ScalarVariable], out_vars: dict[str, ScalarVariable]
    ) -> None:
        assert self._slave is not None
        m = self._mapping
        # Fresh ctypes function objects (dll[name] does not share fmpy's cached ones) without
        # argtypes: every argument below is a pre-built ctypes object of the exact C type, which
        # halves the per-call cost of fmpy's typed wrappers (about 0.5 us instead of 1.2 us).
        dll = self._slave.dll
        self._set_real = dll["fmi2SetReal"]
        self._get_real = dll["fmi2GetReal"]
        self._do_step = dll["fmi2DoStep"]
        for fn in (self._set_real, self._get_real, self._do_step):
            fn.restype = ctypes.c_int
        self._t_c = ctypes.c_double(0.0)  # fmi2Real currentCommunicationPoint
        self._dt_c = ctypes.c_double(0.0)  # fmi2Real communicationStepSize
        self._true_c = ctypes.c_int(1)  # fmi2Boolean noSetFMUStatePriorToCurrentPoint

        in_roles = list(in_vars)  # canonical order: required first, then mapped optional ones
        self._n_u = ctypes.c_size_t(len(in_roles))
        self._u_vr = (ctypes.c_uint * len(in_roles))(*(in_vars[r].valueReference for r in in_roles))
        self._u = (ctypes.c_double * len(in_roles))()
        # fmu = role * k + c, per role in INPUT_ROLES order; index -1 = unmapped.
        self._in_index = [in_roles.index(r) if r in in_vars else -1 for r in INPUT_ROLES]
        self._in_k = [1.0 / m.inputs[r].scale if r in in_vars else 0.0 for r in INPUT_ROLES]
        self._in_c = [-m.inputs[r].offset / m.inputs[r].scale if r in in_vars else 0.0 for r in INPUT_ROLES]

        out_roles = list(out_vars)
        self._n_y = ctypes.c_size_t(len(out_roles))
        self._y_vr = (ctypes.c_uint * len(out_roles))(*(out_vars[r].valueReference for r in out_roles))
        self._y = (ctypes.c_double * len(out_roles))()
        self._out_index = [out_roles.index(r) if r in out_vars else -1 for r in OUTPUT_ROLES]
        self._out_k = [m.outputs[r].scale if r in out_vars else 0.0 for r in OUTPUT_ROLES]
        self._out_c = [m.outputs[r].offset if r in out_vars else 0.0 for r in OUTPUT_ROLES]
        # The common case (bundled model, identity mapping of every role in order) skips the maths.
        self._out_identity = out_roles == list(OUTPUT_ROLES) and all(
            m.outputs[r].scale == 1.0 and m.outputs[r].offset == 0.0 for r in OUTPUT_ROLES
        )
        self._half_track_m = 0.5 * m.track_width_m
        self._names_by_vr = {v.valueReference: v.name for v in md.modelVariables if v.type == "Real"}

    def _error(self, what: str, exc: BaseException | None = None) -> FmuError:
        detail = "\n  ".join(self._log) if self._log else (str(exc) if exc else "no message from the FMU")
        return FmuError(f"{self._fmu_path.name} ({self._instance_name}): {what} failed:\n  {detail}")

    def _check(self, status: int, what: str) -> None:
        if status > _FMI2_WARNING:
            raise self._error(what)

    # -- hot path --

    def _write_inputs(self, inputs: VehicleInputs) -> None:
        u, k, c, idx = self._u, self._in_k, self._in_c, self._in_index
        u[0] = inputs.throttle_pct * k[0] + c[0]
        u[1] = inputs.brake_bar * k[1] + c[1]
        u[2] = inputs.steer_angle_rad * k[2] + c[2]
        if idx[3] >= 0:
            u[idx[3]] = inputs.grade_pct * k[3] + c[3]
        elif inputs.grade_pct != 0.0:
            raise self._unmapped_input("grade_pct", inputs.grade_pct)
        if idx[4] >= 0:
            u[idx[4]] = inputs.wind_mps * k[4] + c[4]
        elif inputs.wind_mps != 0.0:
            raise self._unmapped_input("wind_mps", inputs.wind_mps)
        if idx[5] >= 0:
            u[idx[5]] = inputs.gear * k[5] + c[5]
        elif inputs.gear != 1.0:
            raise self._unmapped_input("gear", inputs.gear)

    def _unmapped_input(self, role: str, value: float) -> ValueError:
        return ValueError(
            f"{self._mapping.source}: [inputs].{role} is not mapped, so {self._fmu_path.name} cannot"
            f" simulate {role} = {value}; map it or keep it 0"
        )

    def _read_outputs(self, inputs: VehicleInputs) -> VehicleOutputs:
        if self._out_identity:
            return VehicleOutputs(*self._y[:])
        y, k, c, idx = self._y[:], self._out_k, self._out_c, self._out_index
        speed = y[0] * k[0] + c[0]
        yaw_rate = y[2] * k[2] + c[2]
        left = speed - yaw_rate * self._half_track_m
        right = speed + yaw_rate * self._half_track_m
        i = idx[7]
        fl = y[i] * k[7] + c[7] if i >= 0 else left
        i = idx[8]
        fr = y[i] * k[8] + c[8] if i >= 0 else right
        i = idx[9]
        rl = y[i] * k[9] + c[9] if i >= 0 else left
        i = idx[10]
        rr = y[i] * k[10] + c[10] if i >= 0 else right
        i = idx[11]
        brake = y[i] * k[11] + c[11] if i >= 0 else inputs.brake_bar
        i = idx[12]
        steer = y[i] * k[12] + c[12] if i >= 0 else inputs.steer_angle_rad
        return VehicleOutputs(
            speed,
            y[1] * k[1] + c[1],
            yaw_rate,
            y[3] * k[3] + c[3],
            y[4] * k[4] + c[4],
            y[5] * k[5] + c[5],
            y[6] * k[6] + c[6],
            fl,
            fr,
            rl,
            rr,
            brake,
            steer,
        )

    def step(self, dt_s: float, inputs: VehicleInputs) -> VehicleOutputs:
        """Apply ``inputs``, advance the model by ``dt_s`` seconds and return its outputs."""
        if not dt_s > 0.0:
            if dt_s == 0.0:
                return self._last
            raise ValueError(f"FmuVehicle.step: dt_s must be > 0, got {dt_s}")
        self._write_inputs(inputs)
        comp = self._component
        if self._set_real(comp, self._u_vr, self._n_u, self._u) > _FMI2_WARNING:
            raise self._error(f"fmi2SetReal at t = {self._t_s} s with {inputs}")
        t = self._t_s
        self._t_c.value = t
        self._dt_c.value = dt_s
        if self._do_step(comp, self._t_c, self._dt_c, self._true_c) > _FMI2_WARNING:
            raise self._error(f"fmi2DoStep({t}, {dt_s})")
        self._t_s = t + dt_s
        if self._get_real(comp, self._y_vr, self._n_y, self._y) > _FMI2_WARNING:
            raise self._error(f"fmi2GetReal at t = {self._t_s} s")
        out = self._last = self._read_outputs(inputs)
        return out

    # -- the rest of the public API --

    def outputs(self) -> VehicleOutputs:
        """The outputs after the latest step (or after initialisation)."""
        return self._last

    @property
    def t_s(self) -> float:
        """Simulated time of this vehicle: the sum of all ``dt_s`` stepped so far."""
        return self._t_s

    @property
    def fmu_path(self) -> Path:
        return self._fmu_path

    def read(self, name: str) -> float:
        """Any Real FMU variable by its FMU name, unmapped (slow; for diagnostics and tests)."""
        var = self._variables.get(name)
        if var is None or var.type != "Real":
            raise KeyError(f"FMU {self._fmu_path.name} has no Real variable {name!r}")
        if self._slave is None:
            raise FmuError(f"{self._fmu_path.name}: read({name!r}) after close()")
        try:
            return float(self._slave.getReal([var.valueReference])[0])
        except Exception as exc:
            raise self._error(f"fmi2GetReal({name})", exc) from exc

    def log_messages(self) -> list[str]:
        """The FMU's most recent log lines (errors and warnings; all if debug logging is on)."""
        return list(self._log)

    def close(self) -> None:
        """Terminate and free the FMU instance and delete its extracted files. Idempotent."""
        slave, self._slave = self._slave, None
        if slave is not None:
            try:
                if slave.component is not None:
                    # Terminating a failed instance may fail too; free it anyway.
                    with contextlib.suppress(Exception):
                        slave.terminate()
                    slave.freeInstance()
                else:
                    slave.freeLibrary()
            finally:
                _log_sinks.pop(self._instance_name, None)
        if self._cleanup is not None:
            self._cleanup()

    def __enter__(self) -> FmuVehicle:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


def default_mapping_path(model: str | Path = "passat") -> Path:
    """The mapping.toml shipped next to a bundled model's sources."""
    return model_dir(model) / "mapping.toml"


def open_vehicle(
    model: str | Path = "passat",
    start_values: dict[str, float] | None = None,
    *,
    mapping: PlantMapping | str | Path | None = None,
    cache_dir: Path | None = None,
    initial_inputs: VehicleInputs | None = None,
    initial: InitialConditions | None = None,
) -> FmuVehicle:
    """Open a vehicle plant.

    ``model`` is a bundled model name or source directory (built and cached by `ensure_fmu`,
    mapped by its own mapping.toml unless ``mapping`` is given) or a path to a ready ``.fmu``
    (then ``mapping`` is required).
    """
    if str(model).endswith(".fmu"):
        if mapping is None:
            raise MappingError(f"{model}: a ready-made FMU needs a plant mapping (mapping=...)")
        fmu_path = Path(model)
    else:
        fmu_path = ensure_fmu(model, cache_dir)
        if mapping is None:
            mapping = default_mapping_path(model)
    if not isinstance(mapping, PlantMapping):
        mapping = load_mapping(mapping)
    return FmuVehicle(fmu_path, mapping, start_values, initial_inputs=initial_inputs, initial=initial)
