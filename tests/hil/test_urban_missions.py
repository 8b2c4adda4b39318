"""The DARPA missions in SIL (seed 000; shared data, read in place): the sample mission and NQE area A
bounded to their first checkpoints by default, whole with `-m slow`; the sample's two exits tighter than
full lock. Apart from the hand-made scenarios (tests/hil/test_urban_scenarios.py) so that the two files,
the suite's longest, run on both of its workers."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
from shared_data import shared_data_dir
from sil_urban import failed, run

from bywire.hil.scenario import Check, Scenario, load_scenario

SAMPLE = shared_data_dir() / "rndf" / "darpa_sample" / "Sample_RNDF.txt"
NQE = shared_data_dir() / "rndf" / "darpa_nqe" / "nqe_rndf.rdf"


def _bounded(name: str, seconds: float, min_checkpoints: int) -> Scenario:
    sc = load_scenario(name)
    checks = tuple(c for c in sc.checks if c.metric not in ("checkpoints_reached", "time_s"))
    checks += (Check("first checkpoints", "checkpoints_reached", "min", min_checkpoints),)
    return dataclasses.replace(sc, duration_s=seconds, checks=checks)


def _need(path: Path) -> None:
    if not path.is_file():
        pytest.skip(f"shared RNDF data not found at {path} (set BYWIRE_SHARED_DATA)")


def test_darpa_sample_mission_first_200_s(tmp_path: Path) -> None:
    _need(SAMPLE)
    sc = _bounded("darpa_sample_mission", 200.0, 4)
    doc = run(sc, tmp_path)
    assert doc["verdict"] == "pass", failed(doc)
    m = doc["metrics"]
    assert m["checkpoints_reached_list"][:4] == [1, 2, 3, 2]
    assert m["lateral_error_rms_m"] <= 0.2 and m["lateral_error_max_m"] <= 0.5
    assert m["stop_line_stops"] >= 2 and m["max_speed_mps"] > 8.0


def test_exits_tighter_than_full_lock_stay_within_their_lanes() -> None:
    """The DARPA sample's two exits the road graph cannot bring under full lock, from checkpoint 9 to 1:
    1.2.6 -> 4.1.1 planned on its own lanes (followed on the graph's curve it took the car 0.4 m off
    the road); 3.2.13 -> 1.2.5 has no plan inside its two 12 ft lanes at any number of moves, and on
    the graph's curve the car keeps within 0.3 m of them."""
    _need(SAMPLE)
    doc = run(load_scenario("unsteerable_exit"))
    assert doc["verdict"] == "pass", failed(doc)
    m = doc["metrics"]
    assert m["road_departure_m"] <= 0.05 and m["lane_departure_m"] < 0.3 and m["behaviour_faults"] == 0


def test_nqe_area_a_first_100_s() -> None:
    _need(NQE)
    doc = run(_bounded("nqe_area_a", 100.0, 4))
    assert doc["verdict"] == "pass", failed(doc)
    assert doc["metrics"]["checkpoints_reached_list"][:4] == [2, 1, 2, 1]


@pytest.mark.slow
@pytest.mark.parametrize("name", ["darpa_sample_mission", "nqe_area_a"])
def test_whole_missions(name: str) -> None:
    _need(SAMPLE if name.startswith("darpa") else NQE)
    doc = run(load_scenario(name))
    assert doc["metrics"]["mission_complete"], failed(doc)
    assert doc["metrics"]["reverse_held"] == 0
    assert doc["verdict"] == "pass", failed(doc)
