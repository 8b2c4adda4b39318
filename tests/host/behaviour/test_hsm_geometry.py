"""Geometry under the HSM: K-turn legs (derived, and driven by the real lateral controller), the passing
shift, the zone stand-in's polylines, the route view (events, checkpoints, speed caps, tracking, stubs),
intersections (clusters, box, conflicts of a crossing), and the interfaces: the situation's checks
(with a fuzz test), the command's plugs into `lateral_step` and `longitudinal_step`."""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest
from hsm_sim import W, cross_network, ring_network
from hypothesis import given, settings
from hypothesis import strategies as st

from bywire.host.behaviour import rules
from bywire.host.behaviour.behaviour import Behaviour
from bywire.host.behaviour.intersection_manager import crossing_geometry
from bywire.host.behaviour.intersection_map import IntersectionMap, convex_hull, inside_convex
from bywire.host.behaviour.manoeuvre import (
    kturn_legs,
    path_leg,
    polyline_leg,
    quintic_step,
    shifted_leg,
    steering_speed_cap,
)
from bywire.host.behaviour.precedence import Turn
from bywire.host.behaviour.route_view import curve_speed_cap_mps
from bywire.host.behaviour.situation import (
    BlockedRoad,
    EgoState,
    EStop,
    LaneRef,
    PathStub,
    Situation,
    TrackedObject,
    stub_from_arrays,
)
from bywire.host.lateral import LateralParams, PathSamples, VehiclePose, lateral_step, simulate_tracking
from bywire.host.longitudinal import LongitudinalParams, LongitudinalState, longitudinal_step


def _wrap(a: float) -> float:
    return math.atan2(math.sin(a), math.cos(a))


# ------------------------------------------------------------------------------------------- K-turn


@pytest.mark.parametrize(("offset", "radius"), [(3.66, 5.5), (4.0, 5.5), (7.0, 6.0), (2.0, 4.71)])
def test_kturn_three_arcs_join_and_end_on_the_opposite_lane(offset: float, radius: float) -> None:
    x0, y0, h0 = 10.0, -3.0, 0.4
    legs = kturn_legs(x0, y0, h0, offset, radius)
    assert [leg.direction for leg in legs] == [1, -1, 1]
    for a, b in itertools.pairwise(legs):
        ax, ay, ah = a.point_at(a.end_s_m)
        assert math.hypot(ax - b.x[0], ay - b.y[0]) < 1e-9  # a cusp: same place ...
        assert abs(_wrap(ah - b.heading[0])) < 1e-9  # ... same heading, the gear changes
    ex, ey, eh = legs[-1].point_at(legs[-1].end_s_m)
    assert ex == pytest.approx(x0 - offset * math.sin(h0), abs=1e-9)
    assert ey == pytest.approx(y0 + offset * math.cos(h0), abs=1e-9)
    assert _wrap(eh - (h0 + math.pi)) == pytest.approx(0.0, abs=1e-9)
    for leg in legs:
        arc = leg.s <= leg.end_s_m
        assert np.allclose(np.abs(leg.kappa[arc]), 1.0 / radius)
        # the body heading is the travel heading forward and the opposite reversing
        travel = np.arctan2(np.diff(leg.y[arc]), np.diff(leg.x[arc]))
        body = 0.5 * (leg.heading[arc][1:] + leg.heading[arc][:-1])
        err = np.angle(np.exp(1j * (travel - body - (0.0 if leg.direction == 1 else math.pi))))
        assert np.max(np.abs(err)) < 1e-3
        # steering curvature: +dheading/ds forward, -dheading/ds reversing (host/lateral.py)
        dh = np.diff(leg.heading[arc]) / np.diff(leg.s[arc])
        assert np.allclose(dh * leg.direction, leg.kappa[arc][1:], rtol=1e-3)  # chords vs arcs


def test_kturn_wide_street_is_one_forward_half_circle() -> None:
    legs = kturn_legs(0.0, 0.0, 0.0, 12.0, 5.5)
    assert len(legs) == 1 and legs[0].direction == 1
    x, y, h = legs[0].point_at(legs[0].end_s_m)
    assert (x, y) == pytest.approx((0.0, 12.0), abs=1e-9) and _wrap(h - math.pi) == pytest.approx(
        0.0, abs=1e-9
    )
    with pytest.raises(ValueError, match="offset_m"):
        kturn_legs(0.0, 0.0, 0.0, -1.0, 5.5)


def test_the_lateral_controller_drives_the_kturn_legs() -> None:
    """Each leg as `PathSamples`, tracked by the real orbital controller from its start (Sec. 11.1)."""
    params = LateralParams()
    for leg in kturn_legs(0.0, 0.0, 0.0, 3.66, rules.KTURN_RADIUS_M):
        path = PathSamples(leg.x, leg.y, leg.heading, leg.kappa, leg.s)
        start = VehiclePose(float(leg.x[0]), float(leg.y[0]), float(leg.heading[0]))
        trace = simulate_tracking(path, start, 1.0, leg.direction, params, 0.05, stop_before_end_m=1.0)
        assert np.max(np.abs(trace.lateral_error_m)) < 0.05


def test_shifted_leg_out_and_back() -> None:
    s = np.arange(0.0, 80.0, 0.25)
    x, y, h = s.copy(), np.zeros_like(s), np.zeros_like(s)
    leg = shifted_leg(x, y, h, s, 3.66, 10.0, 40.0, rules.PASS_SHIFT_LENGTH_M)
    assert leg.y[0] == 0.0 and leg.y[-1] == pytest.approx(0.0, abs=1e-12)
    assert np.max(leg.y) == pytest.approx(3.66) and np.all(leg.y >= -1e-12)
    assert leg.route_s(float(leg.s[-1])) == pytest.approx(s[-1])
    # the quintic shift's curvature d'' / (1 + d'²)^1.5,
    # with d' = 30 u² (1-u)² D/L and d'' = 60 u (1-u) (1-2u) D/L²
    big_l = rules.PASS_SHIFT_LENGTH_M
    u = np.linspace(0.0, 1.0, 2001)
    d1 = 30.0 * u**2 * (1 - u) ** 2 * 3.66 / big_l
    d2 = 60.0 * u * (1 - u) * (1 - 2 * u) * 3.66 / big_l**2
    peak = float(np.max(np.abs(d2 / (1.0 + d1 * d1) ** 1.5)))
    assert peak < 5.78 * 3.66 / big_l**2  # below the shift's own second derivative (rules.py)
    assert np.max(np.abs(leg.kappa)) == pytest.approx(peak, rel=0.03)
    # continuous: per 0.25 m sample no more than the quintic's third derivative 60 D / L^3 allows
    # (a jump would be the whole 0.13 1/m)
    assert np.max(np.abs(np.diff(leg.kappa))) < 1.2 * 0.25 * 60.0 * 3.66 / big_l**3
    assert quintic_step(np.array([-1.0, 0.0, 0.5, 1.0, 2.0])) == pytest.approx([0.0, 0.0, 0.5, 1.0, 1.0])


def test_polyline_leg_samples_and_reversing_heading() -> None:
    fwd = polyline_leg([(0.0, 0.0), (10.0, 0.0), (10.0, 5.0)], 1)
    assert np.max(np.diff(fwd.s)) <= 0.25 + 1e-9 and fwd.end_s_m == pytest.approx(15.0)
    assert fwd.s[-1] == pytest.approx(16.0)  # runs on 1 m past the end
    assert fwd.heading[0] == pytest.approx(0.0) and fwd.point_at(15.5)[:2] == pytest.approx((10.0, 5.5))
    back = polyline_leg([(0.0, 0.0), (-8.0, 0.0)], -1)
    assert _wrap(float(back.heading[0])) == pytest.approx(0.0)  # reversing west, the nose points east
    assert back.locate_anywhere(-4.0, 0.3) == pytest.approx(4.0)
    with pytest.raises(ValueError):
        polyline_leg([(1.0, 1.0), (1.0, 1.0)])


# ------------------------------------------------------------------------------------------- the route view


@pytest.fixture(scope="module")
def cross():  # type: ignore[no-untyped-def]
    return cross_network([1, 3])


def test_curve_speed_caps_lateral_acceleration_and_tight_turns() -> None:
    k = np.array([0.0, 0.02, 0.1, 0.15, 0.199, 0.2, 0.212, -0.2])
    cap = curve_speed_cap_mps(k)
    lateral = np.sqrt(rules.CURVE_LATERAL_ACCEL_MPS2 / np.maximum(np.abs(k), 1e-9))
    gentle = np.abs(k) < rules.TIGHT_TURN_CURVATURE_1PM
    np.testing.assert_allclose(cap[gentle], lateral[gentle])
    # near full lock the steering's rate sets the speed, not the lateral acceleration (3.2 m/s at 0.2)
    assert np.all(cap[~gentle] == np.minimum(lateral[~gentle], rules.TIGHT_TURN_SPEED_MPS))
    assert np.all(cap[~gentle] <= rules.TIGHT_TURN_SPEED_MPS) and lateral[-1] > 3.0


def test_route_view_events_and_checkpoints(cross) -> None:  # type: ignore[no-untyped-def]
    b = Behaviour(cross.planner, lane_index=cross.lane_index)
    view = b.route_view
    [ev] = view.intersections
    assert ev.approach == W("1.1.4") and ev.stop and ev.s_m == pytest.approx(142.0)
    assert view.edges[ev.crossing].kind.value == "exit" and ev.exit_end_s_m > ev.s_m + 10.0
    assert [(m.number, m.final) for m in view.checkpoints] == [(1, False), (3, True)]
    assert view.checkpoints[0].s_m == 0.0 and view.checkpoints[1].s_m == pytest.approx(view.length_m)
    assert view.finish_s_m == pytest.approx(view.length_m)
    # speed caps: the MDF's 25 mph on the straights, sqrt(a_lat / kappa) in the left turn
    assert view.v_cap[10] == pytest.approx(25 * rules.MPH_MPS)
    turn = view.window(ev.s_m, ev.exit_end_s_m)
    k = float(np.max(np.abs(view.kappa[turn])))
    assert float(np.min(view.v_cap[turn])) == pytest.approx(math.sqrt(rules.CURVE_LATERAL_ACCEL_MPS2 / k))
    # tracking in a window, stubs 30 m ahead and 2 m behind
    s, lateral, _ = view.locate(-100.0, -1.5, 40.0)
    assert s == pytest.approx(50.0) and lateral == pytest.approx(0.5)
    stub, ego_s = view.stub(50.0, rules.STUB_LENGTH_M, rules.STUB_BACK_M)
    assert ego_s == pytest.approx(2.0) and stub.length_m == pytest.approx(32.0)
    assert np.max(np.diff(stub.s_m)) <= 0.25 + 1e-9


def test_speed_profile_anticipates_the_turn(cross) -> None:  # type: ignore[no-untyped-def]
    view = Behaviour(cross.planner, lane_index=cross.lane_index).route_view
    ev = view.intersections[0]
    b = rules.SPEED_ANTICIPATION_DECEL_MPS2
    far, _ = view.speed_profile(0.0, b, 100.0, 2.0)
    assert far == pytest.approx(25 * rules.MPH_MPS)
    near, cap = view.speed_profile(ev.s_m - 20.0, b, 100.0, 2.0)
    assert cap < 6.0 and cap <= near < math.sqrt(cap**2 + 2.0 * b * 25.0)
    assert near == pytest.approx(
        max(math.sqrt(cap**2 + 2 * b * (view.s[np.argmin(view.v_cap)] - ev.s_m + 20.0)) - b * 2.0, cap),
        rel=0.05,
    )


# ------------------------------------------------------------------------------------------- intersections


def test_convex_hull_and_inside() -> None:
    hull = convex_hull(np.array([[0, 0], [4, 0], [4, 4], [0, 4], [2, 2], [2, 0]], dtype=float))
    assert hull.shape == (4, 2)
    assert (
        inside_convex(hull, 1.0, 1.0)
        and not inside_convex(hull, 5.0, 1.0)
        and not inside_convex(hull, 4.0, 2.0)
    )
    assert convex_hull(np.array([[0.0, 0.0], [1.0, 1.0]])).shape == (0, 2)


def test_intersection_map_clusters(cross) -> None:  # type: ignore[no-untyped-def]
    imap = IntersectionMap(cross.graph)
    info = imap.at(W("1.1.4"))
    assert info is not None and info.is_real
    assert set(info.stops) == {W("1.1.4"), W("2.2.4"), W("3.1.4"), W("4.2.4")} == set(info.approaches)
    assert len(info.exits) == 12 and len(info.lanes) == 8
    assert info.in_box(0.0, 0.0) and not info.in_box(-10.5, -2.0)  # a car waiting at its line is outside
    assert imap.at(W("1.1.2")) is None
    # an L corner's two turns share no waypoint: they are merged by distance into one intersection
    ring = IntersectionMap(ring_network().graph)
    corner = ring.at(W("1.1.5"))
    assert corner is not None and set(corner.approaches) == {W("1.1.5"), W("2.2.3")}


@pytest.mark.parametrize(
    ("checkpoints", "turn", "oncoming_conflict"),
    [([1, 3], Turn.LEFT, True), ([1, 4], Turn.RIGHT, False), ([1, 2], Turn.STRAIGHT, False)],
)
def test_crossing_conflicts(checkpoints: list[int], turn: Turn, oncoming_conflict: bool) -> None:
    net = cross_network(checkpoints, stops="ns")
    b = Behaviour(net.planner, lane_index=net.lane_index)
    ev = b.route_view.intersections[0]
    crossing = crossing_geometry(net.graph, b.route_view, ev)
    assert crossing.turn == turn and crossing.own_priority
    straight_on = [c for c in crossing.conflicts if c.branch == (W("2.2.4"), W("1.2.1"))]
    assert bool(straight_on) == oncoming_conflict
    for c in straight_on:  # the oncoming lane, straight on, crosses our left turn inside the box
        assert c.side == "opposite" and c.priority and 3.0 < c.own_offset_m < 25.0
        assert net.graph.lane_s(W("2.2.4")) < c.lane_s_m < net.graph.lane_s(W("2.2.4")) + 16.0
    assert all(c.lane != W("1.1.1").lane_id for c in crossing.conflicts)  # never our own lane


# ------------------------------------------------------------------------------------------- interfaces


def _sit(t: float = 0.0, **over: object) -> Situation:
    base = {"t_s": t, "ego": EgoState(-150.0, -2.0, 0.0, 0.0)}
    base.update(over)
    return Situation(**base)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("sit", "message"),
    [
        (_sit(float("nan")), r"Situation.t_s = nan"),
        (_sit(ego=EgoState(float("inf"), 0.0, 0.0, 0.0)), r"Situation.ego.x_m = inf"),
        # finite but off the map: 1e300 m overflowed the lane index's kd-tree (found by the fuzz test below)
        (_sit(ego=EgoState(8.0, 1e300, 0.0, 1.0)), r"Situation.ego.y_m = 1e\+300: beyond"),
        (_sit(objects=(TrackedObject("a", -2e7, 0, 0, 1, 4, 2),)), r"objects\[0\] \('a'\).x_m = -2"),
        (_sit(objects=(TrackedObject("a", 0, 0, 0, -1.0, 4, 2),)), r"objects\[0\] \('a'\).speed_mps = -1.0"),
        (_sit(objects=(TrackedObject("a", 0, 0, 0, 1.0, 0.0, 2),)), r"objects\[0\] \('a'\).length_m = 0.0"),
        (
            _sit(objects=(TrackedObject("a", 0, 0, 0, 1, 4, 2), TrackedObject("a", 9, 0, 0, 1, 4, 2))),
            r"objects\[1\] \('a'\).object_id: listed twice",
        ),
        (_sit(objects=(TrackedObject("", 0, 0, 0, 1, 4, 2),)), r"object_id: must be a non-empty string"),
        (
            _sit(
                objects=(TrackedObject("a", 0, 0, 0, 1, 4, 2, LaneRef((W("1.1.1"), W("1.1.2")), math.nan)),)
            ),
            r"lane.s_m",
        ),
        (_sit(blocked=(BlockedRoad(math.nan, 0.0),)), r"blocked\[0\].x_m"),
        (_sit(estop="run"), r"Situation.estop = 'run'"),
    ],
)
def test_bad_situations_name_the_field(cross, sit: Situation, message: str) -> None:  # type: ignore[no-untyped-def]
    b = Behaviour(cross.planner, lane_index=cross.lane_index)
    with pytest.raises(ValueError, match=message):
        b.step(sit)
    b.step(_sit(5.0))
    with pytest.raises(ValueError, match="before the previous cycle"):
        b.step(_sit(4.0))


_num = st.one_of(st.floats(-200, 200), st.sampled_from([math.nan, math.inf, -math.inf, 0.0, -1.0, 1e300]))


@st.composite
def _situations(draw):  # type: ignore[no-untyped-def]
    objs = draw(
        st.lists(
            st.builds(
                TrackedObject,
                st.sampled_from(["a", "b", "c", ""]),
                _num,
                _num,
                _num,
                _num,
                _num,
                _num,
                st.one_of(
                    st.none(),
                    st.builds(
                        LaneRef, st.sampled_from([(W("1.1.1"), W("1.1.2")), (W("9.9.9"), W("9.9.8"))]), _num
                    ),
                ),
            ),
            max_size=4,
        )
    )
    return Situation(
        t_s=draw(st.one_of(st.floats(0, 100), _num)),
        ego=EgoState(draw(_num), draw(_num), draw(_num), draw(_num), draw(_num)),
        objects=tuple(objs),
        blocked=tuple(draw(st.lists(st.builds(BlockedRoad, _num, _num), max_size=2))),
        estop=draw(st.sampled_from(list(EStop))),
    )


@settings(max_examples=50, deadline=None)
@given(st.lists(_situations(), min_size=1, max_size=4))
def test_fuzzed_situations_give_a_command_or_a_clear_error(cross, sits: list[Situation]) -> None:  # type: ignore[no-untyped-def]
    b = Behaviour(cross.planner, lane_index=cross.lane_index)
    for sit in sits:
        try:
            cmd = b.step(sit)
        except ValueError as exc:
            assert "Situation" in str(exc)
            continue
        assert cmd.fault is None, cmd.fault
        assert math.isfinite(cmd.desired_speed_mps) and cmd.desired_speed_mps >= 0.0
        cmd.path_samples()
        longitudinal_step(
            LongitudinalState(), cmd.longitudinal_inputs(sit.ego.speed_mps), LongitudinalParams()
        )


def test_command_plugs_into_both_controllers(cross) -> None:  # type: ignore[no-untyped-def]
    b = Behaviour(cross.planner, lane_index=cross.lane_index)
    cmd = b.step(_sit(0.0, ego=EgoState(-120.0, -2.3, 0.05, 8.0)))
    out = lateral_step(cmd.path_samples(), VehiclePose(-120.0, -2.3, 0.05), cmd.direction, LateralParams())
    assert out.lateral_error_m == pytest.approx(-0.3, abs=1e-6) and out.steer_rad > 0.0
    inputs = cmd.longitudinal_inputs(-8.0)  # reversing speeds are fed as magnitudes
    assert inputs.v_mps == 8.0 and inputs.v_des_mps == cmd.desired_speed_mps
    assert inputs.stop_distance_m == pytest.approx(cmd.stop_point_s_m - cmd.ego_s_m)  # type: ignore[operator]
    stub = stub_from_arrays([0.0, 0.0, 1.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], -1)
    assert isinstance(stub, PathStub) and stub.s_m.tolist() == [0.0, 1.0] and stub.direction == -1


def test_coarse_then_fine_conflict_search_equals_the_brute_force_one() -> None:
    from bywire.host.behaviour.intersection_manager import _first_close, _first_conflict

    rng = np.random.default_rng(5)
    for _ in range(200):
        t = np.arange(0.0, 60.0, 0.25)
        a0, a1 = rng.uniform(-math.pi, math.pi, 2)
        own = np.column_stack((t * math.cos(a0), t * math.sin(a0) + 0.01 * t * t * rng.uniform(-1, 1)))
        start = rng.uniform(-30.0, 30.0, 2)
        other = np.column_stack((start[0] + t * math.cos(a1), start[1] + t * math.sin(a1)))
        brute = _first_close(own, other, rules.CONFLICT_DISTANCE_M)
        fast = _first_conflict(own, other, rules.CONFLICT_DISTANCE_M)
        assert fast == brute


def _waiting_at(manager, line_id: str, object_id: str, speed_mps: float = 0.0, back_m: float = 0.3):  # type: ignore[no-untyped-def]
    """A car of 4.5 m with its front bumper `back_m` before stop line `line_id`."""
    (lx, ly), h = manager._line_pose[line_id]
    d = back_m + 2.25
    return TrackedObject(object_id, lx - d * math.cos(h), ly - d * math.sin(h), h, speed_mps, 4.5, 1.8)


def _four_way_stop_manager():  # type: ignore[no-untyped-def]
    """The manager of the cross network's four-way stop, and a stop line other than ours."""
    from bywire.host.behaviour.intersection_manager import IntersectionManager

    net = cross_network([1, 2], stops="all")
    b = Behaviour(net.planner, lane_index=net.lane_index)
    ev = b.route_view.intersections[0]
    m = IntersectionManager(net.graph, b.route_view, ev, None)
    other = next(line for line in m._line_pose if line != str(ev.approach))
    return m, other


def test_a_waiting_car_hidden_then_found_under_a_new_id_keeps_its_arrival() -> None:
    """A LIDAR tracker loses a car waiting at its line while another crosses between us, and finds it
    again under a new id, often as it starts: the same car, still first in the queue."""
    from bywire.host.behaviour.intersection_manager import REACQUIRE_S

    m, other = _four_way_stop_manager()
    m.update(0.0, (_waiting_at(m, other, "a"),))
    assert [(w.vehicle_id, w.arrived_s) for w in m.waiting] == [("a", 0.0)]
    m.update(1.0, ())  # hidden: still waits there
    assert [(w.vehicle_id, w.arrived_s) for w in m.waiting] == [("a", 0.0)]
    m.update(1.5, (_waiting_at(m, other, "b", speed_mps=1.5),))  # found again, already starting
    assert [(w.vehicle_id, w.arrived_s) for w in m.waiting] == [("b", 0.0)]
    # gone for longer than REACQUIRE_S: gone, and a car that comes later arrives when it comes
    m.update(2.0, ())
    m.update(2.0 + REACQUIRE_S + 0.1, ())
    assert m.waiting == ()
    m.update(6.0, (_waiting_at(m, other, "c"),))
    assert [(w.vehicle_id, w.arrived_s) for w in m.waiting] == [("c", 6.0)]


def test_two_tracks_at_one_line_share_its_earliest_arrival() -> None:
    """A car half hidden is segmented in two: the fragment that stays keeps the car's place in the queue."""
    m, other = _four_way_stop_manager()
    m.update(0.0, (_waiting_at(m, other, "a"),))
    m.update(5.0, (_waiting_at(m, other, "a"), _waiting_at(m, other, "b", back_m=1.0)))
    assert sorted((w.vehicle_id, w.arrived_s) for w in m.waiting) == [("a", 0.0), ("b", 0.0)]
    m.update(5.5, (_waiting_at(m, other, "b", back_m=1.0),))
    assert [(w.vehicle_id, w.arrived_s) for w in m.waiting] == [("b", 0.0)]


def test_the_speed_cap_gives_the_wheels_time_to_steer_where_the_curvature_jumps() -> None:
    """A leg straight for 10 m, then full left lock: at 0.35 rad/s the wheels need atan(2.72 / 5.5) /
    0.35 s; standing d m before the jump the cap lets that time cover d + 0.5 m, and on the arc itself,
    where the curvature stays, there is nothing to wait for."""
    s = np.arange(0.0, 20.01, 0.25)
    kappa = np.where(s < 10.0, 0.0, 1.0 / 5.5)
    leg = path_leg(s, np.zeros_like(s), np.zeros_like(s), 1)
    leg = dataclasses.replace(leg, kappa=kappa, s=s)
    turn_s = math.atan(2.72 / 5.5) / 0.35
    for d in (6.0, 3.0, 1.0):
        cap = steering_speed_cap(leg, 10.0 - d, 2.72, 0.35, 0.5, 8.0)
        assert cap == pytest.approx((d + 0.5) / turn_s, rel=0.05)
    assert steering_speed_cap(leg, 12.0, 2.72, 0.35, 0.5, 8.0) == math.inf
    assert steering_speed_cap(leg, 0.0, 2.72, 0.35, 0.5, 8.0) == math.inf  # the jump is beyond the preview
