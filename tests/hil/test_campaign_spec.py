"""Campaign files, their expansion into runs, the fields a run sets, the results table and the stopping
distance bound: everything of a campaign but running it (tests/hil/test_campaign_runs.py)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from bywire.cli import main
from bywire.ecu.calibration import default_calibration
from bywire.hil.campaign.spec import CampaignError, builtin_campaigns, expand, load_campaign, parse_campaign
from bywire.hil.campaign.stop_bound import stop_distance_bound
from bywire.hil.campaign.store import build_table
from bywire.hil.scenario import ScenarioError, load_scenario
from bywire.hil.scenario_overrides import OverrideError, apply_overrides, format_assignment, parse_assignment


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "c.yaml"
    path.write_text(text, encoding="utf-8")
    return path


def test_every_shipped_campaign_loads_and_expands_to_checked_runs() -> None:
    names = builtin_campaigns()
    assert {"smoke", "faults", "platoon", "urban", "v2v_fuzz"} <= set(names)
    for name in names:
        _, runs, _ = load_campaign(name)
        assert runs, name
        assert len({r.run_id for r in runs}) == len(runs), f"{name}: a run twice"
    _, smoke, _ = load_campaign("smoke")
    assert 20 <= len(smoke) <= 48  # a few dozen


def test_a_grid_expands_to_every_combination_last_field_fastest(tmp_path: Path) -> None:
    path = _write(
        tmp_path,
        "name: g\nsweeps:\n  - scenario: heartbeat_loss\n    grid:\n"
        "      vehicle.v0_mps: [5, 10]\n      faults[0].at_s: [1.0, 2.0, 3.0]\n",
    )
    _, runs, _ = load_campaign(str(path))
    assert [(r.params["vehicle.v0_mps"], r.params["faults[0].at_s"]) for r in runs] == [
        (5, 1.0), (5, 2.0), (5, 3.0), (10, 1.0), (10, 2.0), (10, 3.0)
    ]  # fmt: skip
    assert [r.index for r in runs] == list(range(6))


def test_draws_depend_on_the_seed_and_the_run_only(tmp_path: Path) -> None:
    text = (
        "name: d\nseed: {seed}\nsweeps:\n  - scenario: accel_steps\n    sample:\n      runs: 5\n"
        "      params:\n"
        "        plant.noise.accel_mps2: {{uniform: [0.0, 0.1]}}\n        seed: {{integer: [1, 100]}}\n"
    )
    one = load_campaign(str(_write(tmp_path, text.format(seed=3))))[1]
    again = load_campaign(str(_write(tmp_path, text.format(seed=3))))[1]
    other = load_campaign(str(_write(tmp_path, text.format(seed=4))))[1]
    assert [r.params for r in one] == [r.params for r in again]
    assert [r.params for r in one] != [r.params for r in other]
    assert all(0.0 <= r.params["plant.noise.accel_mps2"] <= 0.1 for r in one)
    assert all(isinstance(r.params["seed"], int) and 1 <= r.params["seed"] <= 100 for r in one)


def test_shared_leader_profiles_expand_to_every_file(tmp_path: Path) -> None:
    from tests.shared_data import shared_data_dir

    folder = shared_data_dir() / "platoon"
    if not folder.is_dir():
        pytest.skip(f"the shared platoon data is not at {folder}")
    path = _write(
        tmp_path,
        "name: p\nsweeps:\n  - scenario: platoon_sinusoid\n"
        "    set: {'world.vehicles[0].driver': {kind: scripted, replay: true}}\n"
        "    grid:\n      leader_profile: ['shared:platoon/*/*.csv']\n",
    )
    _, runs, _ = load_campaign(str(path))
    assert len(runs) == len(list(folder.glob("*/*.csv")))
    assert all(r.options["leader_profile"].startswith("shared:platoon/") for r in runs)


@pytest.mark.parametrize(
    ("text", "line", "where", "what"),
    [
        ("name: x\nsweeps:\n  - scenario: nope\n", 3, "sweeps[0].scenario", "unknown scenario"),
        (
            "name: x\nsweeps:\n  - scenario: heartbeat_loss\n    grid:\n      vehicle.v0_mps: 5\n",
            5,
            "sweeps[0].grid.vehicle.v0_mps",
            "non-empty list",
        ),
        (
            "name: x\nsweeps:\n  - scenario: heartbeat_loss\n    sample:\n      runs: 2\n      params:\n"
            "        seed: {gauss: [1, 2]}\n",
            7,
            "sweeps[0].sample.params.seed",
            "expected one of",
        ),
        (
            "name: x\nsweeps:\n  - scenario: heartbeat_loss\n    colour: red\n",
            4,
            "sweeps[0].colour",
            "unknown key",
        ),
        (
            "name: x\nsweeps:\n  - scenario: heartbeat_loss\n    grid:\n      vehicle.v0_mps: [5, 500]\n",
            3,
            "sweeps[0]",
            "run 1 (vehicle.v0_mps=500): vehicle.v0_mps: expected a number <= 70.0",
        ),
        (
            "name: x\nsweeps:\n  - scenario: heartbeat_loss\n    checks:\n      - {metric: m, most: 3}\n",
            5,
            "sweeps[0].checks[0]",
            "exactly one of",
        ),
    ],
)
def test_a_bad_campaign_is_refused_with_its_file_line_and_field(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], text: str, line: int, where: str, what: str
) -> None:
    path = _write(tmp_path, text)
    assert main(["campaign", "run", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"error: {path}:{line}: {where}"), err
    assert what in err, err
    assert not (tmp_path / "out").exists()  # refused before anything ran


def test_a_campaign_needs_an_output_folder_and_a_real_address(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["campaign", "run", "smoke"]) == 2
    assert "--out DIR" in capsys.readouterr().err
    assert main(["campaign", "run", "smoke", "--out", str(tmp_path / "o"), "--address", "http://x:1"]) == 2
    assert "expected ray://HOST:PORT, auto or local" in capsys.readouterr().err


def test_overrides_set_add_and_remove_fields_and_refuse_what_is_not_there() -> None:
    data = {"vehicle": {"v0_mps": 15.0}, "faults": [{"at_s": 4.0, "kind": "heartbeat_mute"}], "seed": 1}
    out = apply_overrides(
        data, {"vehicle.v0_mps": 20.0, "faults[0].at_s": 2.5, "plant.noise.accel_mps2": 0.1, "seed": None}
    )
    assert out == {
        "vehicle": {"v0_mps": 20.0},
        "faults": [{"at_s": 2.5, "kind": "heartbeat_mute"}],
        "plant": {"noise": {"accel_mps2": 0.1}},
    }
    assert data["vehicle"]["v0_mps"] == 15.0  # a copy
    with pytest.raises(OverrideError, match=r"there is no faults\[1\] \(the list has 1 items\)"):
        apply_overrides(data, {"faults[1].at_s": 1.0})
    with pytest.raises(OverrideError, match="not a field path"):
        apply_overrides(data, {"faults.0": 1.0})
    with pytest.raises(
        ScenarioError, match=r"vehicle.v0_mps: expected a number <= 70.0, got 90.0 \(as set\)"
    ):
        load_scenario("heartbeat_loss", {"vehicle.v0_mps": 90.0})
    assert load_scenario("heartbeat_loss", {"faults[0].at_s": 2.5}).faults[0].at_s == 2.5


_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=8),
    lambda inner: (
        st.lists(inner, max_size=3) | st.dictionaries(st.text(min_size=1, max_size=5), inner, max_size=3)
    ),
    max_leaves=6,
)


@given(_VALUES)
def test_a_field_assignment_reads_back_as_the_value_it_was_made_from(value: object) -> None:
    """The command a report prints for a run sets exactly the run's values (floats to the bit)."""
    assert parse_assignment(format_assignment("faults[0].at_s", value)) == ("faults[0].at_s", value)


def test_the_table_gives_each_column_the_one_type_its_values_share() -> None:
    rows = [
        {"run_id": "a", "index": 0, "m.n": 1, "m.x": 1, "m.ok": True, "m.s": "SAFE_STOP", "m.mixed": 1},
        {"run_id": "b", "index": 1, "m.n": 2, "m.x": 2.5, "m.ok": None, "m.s": None, "m.mixed": "x"},
    ]
    table = build_table([{"row": r} for r in rows])
    types = {f.name: str(f.type) for f in table.schema}
    assert types == {
        "run_id": "string", "index": "int64", "m.mixed": "string", "m.n": "int64", "m.ok": "bool",
        "m.s": "string", "m.x": "double",
    }  # fmt: skip
    assert table.column_names[:2] == ["run_id", "index"]
    assert table.column("m.mixed").to_pylist() == ["1", "x"]


def test_the_stopping_bound_is_the_textbook_one_plus_ramp_lag_and_margin() -> None:
    cal = default_calibration()
    b = stop_distance_bound(15.0, 0.1, 2.0, cal)
    ramp_lag_s = 2.0 / cal.jerk_max_mps3 + cal.brake_lag_s
    assert b.bound_m == pytest.approx(15.0**2 / 4.0 + 15.0 * 0.1 + 15.0 * ramp_lag_s + 1.0)
    # a request to speed up, a downhill grade, a later detection: each makes it longer
    assert stop_distance_bound(15.0, 0.1, 2.0, cal, accel_mps2=1.0).bound_m > b.bound_m
    assert stop_distance_bound(15.0, 0.1, 2.0, cal, grade_pct=-5.0).bound_m > b.bound_m
    assert stop_distance_bound(15.0, 0.2, 2.0, cal).bound_m > b.bound_m
    assert (
        stop_distance_bound(15.0, 0.1, 2.0, cal, grade_pct=5.0).bound_m == b.bound_m
    )  # uphill not counted on
    assert math.isinf(stop_distance_bound(15.0, 0.1, 2.0, cal, grade_pct=-25.0).bound_m)


def test_parse_campaign_names_two_sweeps_with_one_name() -> None:
    data = {"name": "x", "sweeps": [{"scenario": "heartbeat_loss"}, {"scenario": "heartbeat_loss"}]}
    with pytest.raises(CampaignError, match=r"sweeps\[1\].name: two sweeps are named 'heartbeat_loss'"):
        parse_campaign(data, "x.yaml")
    data["sweeps"][1]["name"] = "again"  # type: ignore[index]
    assert len(expand(parse_campaign(data, "x.yaml"))) == 2
