"""Campaigns run: a bounded campaign (the smoke campaign's sweeps, cut to a few runs) gives the same
rows on the local process pool and on a local Ray instance, bit for bit but for what the wall clock
decides; a campaign killed with SIGKILL and resumed runs every run exactly once; SIGTERM stops it
with its results kept; the report's command for a run reproduces it alone. The full smoke campaign
and the shipped campaigns on reduced grids are `slow` (tests/hil/test_campaign_slow.py)."""

from __future__ import annotations

import json
import os
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from bywire.cli import main
from bywire.hil.campaign import runner, store
from bywire.hil.campaign.report import summarise
from bywire.hil.campaign.spec import builtin_campaigns, load_campaign
from bywire.hil.campaign.worker import WALL_CLOCK_COLUMNS

ROOT = Path(__file__).resolve().parents[2]


def _bounded_smoke(tmp_path: Path) -> Path:
    """The smoke campaign with each grid cut to its first values and two draws: 7 runs."""
    data = yaml.safe_load(builtin_campaigns()["smoke"].read_text(encoding="utf-8"))
    for sweep in data["sweeps"]:
        for key, values in sweep.get("grid", {}).items():
            sweep["grid"][key] = values[:1] if key != "vehicle.v0_mps" else values[:2]
        if "sample" in sweep:
            sweep["sample"]["runs"] = 1
            sweep["set"] = {**sweep.get("set", {}), "duration_s": 6.0}
    path = tmp_path / "bounded_smoke.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return path


def _run(spec: Path, out: Path, address: str | None) -> runner.Outcome:
    campaign, runs, text = load_campaign(str(spec))
    todo = runner.prepare(out, campaign, runs, text, resume=False)
    return runner.execute(out, todo, len(runs), address, workers=2)


def _without_wall_clock(table: object) -> object:
    return table.drop_columns([c for c in WALL_CLOCK_COLUMNS if c in table.column_names])  # type: ignore[attr-defined]


def test_the_pool_and_ray_give_the_same_rows_bit_for_bit(tmp_path: Path) -> None:
    # Ray is the optional extra bywire[cluster], in the test extra: without it this fails, not skips
    spec = _bounded_smoke(tmp_path)
    pool = _run(spec, tmp_path / "pool", None)
    ray = _run(spec, tmp_path / "ray", "local")
    assert (pool.ran, pool.errors) == (ray.ran, ray.errors) == (7, 0)
    a = store.read_results(tmp_path / "pool")
    b = store.read_results(tmp_path / "ray")
    assert a.num_rows == b.num_rows == 7
    assert a.column_names == b.column_names
    assert _without_wall_clock(a).equals(_without_wall_clock(b))
    # every stop within the derived bound, and a row holds what it ran with
    assert set(a.column("verdict").to_pylist()) == {"pass"}
    assert all(x is not None and x < 0.0 for x in a.column("m.stop_distance_excess_m").to_pylist()[:6])
    assert len(set(a.column("m.trajectory_digest").to_pylist())) == 7
    assert a.column("p.vehicle.v0_mps").to_pylist()[:2] == [4.0, 8.0]
    assert all(v for v in a.column("code_version").to_pylist())
    assert len(set(a.column("worker").to_pylist())) >= 1


def _seeds_campaign(path: Path, seeds: int, duration_s: float) -> Path:
    """A campaign file at `path`: `seeds` runs of accel_steps, `duration_s` each, seeds 1, 2, ..."""
    seed_list = ", ".join(str(k) for k in range(1, seeds + 1))
    path.write_text(
        f"name: {path.stem}\nsweeps:\n  - scenario: accel_steps\n    set: {{duration_s: {duration_s}}}\n"
        f"    grid:\n      seed: [{seed_list}]\n",
        encoding="utf-8",
    )
    return path


def _start_short_campaign(
    tmp_path: Path, seeds: int, runs_before: int, stdout: int
) -> tuple[subprocess.Popen[str], Path, Path, list[str]]:
    """`seeds` 3 s runs of accel_steps as a campaign on one worker, started in a process of its own and
    waited for until `runs_before` runs are written: (the process, its spec, its folder, its command)."""
    spec = _seeds_campaign(tmp_path / "short.yaml", seeds, 3.0)
    out = tmp_path / "out"
    cmd = [
        sys.executable,
        "-m",
        "bywire.cli",
        "campaign",
        "run",
        str(spec),
        "--out",
        str(out),
        "--workers",
        "1",
    ]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=stdout, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120.0  # a harness bound: the runs' count is what is judged
    while time.monotonic() < deadline and len(list((out / "runs").glob("*.json"))) < runs_before:
        assert proc.poll() is None, proc.stderr.read() if proc.stderr else ""
        time.sleep(0.05)
    return proc, spec, out, cmd


def test_a_killed_campaign_resumes_with_no_run_repeated_or_lost(tmp_path: Path) -> None:
    proc, _, out, cmd = _start_short_campaign(tmp_path, 6, 2, stdout=subprocess.DEVNULL)
    proc.kill()  # SIGKILL: nothing of the campaign's own runs after this
    proc.wait()
    before = {p.name: (p.read_bytes(), p.stat().st_mtime_ns) for p in (out / "runs").glob("*.json")}
    assert 2 <= len(before) < 6
    assert not list((out / "runs").glob(".*"))  # no half-written run file left behind as a row
    resumed = subprocess.run(
        [*cmd[:-4], "--resume", str(out)], cwd=ROOT, capture_output=True, text=True, timeout=300
    )
    assert resumed.returncode == 0, resumed.stderr
    assert f"{len(before)} done before, {6 - len(before)} to run" in resumed.stderr
    after = {p.name: (p.read_bytes(), p.stat().st_mtime_ns) for p in (out / "runs").glob("*.json")}
    assert {k: after[k] for k in before} == before  # the runs done before were not run again
    table = store.read_results(out)
    assert sorted(table.column("p.seed").to_pylist()) == [1, 2, 3, 4, 5, 6]
    assert table.column("index").to_pylist() == list(range(6))
    assert len(set(table.column("run_id").to_pylist())) == 6


def test_sigterm_stops_a_campaign_with_its_results_kept_and_the_way_to_resume(tmp_path: Path) -> None:
    proc, spec, out, _ = _start_short_campaign(tmp_path, 8, 1, stdout=subprocess.PIPE)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert f"continue with: bywire campaign run {spec} --resume {out}" in err
    done = len(list((out / "runs").glob("*.json")))
    assert store.read_results(out).num_rows == done < 8
    # the same folder again without --resume is refused: it holds a campaign
    assert main(["campaign", "run", str(spec), "--out", str(out)]) == 2


def test_resuming_with_another_campaign_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    one = tmp_path / "one.yaml"
    one.write_text(
        "name: one\nsweeps:\n  - scenario: accel_steps\n    grid: {seed: [1, 2]}\n", encoding="utf-8"
    )
    campaign, runs, text = load_campaign(str(one))
    runner.prepare(tmp_path / "out", campaign, runs, text, resume=False)
    other = tmp_path / "other.yaml"
    other.write_text(
        "name: one\nsweeps:\n  - scenario: accel_steps\n    grid: {seed: [1, 3]}\n", encoding="utf-8"
    )
    assert main(["campaign", "run", str(other), "--resume", str(tmp_path / "out")]) == 2
    assert "differs in 2 of them" in capsys.readouterr().err


def test_the_report_names_the_worst_run_and_its_command_reruns_it_alone(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    spec = tmp_path / "judged.yaml"
    # one of the two stops is judged by a bound it cannot meet: the report must put it first
    spec.write_text(
        "name: judged\nsweeps:\n  - scenario: heartbeat_loss\n    set: {duration_s: 11.0}\n"
        "    grid:\n      vehicle.v0_mps: [6.0, 9.0]\n    checks:\n"
        "      - {name: short stop, metric: stop_distance_m, max: 15.0}\n",
        encoding="utf-8",
    )
    out = tmp_path / "out"
    outcome = _run(spec, out, None)
    assert (outcome.passed, outcome.failed) == (1, 1)
    assert main(["campaign", "report", str(out), "--json", str(tmp_path / "s.json")]) == 1
    summary = json.loads((tmp_path / "s.json").read_text())
    assert (summary["runs"], summary["passed"], summary["failed"]) == (2, 1, 1)
    assert (
        summary["by_scenario"]["heartbeat_loss"]["by_parameter"]["vehicle.v0_mps"]["9.0"]["pass_rate"] == 0.0
    )
    worst = summary["worst"][0]
    assert (worst["verdict"], worst["params"], worst["failed_checks"]) == (
        "fail",
        {"vehicle.v0_mps": 9.0},
        "short stop",
    )
    assert summary["metrics"]["heartbeat_loss.stop_distance_m"]["max"] > 15.0
    assert {p.name for p in (out / "report").glob("*.png")} >= {"heartbeat_loss_distributions.png"}
    words = shlex.split(worst["command"])
    assert words[:4] == ["bywire", "hil", "run", "heartbeat_loss"]
    capsys.readouterr()
    assert main([*words[1:], "--json", str(tmp_path / "alone.json"), "--quiet"]) == 0  # its own checks pass
    alone = json.loads((tmp_path / "alone.json").read_text())
    row = next(r for r in store.load_records(out) if r["row"]["run_id"] == worst["run_id"])["row"]
    assert alone["metrics"]["stop_distance_m"] == row["m.stop_distance_m"]
    assert alone["metrics"]["fault_detect_ms"] == row["m.fault_detect_ms"]
    assert summarise(out)["worst"][0]["run_id"] == worst["run_id"]


def test_a_run_that_raises_is_a_row_with_its_error(tmp_path: Path) -> None:
    spec = tmp_path / "bad.yaml"
    # a leader profile on a scenario without a replay vehicle: refused by the run, not by the campaign file
    profile = tmp_path / "lead.csv"
    profile.write_text("t,v\n", encoding="utf-8")
    spec.write_text(
        f"name: bad\nsweeps:\n  - scenario: accel_steps\n    set: {{duration_s: 2.0}}\n"
        f"    grid:\n      leader_profile: [{profile}]\n",
        encoding="utf-8",
    )
    outcome = _run(spec, tmp_path / "out", None)
    assert (outcome.ran, outcome.errors) == (1, 1)
    row = store.read_results(tmp_path / "out").to_pylist()[0]
    assert row["verdict"] == "error"
    assert "ScenarioError" in row["error"] and "replay" in row["error"]
    assert os.path.isfile(tmp_path / "out" / "results.parquet")


def test_a_damaged_run_file_is_set_aside_on_resume_and_its_run_done_again(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    spec = _seeds_campaign(tmp_path / "two.yaml", 2, 2.0)
    out = tmp_path / "out"
    _run(spec, out, None)
    first, second = sorted((out / "runs").glob("*.json"))
    before = json.loads(first.read_text())
    first.write_text('{"row": {"run_id": "cut sh')  # damaged on disk, or edited by hand
    untouched = second.read_bytes()
    capsys.readouterr()
    assert main(["campaign", "run", str(spec), "--resume", str(out), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert f"{first}.unreadable: not a run's record" in err and "1 done before, 1 to run" in err
    assert (out / "runs" / f"{first.name}.unreadable").read_text() == '{"row": {"run_id": "cut sh'
    assert second.read_bytes() == untouched  # the good run was not run again
    again = json.loads(first.read_text())
    assert {k: v for k, v in again["row"].items() if k not in WALL_CLOCK_COLUMNS} == {
        k: v for k, v in before["row"].items() if k not in WALL_CLOCK_COLUMNS
    }
    assert store.read_results(out).num_rows == 2
