"""`bywire campaign compare`: two executions of one campaign, run by run.

The same campaign run twice is identical but for the wall clock (SIL is deterministic); run again after
its scenario changed under it (the file the campaign names: a later fault, a stricter stopping check),
the compare names the run that passed and now fails, with the check and the command that reruns it
alone, the changed trajectories, and each changed metric with its largest change and direction.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from fuzz_util import mutate
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bywire.cli import main
from bywire.hil.campaign import runner, store
from bywire.hil.campaign.compare import compare
from bywire.hil.campaign.report import summarise
from bywire.hil.campaign.spec import load_campaign
from bywire.hil.scenario import builtin_scenarios

CAMPAIGN = """\
name: stops
sweeps:
  - scenario: hb.yaml
    set: {duration_s: 11.0}
    grid:
      vehicle.v0_mps: [6.0, 9.0]
"""


def _run(spec: Path, out: Path) -> None:
    campaign, runs, text = load_campaign(str(spec))
    todo = runner.prepare(out, campaign, runs, text, resume=False)
    runner.execute(out, todo, len(runs), None, workers=2)


@pytest.fixture(scope="module")
def executions(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """base, the same campaign again, and after the scenario changed: a later fault, a stricter check."""
    tmp = tmp_path_factory.mktemp("compare")
    scenario = tmp / "hb.yaml"
    original = builtin_scenarios()["heartbeat_loss"].read_text(encoding="utf-8")
    scenario.write_text(original, encoding="utf-8")
    spec = tmp / "stops.yaml"
    spec.write_text(CAMPAIGN, encoding="utf-8")
    _run(spec, tmp / "base")
    _run(spec, tmp / "again")
    changed = original.replace("{at_s: 4.0, kind: heartbeat_mute}", "{at_s: 4.5, kind: heartbeat_mute}")
    changed = changed.replace("metric: stop_distance_m, max: 70.0", "metric: stop_distance_m, max: 5.0")
    assert changed.count("4.5") == 1 and "max: 5.0" in changed
    scenario.write_text(changed, encoding="utf-8")
    _run(spec, tmp / "changed")
    return {"base": tmp / "base", "again": tmp / "again", "changed": tmp / "changed"}


def test_the_same_campaign_run_twice_is_identical_but_for_the_wall_clock(
    executions: dict[str, Path], tmp_path: Path
) -> None:
    result = compare(executions["base"], executions["again"])
    assert (result["matched"], result["identical"]) == (2, 2)
    assert result["trajectories"] == {"compared": 2, "same": 2, "changed": []}
    assert (result["regressions"], result["fixes"], result["metrics"]) == ([], [], {})
    out = tmp_path / "c.json"
    assert main(["campaign", "compare", str(executions["base"]), str(executions["again"]), "--identical",
                 "--json", str(out)]) == 0  # fmt: skip
    assert set(json.loads(out.read_text())) >= {
        "base", "new", "matched", "only_in_base", "only_in_new", "identical", "regressions", "fixes",
        "trajectories", "metrics",
    }  # fmt: skip


def test_a_run_that_passed_and_now_fails_is_a_regression_with_its_check_and_command(
    executions: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    result = compare(executions["base"], executions["changed"])
    assert result["matched"] == 2 and result["identical"] == 0
    assert {r["params"]["vehicle.v0_mps"] for r in result["regressions"]} == {6.0, 9.0}
    regression = result["regressions"][0]
    assert (regression["base_verdict"], regression["new_verdict"]) == ("pass", "fail")
    assert regression["newly_failed_checks"] == ["stops"]
    assert regression["command"].startswith("bywire hil run ")
    assert "vehicle.v0_mps=6.0" in regression["command"]
    assert result["trajectories"]["same"] == 0 and len(result["trajectories"]["changed"]) == 2
    stop = result["metrics"]["stop_distance_m"]
    assert stop["runs_changed"] == 2 and stop["max_abs_change"] > 0.0
    # the check bounds it from above: a longer stop is towards the limit
    assert stop["worse"] + stop["better"] == 2
    base_rows = {r["row"]["run_id"]: r["row"] for r in store.load_records(executions["base"])}
    at = stop["at"]
    assert base_rows[at["run_id"]]["m.stop_distance_m"] == at["base"]
    capsys.readouterr()
    assert main(["campaign", "compare", str(executions["base"]), str(executions["changed"])]) == 1
    printed = capsys.readouterr().out
    assert "regressions: 2" in printed and "regression #0 hb: pass -> fail stops" in printed
    # the other way round the same runs are fixes, and nothing regressed
    assert main(["campaign", "compare", str(executions["changed"]), str(executions["base"])]) == 0
    assert len(compare(executions["changed"], executions["base"])["fixes"]) == 2


def test_identical_fails_on_any_difference_and_a_missing_run(
    executions: dict[str, Path], tmp_path: Path
) -> None:
    partial = tmp_path / "partial"
    shutil.copytree(executions["again"], partial)
    run_file = sorted((partial / "runs").glob("*.json"))[0]
    record = json.loads(run_file.read_text())
    record["row"]["m.fault_detect_ms"] = record["row"]["m.fault_detect_ms"] + 1  # one metric, nothing else
    run_file.write_text(json.dumps(record))
    result = compare(executions["base"], partial)
    assert (result["identical"], result["regressions"]) == (1, [])
    assert result["metrics"]["fault_detect_ms"]["runs_changed"] == 1
    assert main(["campaign", "compare", str(executions["base"]), str(partial)]) == 0
    assert main(["campaign", "compare", str(executions["base"]), str(partial), "--identical"]) == 1
    sorted((partial / "runs").glob("*.json"))[1].unlink()
    assert compare(executions["base"], partial)["only_in_base"]


def test_folders_without_a_campaign_or_a_run_in_common_are_refused(
    executions: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["campaign", "compare", str(executions["base"]), str(tmp_path)]) == 2
    assert f"{tmp_path}: no campaign here" in capsys.readouterr().err
    other = tmp_path / "other"
    shutil.copytree(executions["base"], other)
    for path in (other / "runs").glob("*.json"):
        record = json.loads(path.read_text())
        record["row"]["run_id"] = "0" * 16
        path.write_text(json.dumps(record))
    manifest = json.loads((other / "manifest.json").read_text())
    manifest["run_ids"] = ["0" * 16]
    (other / "manifest.json").write_text(json.dumps(manifest))
    (other / "runs" / f"{'0' * 16}.json").write_text(json.dumps(record))
    assert main(["campaign", "compare", str(executions["base"]), str(other)]) == 2
    assert "no run in common" in capsys.readouterr().err
    broken = tmp_path / "broken"
    shutil.copytree(executions["base"], broken)
    bad = sorted((broken / "runs").glob("*.json"))[0]
    bad.write_text("{not json")
    assert main(["campaign", "compare", str(executions["base"]), str(broken)]) == 2
    assert f"{bad}: unreadable" in capsys.readouterr().err


@given(data=st.data())
@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
def test_a_hostile_run_file_is_refused_by_name_or_read_but_never_crashes_a_reader(
    executions: dict[str, Path], tmp_path_factory: pytest.TempPathFactory, data: st.DataObject
) -> None:
    """A run's file edited by hand, merged from elsewhere or cut short: `report` and `compare` read it,
    or refuse it with a ValueError (the command's exit 2, `error: FILE: ...`), never another exception."""
    folder = tmp_path_factory.mktemp("hostile") / "c"
    shutil.copytree(executions["base"], folder)
    path = sorted((folder / "runs").glob("*.json"))[data.draw(st.integers(0, 1))]
    record = json.loads(path.read_text())
    for _ in range(data.draw(st.integers(1, 3))):
        record = mutate(record, data.draw)
    path.write_text(json.dumps(record))
    for read in (lambda: summarise(folder), lambda: compare(executions["base"], folder)):
        try:
            read()
        except ValueError as exc:
            assert str(exc)


@pytest.mark.parametrize(
    "manifest",
    [{"format": "bywire.campaign/1", "name": 3, "run_ids": []}, {"format": "bywire.campaign/1", "name": "x"}],
)
def test_a_manifest_without_its_name_or_runs_is_refused_by_name(
    executions: dict[str, Path],
    tmp_path: Path,
    manifest: dict[str, object],
    capsys: pytest.CaptureFixture[str],
) -> None:
    folder = tmp_path / "c"
    shutil.copytree(executions["base"], folder)
    (folder / "manifest.json").write_text(json.dumps(manifest))
    assert main(["campaign", "compare", str(executions["base"]), str(folder)]) == 2
    assert f"{folder / 'manifest.json'}: " in capsys.readouterr().err
