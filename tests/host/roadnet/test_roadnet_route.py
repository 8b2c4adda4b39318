"""Mission planning (route.py): choices known by hand on the synthetic network (speed limits, lane changes,
zones and spots, K-turns), blockades and re-planning, unreachable checkpoints, A* against Dijkstra on the
real missions, and the route's continuous path."""

from __future__ import annotations

import itertools
import math

import networkx as nx
import numpy as np
import pytest
from roadnet_helpers import (
    INCONSISTENT_PAIRS,
    MDF_TO_RNDF,
    graph,
    network,
    resolved,
    synthetic_mission_text,
    synthetic_network,
)

from bywire.host.roadnet.graph import EdgeKind, RoadGraph, build_graph, join_jump
from bywire.host.roadnet.ids import WaypointId
from bywire.host.roadnet.lane_index import LaneIndex
from bywire.host.roadnet.mdf import ResolvedMission, parse_mdf, resolve_mission
from bywire.host.roadnet.rndf import MPH_TO_MPS
from bywire.host.roadnet.route import MissionPlanner, Route, RouteCosts

W = WaypointId.parse


def planned(checkpoints: list[int], limits: dict[int, tuple[int, int]]) -> tuple[RoadGraph, ResolvedMission]:
    net = synthetic_network()
    res = resolve_mission(net, parse_mdf(synthetic_mission_text(checkpoints, limits), "s.mdf"))
    return build_graph(net, res), res


def kinds_of(route: Route, leg: int) -> set[EdgeKind]:
    return {e.kind for e in route.legs[leg].edges}


def test_straight_on_when_speeds_are_equal() -> None:
    g, res = planned([1, 2], {1: (0, 30), 2: (0, 30), 3: (0, 30)})
    route = MissionPlanner(g, res).plan()
    assert route.start == W("1.1.1") and route.checkpoints == (1, 2) and route.reached_all
    assert route.legs[0].edges == () and route.legs[0].length_m == 0.0  # starts on checkpoint 1
    assert [str(v) for v in route.vertices] == [
        "1.1.1",
        "1.1.2",
        "1.1.3",
        "1.1.4",
        "1.1.5",
        "2.1.1",
        "2.1.2",
        "2.1.3",
    ]
    assert route.length_m == pytest.approx(400.0, abs=1e-6)  # a straight road, 0 .. 400 m
    v = 30 * MPH_TO_MPS
    assert route.time_s == pytest.approx(400.0 / v + RouteCosts().stop_penalty_s, rel=1e-6)  # stop at 2.1.3


def test_faster_detour_when_the_direct_road_is_slow() -> None:
    g, res = planned([1, 2], {1: (0, 30), 2: (0, 5), 3: (0, 30)})
    route = MissionPlanner(g, res).plan()
    assert W("3.1.2") in route.vertices and W("2.1.2") not in route.vertices
    # and the other way round the direct road wins again
    g2, res2 = planned([1, 2], {1: (0, 30), 2: (0, 30), 3: (0, 5)})
    assert W("2.1.2") in MissionPlanner(g2, res2).plan().vertices


def test_lane_change_zone_spot_and_kturn() -> None:
    g, res = planned([4, 5, 3, 1], {1: (0, 30), 2: (0, 30), 3: (0, 30), 4: (0, 30), 5: (0, 10)})
    route = MissionPlanner(g, res).plan(start=W("4.1.1"))
    assert route.reached == (True, True, True, True)
    assert EdgeKind.LANE_CHANGE in kinds_of(route, 0)  # 4.1 -> checkpoint 4 on 4.2
    assert kinds_of(route, 1) >= {EdgeKind.EXIT, EdgeKind.ZONE, EdgeKind.PARK}
    assert route.legs[1].edges[-1].kind == EdgeKind.PARK and route.legs[1].target == W("5.1.2")
    assert route.legs[2].edges[0].kind == EdgeKind.UNPARK  # reverse out of the spot first
    pieces = route.drive_pieces()
    assert [e for piece in pieces for e in piece] == list(route.edges)
    assert [p[0].kind for p in pieces if len(p) == 1 and p[0].kind != EdgeKind.LANE] == [
        EdgeKind.ZONE,
        EdgeKind.PARK,
        EdgeKind.UNPARK,
        EdgeKind.ZONE,
        EdgeKind.UTURN,
    ]
    for piece in pieces:
        for a, b in itertools.pairwise(piece):
            jump = join_jump(a, b)
            assert jump.heading_jump_rad < 1e-9 and jump.curvature_jump_1pm < 1e-9
    assert EdgeKind.UTURN in kinds_of(route, 3)  # 1.2.5 (west end) -> 1.1.1: the only way is a K-turn
    c = RouteCosts()
    kturn = next(e for e in route.legs[3].edges if e.kind == EdgeKind.UTURN)
    planner = MissionPlanner(g, res)
    assert planner.edge_time_s(kturn) > c.kturn_penalty_s
    # route time is the sum of its edges' times
    assert route.time_s == pytest.approx(sum(planner.edge_time_s(e) for e in route.edges))
    # zone speed limit (10 mph) on zone and park edges
    zone_edge = next(e for e in route.legs[1].edges if e.kind == EdgeKind.ZONE)
    assert zone_edge.speed_max_mps == pytest.approx(10 * MPH_TO_MPS)


def test_route_path_is_one_continuous_curve() -> None:
    g, res = planned([1, 2], {1: (0, 30), 2: (0, 5), 3: (0, 30)})
    route = MissionPlanner(g, res).plan()
    p = route.path
    assert p.length_m == pytest.approx(route.length_m)
    assert p.start[:2] == pytest.approx(g.vertex_xy(W("1.1.1")))
    assert p.end[:2] == pytest.approx(g.vertex_xy(W("2.1.3")), abs=1e-9)
    steps = np.diff(p.s_m)
    assert np.all(steps > 0) and np.max(steps) < 0.5
    # Fig. 10c: continuous curvature along the whole mission path (lane, exit, lane, exit, lane): no step
    # at any join, and no step anywhere (the detour's apex turns fast, 0.04 1/m per 0.25 m sample)
    for a, b in itertools.pairwise(route.edges):
        jump = join_jump(a, b)
        assert jump.heading_jump_rad < 1e-9 and jump.curvature_jump_1pm < 1e-9
    assert np.max(np.abs(np.diff(p.curvature_1pm))) < 0.06
    assert np.max(np.abs(np.diff(p.heading_unwrapped_rad))) < 0.05  # radius > 5 m: no kink
    # a route of no edges is the start point
    empty = MissionPlanner(g, res).plan(start=W("2.1.3"), first_checkpoint=1)
    assert empty.edges == () and len(empty.path) == 1 and empty.path.start[:2] == g.vertex_xy(W("2.1.3"))


def test_blockade_replan_and_forgetting() -> None:
    g, res = planned([1, 2], {1: (0, 30), 2: (0, 30), 3: (0, 30)})
    planner = MissionPlanner(g, res)
    direct = planner.plan()
    assert W("2.1.2") in direct.vertices
    g.block_edge(W("2.1.1"), W("2.1.2"))
    around = planner.replan(W("1.1.3"), 1)
    assert around.start == W("1.1.3") and around.checkpoints == (2,)
    assert W("3.1.2") in around.vertices and around.reached_all and not around.blockades_forgotten
    assert all(not e.blocked for e in around.edges)
    assert g.blocked_edges()  # the blockade stays for later plans
    # block the only way on: checkpoint 2 is unreachable with the blockades, so they are forgotten
    g.block_edge(W("1.1.4"), W("1.1.5"))
    again = planner.replan(W("1.1.3"), 1)
    assert again.reached_all and again.blockades_forgotten and again.forgotten_blockades == 2
    assert g.blocked_edges() == [] and W("2.1.2") in again.vertices


def test_replan_from_pose() -> None:
    g, res = planned([1, 3], {1: (0, 30), 2: (0, 30), 3: (0, 30)})
    planner = MissionPlanner(g, res)
    index = LaneIndex(g)
    # eastbound on 1.1 at x = 120, checkpoint 3 at the west end of 1.2: plan from the waypoint ahead
    ahead = planner.replan_from_pose(index, 120.0, -2.0, 0.0, 1)
    assert ahead.start == W("1.1.4") and ahead.reached_all
    assert ahead.edges[0].kind == EdgeKind.UTURN  # the only way back west is a K-turn
    g.block_edge(W("1.1.3"), W("1.1.4"))  # blocked right in front of the car: turn around behind it
    back = planner.replan_from_pose(index, 120.0, -2.0, 0.0, 1)
    assert back.start == W("1.1.3") and back.reached_all and not back.blockades_forgotten
    assert back.edges[0].key == (W("1.1.3"), W("1.2.3")) and back.edges[0].kind == EdgeKind.UTURN
    assert back.length_m < ahead.length_m
    with pytest.raises(ValueError, match="on no lane"):
        planner.replan_from_pose(index, 100.0, 60.0, 0.0, 1)


def test_unreachable_checkpoint_is_reported_and_planning_goes_on() -> None:
    g, res = planned([2, 3, 2], {1: (0, 30), 2: (0, 30), 3: (0, 30)})
    route = MissionPlanner(g, res).plan()
    # 2.1.3 is a dead end without exits: neither checkpoint 3 nor anything else can be reached from it
    assert route.reached == (True, False, True)
    assert not route.reached_all and not route.blockades_forgotten
    assert route.legs[1].edges == () and route.legs[2].edges == ()


def test_planner_input_checks() -> None:
    g, res = planned([1, 2], {1: (0, 30)})
    planner = MissionPlanner(g, res)
    with pytest.raises(ValueError):
        planner.plan(start=W("9.9.9"))
    with pytest.raises(ValueError):
        planner.plan(first_checkpoint=5)
    with pytest.raises(ValueError):
        MissionPlanner(g, [W("9.9.9")])
    explicit = MissionPlanner(g, [W("1.1.1"), W("2.1.3")])
    assert explicit.numbers == (1, 2) and explicit.plan().reached_all


def test_curvature_caps_the_speed_in_tight_exits() -> None:
    g, res = planned([1, 2], {1: (0, 30), 2: (0, 30), 3: (0, 30)})
    planner = MissionPlanner(g, res)
    straight = g.edge(W("1.1.5"), W("2.1.1"))
    bend = g.edge(W("1.1.5"), W("3.1.1"))  # into the detour, turning north-east
    v = 30 * MPH_TO_MPS
    assert planner.edge_time_s(straight) == pytest.approx(straight.length_m / v)
    k = np.abs(bend.path.curvature_1pm)
    assert np.max(k) > 2.0 / v**2  # tight enough that 2 m/s^2 caps the speed somewhere
    assert planner.edge_time_s(bend) > bend.length_m / v


REAL_MISSIONS = sorted(m for m in MDF_TO_RNDF if m not in INCONSISTENT_PAIRS)


@pytest.mark.parametrize("mdf", REAL_MISSIONS)
def test_real_missions_are_planned_optimally(mdf: str) -> None:
    res = resolved(mdf)
    g = graph(MDF_TO_RNDF[mdf])
    g.apply_speed_limits(res)
    try:
        planner = MissionPlanner(g, res)
        route = planner.plan()
        assert route.reached_all and route.checkpoints == res.checkpoint_numbers
        for leg in route.legs:
            end = leg.edges[-1].end if leg.edges else None
            assert end in (None, leg.target)
            if leg.edges:
                assert leg.edges[-1].checkpoint_at_end == leg.checkpoint
        # A* with the straight-line heuristic finds what Dijkstra finds
        weight = {(e.start, e.end): planner.edge_time_s(e) for e in g.edges()}
        here = res.waypoints[0]
        total = 0.0
        for goal in res.waypoints:
            if goal != here:
                total += nx.dijkstra_path_length(
                    g.digraph, here, goal, weight=lambda u, v, _d: weight[(u, v)]
                )
            here = goal
        assert route.time_s == pytest.approx(total, rel=1e-9, abs=1e-9)
        assert route.length_m == pytest.approx(route.path.length_m, rel=1e-9, abs=1e-9)
    finally:
        g.apply_speed_limits(None)


def test_heuristic_is_admissible_on_a_real_network() -> None:
    g = graph("darpa_nqe/nqe_rndf.rdf")
    res = resolved("darpa_nqe/nqe_b1_mdf.mdf")
    g.apply_speed_limits(res)
    try:
        planner = MissionPlanner(g, res)
        vmax = max([RouteCosts().default_speed_mps] + [e.speed_max_mps or 0.0 for e in g.edges()])
        for e in g.edges():
            (x0, y0), (x1, y1) = g.vertex_xy(e.start), g.vertex_xy(e.end)
            assert planner.edge_time_s(e) >= math.hypot(x1 - x0, y1 - y0) / vmax - 1e-9
    finally:
        g.apply_speed_limits(None)
    assert network("darpa_nqe/nqe_rndf.rdf").name == "RNDF_NQE"
