"""The mesh primitives of the simulated LIDAR (hil/lidar/mesh.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bywire.hil.lidar.mesh import Ground, Mesh, Surface, box_corners, box_mesh, prism_mesh, strip_mesh


def test_a_box_has_four_walls_and_a_top_on_its_ground() -> None:
    ground = Ground(grade_pct=10.0)
    box = box_mesh(ground, 5.0, 1.0, math.pi / 2, 4.0, 2.0, 1.5, Surface.VEHICLE)
    assert len(box) == 10 and (box.surface == Surface.VEHICLE).all()
    base = box.vertices_m[:4]
    np.testing.assert_allclose(base[:, 2], 0.1 * base[:, 0], atol=1e-6)
    np.testing.assert_allclose(box.vertices_m[4:, 2] - base[:, 2], 1.5, atol=1e-6)
    # heading north: its length along y
    np.testing.assert_allclose(np.ptp(base[:, :2], axis=0), [2.0, 4.0], atol=1e-6)


def test_corners_go_counter_clockwise() -> None:
    xy = box_corners(0.0, 0.0, 0.3, 4.5, 1.8)
    area = 0.5 * np.sum(xy[:, 0] * np.roll(xy[:, 1], -1) - np.roll(xy[:, 0], -1) * xy[:, 1])
    assert area == pytest.approx(4.5 * 1.8)


def test_strips_drop_their_gaps_and_meshes_concatenate() -> None:
    a = np.column_stack([np.arange(5.0), np.zeros(5), np.zeros(5)])
    b = a + np.array([0.0, 1.0, 0.0])
    full = strip_mesh(a, b, None, Surface.PAINT_WHITE)
    gappy = strip_mesh(a, b, [True, False, False, True], Surface.PAINT_WHITE)
    assert (len(full), len(gappy)) == (8, 4)
    prism = prism_mesh([[0, 0], [1, 0], [0, 1]], 0.0, 1.0, Surface.BUILDING)
    both = Mesh.concat([gappy, Mesh.empty(), prism])
    assert len(both) == 4 + 3 * 2 + 1
    np.testing.assert_array_equal(both.triangles[4:] - 10, prism.triangles)
    assert len(Mesh.concat([])) == 0
    with pytest.raises(ValueError, match="surfaces"):
        Mesh(full.vertices_m, full.triangles, full.surface[:-1])


def test_the_ground_tiles_cover_the_rectangle_on_the_plane() -> None:
    ground = Ground(grade_pct=4.0, uphill_heading_rad=math.pi / 2, origin_xy_m=(0.0, 10.0))
    mesh = ground.mesh(-100.0, 120.0, -50.0, 50.0, 50.0)
    assert len(mesh) == 2 * 5 * 2
    v = mesh.vertices_m
    np.testing.assert_allclose(
        [v[:, 0].min(), v[:, 0].max(), v[:, 1].min(), v[:, 1].max()], [-100, 120, -50, 50]
    )
    np.testing.assert_allclose(v[:, 2], 0.04 * (v[:, 1] - 10.0), atol=1e-5)
    frame = ground.frame(0.0)  # heading east across the slope: level nose, left side up
    np.testing.assert_allclose(frame.T @ frame, np.eye(3), atol=1e-12)
    assert frame[2, 0] == pytest.approx(0.0) and frame[2, 1] > 0.0
