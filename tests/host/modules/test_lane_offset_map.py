"""Where the lane offset compares the map with the paint (seed 000 Sec. 6): against the lane's whole curve.
On a synthetic network in local metres with a marker image of the simulated road's paint
(`hil.lidar.road_marks`, the plant's)."""

from __future__ import annotations

import math

import numpy as np

from bywire.hil.lidar.mesh import Ground
from bywire.hil.lidar.road_marks import road_marks_mesh
from bywire.host.modules.estimation.lane_offset import LaneOffsetModule
from bywire.host.perception.lane_markers import GridParams, MarkerGrid
from bywire.host.perception.lane_offset import measure_offset
from bywire.host.roadnet.graph import RoadGraph, build_graph
from bywire.host.roadnet.ids import LaneId
from bywire.host.roadnet.lane_index import LaneIndex
from bywire.host.roadnet.rndf import parse_rndf

LANE_W_M = 3.6576  # 12 ft


def network(*lanes: list[tuple[float, float]]) -> RoadGraph:
    """One segment of lanes 1.1, 1.2, ... 12 ft wide, each through its points (local metres) in order."""
    text = "RNDF_name\tsynthetic\nnum_segments\t1\nnum_zones\t0\nformat_version\t1.0\nsegment\t1\n"
    text += f"num_lanes\t{len(lanes)}\n"
    for i, pts in enumerate(lanes, start=1):
        text += f"lane\t1.{i}\nnum_waypoints\t{len(pts)}\nlane_width\t12\n"
        if i == 1:
            text += "checkpoint\t1.1.1\t1\n"
        text += "".join(f"1.{i}.{k}\t{x:.3f}\t{y:.3f}\n" for k, (x, y) in enumerate(pts, start=1))
        text += "end_lane\n"
    text += "end_segment\nend_file\n"
    return build_graph(parse_rndf(text, coordinates="local_m"))


def paint_image(graph: RoadGraph, x_m: float, y_m: float) -> MarkerGrid:
    """The marker image centred on (x, y) with every cell the simulated road's paint covers marked once
    (as a revolution marks a cell it saw paint in)."""
    mesh = road_marks_mesh(graph, Ground())
    tri = mesh.vertices_m[mesh.triangles][:, :, :2]
    u = np.linspace(0.0, 1.0, 6)
    a, b = np.meshgrid(u, u)
    keep = a + b <= 1.0
    a, b = a[keep], b[keep]
    pts = (
        tri[:, 0, None, :] * (1.0 - a - b)[None, :, None]
        + tri[:, 1, None, :] * a[None, :, None]
        + tri[:, 2, None, :] * b[None, :, None]
    ).reshape(-1, 2)
    grid = MarkerGrid(GridParams())
    grid.recentre(x_m, y_m)
    ox, oy = grid.origin_xy_m
    col = np.floor((pts[:, 0] - ox) / grid.cell_m).astype(int)
    row = np.floor((pts[:, 1] - oy) / grid.cell_m).astype(int)
    n = grid.image.shape[0]
    ok = (col >= 0) & (col < n) & (row >= 0) & (row < n)
    grid.image[row[ok], col[ok]] = 1.0
    return grid


def test_a_sharp_curve_is_measured_against_the_lanes_whole_curve() -> None:
    """A 90 deg left turn of 25 m radius with a waypoint every 10 m, the map right. Against the edge to
    the next waypoint only, the chord of the map lane came from the 15 m behind the car when a waypoint
    was just ahead, and the lines were read up to 0.61 m off here (the DARPA sample's lane 13.1:
    0.7-1.0 m on every lap)."""
    pts = [(float(x), 0.0) for x in np.arange(0.0, 60.0, 10.0)]
    pts += [(60.0 + 25.0 * math.sin(a), 25.0 * (1.0 - math.cos(a))) for a in np.arange(0.0, math.pi / 2, 0.4)]
    pts += [(85.0, 25.0 + d) for d in np.arange(0.0, 61.0, 10.0)]
    graph = network(pts)
    module = LaneOffsetModule(LaneIndex(graph))
    path = graph.lane_path(LaneId(1, 1))
    assert path is not None
    offsets = []
    for s in np.arange(40.0, path.length_m - 40.0, 1.0):
        p = path.point_at(float(s))
        lane = module._map_lane(p.x_m, p.y_m, p.heading_rad)
        assert lane is not None  # one lane, nothing beside it: measured all along
        centreline, width, markings = lane
        m = measure_offset(paint_image(graph, p.x_m, p.y_m), centreline, width, markings_m=markings)
        if m is not None:
            offsets.append(m.offset_m)
    # where the curve begins and ends the lines run beyond the 4 deg window: not measured there
    assert len(offsets) >= 0.5 * len(np.arange(40.0, path.length_m - 40.0, 1.0))  # 50 of 80
    assert max(abs(o) for o in offsets) <= 0.2  # measured 0.10 m
