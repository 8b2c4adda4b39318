"""Fuzzing the file decoders: calibration files and scenario files.

Whatever bytes arrive (a truncated flash, a bit-rotted file, a hand edit gone wrong), the decoder
either returns a validated object or raises its own documented error naming the file and field —
never anything else, never a silently wrong object.
"""

from __future__ import annotations

import json

import yaml
from fuzz_util import mutate
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bywire.ecu.calibration import CalibrationError, default_calibration, dumps_calibration, loads_calibration
from bywire.hil.scenario import ScenarioError, builtin_scenarios, parse_scenario

GOOD_CAL = dumps_calibration(default_calibration())
GOOD_SCENARIO = yaml.safe_load(builtin_scenarios()["estop_pause"].read_text())


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.binary(max_size=2048))
def test_random_bytes_are_refused_as_calibration(data: bytes) -> None:
    try:
        loads_calibration(data, "fuzz.json")
    except CalibrationError as exc:
        assert exc.source == "fuzz.json"
    else:
        raise AssertionError("random bytes accepted as a calibration")


@settings(max_examples=300, deadline=None)
@given(st.data())
def test_mutated_calibrations_are_refused_or_identical(data: st.DataObject) -> None:
    raw = bytearray(GOOD_CAL)
    n = data.draw(st.integers(1, 4))
    for _ in range(n):
        kind = data.draw(st.sampled_from(["flip", "cut", "insert"]))
        i = data.draw(st.integers(0, max(0, len(raw) - 1)))
        if kind == "flip" and raw:
            raw[i] ^= 1 << data.draw(st.integers(0, 7))
        elif kind == "cut":
            del raw[i:]
        else:
            raw[i:i] = data.draw(st.binary(min_size=1, max_size=4))
    try:
        cal = loads_calibration(bytes(raw), "mutated.json")
    except CalibrationError:
        return
    # Accepted only if the mutation did not change the content (e.g. whitespace inserted).
    assert cal == default_calibration()


@settings(max_examples=300, deadline=None)
@given(st.data())
def test_mutated_scenarios_parse_or_name_the_field(data: st.DataObject) -> None:
    doc = mutate(GOOD_SCENARIO, data.draw)
    try:
        scenario = parse_scenario(doc, "fuzz.yaml")
    except ScenarioError as exc:
        assert str(exc).startswith("fuzz.yaml")
    else:
        assert scenario.duration_s > 0 and scenario.name


def test_good_files_still_load() -> None:
    assert loads_calibration(GOOD_CAL, "good.json") == default_calibration()
    assert json.loads(GOOD_CAL)["crc32"]
    assert parse_scenario(GOOD_SCENARIO, "good.yaml").name == "estop_pause"
