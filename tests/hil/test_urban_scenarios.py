"""The urban driving scenarios (seed 000) in SIL: the FMU Passat through the ECU, the host's urban modules on
the runtime, the RNDF/MDF world with its traffic. Every shipped scenario with its own checks, plus what each
is about (the order at the four-way stop, the stop in the intersection, ...); a recording replays exactly; the
report's plots are written. The DARPA missions: tests/hil/test_urban_missions.py."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import pytest
from sil_urban import failed, run

from bywire.hil.scenario import URBAN_HAND_MADE, load_scenario

HAND_MADE = URBAN_HAND_MADE
CONTRACT = (
    "checkpoints_reached",
    "precedence_violations",
    "min_separation_m",
    "stop_line_error_m",
    "speed_limit_violations",
    "collisions",
    "lateral_error_rms_m",
    "lateral_error_max_m",
    "time_s",
)


def leaves(doc: dict[str, Any]) -> list[str]:
    return [s.rsplit("/", 1)[-1] for _, s in doc["state_history"]]


def ego_departure(doc: dict[str, Any]) -> float:
    return next(a["departure_s"] for a in doc["urban"]["arrivals"] if a["vehicle"] == "ego")


@pytest.fixture(scope="module", params=HAND_MADE)
def hand_made(request: pytest.FixtureRequest) -> tuple[str, dict[str, Any]]:
    name = str(request.param)
    return name, run(load_scenario(name))


def test_hand_made_scenarios_pass_their_checks(hand_made: tuple[str, dict[str, Any]]) -> None:
    _, doc = hand_made
    assert doc["verdict"] == "pass", failed(doc)
    m = doc["metrics"]
    assert m["behaviour_faults"] == 0 and m["collisions"] == 0
    for key in CONTRACT:
        assert key in m, key


def test_what_each_scenario_is_about(hand_made: tuple[str, dict[str, Any]]) -> None:
    name, doc = hand_made
    m = doc["metrics"]
    arrivals = doc["urban"]["arrivals"]
    if name.startswith("four_way_stop_") and name[-1].isdigit():
        n = int(name[-1])
        others = [a for a in arrivals if a["vehicle"] != "ego"]
        assert len(others) == n
        # every car that was there before us crossed before we did, and we stopped at the line
        assert all(a["departure_s"] is not None and a["departure_s"] < ego_departure(doc) for a in others)
        assert leaves(doc)[1:4] == ["IntersectionStop", "IntersectionWait", "IntersectionDriveInside"]
        assert -0.05 <= m["stop_line_error_m"] <= 1.0
    elif name == "four_way_stop_stuck_car":
        stuck = next(a for a in arrivals if a["vehicle"] == "stuck")
        assert stuck["departure_s"] is None  # it never moved ...
        assert ego_departure(doc) - stuck["arrival_s"] >= 10.0  # ... and we gave it its turn first
        assert m["checkpoints_reached"] == 2
    elif name == "left_turn_oncoming":
        assert "IntersectionPrioStop" in leaves(doc)  # we waited for the gap
        assert m["lateral_error_max_m"] <= 0.5
    elif name == "merge_moving_traffic":
        assert "IntersectionWait" in leaves(doc) and m["min_separation_m"] >= 3.0
    elif name == "lane_change":
        assert "LaneChange" in leaves(doc)
    elif name == "pass_parked_car":
        assert {"PassObstacleOut", "PassObstacleBy", "PassObstacleBack"} <= set(leaves(doc))
    elif name == "blocked_road_replan":
        assert "DriveKTurnForward" in leaves(doc) and m["reverse_held"] == 0
        assert m["mission_complete"]
    elif name == "estop_in_intersection":
        assert m["hsm_state_at_fault"] == "Intersection/IntersectionDriveInside"
        assert m["standstill_held"] is True and m["final_state"] == "ENGAGED" and m["mission_complete"]
    elif name == "maze_zone":
        # through the three corridors to the spot at the far end and back, parked forward, never stuck
        assert leaves(doc)[1:5] == ["ZoneApproach", "ZoneEnter", "ZonePark", "ZoneLeave"]
        assert not {"ZoneRecovery", "GlobalRecovery"} & set(leaves(doc))
        assert m["mission_complete"] and m["min_separation_m"] >= 0.3
    elif name == "zone_park_between_cars":
        # the zone planner's path: in past the car parked across the way, into the spot between two
        # parked cars, reversing out, out by the exit; never the recovery states
        assert leaves(doc)[1:5] == ["ZoneApproach", "ZoneEnter", "ZonePark", "ZoneLeave"]
        assert not {"ZoneRecovery", "GlobalRecovery"} & set(leaves(doc))
        assert m["min_speed_mps"] < -0.2 and m["min_separation_m"] >= 0.3 and m["mission_complete"]
    elif name in ("kturn_narrow_road", "blocked_road_no_uturn_edge"):
        # the turn planned on the road: three legs at their cusps, then on along the other lane, no
        # corner of the car past the curbs (0.3 m outside the lanes), never the recovery states
        turn = [s for s in leaves(doc) if s.startswith("DriveKTurn")]
        assert turn[0] == "DriveKTurnPlanning" and turn[-1] == "DriveKTurnFinish" and len(turn) == 4
        assert not {"DriveRecovery", "GlobalRecovery"} & set(leaves(doc))
        assert m["road_departure_m"] < 0.3 and m["direction_changes"] == 4 and m["mission_complete"]
    elif name == "obstacle_appears_close":
        # the box appeared 15 m ahead at speed; the tentacles took the car past it within the lanes,
        # without stopping for it
        appeared = doc["_extra"]["urban"]["appeared"]
        assert [a[0] for a in appeared] == ["box"]
        assert m["min_separation_m"] >= 0.2 and m["lane_departure_m"] <= 0.0 and m["mission_complete"]
        assert leaves(doc) == ["DriveOnLane", "MissionComplete"]
    elif name == "host_freeze_in_turn":
        assert m["final_state"] == "SAFE_STOP" and m["standstill_held"] is True
        assert m["hsm_state_at_fault"] == "Intersection/IntersectionDriveInside"


def test_a_recording_replays_exactly(tmp_path: Path) -> None:
    from bywire.hil.host_inputs import recorded_inputs
    from bywire.host.replay import replay

    rec = tmp_path / "urban.mcap"
    sc = dataclasses.replace(load_scenario("four_way_stop_1"), duration_s=30.0)
    run(sc, record=rec)
    result = replay(rec, inputs_for=recorded_inputs)
    assert result.matches, json.dumps(result.to_json()["topics"], indent=1)
    assert {"behaviour", "control"} <= set(result.modules)
    assert result.topics["/urban/plan"].compared > 500


def test_the_report_has_the_trajectory_and_the_state_history(tmp_path: Path) -> None:
    from bywire.hil.run import run_scenario

    doc = run_scenario("four_way_stop_0", "sil", json_path=tmp_path / "r.json", report_dir=tmp_path)
    assert doc["verdict"] == "pass"
    assert (tmp_path / "four_way_stop_0_urban.png").stat().st_size > 20_000
    assert (tmp_path / "four_way_stop_0_states.png").stat().st_size > 10_000
    saved = json.loads((tmp_path / "r.json").read_text())
    assert saved["state_history"][0][1] == "Drive/DriveOnLane"
    assert math.isfinite(saved["metrics"]["lateral_error_rms_m"])
