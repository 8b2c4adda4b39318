"""`bywire zone plan` as a user runs it: a map file in, the contract's JSON keys and a plot out; a bad map
or pose is refused in one line that names it."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np

from bywire.host.navigation.reference_maps import autoware_lot


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "bywire", "zone", "plan", *args], capture_output=True, text=True
    )


def test_zone_plan_on_a_map_file(tmp_path: Path) -> None:
    np.save(tmp_path / "lot.npy", autoware_lot().grid.occupied.astype(np.uint8))
    out, png = tmp_path / "plan.json", tmp_path / "plan.png"
    goal = f"18.4,26.3,{1.5 * math.pi}"
    start = f"5.5,4.0,{0.5 * math.pi}"
    lot = str(tmp_path / "lot.npy")
    proc = _run(lot, "--start", start, "--goal", goal, "--car", "lexus", "--margin", "0",
                "--json", str(out), "--plot", str(png))  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(out.read_text())
    assert {"found", "length_m", "direction_changes", "plan_ms", "expansions"} <= set(doc)
    assert doc["found"] and 25.0 < doc["length_m"] < 60.0
    assert doc["poses"][-1][:2] == [18.4, 26.3]
    assert png.stat().st_size > 20_000


def test_zone_plan_refuses_bad_input_plainly(tmp_path: Path) -> None:
    proc = _run(str(tmp_path / "missing.npy"), "--start", "1,1,0", "--goal", "2,2,0")
    assert proc.returncode == 2 and "missing.npy: no such map file" in proc.stderr
    np.save(tmp_path / "m.npy", np.zeros((50, 50)))
    proc = _run(str(tmp_path / "m.npy"), "--start", "1,1", "--goal", "2,2,0")
    assert proc.returncode == 2 and "'1,1': a pose is three finite numbers" in proc.stderr
    proc = _run(
        str(tmp_path / "m.npy"), "--start", "0.5,0.5,0", "--goal", "5,5,0"
    )  # the car sticks out of the map
    assert proc.returncode == 1 and "start pose" in proc.stdout


def test_the_commands_defaults_are_the_planners() -> None:
    """The parser holds its own copy of the planner's defaults, so that `--help` loads no planner."""
    from bywire.host.navigation import zone_cli
    from bywire.host.navigation.hybrid_astar import PlannerParams

    assert PlannerParams.heuristic_weight == zone_cli.DEFAULT_HEURISTIC_WEIGHT
    assert set(zone_cli.CAR_NAMES) == set(zone_cli.cars())
