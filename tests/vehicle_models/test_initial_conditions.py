"""Initial conditions through the plant mapping's [initial] table, and an FMU that is not ours.

The vendor car (tests/vendor_fmu.py) names and scales everything otherwise: km/h, Pa, degrees, a
pedal fraction, its initial speed in the parameter ``vx_init``. Our own names reach it only through
its mapping file.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import pytest
from fmpy import read_model_description
from vendor_fmu import VENDOR_MAPPING, mapping_without_initial, vendor_fmu

from bywire.vehicle_models import (
    FmuVehicle,
    InitialConditions,
    MappingError,
    VehicleInputs,
    default_mapping_path,
    ensure_fmu,
    load_mapping,
    parse_mapping,
)

KMH_PER_MPS = 3.6

MINIMAL = {
    "inputs": {"throttle_pct": "pedal", "brake_bar": "p_brake", "steer_angle_rad": "delta_req"},
    "outputs": {
        "speed_mps": "vx",
        "accel_mps2": "ax",
        "yaw_rate_radps": "yaw_rate",
        "x_m": "pos_x",
        "y_m": "pos_y",
        "heading_rad": "psi",
        "distance_m": "odometer",
    },
}


@pytest.fixture(scope="module")
def fmu() -> Path:
    return vendor_fmu()


def with_initial(initial: object, **tables: object) -> dict[str, object]:
    return {**MINIMAL, "initial": initial, **tables}


# ---- the [initial] table -----------------------------------------------------------------------


def test_initial_takes_a_name_or_a_converted_variable() -> None:
    plain = parse_mapping(with_initial({"speed_mps": "v_init"}))
    assert plain.initial_start_values({"speed_mps": 12.5}) == {
        "v_init": (12.5, "<mapping>: [initial].speed_mps")
    }
    kmh = parse_mapping(
        with_initial({"speed_mps": {"name": "vx_init", "scale": 1 / KMH_PER_MPS}}), "car.toml"
    )
    ((name, (value, where)),) = kmh.initial_start_values({"speed_mps": 10.0}).items()
    assert (name, where) == ("vx_init", "car.toml: [initial].speed_mps")
    assert value == pytest.approx(36.0)


def test_unmapped_initial_condition_may_only_be_zero() -> None:
    mapping = parse_mapping(MINIMAL, source="cars/vendor.toml")
    assert mapping.initial_start_values({"speed_mps": 0.0}) == {}
    with pytest.raises(MappingError) as info:
        mapping.initial_start_values({"speed_mps": 10.0})
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith("cars/vendor.toml: [initial].speed_mps is not mapped")
    assert "speed_mps = 10" in message


@pytest.mark.parametrize(
    ("initial", "extra", "key"),
    [
        ({"x_m": "x0"}, {}, r"\[initial\]\.x_m: unknown role"),
        ({"speed_mps": {"name": "v0", "scale": 0}}, {}, r"\[initial\]\.speed_mps\.scale"),
        ({"speed_mps": 3}, {}, r"\[initial\]\.speed_mps"),
        ({"speed_mps": "pedal"}, {}, r"\[initial\]\.speed_mps: variable 'pedal' is an input"),
        ({"speed_mps": "v0"}, {"parameters": {"v0": 1.0}}, r"\[initial\]\.speed_mps: .*\[parameters\]"),
        ("v0", {}, r"initial: must be a table"),
    ],
)
def test_initial_table_errors_name_the_file_and_key(initial: object, extra: dict, key: str) -> None:
    with pytest.raises(MappingError, match=key) as info:
        parse_mapping(with_initial(initial, **extra), source="car.toml")
    assert str(info.value).startswith("car.toml: ")


def test_bundled_passat_mapping_starts_the_car_through_initial() -> None:
    mapping = load_mapping(default_mapping_path("passat"))
    assert mapping.initial["speed_mps"].name == "v0_mps"
    with FmuVehicle(ensure_fmu("passat"), mapping, initial=InitialConditions(speed_mps=12.5)) as car:
        assert car.outputs().speed_mps == 12.5
        assert car.read("v0_mps") == 12.5


def test_initial_variable_must_be_settable_before_initialisation() -> None:
    # The passat's speed_mps is a calculated output: FMI 2.0 sec. 4.2.4 lets no one set it then.
    data = tomllib.loads(default_mapping_path("passat").read_text())
    data["initial"] = {"speed_mps": "speed_mps"}
    mapping = parse_mapping(data, source="passat.toml")
    with pytest.raises(
        MappingError, match=r"passat.toml: \[initial\]\.speed_mps: .*'speed_mps'.*cannot take"
    ):
        FmuVehicle(ensure_fmu("passat"), mapping, initial=InitialConditions(speed_mps=5.0))


# ---- the vendor car ----------------------------------------------------------------------------


def test_vendor_car_shares_no_variable_name_with_ours(fmu: Path) -> None:
    ours = {v.name for v in read_model_description(str(ensure_fmu("passat"))).modelVariables}
    theirs = {v.name for v in read_model_description(str(fmu)).modelVariables}
    assert ours.isdisjoint(theirs)


def test_vendor_car_c_table_matches_its_model_description(fmu: Path) -> None:
    # Every start value read back through its value reference: the C table's order is the XML's.
    starts = {
        v.name: float(v.start) for v in read_model_description(str(fmu)).modelVariables if v.start is not None
    }
    assert len(starts) == 23
    with FmuVehicle(fmu, load_mapping(VENDOR_MAPPING)) as car:
        assert {name: car.read(name) for name in starts} == starts


def test_vendor_car_speaks_its_units_through_the_mapping(fmu: Path) -> None:
    mapping = load_mapping(VENDOR_MAPPING)
    inputs = VehicleInputs(
        throttle_pct=40.0, brake_bar=2.0, steer_angle_rad=0.05, grade_pct=3.0, wind_mps=5.0
    )
    with FmuVehicle(fmu, mapping, initial=InitialConditions(speed_mps=10.0)) as car:
        assert car.read("vx_init") == pytest.approx(36.0)
        assert car.outputs().speed_mps == pytest.approx(10.0)
        for _ in range(1000):
            out = car.step(0.001, inputs)
        assert car.read("pedal") == pytest.approx(0.4)
        assert car.read("p_brake") == pytest.approx(2.0e5)
        assert car.read("delta_req") == pytest.approx(math.degrees(0.05))
        assert car.read("gradient") == pytest.approx(0.03)
        assert car.read("headwind") == pytest.approx(18.0)
        assert out.speed_mps == pytest.approx(car.read("vx") / KMH_PER_MPS)
        assert out.yaw_rate_radps == pytest.approx(math.radians(car.read("yaw_rate")))
        assert out.heading_rad == pytest.approx(math.radians(car.read("psi")))
        assert out.distance_m == pytest.approx(car.read("odometer") * 1000.0)
        assert 9.0 < out.distance_m < 12.0  # about a second at about 10 m/s
        # Unmapped: derived from speed and yaw rate, and the commanded values.
        assert out.wheel_speed_fr_mps == pytest.approx(out.speed_mps + out.yaw_rate_radps * 1.55 / 2)
        assert (out.brake_bar_actual, out.steer_angle_rad_actual) == (2.0, 0.05)


def test_vendor_car_cannot_start_moving_without_initial(fmu: Path, tmp_path: Path) -> None:
    path = mapping_without_initial(tmp_path)
    mapping = load_mapping(path)
    with FmuVehicle(fmu, mapping, initial=InitialConditions(speed_mps=0.0)) as car:
        assert car.outputs().speed_mps == 0.0
    with pytest.raises(MappingError) as info:
        FmuVehicle(fmu, mapping, initial=InitialConditions(speed_mps=10.0))
    assert str(info.value) == (
        f"{path}: [initial].speed_mps is not mapped, so the FMU cannot start at speed_mps = 10;"
        " map it to the FMU's start variable or start at 0"
    )


def test_a_wrong_initial_scale_is_caught_at_the_start(fmu: Path, tmp_path: Path) -> None:
    # km/h taken for m/s: the car would start at 2.8 m/s where the scenario asked for 10.
    path = tmp_path / "wrong.toml"
    path.write_text(
        VENDOR_MAPPING.read_text().replace(
            'speed_mps = { name = "vx_init", scale = 0.2777777777777778 }', 'speed_mps = "vx_init"'
        )
    )
    with pytest.raises(
        MappingError, match=r"starts at speed_mps = 2\.777.*not the requested 10; check \[initial\]"
    ):
        FmuVehicle(fmu, load_mapping(path), initial=InitialConditions(speed_mps=10.0))


def test_the_fmus_own_start_value_is_checked_too(fmu: Path, tmp_path: Path) -> None:
    # No [initial], but the FMU starts at 36 km/h of its own: a scenario starting at rest is refused.
    path = mapping_without_initial(tmp_path)
    path.write_text(path.read_text() + "\n[parameters]\nvx_init = 36.0\n")
    with pytest.raises(MappingError, match=r"starts at speed_mps = 10, not the requested 0; map \[initial\]"):
        FmuVehicle(fmu, load_mapping(path), initial=InitialConditions(speed_mps=0.0))
