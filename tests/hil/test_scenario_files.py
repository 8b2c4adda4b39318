"""Scenario files: strict parsing, errors that name the file and the field."""

from __future__ import annotations

from pathlib import Path

import pytest

from bywire.hil.scenario import (
    ScenarioError,
    builtin_scenarios,
    load_scenario,
    parse_scenario,
    ramp_value,
    step_value,
)

BASE = {"name": "x", "duration_s": 5.0, "host": {"accel_profile": [[0, 0.0], [1, 1.0]]}}


def test_every_shipped_scenario_parses() -> None:
    for name in builtin_scenarios():
        assert load_scenario(name).name == name


@pytest.mark.parametrize(
    ("patch", "path", "words"),
    [
        ({"duration_s": "long"}, "duration_s", "expected a number"),
        ({"durations": 3}, "durations", "unknown key"),
        ({"faults": [{"kind": "estop", "at_s": 1.0, "mode": "STOP"}]}, "faults[0].mode", "expected one of"),
        ({"faults": [{"kind": "meteor", "at_s": 1.0}]}, "faults[0].kind", "expected one of"),
        ({"faults": [{"kind": "corrupt", "at_s": 1.0}]}, "faults[0].frames", "needs the list of frames"),
        ({"faults": [{"kind": "estop", "at_s": -1.0, "mode": "RUN"}]}, "faults[0].at_s", ">= 0"),
        ({"host": {"accel_profile": [[0, 0.0], [0, 1.0]]}}, "host.accel_profile[1]", "times must increase"),
        ({"host": {"accel_profile": [[0, 50.0]]}}, "host.accel_profile[0]", "not physical"),
        ({"host": {"mode": "drive"}}, "host.speed_profile", "drive mode needs"),
        ({"checks": [{"metric": "x", "max": 1, "min": 0}]}, "checks[0]", "exactly one of"),
        ({"vehicle": {"v0_mps": 500}}, "vehicle.v0_mps", "<= 70"),
        ({"checks": [{"metric": "x", "max": 10, "hil": 5}]}, "checks[0].hil", "only be looser"),
        ({"checks": [{"metric": "x", "min": 10, "hil": 20}]}, "checks[0].hil", "only be looser"),
        ({"checks": [{"metric": "x", "equals": "A", "hil": "B"}]}, "checks[0].hil", "max and min"),
        ({"checks": [{"metric": "x", "max": 10, "hil": "soon"}]}, "checks[0].hil", "expected a number"),
    ],
)
def test_bad_fields_are_named(patch: dict, path: str, words: str) -> None:
    data = {**BASE, **patch}
    with pytest.raises(ScenarioError) as err:
        parse_scenario(data, "bad.yaml")
    assert err.value.path == path
    assert str(err.value).startswith(f"bad.yaml: {path}: ")
    assert words in str(err.value)


def test_unknown_scenario_lists_the_shipped_ones() -> None:
    with pytest.raises(ScenarioError, match="accel_steps"):
        load_scenario("no_such_scenario")


def test_broken_yaml_names_the_file(tmp_path: Path) -> None:
    path = tmp_path / "broken.yaml"
    path.write_text("name: [unclosed\n")
    with pytest.raises(ScenarioError, match=r"broken\.yaml"):
        load_scenario(str(path))


def test_toml_scenarios_work_too(tmp_path: Path) -> None:
    path = tmp_path / "t.toml"
    path.write_text('name = "t"\nduration_s = 2.0\n[host]\naccel_profile = [[0, 0.0], [1, 0.5]]\n')
    assert load_scenario(str(path)).accel_profile == ((0.0, 0.0), (1.0, 0.5))


def test_profiles() -> None:
    profile = ((0.0, 1.0), (2.0, 3.0))
    assert step_value(profile, -1.0, default=7.0) == 7.0
    assert step_value(profile, 1.9) == 1.0 and step_value(profile, 2.0) == 3.0
    assert ramp_value(profile, 1.0) == pytest.approx(2.0)
    assert ramp_value(profile, 5.0) == 3.0 and ramp_value((), 1.0, default=4.0) == 4.0


def test_a_check_may_allow_more_in_hil() -> None:
    from bywire.hil.evaluate import run_check

    scenario = parse_scenario({**BASE, "checks": [{"metric": "detect_ms", "max": 41, "hil": 120}]}, "x.yaml")
    (check,) = scenario.checks
    sil = run_check(check, {"detect_ms": 70.0}, "sil")
    hil = run_check(check, {"detect_ms": 70.0}, "hil")
    assert (sil["passed"], sil["limit"]) == (False, 41)
    assert (hil["passed"], hil["limit"]) == (True, 120)
    assert not run_check(check, {"detect_ms": 121.0}, "hil")["passed"]


BAD_AT_LINES = """\
name: x
duration_s: 5.0
host:
  accel_profile: [[0, 0.0], [1, 1.0]]
faults:
  - {kind: estop, at_s: 1.0, mode: RUN}
  - kind: estop
    at_s: soon
    mode: RUN
"""


@pytest.mark.parametrize(
    ("change", "where"),
    [
        (("", ""), "bad.yaml:8: faults[1].at_s: expected a number"),
        (("duration_s: 5.0", "duration_s: long"), "bad.yaml:2: duration_s: expected a number"),
        (("host:", "hots: 1\nhost:"), "bad.yaml:3: hots: unknown key"),
        (("[1, 1.0]]", "[0, 1.0]]"), "bad.yaml:4: host.accel_profile[1]: times must increase"),
    ],
)
def test_a_yaml_scenario_names_the_line_of_the_bad_field(
    tmp_path: Path, change: tuple[str, str], where: str
) -> None:
    """As compilers and linters do: `file:line: field: what` (an editor jumps there)."""
    path = tmp_path / "bad.yaml"
    text = BAD_AT_LINES.replace(*change)
    if change[0]:  # only the one change: the fault on line 8 repaired
        text = text.replace("at_s: soon", "at_s: 2.0")
    path.write_text(text)
    with pytest.raises(ScenarioError) as err:
        load_scenario(str(path))
    assert str(err.value).startswith(f"{tmp_path}/{where}"), str(err.value)
    assert err.value.line == int(where.split(":")[1])


def test_yaml_line_finds_the_deepest_part_that_is_there() -> None:
    from bywire.schema import yaml_line

    assert yaml_line(BAD_AT_LINES, "faults[1].mode") == 9
    assert yaml_line(BAD_AT_LINES, "faults[1].colour") == 7  # the item: the key is not there
    assert yaml_line(BAD_AT_LINES, "faults[7].at_s") == 5  # no such item: the list
    assert yaml_line(BAD_AT_LINES, "nothing") is None
    assert yaml_line("name: [unclosed\n", "name") is None
