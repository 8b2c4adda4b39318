"""Calibration schema, canonical JSON with CRC-32, and refusal of bad calibrations by field."""

from __future__ import annotations

import copy
import importlib.util
import json
import math
import sys
import zlib
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bywire.ecu.calibration import (
    FORMAT,
    Calibration,
    CalibrationError,
    calibration_from_dict,
    calibration_to_dict,
    default_calibration,
    dumps_calibration,
    load_calibration,
    loads_calibration,
)

CALIBRATIONS_DIR = Path(__file__).resolve().parents[2] / "ecu" / "calibrations"


def _load_generator() -> Any:
    name = "bywire_tests_make_passat"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, CALIBRATIONS_DIR / "make_passat.py")
        assert spec is not None and spec.loader is not None
        mod = importlib.util.module_from_spec(spec)
        sys.modules[name] = mod
        spec.loader.exec_module(mod)
    return sys.modules[name]


make_passat = _load_generator()


@pytest.fixture
def doc() -> dict[str, Any]:
    """A valid calibration document (a fresh deep copy per test)."""
    return copy.deepcopy(make_passat.make_document())


def _refused(d: Any, field: str) -> CalibrationError:
    with pytest.raises(CalibrationError) as exc:
        calibration_from_dict(d, source="test.json")
    assert exc.value.field == field, str(exc.value)
    assert exc.value.source == "test.json"
    assert field in str(exc.value) and "test.json" in str(exc.value)
    return exc.value


def _with_crc(d: dict[str, Any]) -> bytes:
    canonical = json.dumps(d, sort_keys=True, separators=(",", ":"), ensure_ascii=True).encode()
    return json.dumps({**d, "crc32": zlib.crc32(canonical)}).encode()


class TestPackagedCalibration:
    def test_default_calibration_is_the_generated_passat(self) -> None:
        cal = default_calibration()
        assert cal == calibration_from_dict(make_passat.make_document())
        assert cal.format == FORMAT and cal.version >= 1
        assert cal.accel_min_mps2 == -4.5 and cal.accel_max_mps2 == 2.0  # seed 003 V-A

    def test_passat_json_is_up_to_date_with_its_generator(self) -> None:
        assert make_passat.main(["--check", "--out", str(CALIBRATIONS_DIR / "passat.json")]) == 0

    def test_generator_check_fails_on_a_stale_file(self, tmp_path: Path) -> None:
        stale = tmp_path / "passat.json"
        stale.write_bytes(
            (CALIBRATIONS_DIR / "passat.json").read_bytes().replace(b'"version": 1', b'"version": 2')
        )
        assert make_passat.main(["--check", "--out", str(stale)]) == 1

    def test_identification_is_imperfect_on_purpose(self) -> None:
        # The integrator must have work to do: the maps are not the plant's (1650 kg, 140 N/bar).
        assert make_passat.MASS_KG != 1650.0 and make_passat.BRAKE_GAIN_N_PER_BAR != 140.0

    def test_hold_pressure_holds_a_steep_slope_on_the_plant(self) -> None:
        cal = default_calibration()
        grade = 0.30  # 30 %: steeper than any public road
        slope_force_n = 1650.0 * 9.81 * math.sin(math.atan(grade))
        assert cal.hold_brake_bar * 140.0 > slope_force_n


class TestRoundTrip:
    def test_dict_round_trip(self) -> None:
        cal = default_calibration()
        assert calibration_from_dict(calibration_to_dict(cal)) == cal

    def test_bytes_round_trip_and_canonical_form(self) -> None:
        cal = default_calibration()
        data = dumps_calibration(cal)
        assert loads_calibration(data, "x") == cal
        d = json.loads(data)
        crc = d.pop("crc32")
        canonical = json.dumps(d, sort_keys=True, separators=(",", ":"), ensure_ascii=True).encode()
        assert crc == zlib.crc32(canonical)
        assert data == json.dumps({**d, "crc32": crc}, sort_keys=True, separators=(",", ":")).encode()
        assert isinstance(d["version"], int)

    def test_indented_file_has_the_same_crc(self) -> None:
        cal = default_calibration()
        pretty = dumps_calibration(cal, indent=1)
        assert b"\n" in pretty
        assert json.loads(pretty)["crc32"] == json.loads(dumps_calibration(cal))["crc32"]
        assert loads_calibration(pretty, "pretty") == cal

    def test_load_calibration_names_the_file(self, tmp_path: Path) -> None:
        path = tmp_path / "cal.json"
        path.write_bytes(dumps_calibration(default_calibration()))
        assert load_calibration(path) == default_calibration()
        path.write_bytes(dumps_calibration(default_calibration())[:-20])
        with pytest.raises(CalibrationError) as exc:
            load_calibration(path)
        assert exc.value.source == str(path)

    def test_missing_file_is_an_oserror(self, tmp_path: Path) -> None:
        with pytest.raises(FileNotFoundError):
            load_calibration(tmp_path / "nope.json")

    @settings(max_examples=30, deadline=None)
    @given(st.integers(1, 10**6), st.floats(0.0, 20.0), st.floats(0.0, 5.0))
    def test_any_valid_values_round_trip(self, version: int, ki: float, imax: float) -> None:
        d = make_passat.make_document()
        d.update(version=version, ki_per_s=ki, integrator_max_mps2=imax)
        cal = calibration_from_dict(d)
        assert loads_calibration(dumps_calibration(cal), "x") == cal


class TestBadDocuments:
    def test_unknown_top_level_key(self, doc: dict[str, Any]) -> None:
        doc["kp"] = 1.0
        err = _refused(doc, "kp")
        assert "unknown key" in str(err)

    def test_unknown_map_key(self, doc: dict[str, Any]) -> None:
        doc["brake_map"]["offset_bar"] = [0.0]
        _refused(doc, "brake_map.offset_bar")

    def test_missing_key(self, doc: dict[str, Any]) -> None:
        del doc["hold_brake_bar"]
        assert "missing" in str(_refused(doc, "hold_brake_bar"))

    def test_missing_map_key(self, doc: dict[str, Any]) -> None:
        del doc["coast_map"]["accel_mps2"]
        _refused(doc, "coast_map.accel_mps2")

    def test_not_an_object(self) -> None:
        _refused([1, 2], "")

    def test_wrong_format(self, doc: dict[str, Any]) -> None:
        doc["format"] = "bywire.calibration/0"
        _refused(doc, "format")

    @pytest.mark.parametrize("version", [0, -1, 1.0, True, "1"])
    def test_bad_version(self, doc: dict[str, Any], version: Any) -> None:
        doc["version"] = version
        _refused(doc, "version")

    @pytest.mark.parametrize("created", ["yesterday", "", 20250101])
    def test_bad_created(self, doc: dict[str, Any], created: Any) -> None:
        doc["created"] = created
        _refused(doc, "created")

    @pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
    def test_non_finite_scalar(self, doc: dict[str, Any], value: float) -> None:
        doc["ki_per_s"] = value
        assert "finite" in str(_refused(doc, "ki_per_s"))

    def test_non_finite_map_value(self, doc: dict[str, Any]) -> None:
        doc["throttle_map"]["pct"][2][5] = math.nan
        _refused(doc, "throttle_map.pct[2][5]")

    @pytest.mark.parametrize("value", [True, "2.0", None, [2.0]])
    def test_not_a_number(self, doc: dict[str, Any], value: Any) -> None:
        doc["accel_max_mps2"] = value
        assert "expected a number" in str(_refused(doc, "accel_max_mps2"))

    def test_throttle_row_not_monotone(self, doc: dict[str, Any]) -> None:
        row = doc["throttle_map"]["pct"][4]
        row[9] = row[8] - 1.0
        assert "non-decreasing" in str(_refused(doc, "throttle_map.pct[4][9]"))

    def test_brake_map_not_monotone(self, doc: dict[str, Any]) -> None:
        doc["brake_map"]["bar"][3] = doc["brake_map"]["bar"][2] - 0.5
        _refused(doc, "brake_map.bar[3]")

    def test_coast_map_rising(self, doc: dict[str, Any]) -> None:
        doc["coast_map"]["accel_mps2"][6] = doc["coast_map"]["accel_mps2"][5] + 0.05
        assert "non-increasing" in str(_refused(doc, "coast_map.accel_mps2[6]"))

    def test_axis_not_strictly_increasing(self, doc: dict[str, Any]) -> None:
        doc["throttle_map"]["speed_mps"][3] = doc["throttle_map"]["speed_mps"][2]
        assert "strictly increasing" in str(_refused(doc, "throttle_map.speed_mps[3]"))

    def test_brake_axis_must_start_at_coasting(self, doc: dict[str, Any]) -> None:
        doc["brake_map"]["decel_mps2"][0] = 0.1
        _refused(doc, "brake_map.decel_mps2[0]")

    def test_throttle_grid_wrong_row_count(self, doc: dict[str, Any]) -> None:
        doc["throttle_map"]["pct"].pop()
        assert "rows" in str(_refused(doc, "throttle_map.pct"))

    def test_throttle_grid_wrong_row_length(self, doc: dict[str, Any]) -> None:
        doc["throttle_map"]["pct"][7].append(100.0)
        _refused(doc, "throttle_map.pct[7]")

    def test_brake_map_length_mismatch(self, doc: dict[str, Any]) -> None:
        doc["brake_map"]["bar"].pop()
        _refused(doc, "brake_map.bar")

    def test_coast_map_length_mismatch(self, doc: dict[str, Any]) -> None:
        doc["coast_map"]["accel_mps2"].append(-1.0)
        _refused(doc, "coast_map.accel_mps2")

    def test_axis_too_short(self, doc: dict[str, Any]) -> None:
        doc["coast_map"]["speed_mps"] = [0.0]
        doc["coast_map"]["accel_mps2"] = [-0.1]
        _refused(doc, "coast_map.speed_mps")

    def test_map_value_out_of_range(self, doc: dict[str, Any]) -> None:
        doc["throttle_map"]["pct"][0][16] = 100.5
        _refused(doc, "throttle_map.pct[0][16]")
        doc["throttle_map"]["pct"][0][16] = 100.0
        doc["brake_map"]["bar"][-1] = 250.0
        _refused(doc, f"brake_map.bar[{len(doc['brake_map']['bar']) - 1}]")

    def test_stop_decel_beyond_the_request_clamp(self, doc: dict[str, Any]) -> None:
        doc["disable_decel_mps2"] = 5.0  # > 4.5 = -accel_min
        assert "accel_min" in str(_refused(doc, "disable_decel_mps2"))

    def test_brake_map_must_reach_the_strongest_request(self, doc: dict[str, Any]) -> None:
        doc["brake_map"]["decel_mps2"] = [0.0, 1.0, 2.0, 4.0]
        doc["brake_map"]["bar"] = [0.0, 10.0, 20.0, 40.0]
        _refused(doc, "brake_map.decel_mps2[3]")


# Every scalar with its inclusive range; values just outside must be refused, the bounds accepted.
RANGES = {
    "accel_min_mps2": (-10.0, -0.5),
    "accel_max_mps2": (0.5, 5.0),
    "jerk_max_mps3": (0.5, 50.0),
    "steer_max_rad": (0.01, 0.6),
    "steer_rate_max_radps": (0.01, 3.0),
    "pause_decel_mps2": (0.5, 4.5),  # upper bound: -accel_min of the Passat calibration
    "disable_decel_mps2": (0.5, 4.5),
    "safe_stop_decel_mps2": (0.5, 4.5),
    "hold_brake_bar": (5.0, 200.0),
    "standstill_speed_mps": (0.01, 1.0),
    "stop_margin_s": (0.0, 30.0),
    "driver_torque_threshold_nm": (0.1, 20.0),
    "driver_throttle_threshold_pct": (0.1, 50.0),
    "ki_per_s": (0.0, 20.0),
    "integrator_max_mps2": (0.0, 5.0),
    "switch_freeze_s": (0.0, 5.0),
    "throttle_lag_s": (0.0, 2.0),
    "brake_lag_s": (0.0, 2.0),
    "pedal_hysteresis_mps2": (0.0, 1.0),
}


def _consistent(doc: dict[str, Any], key: str, value: float) -> dict[str, Any]:
    doc[key] = value
    if key == "accel_min_mps2":  # the stop decelerations must stay inside the request clamp
        for k in ("pause_decel_mps2", "disable_decel_mps2", "safe_stop_decel_mps2"):
            doc[k] = min(doc[k], -value)
    return doc


def test_every_scalar_has_a_range_test() -> None:
    numeric = {k for k, v in make_passat.make_document().items() if isinstance(v, float)}
    assert numeric == set(RANGES)


@pytest.mark.parametrize("key", sorted(RANGES))
def test_range_boundaries(key: str, doc: dict[str, Any]) -> None:
    lo, hi = RANGES[key]
    for ok in (lo, hi):
        calibration_from_dict(_consistent(copy.deepcopy(doc), key, ok))
    for bad in (lo - 1e-6, hi + 1e-6):
        d = _consistent(copy.deepcopy(doc), key, bad)
        err = _refused(d, key)
        assert "out of range" in str(err) or "exceeds" in str(err)


class TestBadBytes:
    def test_bad_crc(self) -> None:
        d = json.loads(dumps_calibration(default_calibration()))
        d["ki_per_s"] = 1.6  # edited without updating the CRC
        with pytest.raises(CalibrationError) as exc:
            loads_calibration(json.dumps(d).encode(), "edited.json")
        assert exc.value.field == "crc32" and "mismatch" in str(exc.value)

    def test_missing_crc(self) -> None:
        d = json.loads(dumps_calibration(default_calibration()))
        del d["crc32"]
        with pytest.raises(CalibrationError) as exc:
            loads_calibration(json.dumps(d).encode(), "nocrc.json")
        assert exc.value.field == "crc32"

    @pytest.mark.parametrize("crc", [-1, 2**32, "0x1234", 1.5, True])
    def test_crc_of_wrong_type(self, crc: Any) -> None:
        d = json.loads(dumps_calibration(default_calibration()))
        d["crc32"] = crc
        with pytest.raises(CalibrationError) as exc:
            loads_calibration(json.dumps(d).encode(), "x.json")
        assert exc.value.field == "crc32"

    def test_wrong_format_is_refused_before_the_crc(self) -> None:
        d = json.loads(dumps_calibration(default_calibration()))
        d["format"] = "something/else"
        with pytest.raises(CalibrationError) as exc:
            loads_calibration(json.dumps(d).encode(), "x.json")
        assert exc.value.field == "format"

    def test_truncated_json_names_line_and_column(self) -> None:
        data = dumps_calibration(default_calibration(), indent=1)
        cut = data[: len(data) // 2]
        line = cut.count(b"\n") + 1
        with pytest.raises(CalibrationError) as exc:
            loads_calibration(cut, "cut.json")
        assert exc.value.source == "cut.json"
        assert f"line {line}" in str(exc.value) and "column" in str(exc.value)

    def test_not_utf8(self) -> None:
        with pytest.raises(CalibrationError, match="UTF-8"):
            loads_calibration(b'{"format": "\xff"}', "bin.json")

    def test_top_level_not_an_object(self) -> None:
        with pytest.raises(CalibrationError, match="JSON object"):
            loads_calibration(b"[1, 2, 3]", "list.json")

    def test_duplicate_key(self) -> None:
        data = dumps_calibration(default_calibration())
        dup = data[:-1] + b',"ki_per_s":9.0}'
        with pytest.raises(CalibrationError, match="duplicate key 'ki_per_s'"):
            loads_calibration(dup, "dup.json")

    def test_nan_with_a_valid_crc_is_refused_by_field(self, doc: dict[str, Any]) -> None:
        doc["hold_brake_bar"] = math.nan
        with pytest.raises(CalibrationError) as exc:
            loads_calibration(_with_crc(doc), "nan.json")
        assert exc.value.field == "hold_brake_bar"

    def test_validation_runs_after_a_good_crc(self, doc: dict[str, Any]) -> None:
        doc["brake_map"]["bar"][5] = 0.0
        with pytest.raises(CalibrationError) as exc:
            loads_calibration(_with_crc(doc), "mono.json")
        assert exc.value.field == "brake_map.bar[5]"

    @settings(max_examples=60, deadline=None)
    @given(st.data())
    def test_any_single_byte_change_is_refused(self, data: st.DataObject) -> None:
        good = dumps_calibration(default_calibration())
        i = data.draw(st.integers(0, len(good) - 1))
        b = data.draw(st.integers(0, 255).filter(lambda b: b != good[i]))
        bad = good[:i] + bytes([b]) + good[i + 1 :]
        try:
            cal = loads_calibration(bad, "flip.json")
        except CalibrationError:
            return
        # A change that keeps the document equal (e.g. 2.0 -> 2.00 is impossible in canonical
        # JSON; whitespace between tokens is) must decode to the same calibration.
        assert cal == default_calibration()


def test_calibration_is_immutable() -> None:
    cal = default_calibration()
    with pytest.raises(AttributeError):
        cal.ki_per_s = 0.0  # type: ignore[misc]
    assert isinstance(cal, Calibration)


def test_error_is_a_value_error_with_field_and_source() -> None:
    err = CalibrationError("brake_map.bar[3]", "cal.json", "expected non-decreasing values")
    assert isinstance(err, ValueError)
    assert str(err) == "cal.json: brake_map.bar[3]: expected non-decreasing values"
