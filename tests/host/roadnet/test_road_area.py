"""The road area (`host.roadnet.road_area`): on the lanes, between the lanes of one street, in a zone,
and how far off it a point lies, on the shipped networks."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bywire.hil.world.urban import load_network
from bywire.host.roadnet.road_area import RoadArea, polygon_contains

NETWORKS = Path(__file__).resolve().parents[3] / "bywire" / "hil" / "scenarios" / "networks"
FT = 0.3048


def _area(name: str) -> RoadArea:
    graph, _ = load_network(str(NETWORKS / f"{name}.rndf"), str(NETWORKS / f"{name}.mdf"))
    return RoadArea.of(graph)


def test_a_lane_is_its_width_and_what_lies_beyond_is_measured() -> None:
    area = _area("parking_lot")  # lane 1.1 along y = 0 (12 ft), lane 1.2 along y = -3.66 going back
    half = 6 * FT
    x = np.full(5, -30.0)
    y = np.array([0.0, half - 0.01, half + 0.5, half + 2.0, -3.66 - half - 1.0])
    excess = area.excess_m(x, y)
    assert excess[0] < 0.0 and excess[1] <= 0.0
    assert excess[2] == pytest.approx(0.5, abs=0.02)
    assert excess[3] == pytest.approx(2.0, abs=0.02)
    assert excess[4] == pytest.approx(1.0, abs=0.02)
    assert area.off_road(x, y).tolist() == [False, False, True, True, True]


def test_a_lane_end_is_rounded_by_its_half_width() -> None:
    area = _area("parking_lot")  # the road begins at x = -60
    half = 6 * FT
    excess = area.excess_m(np.array([-60.0 - half + 0.1, -60.0 - half - 1.0]), np.array([0.0, 0.0]))
    assert excess[0] <= 0.0
    assert excess[1] == pytest.approx(1.0, abs=0.02)


def test_the_band_between_the_lanes_of_a_wide_street_is_road() -> None:
    area = _area("ring_wide")  # lanes 1.1 (y = -5) and 1.2 (y = +5), 16 ft wide: 5 m of asphalt between
    x = np.full(3, 100.0)
    y = np.array([0.0, 2.0, -2.0])
    assert (area.excess_m(x, y) <= 0.0).all()
    outside = area.excess_m(np.array([100.0]), np.array([5.0 + 8 * FT + 1.0]))
    assert outside[0] == pytest.approx(1.0, abs=0.02)


def test_a_zone_is_road_inside_its_perimeter() -> None:
    area = _area("parking_lot")  # the lot spans x 4..34, y -16..14
    assert area.excess_m(np.array([20.0, 30.0]), np.array([0.0, 10.0])).max() <= 0.0
    # outside the perimeter (x = 34) by its distance to it, the road's corridors being farther
    assert area.excess_m(np.array([40.0]), np.array([0.0]))[0] == pytest.approx(6.0, abs=1e-9)


def test_polygon_contains_is_even_odd() -> None:
    square = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])
    got = polygon_contains(square, np.array([1.0, 3.0, -0.5, 1.9]), np.array([1.0, 1.0, 1.0, 0.1]))
    assert got.tolist() == [True, False, False, True]


def test_with_a_heading_only_the_lanes_running_that_way_count() -> None:
    area = _area("parking_lot")  # 1.1 eastbound along y = 0, 1.2 westbound along y = -3.66, 12 ft each
    half = 6 * FT
    x, y = np.array([-30.0]), np.array([-3.66])
    assert area.excess_m(x, y)[0] < 0.0  # on the road ...
    # ... but in the oncoming lane for a car heading east: its own lane's edge is 3.66 - 1.83 m away
    assert area.excess_m(x, y, 0.0)[0] == pytest.approx(3.66 - half, abs=0.02)
    assert area.excess_m(x, y, np.pi)[0] < 0.0  # a car heading west is in its lane
    assert area.excess_m(np.array([-30.0]), np.array([0.5]), 0.2)[0] < 0.0


def test_an_area_of_a_few_paths_is_only_theirs() -> None:
    graph, _ = load_network(str(NETWORKS / "parking_lot.rndf"), str(NETWORKS / "parking_lot.mdf"))
    lane = graph.lane_path(next(iter(graph.network.segments[0].lanes)).id)
    assert lane is not None
    area = RoadArea.of_paths([(lane, 3.0)])
    assert area.excess_m(np.array([-30.0, -30.0]), np.array([1.0, -3.66])).tolist() == pytest.approx(
        [-0.5, 2.16], abs=0.02
    )
