"""The geometric graph (graph.py) and the lane index (lane_index.py): edges and annotations of a synthetic
network known by hand, continuity of heading and curvature at every join of the real networks, run-time
blockades and speed limits, and matching objects to lanes by position and heading."""

from __future__ import annotations

import collections
import math

import numpy as np
import pytest
from roadnet_helpers import graph, synthetic_mission_text, synthetic_network

from bywire.host.roadnet.graph import EdgeKind, GraphParams, RoadGraph, build_graph, join_jump
from bywire.host.roadnet.ids import LaneId, WaypointId
from bywire.host.roadnet.lane_index import LaneIndex
from bywire.host.roadnet.mdf import parse_mdf, resolve_mission
from bywire.host.roadnet.rndf import MPH_TO_MPS

W = WaypointId.parse

REAL_RNDFS = (
    "darpa_sample/Sample_RNDF.txt",
    "darpa_nqe/nqe_rndf.rdf",
    "stanford/VAIL_rndf_20091020.txt",
    "stanford/shoreline_trafficcircle_8_rndf.txt",
    "utexas/prc_large_obstacle.rndf",
    "utexas/swri_site_visit.rndf",
    "cornell_samples/Sample3.rndf",
)


@pytest.fixture(scope="module")
def synth() -> RoadGraph:
    return build_graph(synthetic_network())


def kinds(g: RoadGraph) -> dict[str, int]:
    return dict(collections.Counter(e.kind.value for e in g.edges()))


def test_synthetic_edges_by_hand(synth: RoadGraph) -> None:
    assert synth.digraph.number_of_nodes() == 5 + 5 + 3 + 3 + 5 + 5 + 4 + 2
    assert kinds(synth) == {
        "lane": 4 + 4 + 2 + 2 + 4 + 4,
        "exit": 6,  # 1.1.5->2.1.1, 1.1.5->3.1.1, 3.1.3->2.1.3, 4.1.5->5.0.1, 4.2.5->5.0.1, 5.0.4->1.2.1
        "lane_change": 4 + 4,  # 4.1.k -> 4.2.(k+1) and back, 50 m apart >= 25 m
        "uturn": 5 + 5,  # 1.1.k <-> 1.2 alongside, both ways
        "zone": 3,  # 5.0.1 -> 5.0.4, 5.0.1 -> 5.1.1, 5.1.1 -> 5.0.4
        "park": 1,
        "unpark": 1,
    }
    assert synth.has_edge(W("4.1.1"), W("4.2.2")) and synth.has_edge(W("4.2.3"), W("4.1.4"))
    assert synth.has_edge(W("1.1.1"), W("1.2.5")) and synth.has_edge(W("1.1.5"), W("1.2.1"))
    assert synth.has_edge(W("1.2.3"), W("1.1.3"))
    assert not synth.has_edge(W("4.1.5"), W("4.2.5"))  # nothing 25 m ahead of the last waypoint
    assert synth.warnings == []


def test_synthetic_annotations(synth: RoadGraph) -> None:
    lane = synth.edge(W("1.1.4"), W("1.1.5"))
    assert lane.kind == EdgeKind.LANE and lane.lane == LaneId(1, 1)
    assert lane.length_m == pytest.approx(50.0, abs=1e-9)
    assert lane.lane_width_m == pytest.approx(12 * 0.3048)
    assert (lane.left_boundary, lane.right_boundary) == ("double_yellow", "solid_white")
    stop = synth.edge(W("2.1.2"), W("2.1.3"))
    assert stop.stop_at_end and stop.checkpoint_at_end == 2
    assert not synth.edge(W("2.1.1"), W("2.1.2")).stop_at_end
    ex = synth.edge(W("1.1.5"), W("2.1.1"))
    assert ex.kind == EdgeKind.EXIT and ex.areas == (1, 2) and ex.rndf_line is not None and ex.from_rndf
    assert ex.length_m == pytest.approx(10.0, abs=1e-6)  # straight on: the connector is the chord
    change = synth.edge(W("4.1.2"), W("4.2.3"))
    assert change.kind == EdgeKind.LANE_CHANGE and not change.from_rndf and change.lane == LaneId(4, 2)
    assert change.right_boundary == "broken_white"  # 4.2 lies right of 4.1: crossing 4.1's right line
    kturn = synth.edge(W("1.1.3"), W("1.2.3"))
    assert kturn.kind == EdgeKind.UTURN and not kturn.from_rndf and kturn.left_boundary == "double_yellow"
    park, unpark = synth.edge(W("5.1.1"), W("5.1.2")), synth.edge(W("5.1.2"), W("5.1.1"))
    assert park.kind == EdgeKind.PARK and park.checkpoint_at_end == 5 and park.length_m == pytest.approx(10.0)
    assert unpark.kind == EdgeKind.UNPARK and unpark.lane_width_m == pytest.approx(10 * 0.3048)
    zone = synth.edge(W("5.0.1"), W("5.0.4"))
    assert zone.kind == EdgeKind.ZONE and zone.length_m == pytest.approx(40.0) and zone.areas == (5,)
    assert synth.lane_s(W("1.1.3")) == pytest.approx(100.0)
    assert synth.vertex_pose(W("5.0.1")) is None and synth.vertex_xy(W("5.0.1")) == (210.0, -48.0)
    assert synth.checkpoint_vertex(4) == W("4.2.5") and synth.checkpoint_at(W("4.2.5")) == 4


def test_speed_limits_and_blockades(synth: RoadGraph) -> None:
    mission = parse_mdf(synthetic_mission_text([1, 2], {1: (0, 30), 2: (5, 10), 3: (0, 0)}))
    synth.apply_speed_limits(resolve_mission(synth.network, mission))
    try:
        assert synth.edge(W("1.1.1"), W("1.1.2")).speed_max_mps == pytest.approx(30 * MPH_TO_MPS)
        # an exit from segment 1 into 2 takes the lower maximum and the higher minimum
        ex = synth.edge(W("1.1.5"), W("2.1.1"))
        assert ex.speed_max_mps == pytest.approx(10 * MPH_TO_MPS) and ex.speed_min_mps == pytest.approx(
            5 * MPH_TO_MPS
        )
        assert synth.edge(W("3.1.1"), W("3.1.2")).speed_max_mps is None  # 0 = undefined
        assert synth.max_speed_mps == pytest.approx(30 * MPH_TO_MPS)
    finally:
        synth.apply_speed_limits(None)
    assert synth.edge(W("1.1.1"), W("1.1.2")).speed_max_mps is None
    synth.block_edge(W("2.1.1"), W("2.1.2"))
    synth.block_edge(W("1.1.1"), W("1.1.2"))
    assert {e.key for e in synth.blocked_edges()} == {(W("2.1.1"), W("2.1.2")), (W("1.1.1"), W("1.1.2"))}
    assert "blocked" in repr(synth.edge(W("2.1.1"), W("2.1.2")))
    assert synth.unblock_all() == 2 and synth.blocked_edges() == []
    with pytest.raises(KeyError):
        synth.block_edge(W("1.1.1"), W("2.1.3"))


def test_rndf_uturn_exits_are_uturns() -> None:
    g = graph("utexas/prc_small.rndf")
    e = g.edge(W("1.1.4"), W("1.2.14"))  # "exit 1.1.4 1.2.14 /* U-turn to lane 1.2 */"
    assert e.kind == EdgeKind.UTURN and e.from_rndf
    assert g.edge(W("1.2.17"), W("4.2.8")).kind == EdgeKind.EXIT


@pytest.mark.parametrize("rel", REAL_RNDFS)
def test_joins_have_continuous_heading_and_curvature(rel: str) -> None:
    """Fig. 10c: "It has continuous curvature" - at every lane waypoint where one drivable edge ends and
    the next begins (lane -> lane, lane -> exit -> lane, lane changes)."""
    g = graph(rel)
    drivable = (EdgeKind.LANE, EdgeKind.EXIT, EdgeKind.LANE_CHANGE)
    joins = 0
    for e in g.edges(drivable):
        if g.vertex_pose(e.end) is None:
            continue  # perimeter or spot point: zone navigation takes over there
        for nxt in g.out_edges(e.end):
            if nxt.kind in drivable:
                jump = join_jump(e, nxt)
                assert jump.heading_jump_rad < 1e-6 and jump.curvature_jump_1pm < 1e-6, (e, nxt, jump)
                joins += 1
    assert joins > 0


@pytest.mark.parametrize("rel", REAL_RNDFS)
def test_edge_geometry_is_sound(rel: str) -> None:
    g = graph(rel)
    for e in g.edges((EdgeKind.LANE, EdgeKind.EXIT)):
        p = e.path
        (x0, y0), (x1, y1) = g.vertex_xy(e.start), g.vertex_xy(e.end)
        # a path is never shorter than the chord between its vertices (A* heuristic admissibility)
        assert p.length_m >= math.hypot(x1 - x0, y1 - y0) - 0.5 - 1e-9  # 0.5: merged waypoints
        if len(p) > 1:
            assert np.max(np.diff(p.s_m)) <= 0.51
            assert np.all(np.isfinite(p.curvature_1pm))
    for e in g.edges(EdgeKind.LANE):
        # lanes are smooth: no radius under 3.5 m on any real lane (the tightest are the shoreline
        # traffic circle's 3.9 m and a VAIL hairpin's 4.2 m)
        assert np.max(np.abs(e.path.curvature_1pm)) < 1 / 3.5, e
    for lane in g.network.lanes():
        lp = g.lane_path(lane.id)
        if lp is None:
            continue
        s = [g.lane_s(w.id) for w in lane.waypoints]
        assert s == sorted(s) and s[0] == 0.0 and s[-1] == pytest.approx(lp.length_m)


def test_lane_changes_stay_between_parallel_lanes() -> None:
    g = graph("darpa_sample/Sample_RNDF.txt")
    changes = list(g.edges(EdgeKind.LANE_CHANGE))
    assert changes
    for e in changes:
        a = g.vertex_pose(e.start)
        assert a is not None
        assert e.start.segment == e.end.segment and abs(e.start.lane - e.end.lane) == 1
        assert e.length_m >= 25.0 - 1e-6
        target = g.lane_path(e.end.lane_id)
        assert target is not None
        # every point of the manoeuvre runs along the target lane, within reach of it
        s, lateral, heading = target.project_points(e.path.x_m, e.path.y_m)
        assert np.max(np.abs(wrap_angle_vec(e.path.heading_rad - heading))) < math.radians(35), e
        assert np.max(np.abs(lateral)) <= 2.2 * 12 * 0.3048 + 1e-6, e
        assert np.all(np.diff(s) > -1e-6)  # forward along it


def wrap_angle_vec(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def test_degenerate_exits_are_reported() -> None:
    g = graph("cornell_samples/Sample1.rndf")
    lines = {w.line for w in g.warnings}
    assert 9 in lines  # exit 1.1.2 2.1.1: the entry lies behind the exit waypoint
    assert all("no room for a drivable turn" in w.message for w in g.warnings)
    assert graph("darpa_nqe/nqe_rndf.rdf").warnings == []


def test_params_switch_derived_edges_off() -> None:
    g = build_graph(synthetic_network(), params=GraphParams(lane_changes=False, uturns=False))
    assert "lane_change" not in kinds(g) and "uturn" not in kinds(g)


# ---------------------------------------------------------------------------------------------- lane index


def test_lane_index_by_position_and_heading(synth: RoadGraph) -> None:
    index = LaneIndex(synth)
    m = index.match(75.0, -2.0, 0.0)
    assert m is not None and m.edge.key == (W("1.1.2"), W("1.1.3"))
    assert m.s_m == pytest.approx(25.0, abs=1e-6) and m.lateral_offset_m == pytest.approx(0.0, abs=1e-6)
    # the same place facing west belongs to the westbound lane 4 m away (on its left)
    m = index.match(75.0, -2.0, math.pi)
    assert (
        m is not None and m.edge.lane == LaneId(1, 2) and m.lateral_offset_m == pytest.approx(4.0, abs=1e-6)
    )
    # between the lanes, eastbound: lane 1.1 although 1.2 is nearer (an oncoming lane is no match)
    m = index.match(75.0, 0.5, 0.05)
    assert (
        m is not None and m.edge.lane == LaneId(1, 1) and m.lateral_offset_m == pytest.approx(2.5, abs=1e-6)
    )
    assert m.heading_error_rad == pytest.approx(0.05)
    # the next lane's car is not projected into ours: 1 m from 4.2, 2.5 m from 4.1
    m = index.match(110.0, -52.5, 0.0)
    assert m is not None and m.edge.lane == LaneId(4, 2)
    assert [c.edge.lane for c in index.candidates(110.0, -52.5, 0.0)] == [LaneId(4, 2), LaneId(4, 1)]
    # an exit through the "intersection" is a lane too
    m = index.match(205.0, -2.0, 0.0)
    assert m is not None and m.edge.kind == EdgeKind.EXIT
    assert index.match(100.0, 40.0, 0.0) is None  # far from every lane
    assert index.match(75.0, -2.0, math.pi / 2) is None  # crossing the road: no lane fits
    without = index.match(75.0, -1.0)
    assert without is not None and without.edge.lane == LaneId(1, 1) and math.isnan(without.heading_error_rad)


def test_lane_index_on_a_real_network() -> None:
    g = graph("darpa_nqe/nqe_rndf.rdf")
    index = LaneIndex(g)
    rng = np.random.default_rng(7)
    lanes = [e for e in g.edges(EdgeKind.LANE) if e.length_m > 10.0]
    right = 0
    trials = 200
    for _ in range(trials):
        e = lanes[int(rng.integers(len(lanes)))]
        q = e.path.point_at(float(rng.uniform(2.0, e.length_m - 2.0)))
        x = q.x_m + rng.normal(0, 0.3)
        y = q.y_m + rng.normal(0, 0.3)
        m = index.match(x, y, q.heading_rad + rng.normal(0, math.radians(3)))
        assert m is not None
        right += m.edge.lane == e.lane
    # lanes of the NQE cross only at intersections; near them a car may well be on a crossing lane
    assert right >= 0.95 * trials
