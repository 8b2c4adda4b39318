"""Tentacles (`host.navigation.tentacles`, seed 000 Sec. 7): the speed-dependent set, the arc
coordinates, and the choice on the paper's four aspects."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bywire.host.navigation.tentacles import (
    TentacleParams,
    _arc,
    _arc_coordinates,
    box_points,
    choose_tentacle,
    tentacle_curvatures,
)

P = TentacleParams()


def test_faster_means_gentler_arcs_never_sharper_than_full_lock() -> None:
    slow, fast = tentacle_curvatures(1.0, P), tentacle_curvatures(15.0, P)
    assert np.max(np.abs(slow)) == pytest.approx(1.0 / P.min_radius_m)
    assert np.max(np.abs(fast)) == pytest.approx(P.lateral_accel_mps2 / 15.0**2)
    assert np.all(np.diff(slow) > 0) and 0.0 in slow  # ordered, straight ahead included
    # denser near straight ahead
    assert abs(slow[P.n // 2 + 1]) < 0.5 * abs(slow[-1] - slow[-2])


@settings(max_examples=200, deadline=None)
@given(st.floats(-0.2, 0.2), st.floats(0.0, 12.0), st.floats(-2.0, 2.0))
def test_arc_coordinates_invert_the_arc(kappa: float, u: float, d: float) -> None:
    """A point d to the left of the arc at arc length u maps back to (u, d)."""
    pose = _arc((0.0, 0.0, 0.0), kappa, np.array([u]))[0]
    px = pose[0] - d * math.sin(pose[2])
    py = pose[1] + d * math.cos(pose[2])
    if abs(kappa) > 1e-9 and abs(d) >= 0.9 / abs(kappa):
        return  # at or beyond the centre the arc coordinates are not unique
    uu, dd = _arc_coordinates(kappa, np.array([px]), np.array([py]))
    assert uu[0] == pytest.approx(u, abs=1e-6) and dd[0] == pytest.approx(d, abs=1e-6)


def test_a_free_road_keeps_the_planned_path() -> None:
    path = np.column_stack((np.arange(0.0, 40.0, 0.5), np.zeros(80)))
    choice = choose_tentacle((0.0, 0.0, 0.0), 10.0, np.zeros((0, 2)), path, None)
    assert choice is not None and choice.kappa_1pm == 0.0 and math.isinf(choice.free_m)


def test_a_box_on_the_left_of_the_lane_is_passed_on_the_right() -> None:
    path = np.column_stack((np.arange(0.0, 60.0, 0.5), np.zeros(120)))
    box = box_points(3.67 + 15.0 + 0.5, 1.0, 0.0, 1.0, 0.6)  # 15 m ahead of the front bumper
    choice = choose_tentacle((0.0, 0.0, 0.0), 10.0, box, path, None)
    assert choice is not None and choice.kappa_1pm < 0.0  # to the right
    # at the box the arc has moved the car's left side clear of it
    at_box = choice.poses[np.searchsorted(choice.s_m, 15.0)]
    assert at_box[1] + P.half_width_m + P.margin_m <= 0.7 + 1e-6
    # straight on we could still stop (15 m > 12.3 m at 6 m/s²), but it costs more than the swerve ...
    straight = choose_tentacle((0.0, 0.0, 0.0), 10.0, box, path, 0.0, TentacleParams(n=1))
    assert straight is not None and straight.free_m == pytest.approx(15.0) and straight.cost > choice.cost
    # ... and 8 m ahead it is no longer drivable at all
    near = box_points(3.67 + 8.0 + 0.5, 1.0, 0.0, 1.0, 0.6)
    assert choose_tentacle((0.0, 0.0, 0.0), 10.0, near, path, 0.0, TentacleParams(n=1)) is None


def test_a_wall_across_the_road_leaves_no_tentacle() -> None:
    wall = box_points(3.67 + 12.0, 0.0, 0.0, 0.5, 30.0)
    assert choose_tentacle((0.0, 0.0, 0.0), 10.0, wall, np.zeros((0, 2)), None) is None
    # slowly, the same wall is far enough to stop for: straight ahead is drivable up to it
    straight = TentacleParams(n=1)
    slow = choose_tentacle((0.0, 0.0, 0.0), 2.0, wall, np.zeros((0, 2)), None, straight)
    assert slow is not None and slow.free_m == pytest.approx(12.0 - 0.25, abs=0.1)


def test_agreement_with_the_last_choice_breaks_ties() -> None:
    box = box_points(3.67 + 14.0, 0.0, 0.0, 1.0, 0.6)  # dead ahead: left and right are alike
    left = choose_tentacle((0.0, 0.0, 0.0), 8.0, box, np.zeros((0, 2)), 0.05)
    right = choose_tentacle((0.0, 0.0, 0.0), 8.0, box, np.zeros((0, 2)), -0.05)
    assert left is not None and right is not None
    assert left.kappa_1pm > 0.0 > right.kappa_1pm
