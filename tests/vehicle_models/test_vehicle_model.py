"""The passat FMU plant: build and cache, FMI conformance, physics, mapping and the adapter."""

from __future__ import annotations

import itertools
import math
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import fmpy
import pytest
from fmpy import read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave
from fmpy.validation import validate_fmu
from hypothesis import given, settings
from hypothesis import strategies as st

from bywire.vehicle_models import (
    BuildError,
    FmuError,
    FmuVehicle,
    MappingError,
    PlantMapping,
    VehicleInputs,
    default_mapping_path,
    ensure_fmu,
    load_mapping,
    open_vehicle,
    parse_mapping,
)
from bywire.vehicle_models import build as build_module
from bywire.vehicle_models.build import MODELS_DIR

M_KG = 1650.0
G = 9.81
L_M = 2.72
LF_M, LR_M = 1.30, 1.42
CF, CR = 85000.0, 95000.0
TRACK_M = 1.55
F_RR_FLAT_N = 0.011 * M_KG * G
STEER_MAX_RAD = math.radians(30.0)
STEER_RATE_RADPS = 0.7


def drag_n(v_mps: float) -> float:
    return 0.5 * 1.2 * 0.70 * v_mps * abs(v_mps)


# ---- fixtures ----------------------------------------------------------------------------------


@pytest.fixture(scope="session")
def fmu_cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("fmu-cache")


@pytest.fixture(scope="session")
def passat_fmu(fmu_cache: Path) -> Path:
    return ensure_fmu("passat", fmu_cache)


@pytest.fixture(scope="session")
def passat_dir(passat_fmu: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    # Extracted once: opening a directory skips the unzip, which keeps property tests quick.
    return Path(fmpy.extract(str(passat_fmu), str(tmp_path_factory.mktemp("passat-fmu"))))


@pytest.fixture(scope="session")
def mapping() -> PlantMapping:
    return load_mapping(default_mapping_path("passat"))


@pytest.fixture
def open_passat(passat_dir: Path, mapping: PlantMapping):  # type: ignore[no-untyped-def]
    opened: list[FmuVehicle] = []

    def _open(initial: VehicleInputs | None = None, **start_values: float) -> FmuVehicle:
        vehicle = FmuVehicle(passat_dir, mapping, start_values, initial_inputs=initial)
        opened.append(vehicle)
        return vehicle

    yield _open
    for vehicle in opened:
        vehicle.close()


def copy_model(tmp_path: Path) -> Path:
    dest = tmp_path / "passat"
    shutil.copytree(MODELS_DIR / "passat", dest)
    return dest


# ---- build, cache, FMI conformance -------------------------------------------------------------


def test_fmu_builds_and_validates(passat_fmu: Path) -> None:
    assert passat_fmu.is_file() and passat_fmu.suffix == ".fmu"
    assert validate_fmu(str(passat_fmu)) == []
    names = zipfile.ZipFile(passat_fmu).namelist()
    assert "modelDescription.xml" in names
    assert "sources/passat.c" in names
    assert f"binaries/{fmpy.platform}/passat.so" in names


def test_cache_is_reused_without_rebuilding(
    passat_fmu: Path, fmu_cache: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    mtime = passat_fmu.stat().st_mtime_ns

    def no_build(*args: object) -> None:
        raise AssertionError("ensure_fmu rebuilt an FMU that was cached")

    monkeypatch.setattr(build_module, "_build", no_build)
    assert ensure_fmu("passat", fmu_cache) == passat_fmu
    assert passat_fmu.stat().st_mtime_ns == mtime
    captured = capsys.readouterr()
    assert "building" not in captured.out + captured.err


def test_rebuilds_when_a_source_changes_and_not_for_docs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    model = copy_model(tmp_path)
    cache = tmp_path / "cache"
    first = ensure_fmu(model, cache)
    assert capsys.readouterr().err.count("building passat FMU") == 1

    (model / "README.md").write_text("docs are not part of the FMU\n")
    assert ensure_fmu(model, cache) == first
    assert "building" not in capsys.readouterr().err

    source = model / "sources" / "passat.c"
    source.write_text(source.read_text() + "\n/* changed */\n")
    second = ensure_fmu(model, cache)
    assert second != first and second.is_file() and first.is_file()
    assert capsys.readouterr().err.count("building passat FMU") == 1
    assert validate_fmu(str(second)) == []
    # Only finished FMUs and lock files remain: the build's temporary directories are gone.
    assert sorted(p.suffix for p in cache.iterdir()) == [".fmu", ".fmu", ".lock"]


def test_two_processes_build_once(tmp_path: Path) -> None:
    model = copy_model(tmp_path)
    cache = tmp_path / "cache"
    code = (
        "import sys; from pathlib import Path; from bywire.vehicle_models.build import ensure_fmu; "
        "print(ensure_fmu(Path(sys.argv[1]), Path(sys.argv[2])))"
    )
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", code, str(model), str(cache)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for _ in range(2)
    ]
    results = [proc.communicate(timeout=120) for proc in procs]
    assert [proc.returncode for proc in procs] == [0, 0], results
    paths = {out.strip() for out, _ in results}
    assert len(paths) == 1
    assert sum(err.count("building passat FMU") for _, err in results) == 1
    assert validate_fmu(paths.pop()) == []


def test_compile_error_is_reported_with_the_file(tmp_path: Path) -> None:
    model = copy_model(tmp_path)
    source = model / "sources" / "passat.c"
    source.write_text(source.read_text() + "\nthis is not C;\n")
    with pytest.raises(BuildError, match=r"passat\.c"):
        ensure_fmu(model, tmp_path / "cache")
    assert not list((tmp_path / "cache").glob("*.fmu"))


def test_unknown_model_is_refused_with_its_path(tmp_path: Path) -> None:
    with pytest.raises(BuildError, match=r"no modelDescription\.xml"):
        ensure_fmu("no_such_car", tmp_path)


def test_c_variable_table_matches_model_description(
    passat_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Every XML variable's value reference reaches the C variable of the same name and start."""
    md = read_model_description(str(passat_dir))
    slave = FMU2Slave(
        guid=md.guid,
        unzipDirectory=str(passat_dir),
        modelIdentifier=md.coSimulation.modelIdentifier,
        instanceName="table-check",
    )
    slave.instantiate()
    try:
        for var in md.modelVariables:
            if var.causality in ("parameter", "input"):
                assert slave.getReal([var.valueReference])[0] == pytest.approx(float(var.start), rel=1e-15)
            capsys.readouterr()
            with pytest.raises(FMICallException):
                slave.setReal([var.valueReference], [math.nan])
            log = capsys.readouterr()
            text = log.out + log.err
            # The C code names the variable in its error: the XML name must be the C name.
            if var.causality == "output":
                assert f"{var.name} is an output" in text
            else:
                assert f"{var.name} = nan is not finite" in text
    finally:
        slave.freeInstance()


# ---- longitudinal physics ----------------------------------------------------------------------


def test_full_throttle_accelerates_at_most_5200_n(open_passat) -> None:  # type: ignore[no-untyped-def]
    vehicle = open_passat()
    full = VehicleInputs(throttle_pct=100.0)
    accels = [vehicle.step(0.001, full).accel_mps2 for _ in range(3000)]
    assert max(accels) <= 5200.0 / M_KG + 1e-9
    # After 3 s the 0.25 s lag has settled (e^-12); at about 9 m/s the force limit still rules.
    out = vehicle.outputs()
    expected = (5200.0 - F_RR_FLAT_N - drag_n(out.speed_mps)) / M_KG
    assert out.accel_mps2 == pytest.approx(expected, rel=2e-3)
    assert accels[1500] > 0.95 * expected
    assert vehicle.read("drive_force_n") == pytest.approx(5200.0, rel=1e-4)


def test_power_limit_at_speed(open_passat) -> None:  # type: ignore[no-untyped-def]
    full = VehicleInputs(throttle_pct=100.0)
    vehicle = open_passat(full, v0_mps=30.0)
    out = vehicle.step(0.001, full)
    expected = (103000.0 / 30.0 - F_RR_FLAT_N - drag_n(30.0)) / M_KG
    assert out.accel_mps2 == pytest.approx(expected, rel=2e-3)


def test_coast_down_decelerates_by_drag_and_rolling_resistance(open_passat) -> None:  # type: ignore[no-untyped-def]
    vehicle = open_passat(v0_mps=20.0)
    out = vehicle.step(0.001, VehicleInputs())
    assert out.accel_mps2 == pytest.approx(-(drag_n(20.0) + F_RR_FLAT_N) / M_KG, rel=1e-3)
    for _ in range(100):
        out = vehicle.step(0.1, VehicleInputs())
    assert 0.0 < out.speed_mps < 20.0
    assert out.accel_mps2 == pytest.approx(-(drag_n(out.speed_mps) + F_RR_FLAT_N) / M_KG, rel=1e-3)


def test_head_wind_adds_drag(open_passat) -> None:  # type: ignore[no-untyped-def]
    wind = VehicleInputs(wind_mps=10.0)
    out = open_passat(wind, v0_mps=20.0).step(0.001, wind)
    assert out.accel_mps2 == pytest.approx(-(drag_n(30.0) + F_RR_FLAT_N) / M_KG, rel=1e-3)


def test_brake_20_bar_decelerates_about_2800_n(open_passat) -> None:  # type: ignore[no-untyped-def]
    brake = VehicleInputs(brake_bar=20.0)
    vehicle = open_passat(brake, v0_mps=10.0)
    out = vehicle.step(0.001, brake)
    assert out.accel_mps2 == pytest.approx(-20.0 * 140.0 / M_KG, abs=0.15)
    assert out.accel_mps2 == pytest.approx(-(20.0 * 140.0 + F_RR_FLAT_N + drag_n(10.0)) / M_KG, rel=1e-3)
    for _ in range(10_000):
        out = vehicle.step(0.001, brake)
    assert out.speed_mps == 0.0 and math.copysign(1.0, out.speed_mps) == 1.0
    assert out.accel_mps2 == 0.0


def test_brake_pressure_follows_a_100_ms_lag(open_passat) -> None:  # type: ignore[no-untyped-def]
    vehicle = open_passat()
    for _ in range(100):
        out = vehicle.step(0.001, VehicleInputs(brake_bar=20.0))
    assert out.brake_bar_actual == pytest.approx(20.0 * (1.0 - math.exp(-1.0)), rel=1e-6)
    for _ in range(2000):
        out = vehicle.step(0.001, VehicleInputs(brake_bar=500.0))
    assert out.brake_bar_actual == pytest.approx(200.0, rel=1e-6)  # saturation


def test_held_on_5_percent_grade_for_60_s(open_passat) -> None:  # type: ignore[no-untyped-def]
    held = VehicleInputs(brake_bar=15.0, grade_pct=5.0)
    vehicle = open_passat(held)
    for _ in range(6000):
        out = vehicle.step(0.01, held)
        assert out.speed_mps == 0.0 and math.copysign(1.0, out.speed_mps) == 1.0
        assert out.accel_mps2 == 0.0
    assert vehicle.t_s == pytest.approx(60.0)
    assert out.x_m == 0.0 and out.distance_m == 0.0


def test_rolls_back_on_5_percent_grade_without_brake(open_passat) -> None:  # type: ignore[no-untyped-def]
    free = VehicleInputs(grade_pct=5.0)
    vehicle = open_passat(free)
    theta = math.atan(0.05)
    expected = -(M_KG * G * math.sin(theta) - 0.011 * M_KG * G * math.cos(theta)) / M_KG
    out = vehicle.step(0.001, free)
    assert out.accel_mps2 == pytest.approx(expected, rel=1e-6)
    speeds = [vehicle.step(0.01, free).speed_mps for _ in range(300)]
    assert all(b < a < 0.0 for a, b in itertools.pairwise(speeds))  # monotonic, no chatter
    out = vehicle.outputs()
    assert out.distance_m < 0.0 and out.x_m < 0.0


@settings(max_examples=40, deadline=None)
@given(
    grade_pct=st.floats(-15.0, 15.0),
    brake_bar=st.floats(0.0, 30.0),
)
def test_stiction_holds_exactly_when_friction_exceeds_grade_force(
    passat_dir: Path, mapping: PlantMapping, grade_pct: float, brake_bar: float
) -> None:
    theta = math.atan(grade_pct / 100.0)
    grade_force = M_KG * G * math.sin(theta)
    friction = 140.0 * brake_bar + 0.011 * M_KG * G * math.cos(theta)
    if abs(abs(grade_force) - friction) < 20.0:
        return  # too close to the boundary to call from outside
    inputs = VehicleInputs(brake_bar=brake_bar, grade_pct=grade_pct)
    with FmuVehicle(passat_dir, mapping, initial_inputs=inputs) as vehicle:
        # 1 ms steps: sampling every n-th internal step could hide a chatter of period n.
        speeds = [vehicle.step(0.001, inputs).speed_mps for _ in range(1000)]
        distance_m = vehicle.outputs().distance_m
    if friction > abs(grade_force):
        assert all(v == 0.0 and math.copysign(1.0, v) == 1.0 for v in speeds)
        assert distance_m == 0.0
    else:
        # Rolls downhill and never the other way.
        downhill = -1.0 if grade_force > 0 else 1.0
        assert all(v * downhill >= 0.0 for v in speeds)
        assert speeds[-1] * downhill > 0.0


@settings(max_examples=40, deadline=None)
@given(v0_mps=st.floats(-5.0, 5.0), brake_bar=st.floats(0.0, 50.0))
def test_friction_never_reverses_motion_on_flat_ground(
    passat_dir: Path, mapping: PlantMapping, v0_mps: float, brake_bar: float
) -> None:
    inputs = VehicleInputs(brake_bar=brake_bar)
    with FmuVehicle(passat_dir, mapping, {"v0_mps": v0_mps}, initial_inputs=inputs) as vehicle:
        previous = vehicle.outputs().speed_mps
        for _ in range(300):
            v = vehicle.step(0.01, inputs).speed_mps
            assert abs(v) <= abs(previous)
            assert v * previous >= 0.0  # never through zero
            if previous == 0.0:
                assert v == 0.0 and math.copysign(1.0, v) == 1.0  # once stopped, held at +0.0
            previous = v
    if (140.0 * brake_bar / M_KG) * 2.5 > abs(v0_mps) + 0.1:
        assert previous == 0.0


# ---- lateral physics ---------------------------------------------------------------------------


def steer_at_speed(open_passat, v_mps: float, delta_rad: float, seconds: float):  # type: ignore[no-untyped-def]
    """Constant steer while a P throttle loop holds the speed; returns the final outputs."""
    vehicle = open_passat(VehicleInputs(steer_angle_rad=delta_rad), v0_mps=v_mps)
    out = vehicle.outputs()
    for _ in range(int(seconds * 1000)):
        throttle = min(100.0, max(0.0, 50.0 * (v_mps - out.speed_mps) + 5.0))
        out = vehicle.step(0.001, VehicleInputs(throttle_pct=throttle, steer_angle_rad=delta_rad))
    return out


def test_low_speed_yaw_rate_is_kinematic(open_passat) -> None:  # type: ignore[no-untyped-def]
    out = steer_at_speed(open_passat, 1.5, 0.2, 3.0)
    assert out.yaw_rate_radps == pytest.approx(out.speed_mps * math.tan(0.2) / L_M, rel=1e-9)


def test_yaw_rate_at_5_mps_is_about_v_tan_delta_over_l(open_passat) -> None:  # type: ignore[no-untyped-def]
    out = steer_at_speed(open_passat, 5.0, 0.05, 5.0)
    assert out.speed_mps == pytest.approx(5.0, abs=0.05)
    assert out.yaw_rate_radps == pytest.approx(out.speed_mps * math.tan(0.05) / L_M, rel=0.03)


def test_high_speed_yaw_rate_shows_understeer(open_passat) -> None:  # type: ignore[no-untyped-def]
    out = steer_at_speed(open_passat, 15.0, 0.02, 5.0)
    k_us = M_KG / L_M * (LR_M / CF - LF_M / CR)
    v = out.speed_mps
    assert out.yaw_rate_radps == pytest.approx(v * 0.02 / (L_M + k_us * v * v), rel=0.01)
    assert out.yaw_rate_radps < 0.93 * v * math.tan(0.02) / L_M


def test_kinematic_dynamic_blend_is_continuous(open_passat) -> None:  # type: ignore[no-untyped-def]
    """Through the 3..6 m/s blend both ways; downwards the dynamic states differ from kinematic."""
    steer = 0.1
    vehicle = open_passat(VehicleInputs(steer_angle_rad=steer), v0_mps=2.0)
    out = vehicle.outputs()
    worst_jump = 0.0
    while out.speed_mps < 8.0:
        previous = out
        out = vehicle.step(0.001, VehicleInputs(throttle_pct=20.0, steer_angle_rad=steer))
        worst_jump = max(worst_jump, abs(out.yaw_rate_radps - previous.yaw_rate_radps))
    # Understeer at 8 m/s: the dynamic yaw rate is well below the kinematic one.
    assert out.yaw_rate_radps < 0.98 * out.speed_mps * math.tan(steer) / L_M
    while out.speed_mps > 2.0:
        previous = out
        out = vehicle.step(0.001, VehicleInputs(brake_bar=8.0, steer_angle_rad=steer))
        worst_jump = max(worst_jump, abs(out.yaw_rate_radps - previous.yaw_rate_radps))
    # Smooth change with speed is < 5e-5 rad/s per 1 ms step; a hard model switch jumps > 2e-3.
    assert worst_jump < 2e-4
    assert vehicle.t_s < 40.0


def test_steering_rate_and_saturation_limits(open_passat) -> None:  # type: ignore[no-untyped-def]
    vehicle = open_passat()
    angles = [
        vehicle.step(0.001, VehicleInputs(steer_angle_rad=1.0)).steer_angle_rad_actual for _ in range(2000)
    ]
    steps = [b - a for a, b in itertools.pairwise([0.0, *angles])]
    assert max(steps) <= STEER_RATE_RADPS * 0.001 + 1e-12
    assert steps[0] == pytest.approx(STEER_RATE_RADPS * 0.001)  # the rate limit, not the lag, binds first
    assert max(angles) <= STEER_MAX_RAD + 1e-12
    assert angles[-1] == pytest.approx(STEER_MAX_RAD, rel=1e-6)


@settings(max_examples=30, deadline=None)
@given(requests=st.lists(st.floats(-2.0, 2.0), min_size=1, max_size=20))
def test_steering_limits_hold_for_any_request_sequence(
    passat_dir: Path, mapping: PlantMapping, requests: list[float]
) -> None:
    with FmuVehicle(passat_dir, mapping) as vehicle:
        previous = 0.0
        for request in requests:
            for _ in range(50):
                angle = vehicle.step(0.001, VehicleInputs(steer_angle_rad=request)).steer_angle_rad_actual
                assert abs(angle - previous) <= STEER_RATE_RADPS * 0.001 + 1e-12
                assert abs(angle) <= STEER_MAX_RAD + 1e-12
                previous = angle


def test_wheel_speeds_from_speed_and_yaw_rate(open_passat) -> None:  # type: ignore[no-untyped-def]
    out = steer_at_speed(open_passat, 2.0, 0.3, 3.0)
    r, v = out.yaw_rate_radps, out.speed_mps
    assert out.wheel_speed_rl_mps == pytest.approx(v - r * TRACK_M / 2, rel=1e-12)
    assert out.wheel_speed_rr_mps == pytest.approx(v + r * TRACK_M / 2, rel=1e-12)
    # Kinematic turn: the steered front axle runs on a larger radius than the rear one.
    assert out.wheel_speed_fl_mps > out.wheel_speed_rl_mps
    assert out.wheel_speed_fr_mps > out.wheel_speed_rr_mps
    front_axle = (out.wheel_speed_fl_mps + out.wheel_speed_fr_mps) / 2
    assert front_axle == pytest.approx(v / math.cos(0.3), rel=1e-9)


def test_pose_integrates_along_the_heading(open_passat) -> None:  # type: ignore[no-untyped-def]
    vehicle = open_passat(v0_mps=10.0, heading0_rad=math.pi / 2, x0_m=5.0, y0_m=-3.0)
    for _ in range(100):
        out = vehicle.step(0.01, VehicleInputs())
    assert out.x_m == pytest.approx(5.0, abs=1e-9)
    assert out.y_m == pytest.approx(-3.0 + out.distance_m, abs=1e-9)
    assert out.distance_m == pytest.approx(10.0 - 0.5 * (drag_n(10.0) + F_RR_FLAT_N) / M_KG, abs=0.005)
    assert out.heading_rad == pytest.approx(math.pi / 2)


def test_communication_step_is_split_into_1_ms_substeps(open_passat) -> None:  # type: ignore[no-untyped-def]
    inputs = VehicleInputs(throttle_pct=60.0, steer_angle_rad=0.1)
    fine, coarse = open_passat(), open_passat()
    for _ in range(100):
        a = fine.step(0.001, inputs)
    b = coarse.step(0.1, inputs)
    assert b.speed_mps == pytest.approx(a.speed_mps, rel=1e-12)
    assert b.steer_angle_rad_actual == pytest.approx(a.steer_angle_rad_actual, rel=1e-12)


# ---- mapping -----------------------------------------------------------------------------------


def write_mapping(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "plant.toml"
    path.write_text(text)
    return path


MINIMAL = """
[inputs]
throttle_pct = "throttle_pct"
brake_bar = "brake_bar"
steer_angle_rad = "steer_angle_rad"
[outputs]
speed_mps = "speed_mps"
accel_mps2 = "accel_mps2"
yaw_rate_radps = "yaw_rate_radps"
x_m = "x_m"
y_m = "y_m"
heading_rad = "heading_rad"
distance_m = "distance_m"
"""


@pytest.mark.parametrize(
    ("edit", "key"),
    [
        (
            lambda t: t.replace('throttle_pct = "throttle_pct"', 'throttle = "throttle_pct"'),
            r"\[inputs\]\.throttle",
        ),
        (lambda t: t.replace('speed_mps = "speed_mps"\n', ""), r"\[outputs\]\.speed_mps"),
        (
            lambda t: t.replace('brake_bar = "brake_bar"', 'brake_bar = {name = "brake_bar", scale = 0}'),
            r"\[inputs\]\.brake_bar\.scale",
        ),
        (
            lambda t: t.replace('brake_bar = "brake_bar"', 'brake_bar = {name = "brake_bar", scale = true}'),
            r"\[inputs\]\.brake_bar\.scale",
        ),
        (
            lambda t: t.replace('brake_bar = "brake_bar"', 'brake_bar = {nam = "brake_bar"}'),
            r"\[inputs\]\.brake_bar\.nam",
        ),
        (lambda t: t.replace('x_m = "x_m"', "x_m = 3"), r"\[outputs\]\.x_m"),
        (
            lambda t: t.replace('brake_bar = "brake_bar"', 'brake_bar = "throttle_pct"'),
            r"\[inputs\]\.brake_bar",
        ),
        (lambda t: t + "\n[plant]\nx = 1\n", r"\[plant\]"),
        (lambda t: t + "\n[parameters]\nmass_kg = 'heavy'\n", r"\[parameters\]\.mass_kg"),
        (lambda t: t + "\n[fallback]\ntrack_width_m = -1.0\n", r"\[fallback\]\.track_width_m"),
        (lambda t: t + "\n[inputs\n", "not valid TOML"),
    ],
)
def test_mapping_errors_name_the_file_and_key(tmp_path: Path, edit, key: str) -> None:  # type: ignore[no-untyped-def]
    path = write_mapping(tmp_path, edit(MINIMAL))
    with pytest.raises(MappingError, match=key) as info:
        load_mapping(path)
    assert str(path) in str(info.value)


def test_missing_mapping_file_is_named(tmp_path: Path) -> None:
    with pytest.raises(MappingError, match=r"nope\.toml"):
        load_mapping(tmp_path / "nope.toml")


def test_mapping_to_a_variable_the_fmu_lacks_is_refused(passat_dir: Path, tmp_path: Path) -> None:
    path = write_mapping(
        tmp_path, MINIMAL.replace('brake_bar = "brake_bar"', 'brake_bar = {name = "p_brake"}')
    )
    with pytest.raises(MappingError, match=r"\[inputs\]\.brake_bar.*'p_brake'"):
        FmuVehicle(passat_dir, load_mapping(path))


def test_mapping_an_input_role_to_an_output_is_refused(passat_dir: Path, tmp_path: Path) -> None:
    path = write_mapping(
        tmp_path, MINIMAL.replace('brake_bar = "brake_bar"', 'brake_bar = "brake_bar_actual"')
    )
    with pytest.raises(MappingError, match=r"brake_bar_actual.*expected a Real input"):
        FmuVehicle(passat_dir, load_mapping(path))


def test_scale_and_offset_convert_both_ways(passat_dir: Path) -> None:
    # As if the FMU took brake pressure in half-bars and reported speed in km/h.
    data = {
        "inputs": {
            "throttle_pct": "throttle_pct",
            "brake_bar": {"name": "brake_bar", "scale": 0.5},
            "steer_angle_rad": "steer_angle_rad",
        },
        "outputs": {
            role: role for role in ("accel_mps2", "yaw_rate_radps", "x_m", "y_m", "heading_rad", "distance_m")
        }
        | {"speed_mps": {"name": "speed_mps", "scale": 3.6, "offset": 1.0}},
    }
    mapping = parse_mapping(data, source="test")
    with FmuVehicle(passat_dir, mapping, {"v0_mps": 10.0}) as vehicle:
        out = vehicle.step(0.001, VehicleInputs(brake_bar=10.0))
        assert out.speed_mps == pytest.approx(vehicle.read("speed_mps") * 3.6 + 1.0)
        for _ in range(1000):
            vehicle.step(0.001, VehicleInputs(brake_bar=10.0))
        assert vehicle.read("brake_bar_actual") == pytest.approx(20.0, rel=1e-3)


def test_unmapped_optional_roles_fall_back(passat_dir: Path, tmp_path: Path) -> None:
    mapping = load_mapping(write_mapping(tmp_path, MINIMAL))
    inputs = VehicleInputs(throttle_pct=10.0, brake_bar=3.0, steer_angle_rad=0.2)
    with FmuVehicle(passat_dir, mapping, {"v0_mps": 2.0}) as vehicle:
        for _ in range(500):
            out = vehicle.step(0.001, inputs)
        assert out.wheel_speed_rl_mps == pytest.approx(out.speed_mps - out.yaw_rate_radps * TRACK_M / 2)
        assert out.wheel_speed_fr_mps == pytest.approx(out.speed_mps + out.yaw_rate_radps * TRACK_M / 2)
        assert out.brake_bar_actual == 3.0 and out.steer_angle_rad_actual == 0.2
        vehicle.step(0.001, VehicleInputs(grade_pct=0.0))
        with pytest.raises(ValueError, match="grade_pct"):
            vehicle.step(0.001, VehicleInputs(grade_pct=2.0))


def test_mapping_parameters_set_start_values(passat_dir: Path, tmp_path: Path) -> None:
    mapping = load_mapping(write_mapping(tmp_path, MINIMAL + "\n[parameters]\nmass_kg = 3300.0\n"))
    with FmuVehicle(passat_dir, mapping, {"v0_mps": 20.0}) as vehicle:
        out = vehicle.step(0.001, VehicleInputs())
    assert out.accel_mps2 == pytest.approx(-(drag_n(20.0) + 0.011 * 3300.0 * G) / 3300.0, rel=1e-3)


# ---- adapter -----------------------------------------------------------------------------------


def test_open_vehicle_uses_the_cache_and_default_mapping(fmu_cache: Path, passat_fmu: Path) -> None:
    with open_vehicle("passat", {"v0_mps": 3.0}, cache_dir=fmu_cache) as vehicle:
        assert vehicle.fmu_path == passat_fmu
        assert vehicle.outputs().speed_mps == 3.0
        out = vehicle.step(0.002, VehicleInputs())
        assert vehicle.t_s == pytest.approx(0.002)
        assert 0.0 < out.speed_mps < 3.0


def test_ready_made_fmu_needs_a_mapping(passat_fmu: Path) -> None:
    with pytest.raises(MappingError, match="needs a plant mapping"):
        open_vehicle(passat_fmu)
    with open_vehicle(passat_fmu, mapping=default_mapping_path()) as vehicle:
        assert vehicle.step(1.0, VehicleInputs(throttle_pct=50.0)).speed_mps > 0.0


def test_bad_parameter_is_reported_by_name(open_passat) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(FmuError, match="mass_kg = -1"):
        open_passat(mass_kg=-1.0)
    with pytest.raises(FmuError, match="v_dynamic_min_mps"):
        open_passat(v_dynamic_min_mps=2.0)


def test_unknown_start_value_is_refused_by_name(open_passat) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(MappingError, match="'mass'"):
        open_passat(mass=1.0)
    with pytest.raises(MappingError, match=r"speed_mps.*cannot take a start value"):
        open_passat(speed_mps=1.0)


def test_non_finite_input_is_refused_by_name(open_passat) -> None:  # type: ignore[no-untyped-def]
    vehicle = open_passat()
    with pytest.raises(FmuError, match="fmi2SetReal: throttle_pct = nan is not finite"):
        vehicle.step(0.001, VehicleInputs(throttle_pct=math.nan))


def test_step_size_checks_and_lifecycle(open_passat) -> None:  # type: ignore[no-untyped-def]
    vehicle = open_passat(v0_mps=1.0)
    before = vehicle.outputs()
    assert vehicle.step(0.0, VehicleInputs()) is before
    with pytest.raises(ValueError, match="dt_s"):
        vehicle.step(-0.001, VehicleInputs())
    with pytest.raises(ValueError, match="dt_s"):
        vehicle.step(math.nan, VehicleInputs())
    vehicle.close()
    vehicle.close()  # idempotent
    with pytest.raises(FmuError, match="after close"):
        vehicle.read("speed_mps")


def test_two_instances_are_independent(open_passat) -> None:  # type: ignore[no-untyped-def]
    a, b = open_passat(), open_passat(v0_mps=5.0)
    for _ in range(200):  # 5 m/s at 50 bar (4.3 m/s^2) stop in about 1.3 s
        a.step(0.01, VehicleInputs(throttle_pct=50.0))
        b.step(0.01, VehicleInputs(brake_bar=50.0))
    assert a.outputs().speed_mps > 1.0
    assert b.outputs().speed_mps == 0.0
