"""Ego-motion by scan registration (bywire.host.perception.registration): a synthetic scene seen from
two poses, the pose algebra, and the shared KITTI odometry scans (skipped when the data is absent)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from grid_scenes import Box, cast
from hypothesis import given, settings
from hypothesis import strategies as st
from shared_data import shared_data_dir

from bywire.host.perception.ego_pose import EgoPose, wrap_angle
from bywire.host.perception.registration import register, registration_points
from bywire.host.perception.scan import read_kitti_bin

ODOMETRY = shared_data_dir() / "lidar_kitti" / "odometry_seq00_frames0-5"

# A street: two building fronts with gaps, parked cars, posts.
STREET = (
    Box(0.0, 9.0, 30.0, 2.0, 6.0),
    Box(40.0, 9.5, 30.0, 2.0, 6.0),
    Box(5.0, -9.0, 50.0, 2.0, 6.0),
    Box(8.0, 5.0, 4.4, 1.8, 1.5, 0.1),
    Box(18.0, -5.5, 4.4, 1.8, 1.5),
    Box(-12.0, 4.0, 4.4, 1.8, 1.5, -0.2),
    Box(25.0, 3.0, 0.3, 0.3, 3.0),
    Box(-20.0, -4.0, 0.3, 0.3, 3.0),
    Box(30.0, -15.0, 6.0, 6.0, 4.0, 0.5),
)


@settings(max_examples=100)
@given(
    st.tuples(st.floats(-50, 50), st.floats(-50, 50), st.floats(-4, 4)),
    st.tuples(st.floats(-50, 50), st.floats(-50, 50), st.floats(-4, 4)),
)
def test_poses_compose_and_invert(a: tuple[float, float, float], b: tuple[float, float, float]) -> None:
    pa, pb = EgoPose(*a), EgoPose(*b)
    pts = np.array([[1.0, 2.0], [-3.0, 0.5]])
    np.testing.assert_allclose(pa.compose(pb).apply(pts), pa.apply(pb.apply(pts)), atol=1e-9)
    ident = pa.compose(pa.inverse())
    assert (ident.x_m, ident.y_m) == pytest.approx((0.0, 0.0), abs=1e-9)
    assert wrap_angle(ident.yaw_rad) == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize(
    "motion", [EgoPose(0.7, 0.0, 0.0), EgoPose(1.5, -0.4, math.radians(4.0)), EgoPose(-0.5, 0.8, -0.05)]
)
def test_a_scene_seen_from_two_poses_gives_the_motion_between_them(motion: EgoPose) -> None:
    first = EgoPose(2.0, -1.0, 0.2)
    second = first.compose(motion)
    result = register(cast(STREET, second, azimuth_step_deg=0.2), cast(STREET, first, azimuth_step_deg=0.2))
    assert result.converged
    # the cars' roofs, seen from above, sample differently from the two poses: a few centimetres
    assert (result.pose.x_m, result.pose.y_m) == pytest.approx((motion.x_m, motion.y_m), abs=0.05)
    assert result.pose.yaw_rad == pytest.approx(motion.yaw_rad, abs=math.radians(0.2))


def test_registration_points_are_thinned_vertical_structure() -> None:
    scan = cast(STREET)
    pts = registration_points(scan)
    assert 200 < len(pts) < len(scan) / 5
    key = np.floor(pts / 0.2).astype(np.int64)
    assert len(np.unique(key, axis=0)) == len(pts)  # one per 0.2 m square
    assert np.hypot(pts[:, 0], pts[:, 1]).min() >= 3.0


def test_too_few_points_do_not_converge() -> None:
    few = np.array([[1.0, 1.0], [2.0, 2.0]])
    result = register(few, few)
    assert not result.converged and math.isnan(result.rms_m)


def kitti_scan(i: int) -> Path:
    path = ODOMETRY / f"{i:06d}.bin"
    if not path.exists():
        pytest.skip(f"KITTI odometry scans not found at {ODOMETRY} (shared data absent)")
    return path


@pytest.mark.parametrize("frame", range(5))
def test_consecutive_kitti_scans_register_to_the_cars_forward_motion(frame: int) -> None:
    fixed, moving = read_kitti_bin(kitti_scan(frame)), read_kitti_bin(kitti_scan(frame + 1))
    result = register(moving, fixed)
    assert result.converged
    # the shared data's note: 0.67-0.75 m per revolution by registration, straight ahead
    assert 0.6 <= result.pose.x_m <= 0.8
    assert abs(result.pose.y_m) < 0.1 and abs(result.pose.yaw_rad) < math.radians(1.0)
    assert result.rms_m < 0.15


def test_a_kitti_scan_moved_by_a_known_pose_is_recovered() -> None:
    pts = registration_points(read_kitti_bin(kitti_scan(0)))
    true = EgoPose(1.2, -0.4, math.radians(4.0))
    result = register(true.inverse().apply(pts), pts)
    assert result.converged
    assert (result.pose.x_m, result.pose.y_m, result.pose.yaw_rad) == pytest.approx(
        (true.x_m, true.y_m, true.yaw_rad), abs=1e-4
    )
