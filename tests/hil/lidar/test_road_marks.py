"""Lane paint and curbs drawn from an RNDF network (hil/lidar/road_marks.py), checked on the triangles."""

from __future__ import annotations

import numpy as np
import pytest

from bywire.hil.lidar.mesh import PAINT_THICKNESS_M, Ground, Mesh, Surface
from bywire.hil.lidar.road_marks import DASH_M, DASH_PERIOD_M, LINE_WIDTH_M, road_marks_mesh
from bywire.hil.world.urban import load_network
from bywire.hil.world.urban_spec import resolve_data_path

LANE_WIDTH_M = 12 * 0.3048


def _marks(network: str, mdf: str, **kw: float) -> Mesh:
    graph, _ = load_network(
        str(resolve_data_path(f"networks/{network}", "x.yaml")),
        str(resolve_data_path(f"networks/{mdf}", "x.yaml")),
    )
    return road_marks_mesh(graph, Ground(), **kw)


def _centroids(mesh: Mesh, surface: Surface) -> np.ndarray:
    tri = mesh.triangles[mesh.surface == surface]
    return mesh.vertices_m[tri].mean(axis=1)


def test_two_lanes_one_way_share_a_broken_line_and_have_solid_edges() -> None:
    # networks/two_lane.rndf: lane 1.1 on y = 0 and lane 1.2 on y = -3.66, both eastward, x 0..300
    mesh = _marks("two_lane.rndf", "two_lane.mdf")
    white = _centroids(mesh, Surface.PAINT_WHITE)
    assert not (mesh.surface == Surface.PAINT_YELLOW).any()
    mid = np.abs(white[:, 1] + 1.83) < LINE_WIDTH_M
    edges = np.abs(np.abs(white[:, 1] + 1.83) - (1.83 + LANE_WIDTH_M / 2)) < LINE_WIDTH_M
    assert mid.any() and edges.any() and (mid | edges).all()
    # the shared line: 3 m painted in every 12 m; the edges: painted all along but near the ends' exits
    phase = np.mod(white[mid, 0], DASH_PERIOD_M)
    assert phase.max() <= DASH_M + 0.5
    x_edge = np.sort(white[edges & (white[:, 1] > 0), 0])
    assert x_edge.min() < 1.0 and x_edge.max() > 299.0 and np.diff(x_edge).max() < 0.6
    np.testing.assert_allclose(mesh.vertices_m[:, 2], PAINT_THICKNESS_M, atol=1e-6)


def test_an_oncoming_lane_gets_a_double_yellow_line_midway() -> None:
    # networks/ring.rndf, segment 1: lanes on y = -2 (east) and y = +2 (west), 12 ft wide, 4 m apart
    mesh = _marks("ring.rndf", "ring_pass.mdf")
    yellow = mesh.vertices_m[mesh.triangles[mesh.surface == Surface.PAINT_YELLOW]].reshape(-1, 3)
    on_segment_1 = (yellow[:, 0] > 20.0) & (yellow[:, 0] < 180.0) & (np.abs(yellow[:, 1]) < 1.0)
    # two 12 cm lines 10 cm apart, centred on y = 0
    edges = np.unique(np.round(yellow[on_segment_1, 1], 3))
    np.testing.assert_allclose(edges, [-0.17, -0.05, 0.05, 0.17], atol=1e-3)


def test_curbs_stand_beside_the_edges_at_their_height() -> None:
    mesh = _marks("two_lane.rndf", "two_lane.mdf", curb_height_m=0.13)
    curb = mesh.surface == Surface.CURB
    z = mesh.vertices_m[mesh.triangles[curb]][:, :, 2]
    assert z.max() == pytest.approx(0.13) and z.min() == pytest.approx(0.0)
    assert not (_marks("two_lane.rndf", "two_lane.mdf").surface == Surface.CURB).any()
