"""The host configuration file: shipped ones load, variants extend, bad ones name the field."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from fuzz_util import mutate
from hypothesis import given, settings
from hypothesis import strategies as st

from bywire.host.config import HostConfigError, load_host_config, parse_host_config, shipped_configs

DEFAULT = yaml.safe_load(shipped_configs()["default"].read_text())


def test_shipped_configurations_load() -> None:
    assert set(shipped_configs()) >= {"default", "isolated_perception"}
    cfg = load_host_config("default")
    assert [m.spec.name for m in cfg.modules] == [
        "mission",
        "ecu_rx",
        "odometry",
        "radar",
        "lead_tracker",
        "longitudinal",
        "ecu_tx",
    ]
    lon = cfg.module("longitudinal").spec
    assert lon.period_s == pytest.approx(0.02) and lon.deadline_s == pytest.approx(0.01)
    assert lon.policy.on_slow == "degrade" and lon.policy.escalate_to == "stop"
    assert cfg.module("ecu_tx").spec.policy.restart_as_dependant is False
    assert cfg.live_view_port is None


def test_a_variant_overrides_modules_by_name(tmp_path: Path) -> None:
    iso = load_host_config("isolated_perception")
    assert iso.module("lead_tracker").spec.isolation == "process"
    assert iso.module("lead_tracker").spec.policy.escalate_to == "degrade"
    assert len(iso.modules) == len(load_host_config("default").modules)
    mine = tmp_path / "mine.yaml"
    mine.write_text(
        "extends: default\nmodules:\n  - {name: longitudinal, deadline_ms: 15, policy: {slow_misses: 5}}\n"
    )
    lon = load_host_config(str(mine)).module("longitudinal").spec
    assert lon.deadline_s == pytest.approx(0.015)
    assert lon.policy.slow_misses == 5 and lon.policy.on_slow == "degrade"  # the rest of the policy kept


@pytest.mark.parametrize(
    ("change", "where", "what"),
    [
        ({"modules": [{"name": "x", "kind": "warp_drive"}]}, "modules[0].kind", "expected one of"),
        (
            {"modules": [{"name": "x", "kind": "odometry", "policy": {"action": "reboot"}}]},
            "modules[0].policy.action",
            "reboot",
        ),
        ({"modules": [{"name": "x", "kind": "odometry", "period_ms": -1}]}, "modules[0].period_ms", ">= 0.1"),
        (
            {"modules": [{"name": "x", "kind": "ecu_rx", "isolation": "process"}]},
            "modules[0].isolation",
            "buses",
        ),
        (
            {"modules": [{"name": "a", "kind": "odometry"}, {"name": "a", "kind": "lead_tracker"}]},
            "modules[1].name",
            "two modules",
        ),
        (
            {"modules": [{"name": "a", "kind": "odometry"}, {"name": "b", "kind": "odometry"}]},
            "modules[1]",
            "already produced",
        ),
        (
            {"modules": [{"name": "a", "kind": "odometry", "policy": {"slow_misses": 5, "slow_window": 2}}]},
            "modules[0].policy.slow_window",
            ">= slow_misses",
        ),
        ({"modules": [{"name": "a b", "kind": "odometry"}]}, "modules[0].name", "letters"),
        ({"modules": []}, "modules", "non-empty"),
        ({"modulez": 1, "modules": [{"name": "a", "kind": "odometry"}]}, "modulez", "unknown key"),
        # A module's params are read when the file loads, as the module will read them at its start
        # (where a refusal would restart it until its policy stopped the host).
        (
            {"modules": [{"name": "a", "kind": "odometry", "params": {"gain": 1}}]},
            "modules[0].params",
            "odometry: unknown params ['gain'] (known: none)",
        ),
        (
            {"modules": [{"name": "a", "kind": "longitudinal", "params": {"velocity_gain_per_s": "fast"}}]},
            "modules[0].params",
            "longitudinal: params.velocity_gain_per_s must be a number",
        ),
        (
            {"modules": [{"name": "a", "kind": "longitudinal", "params": {"velocity_gain": 0.5}}]},
            "modules[0].params",
            "longitudinal: unknown params ['velocity_gain'] (known: accel_max_mps2",
        ),
        (
            {"modules": [{"name": "a", "kind": "longitudinal", "params": {"velocity_gain_per_s": -1}}]},
            "modules[0].params",
            "velocity_gain_per_s",
        ),
        (
            {"modules": [{"name": "p", "kind": "platoon_control", "params": {"headway_ss": 0.8}}]},
            "modules[0].params",
            "platoon_control: unknown params ['headway_ss']",
        ),
        (
            {"modules": [{"name": "p", "kind": "platoon_control", "params": {"max_leaders": 2.5}}]},
            "modules[0].params",
            "max_leaders must be an integer in 1..64",
        ),
        (
            {"modules": [{"name": "t", "kind": "ecu_tx", "params": {"request_max_age_ms": 5}}]},
            "modules[0].params",
            "request_max_age_ms must be a number in 20..1000",
        ),
        (
            {"modules": [{"name": "w", "kind": "world_model", "params": {"blacklist": ["x"]}}]},
            "modules[0].params",
            "blacklist must be a list of station ids",
        ),
        (
            {"modules": [{"name": "r", "kind": "v2v_rx", "params": {"black_list": [3]}}]},
            "modules[0].params",
            "v2v_rx: unknown params ['black_list']",
        ),
        (
            {"modules": [{"name": "t", "kind": "v2v_tx", "params": {"profile": "fast"}}]},
            "modules[0].params",
            "profile must be one of etsi, gcdc",
        ),
        (
            {"modules": [{"name": "l", "kind": "lidar_perception", "params": {"join_distanse_m": 0.4}}]},
            "modules[0].params",
            "lidar_perception: unknown params ['join_distanse_m']",
        ),
        (
            {"modules": [{"name": "l", "kind": "lane_offset", "params": {"min_correction_m": -1}}]},
            "modules[0].params",
            "min_correction_m must be a number in 0..10",
        ),
        (
            {"modules": [{"name": "c", "kind": "urban_control", "params": {"lateral_k0": 1.0}}]},
            "modules[0].params",
            "urban_control: unknown params ['lateral_k0'] (known: accel_max_mps2",
        ),
        (
            {"modules": [{"name": "c", "kind": "urban_control", "params": {"lateral_k0_per_m2": 0.0}}]},
            "modules[0].params",
            "k0_per_m2",
        ),
    ],
)
def test_bad_configurations_name_the_field(change: dict, where: str, what: str) -> None:
    with pytest.raises(HostConfigError) as err:
        parse_host_config(change, "bad.yaml")
    assert err.value.path == where
    assert what in str(err.value)
    assert str(err.value).startswith("bad.yaml: ")


def test_unknown_and_missing_configurations() -> None:
    with pytest.raises(HostConfigError, match="shipped ones: default"):
        load_host_config("nonexistent")
    with pytest.raises(HostConfigError, match="no such host configuration file"):
        load_host_config("/nowhere/host.yaml")


@settings(max_examples=200, deadline=None)
@given(st.data())
def test_mutated_configurations_parse_or_name_the_field(data: st.DataObject) -> None:
    doc = mutate(DEFAULT, data.draw)
    try:
        cfg = parse_host_config(doc, "fuzz.yaml")
    except HostConfigError as exc:
        assert str(exc).startswith("fuzz.yaml")
    else:
        assert cfg.modules and all(m.spec.deadline_s > 0 for m in cfg.modules)


def test_module_faults_must_name_a_module_of_the_host(tmp_path: Path) -> None:
    from bywire.hil.run import run_scenario
    from bywire.hil.scenario import ScenarioError

    bad = tmp_path / "bad.yaml"
    bad.write_text(
        "name: bad\nduration_s: 1\nfaults:\n  - {at_s: 0.5, kind: module_hang, module: longitudinl}\n"
    )
    with pytest.raises(ScenarioError, match=r"faults\[0\].module: no module 'longitudinl'"):
        run_scenario(str(bad))
    bad.write_text(
        "name: bad\nduration_s: 1\nfaults:\n  - {at_s: 0.5, kind: module_kill, module: longitudinal}\n"
    )
    with pytest.raises(ScenarioError, match="only a worker process can be killed"):
        run_scenario(str(bad))


def test_a_scenarios_host_params_set_module_parameters_over_the_configuration(tmp_path: Path) -> None:
    """`host.params` (a campaign's headway): merged over the module's parameters as an `extends` file
    would; a module the configuration lacks, or parameters that are no mapping, named in the scenario."""
    from bywire.hil.scenario import ScenarioError, load_scenario, scenario_host_config

    base = load_host_config("gcdc").module("platoon").params
    cfg = load_host_config("gcdc", {"platoon": {"headway_s": 0.8}})
    assert cfg.module("platoon").params == {**base, "headway_s": 0.8} and base["headway_s"] == 0.6
    path = tmp_path / "s.yaml"
    path.write_text("name: s\nduration_s: 1\nhost: {config: gcdc, params: {platoon: {headway_s: 0.9}}}\n")
    assert scenario_host_config(load_scenario(str(path))).module("platoon").params["headway_s"] == 0.9
    path.write_text("name: s\nduration_s: 1\nhost: {config: gcdc, params: {platon: {headway_s: 0.9}}}\n")
    with pytest.raises(HostConfigError, match=r"s.yaml: host.params.platon: no module 'platon' in gcdc.yaml"):
        scenario_host_config(load_scenario(str(path)))
    path.write_text("name: s\nduration_s: 1\nhost: {config: gcdc, params: {platoon: {headway_ss: 0.9}}}\n")
    with pytest.raises(HostConfigError, match=r"params: platoon_control: unknown params \['headway_ss'\]"):
        scenario_host_config(load_scenario(str(path)))
    path.write_text("name: s\nduration_s: 1\nhost: {config: gcdc, params: {platoon: 0.9}}\n")
    with pytest.raises(ScenarioError, match=r"host.params: expected module name -> mapping"):
        load_scenario(str(path))


def test_a_stop_policy_brings_the_car_to_a_controlled_stop_through_the_ecu(tmp_path: Path) -> None:
    """The host runtime supervisor's third reaction, end to end in SIL: the controller fails, its policy
    says stop, the ECU link sets the STOP flag, and the ECU stops and holds the car."""
    from bywire.hil.run import run_scenario

    host = tmp_path / "stop_host.yaml"
    host.write_text("extends: default\nmodules:\n  - {name: longitudinal, policy: {action: stop}}\n")
    scenario = tmp_path / "stop.yaml"
    scenario.write_text(
        "name: supervisor_stop\nduration_s: 16\nvehicle: {v0_mps: 0}\n"
        "host: {mode: drive, config: stop_host.yaml, engage_at_s: 0.5, speed_profile: [[0, 10]]}\n"
        "faults:\n  - {at_s: 6.0, kind: module_exception, module: longitudinal}\n"
        "checks:\n  - {metric: state_at_fault, equals: ENGAGED}\n  - {metric: action, equals: stop}\n"
        "  - {metric: final_speed_mps, max: 0.05}\n  - {metric: standstill_held, equals: true}\n"
    )
    doc = run_scenario(str(scenario))
    assert doc["verdict"] == "pass", doc["checks"]
    assert doc["metrics"]["final_state"] in ("SAFE_STOP", "PAUSED")
    assert doc["metrics"]["detect_ms"] == 0.0
