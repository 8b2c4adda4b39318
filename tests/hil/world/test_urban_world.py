"""The urban world (hil/world/urban.py) and its evaluation (hil/urban_eval.py) without the closed loop: the
`urban:` schema's refusals, where the shared data is looked for, our car's placement on the network, the
traffic drivers' first-come-first-served at a four-way stop, box geometry, and the precedence rule the
scenarios are judged by (known answers)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from bywire.hil.scenario import ScenarioError, builtin_scenarios, load_scenario, parse_scenario
from bywire.hil.urban_eval import direction_changes, precedence_violations
from bywire.hil.world.urban import UrbanWorld, box, box_distance, boxes_overlap
from bywire.hil.world.urban_spec import resolve_data_path, shared_data_root

NETWORKS = builtin_scenarios()["four_way_stop_0"].parent / "networks"


def _doc(**urban: object) -> dict[str, object]:
    base: dict[str, object] = {"rndf": str(NETWORKS / "cross.rndf"), "mdf": str(NETWORKS / "cross_east.mdf")}
    base.update(urban)
    return {"name": "t", "duration_s": 10, "host": {"config": "urban"}, "urban": base}


@pytest.mark.parametrize(
    ("urban", "message"),
    [
        ({"rndf": "nope.rndf"}, r"urban.rndf: no such file"),
        (
            {"vehicles": [{"name": "a", "route": ["1.1.1"]}]},
            r"urban.vehicles\[0\].route: expected at least two",
        ),
        ({"vehicles": [{"name": "a", "route": "1.1.1"}]}, r"urban.vehicles\[0\].route: expected a list"),
        (
            {"vehicles": [{"name": "a", "driver": "lane", "x_m": 1, "y_m": 2}]},
            r"urban.vehicles\[0\].x_m: only a parked",
        ),
        (
            {"vehicles": [{"name": "a", "route": ["1.1.1", "1.1.2"], "speed_mps": -1}]},
            r"vehicles\[0\].speed_mps",
        ),
        ({"vehicles": [{"name": "a", "route": ["1.1.1", "1.1.2"], "colour": "red"}]}, r"vehicles\[0\]"),
        ({"objects": {"position_noise_m": 9}}, r"urban.objects.position_noise_m"),
        ({"extra_key": 1}, r"urban"),
    ],
)
def test_bad_urban_sections_name_the_field(urban: dict[str, object], message: str) -> None:
    with pytest.raises(ScenarioError, match=message):
        parse_scenario(_doc(**urban), "t.yaml")


def test_missing_shared_files_are_named_when_the_run_starts() -> None:
    from bywire.hil.run import run_scenario
    from bywire.hil.world.urban_spec import require_files

    sc = parse_scenario(_doc(mdf="shared:rndf/none/x.mdf"), "t.yaml")  # parses: listed without the data
    assert sc.urban is not None
    with pytest.raises(ScenarioError, match=r"urban.mdf: no such file .*x.mdf .*BYWIRE_SHARED_DATA"):
        require_files(sc.urban, "t.yaml", ScenarioError)
    with pytest.raises(FileNotFoundError, match="BYWIRE_SHARED_DATA"):
        UrbanWorld(sc.urban)
    assert callable(run_scenario)


def test_an_urban_scenario_has_no_world() -> None:
    doc = _doc()
    doc["host"] = {"config": "urban", "lead": {"gap0_m": 20, "speed_profile": [[0, 1]]}}
    with pytest.raises(ScenarioError, match="urban"):
        parse_scenario(doc, "t.yaml")


def test_shared_paths_follow_the_environment(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("BYWIRE_SHARED_DATA", str(tmp_path))
    assert shared_data_root() == tmp_path
    assert resolve_data_path("shared:rndf/a.rndf", "x.yaml") == tmp_path / "rndf" / "a.rndf"
    # a scenario re-read from a recording has no folder: shipped networks are still found
    assert resolve_data_path("networks/cross.rndf", "rec.mcap:/run/info") == NETWORKS / "cross.rndf"


def test_bad_routes_are_refused_naming_the_vehicle() -> None:
    sc = parse_scenario(_doc(vehicles=[{"name": "a", "route": ["1.1.1", "3.1.1"]}]), "t.yaml")
    assert sc.urban is not None
    with pytest.raises(
        ValueError, match=r"urban.vehicles\[0\].route\[1\]: no lane or exit from 1.1.1 to 3.1.1"
    ):
        UrbanWorld(sc.urban)
    sc = parse_scenario(
        _doc(vehicles=[{"name": "a", "route": ["1.1.1", "1.1.2"], "at_stop_line": True}]), "t.yaml"
    )
    assert sc.urban is not None
    with pytest.raises(ValueError, match=r"at_stop_line: no stop line"):
        UrbanWorld(sc.urban)


def test_our_rear_axle_starts_on_the_first_checkpoint() -> None:
    sc = load_scenario("four_way_stop_0")
    assert sc.urban is not None
    w = UrbanWorld(sc.urban)
    assert w.start == pytest.approx((-150.0, -2.0, 0.0), abs=1e-6)
    # the FMU's CG at its origin is 1.42 m ahead of the rear axle; 10 m on and turned 90 deg left
    assert w.ego_from_fmu(0.0, 0.0, 0.0) == pytest.approx((-150.0, -2.0, 0.0))
    x, y, h = w.ego_from_fmu(10.0, 5.0, math.pi / 2)
    assert (x, y, h) == pytest.approx((-150.0 + 10.0 + 1.42, -2.0 + 5.0 - 1.42, math.pi / 2))


def test_traffic_takes_turns_first_come_first_served() -> None:
    """Three cars waiting at a four-way stop from t = 0 (our car far away): they leave one at a time, in
    name order (a tie), each only once the one before has left the box; nobody touches."""
    sc = load_scenario("four_way_stop_3")
    assert sc.urban is not None
    w = UrbanWorld(sc.urban)
    for k in range(int(60 / 0.01)):
        w.step(k * 0.01, 0.0, 0.0, 0.0, 0.0, 0.0)  # we stand 142 m west of the line
    deps = {a.vehicle: a.departure_s for a in w.arrivals}
    assert set(deps) == {"east", "north", "south"} and all(d is not None for d in deps.values())
    order = sorted(deps, key=lambda n: deps[n] or 0.0)
    assert order == ["east", "north", "south"]
    times = sorted(d for d in deps.values() if d is not None)
    assert times[0] >= 20.0  # their scripted departure
    assert times[1] - times[0] > 2.0 and times[2] - times[1] > 2.0  # the box was left first
    assert w.collisions == []


def test_box_geometry() -> None:
    a = box(0.0, 0.0, 0.0, 4.0, 2.0)
    assert boxes_overlap(a, box(3.9, 0.0, 0.0, 4.0, 2.0))
    assert not boxes_overlap(a, box(4.1, 0.0, 0.0, 4.0, 2.0))
    assert box_distance(a, box(5.0, 0.0, 0.0, 4.0, 2.0)) == pytest.approx(1.0)
    assert box_distance(a, box(0.0, 5.0, math.pi / 2, 4.0, 2.0)) == pytest.approx(2.0)
    assert box_distance(a, box(1.0, 0.5, 0.3, 4.0, 2.0)) == 0.0
    assert np.allclose(box(1.0, 2.0, 0.0, 2.0, 2.0)[0], [2.0, 3.0])


def _arr(v: str, arrival: float, departure: float | None, inter: int = 0) -> dict[str, object]:
    return {"vehicle": v, "intersection": inter, "line": "x", "arrival_s": arrival, "departure_s": departure,
            "front_error_m": 0.1}  # fmt: skip


def test_precedence_known_answers() -> None:
    # we go before a car that arrived 3 s before us and left after us: one violation
    assert len(precedence_violations([_arr("a", 1.0, 9.0), _arr("ego", 4.0, 6.0)])) == 1
    # it left first: none; it arrived after us: none; within the tie: none
    assert precedence_violations([_arr("a", 1.0, 5.0), _arr("ego", 4.0, 6.0)]) == []
    assert precedence_violations([_arr("a", 5.0, 9.0), _arr("ego", 4.0, 6.0)]) == []
    assert precedence_violations([_arr("a", 3.8, 9.0), _arr("ego", 4.0, 6.0)]) == []
    # a car that never moves: its turn came at its arrival; after 10 s we may go
    assert precedence_violations([_arr("stuck", 0.0, None), _arr("ego", 11.0, 21.0)]) == []
    assert len(precedence_violations([_arr("stuck", 0.0, None), _arr("ego", 1.0, 8.0)])) == 1
    # its turn came when the car before it left (at 12): we went 3 s later: a violation
    arr = [_arr("b", 0.0, 12.0), _arr("stuck", 1.0, None), _arr("ego", 2.0, 15.0)]
    assert [v["before"] for v in precedence_violations(arr)] == ["stuck"]
    # another intersection is not ours
    assert precedence_violations([_arr("a", 1.0, 9.0, inter=1), _arr("ego", 4.0, 6.0)]) == []


def test_the_smallest_separation_is_a_distance_not_a_bound() -> None:
    """Our car just past the end of a 20 m wall: the separation booked is the boxes' real distance,
    never the centre distance less both half diagonals (a bound that, for a long object, lies far below
    the distance, and goes negative: an overlap that never happened)."""
    sc = load_scenario("zone_park_between_cars")
    assert sc.urban is not None
    w = UrbanWorld(sc.urban)
    w.step(0.0, 91.5, -5.0, 0.0, 0.0, 0.0)  # rear axle at (31.5, -5): the wall runs x 10..30 at y = -8
    assert w.collisions == []
    cx, cy = w.ego_centre()
    ours = box(cx, cy, w.ego[2], sc.urban.ego_length_m, sc.urban.ego_width_m)
    exact = min(box_distance(ours, box(c.x_m, c.y_m, c.heading_rad, c.length_m, c.width_m)) for c in w.cars)
    assert w.min_separation_m == pytest.approx(exact, abs=1e-9)
    assert w.min_separation_to == "wall" and 1.5 < exact < 2.5


def test_the_road_departure_is_the_farthest_corner_off_the_road() -> None:
    """Our car on its lane books nothing; turned across the dead end's 9.1 m street its nose reaches
    past the far lane's edge, and the booking is that corner's distance off the road."""
    sc = load_scenario("kturn_narrow_road")
    assert sc.urban is not None
    w = UrbanWorld(sc.urban)  # the rear axle starts at (0, 0) heading east; lanes y = 0 and 4.572, 15 ft
    w.step(0.0, 60.0, 0.0, 0.0, 0.0, 0.0)
    assert w.summary()["road_departure_m"] == 0.0
    # rear axle at (61.42, 1.0) turned north: the front bumper at y = 4.67, its corners past the edge
    # of the far lane (y = 4.572 + 2.286 = 6.858) by nothing yet; 3 m further north by 1.81 m
    w.step(0.1, 60.0 + 1.42, 1.0 + 1.42 + 3.0, math.pi / 2, 0.0, 0.0)
    _, ry, _ = w.ego_from_fmu(60.0 + 1.42, 1.0 + 1.42 + 3.0, math.pi / 2)
    front = ry + 2.72 + 0.95
    summary = w.summary()
    assert summary["road_departure_m"] == pytest.approx(front - (4.572 + 7.5 * 0.3048), abs=0.03)
    assert summary["road_departure_at_s"] == 0.1
    assert summary["road_departure_xy"][1] == pytest.approx(front, abs=0.01)


def test_direction_changes_count_forward_backward_switches() -> None:
    v = np.array([0.0, 1.0, 2.0, 0.1, -0.1, -1.0, -0.05, 0.05, 1.5, 0.0])
    assert direction_changes({"speed_mps": v}) == 2
    assert direction_changes({"speed_mps": np.zeros(5)}) == 0
