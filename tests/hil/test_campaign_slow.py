"""The shipped campaigns end to end on reduced grids, and the whole smoke campaign on the local pool and
on a local Ray instance (`pytest -m slow`: minutes; the default suite runs a bounded smoke campaign in
tests/hil/test_campaign_runs.py)."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from bywire.hil.campaign import runner, store
from bywire.hil.campaign.report import summarise
from bywire.hil.campaign.spec import builtin_campaigns, load_campaign
from bywire.hil.campaign.worker import WALL_CLOCK_COLUMNS

pytestmark = pytest.mark.slow


def _reduced(name: str, tmp_path: Path) -> Path:
    """The shipped campaign with each grid cut to its last value (the fastest, steepest, latest) and one
    draw; v2v_fuzz keeps the run without the flood and one with it, so that its invariant is judged."""
    data = yaml.safe_load(builtin_campaigns()[name].read_text(encoding="utf-8"))
    for sweep in data["sweeps"]:
        for key, values in sweep.get("grid", {}).items():
            sweep["grid"][key] = values[:2] if name == "v2v_fuzz" else values[-1:]
        if "sample" in sweep:
            sweep["sample"]["runs"] = 1
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return path


def _run(spec: Path, out: Path, address: str | None = None) -> runner.Outcome:
    campaign, runs, text = load_campaign(str(spec))
    todo = runner.prepare(out, campaign, runs, text, resume=False)
    return runner.execute(out, todo, len(runs), address, workers=2)


@pytest.mark.parametrize("name", ["faults", "platoon", "urban", "v2v_fuzz"])
def test_a_shipped_campaign_runs_end_to_end_on_a_reduced_grid(name: str, tmp_path: Path) -> None:
    outcome = _run(_reduced(name, tmp_path), tmp_path / "out")
    assert outcome.errors == 0
    summary = summarise(tmp_path / "out")
    assert summary["runs"] == outcome.ran > 0
    assert all(inv["holds"] for inv in summary["invariants"]), summary["invariants"]
    assert summary["failed"] == 0, summary["worst"]


def test_the_smoke_campaign_gives_the_same_rows_on_the_pool_and_on_ray(tmp_path: Path) -> None:
    # Ray is the optional extra bywire[cluster], in the test extra: without it this fails, not skips
    spec = builtin_campaigns()["smoke"]
    pool = _run(spec, tmp_path / "pool")
    ray = _run(spec, tmp_path / "ray", "local")
    assert pool.passed == ray.passed == pool.ran
    a, b = store.read_results(tmp_path / "pool"), store.read_results(tmp_path / "ray")
    keep = [c for c in a.column_names if c not in WALL_CLOCK_COLUMNS]
    assert a.select(keep).equals(b.select(keep))
