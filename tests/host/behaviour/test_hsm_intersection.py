"""The Intersection family (seed 000 Sec. 9.3, Fig. 15; the n x 10 s lesson of Sec. 12).

Scripted situations at a four-way stop (the cross network, stop signs on all four approaches): 0, 1, 2
and 3 vehicles already waiting go first, each in its turn, however long that takes; a vehicle that
arrives after us does not delay us; one that never moves is waited for its own bounded turn, then we
go with caution. Closed loops: three waiting cars, queueing behind a car at our stop line, stop-line
accuracy, a left turn across oncoming traffic on a priority road (with the MTC's point-mass inputs
checked against the geometry), merging into moving traffic, an E-stop PAUSE while waiting, and the
family's recovery."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hsm_sim import (
    Script,
    Sim,
    W,
    at_stop_line,
    car_on,
    constant,
    cross_network,
    depart_at,
)

from bywire.host.behaviour import rules
from bywire.host.behaviour.mtc import DriveOff
from bywire.host.behaviour.situation import EStop

LINE_S = 142.0  # our stop line 1.1.4 along the route from 1.1.1 (the west arm's far end)
FRONT = rules.PASSAT_REAR_AXLE_TO_FRONT_M
# a car waiting with its front 0.3 m before its line drives 18.55 m straight across until its centre is
# past the far side of the box (the hull through the stop lines 8 m from the centre): 3.71 s at 5 m/s
CROSS_S = (8.0 + 8.0 + 0.5 * 4.5 + 0.3) / 5.0
OTHER_LINES = {"east": "2.2.4", "north": "4.2.4", "south": "3.1.4"}


@pytest.fixture(scope="module")
def fourway():  # type: ignore[no-untyped-def]
    return cross_network([1, 2])


def run_fourway(net, cars: dict[str, tuple[float, float | None]], t_end: float = 60.0) -> Script:  # type: ignore[no-untyped-def]
    """We approach (t < 2 s, moving), then stand with the front bumper on the line. `cars`: name ->
    (when it appears stopped at its line, when it departs straight across or None)."""
    run = Script(net)
    for k in range(int(t_end / 0.1) + 1):
        t = round(0.1 * k, 9)
        ego = run.ego_at(100.0 + 6.0 * t, 6.0) if t < 2.0 else run.ego_at(LINE_S - FRONT, 0.0)
        objects = [
            at_stop_line(net.graph, OTHER_LINES[name], name, t, go)
            for name, (seen, go) in cars.items()
            if t >= seen
        ]
        run.step(t, ego, objects)
    return run


@pytest.mark.parametrize("n", [0, 1, 2, 3])
def test_vehicles_already_waiting_go_first_in_turn(fourway, n: int) -> None:  # type: ignore[no-untyped-def]
    # they stand there before we come; each leaves 5 s after the previous one (so together they take
    # longer than the 10 s after which AnnieWAY's planner stopped waiting for all of them)
    names = ["east", "north", "south"][:n]
    cars = {name: (0.0, 5.0 + 5.0 * i) for i, name in enumerate(names)}
    run = run_fourway(fourway, cars)
    assert run.leaves() == ["IntersectionStop", "IntersectionWait", "IntersectionDriveInside"]
    wait = run.first("IntersectionWait")
    go = run.first("IntersectionDriveInside")
    assert wait is not None and go is not None
    if n == 0:  # a clear intersection: the minimum full stop, far inside the rules' 10 s
        assert go.t_s == pytest.approx(wait.t_s + rules.INTERSECTION_MIN_WAIT_S, abs=0.11)
        return
    assert wait.reason.count("with precedence") == 1 and all(name in wait.reason for name in names)
    last_clear = 5.0 + 5.0 * (n - 1) + CROSS_S
    assert last_clear <= go.t_s <= last_clear + 0.3  # the n x 10 s bug would have gone at 12 s
    assert not go.reason.count("caution")
    # while waiting the command holds us at the line (a car crossing in front may ask for more braking)
    waiting = [c for c in run.commands if c.state.endswith("IntersectionWait")]
    assert all(
        c.desired_speed_mps == 0.0 and c.stop_distance_m is not None and c.stop_distance_m <= 1e-6
        for c in waiting
    )


def test_a_car_arriving_after_us_waits_for_us(fourway) -> None:  # type: ignore[no-untyped-def]
    run = run_fourway(fourway, {"east": (4.0, None), "north": (2.6, None)})  # both stop after us (t = 2 s)
    wait, go = run.first("IntersectionWait"), run.first("IntersectionDriveInside")
    assert wait is not None and go is not None
    assert go.t_s == pytest.approx(wait.t_s + rules.INTERSECTION_MIN_WAIT_S, abs=0.11)


@pytest.mark.parametrize("stuck", [["east"], ["east", "south"]])
def test_a_car_that_never_moves_gets_its_turn_then_we_go_with_caution(fourway, stuck: list[str]) -> None:  # type: ignore[no-untyped-def]
    run = run_fourway(fourway, {name: (0.0, None) for name in stuck})
    wait, go = run.first("IntersectionWait"), run.first("IntersectionDriveInside")
    assert wait is not None and go is not None
    # each gets its own PRECEDENCE_STUCK_S turn, one after the other: n x 10 s, done right
    assert go.t_s == pytest.approx(wait.t_s + len(stuck) * rules.PRECEDENCE_STUCK_S, abs=0.11)
    assert "with caution" in go.reason


def test_pause_holds_everything_and_resumes_in_the_same_state(fourway) -> None:  # type: ignore[no-untyped-def]
    """E-stop PAUSE while we wait our turn: 100 s (longer than every no-progress time and than the 10 s
    a vehicle gets for its turn), the state, its timers and the precedence are frozen; after RUN we
    resume waiting and go in turn. East's turn runs from our arrival (2 s); it goes 1 s after the
    pause; north, also there before us, leaves during the pause (then it no longer counts)."""
    run = Script(fourway)
    net = fourway
    cars = {"east": (0.0, 106.0), "north": (0.0, 50.0)}
    pause = (5.0, 105.0)
    for k in range(int(120 / 0.1)):
        t = round(0.1 * k, 9)
        ego = run.ego_at(100.0 + 6.0 * t, 6.0) if t < 2.0 else run.ego_at(LINE_S - FRONT, 0.0)
        objs = [at_stop_line(net.graph, OTHER_LINES[n], n, t, go) for n, (seen, go) in cars.items()]
        run.step(t, ego, objs, EStop.PAUSE if pause[0] <= t < pause[1] else EStop.RUN)
    paused = [c for c in run.commands if c.paused]
    assert paused and {c.state for c in paused} == {"Intersection/IntersectionWait"}
    assert all(c.desired_speed_mps == 0.0 and c.stop_distance_m == pytest.approx(0.0) for c in paused)
    assert not any(c.transitions for c in paused)
    assert not any("Recovery" in c.state for c in run.commands)
    go = run.first("IntersectionDriveInside")
    assert go is not None and 106.0 + CROSS_S <= go.t_s <= 106.0 + CROSS_S + 0.3
    assert "caution" not in go.reason  # nobody was declared stuck: the pause did not count
    assert run.behaviour.clock_s == pytest.approx(run.commands[-1].t_s - 100.0, abs=0.11)


def test_intersection_recovery_then_global_recovery(fourway) -> None:  # type: ignore[no-untyped-def]
    """Stuck 15 m before the line (the car does not move, nothing else does): after
    INTERSECTION_NO_PROGRESS_S the family's recovery, RECOVERY_NO_PROGRESS_S later the global one."""
    run = Script(fourway)
    for k in range(int(100 / 0.5)):
        run.step(0.5 * k, run.ego_at(LINE_S - FRONT - 15.0, 0.0))
    rec, glob = run.first("IntersectionRecovery"), run.first("GlobalRecovery")
    stop = run.first("IntersectionStop")
    assert stop is not None and rec is not None and glob is not None
    assert rec.t_s == pytest.approx(stop.t_s + rules.INTERSECTION_NO_PROGRESS_S, abs=0.51)
    assert glob.t_s == pytest.approx(rec.t_s + rules.RECOVERY_NO_PROGRESS_S, abs=0.51)
    assert run.leaves()[-1] in ("GlobalRecovery", "DriveOnLane", "IntersectionApproach", "IntersectionStop")


def test_moving_traffic_at_the_intersection_is_progress(fourway) -> None:  # type: ignore[no-untyped-def]
    run = Script(fourway)
    for k in range(int(90 / 0.5)):
        t = 0.5 * k
        crossing = at_stop_line(fourway.graph, "3.1.4", "busy", t, depart_s=t - 1.0, speed_mps=1.0)
        run.step(t, run.ego_at(LINE_S - FRONT - 15.0, 0.0), [crossing])
    assert run.first("IntersectionRecovery") is None


# ------------------------------------------------------------------------------------------- closed loops


def _waiting_car(net, name: str, wps: list[str], t_go: float):  # type: ignore[no-untyped-def]
    s_line = net.graph.edge(W(wps[0]), W(wps[1])).length_m
    return car_on(net.graph, name, wps, s_line - 0.5 * 4.5 - 0.3, depart_at(t_go, 5.0))


@pytest.fixture(scope="module")
def three_waiting():  # type: ignore[no-untyped-def]
    net = cross_network([1, 2])
    cars = [
        _waiting_car(net, "east", ["2.2.3", "2.2.4", "1.2.1", "1.2.2"], 22.0),
        _waiting_car(net, "south", ["3.1.3", "3.1.4", "4.1.1", "4.1.2"], 27.0),
        _waiting_car(net, "north", ["4.2.3", "4.2.4", "3.2.1", "3.2.2"], 32.0),
    ]
    sim = Sim(net, cars=cars)
    assert sim.run_until(lambda s: s.state == "MissionComplete", 120.0)
    return sim


def test_closed_loop_four_way_stop_with_three_waiting(three_waiting) -> None:  # type: ignore[no-untyped-def]
    sim = three_waiting
    assert sim.collisions == [] and sim.faults == []
    assert sim.leaves() == [
        "DriveOnLane",
        "IntersectionStop",
        "IntersectionWait",
        "IntersectionDriveInside",
        "DriveOnLane",
        "MissionComplete",
    ]
    go = sim.first_time("IntersectionDriveInside")
    assert go is not None and go > 32.0 + CROSS_S  # after the last of them has crossed
    reached = sim.frames[-1].command.checkpoints_reached
    assert reached == (1, 2)


def test_stop_line_accuracy(three_waiting) -> None:  # type: ignore[no-untyped-def]
    """rules 5.2: the front bumper stops within 1 m of the stop line (and does not cross it)."""
    sim = three_waiting
    first_wait = next(f for f in sim.frames if f.state.endswith("IntersectionWait"))
    fx = first_wait.x_m + FRONT * math.cos(first_wait.heading_rad)
    assert -rules.STOP_LINE_TOLERANCE_M <= fx - (-8.0) <= 0.0
    waiting = [f for f in sim.frames if f.state.endswith("IntersectionWait")]
    assert max(f.x_m for f in waiting) + FRONT <= -8.0 + 0.05


def test_queueing_behind_a_car_at_the_stop_line() -> None:
    net = cross_network([1, 2])
    ahead = _waiting_car(net, "ahead", ["1.1.3", "1.1.4", "2.1.1", "2.1.2"], 25.0)
    sim = Sim(net, cars=[ahead])
    assert sim.run_until(lambda s: s.state == "MissionComplete", 120.0)
    assert sim.collisions == [] and sim.faults == []
    assert sim.leaves()[:5] == [
        "DriveOnLane",
        "IntersectionQueue",
        "IntersectionStop",  # through IntersectionApproach in the same cycle, as Fig. 15 has it:
        "IntersectionWait",
        "IntersectionDriveInside",
    ]
    fired = [t for f in sim.frames for t in f.command.transitions]
    assert "IntersectionQueue -> IntersectionApproach (the lane to the intersection is free)" in fired
    # in the queue we stop 5-10 m behind the car at the line (rules 5.2)
    queued = [f for f in sim.frames if f.state.endswith("IntersectionQueue") and abs(f.speed_mps) < 0.05]
    assert queued
    gaps = [(-8.0 - 0.3 - 4.5) - (f.x_m + FRONT) for f in queued]
    assert all(rules.STOPPED_LEAD_GAP_MIN_M <= g <= rules.STOPPED_LEAD_GAP_MAX_M for g in gaps)
    # then on to the line, and across once the car ahead has left the box (its own, after 25 s)
    go = sim.first_time("IntersectionDriveInside")
    assert go is not None and go > 25.0 + 2.0


@pytest.fixture(scope="module")
def left_turn():  # type: ignore[no-untyped-def]
    """Priority east-west road (stops only north-south); we turn left from the west arm to the north
    arm; oncoming westbound traffic at 10 m/s, 30 m apart, then a 15 s gap."""
    net = cross_network([1, 3], stops="ns")
    wps = ["2.2.1", "2.2.2", "2.2.3", "2.2.4", "1.2.1", "1.2.2", "1.2.3", "1.2.4"]
    cars = [
        car_on(net.graph, f"on{k}", wps, -30.0 * k - (120.0 if k >= 6 else 0.0), constant(10.0), 10.0)
        for k in range(8)
    ]
    sim = Sim(net, cars=cars)
    assert sim.run_until(lambda s: s.state == "MissionComplete", 120.0)
    return sim, net


def test_left_turn_across_oncoming_traffic(left_turn) -> None:  # type: ignore[no-untyped-def]
    sim, _ = left_turn
    assert sim.collisions == [] and sim.faults == []
    assert sim.leaves()[:5] == [
        "DriveOnLane",
        "IntersectionApproach",
        "IntersectionPrioStop",
        "IntersectionPrioDriveInside",
        "DriveOnLane",
    ]
    # we stood before the opposing lane and turned only in the 15 s gap after the sixth car
    stop_frames = [f for f in sim.frames if f.state.endswith("IntersectionPrioStop")]
    assert min(abs(f.speed_mps) for f in stop_frames) < 0.05
    assert max(f.x_m for f in stop_frames) + FRONT < 0.0  # our front never reached the opposing lane
    go = sim.first_time("IntersectionPrioDriveInside")
    last_car_at_line = (142.0 + 150.0) / 10.0  # car 5 starts 150 m back on a 142 m lane to its line
    assert go is not None and last_car_at_line < go < last_car_at_line + 4.0


def test_left_turn_mtc_uses_the_point_mass_predictions_of_the_geometry() -> None:
    """Standing at the IntersectionPrioStop point, one oncoming car at a range of distances: the MTC's
    t_BMP and t_AMP are those of the merge point found independently here (the polylines' crossing), and
    every approval is safe in a point-mass simulation of eqs. 8-12 (A never in its window while B is in
    its window)."""
    net = cross_network([1, 3], stops="ns")
    run = Script(net)
    view = run.view
    # the independent merge point: where our route first comes within CONFLICT_DISTANCE_M of the
    # oncoming lane's straight exit 2.2.4 -> 1.2.1
    exit_path = net.graph.edge(W("2.2.4"), W("1.2.1")).path
    own = np.column_stack((view.x, view.y))
    other = np.column_stack((exit_path.x_m, exit_path.y_m))
    d2 = ((own[:, None, :] - other[None, :, :]) ** 2).sum(axis=2)
    i = int(np.flatnonzero((d2 < rules.CONFLICT_DISTANCE_M**2).any(axis=1))[0])
    mp_route_s = float(view.s[i])
    mp_lane_s = net.graph.lane_s(W("2.2.4")) + float(exit_path.s_m[int(np.argmin(d2[i]))])
    params = rules.mtc_params(rules.MtcSituation.INTERSECTION_LEFT_TURN)
    stop_front = mp_route_s - params.d_a1_m
    # get into IntersectionPrioStop: approach with an oncoming car close by, then stand at its stop point
    wps = ["2.2.1", "2.2.2", "2.2.3", "2.2.4", "1.2.1"]
    lane_s0 = net.graph.lane_s(W("2.2.1"))
    t = 0.0
    approved = refused = 0
    for d_b in [5.0, 20.0, 40.0, 60.0, 80.0, 100.0, 120.0]:
        for v_b in (5.0, 10.0):
            car = car_on(net.graph, "b", wps, mp_lane_s - lane_s0 - d_b - 2.25, constant(v_b), v_b)
            run2 = Script(net)
            for k in range(30):  # approach: at the decision the car is 6 s from the MP, we as far: stop
                close = car_on(net.graph, "b", wps, mp_lane_s - lane_s0 - 60.0 - 2.25, constant(10.0), 10.0)
                run2.step(0.1 * k, run2.ego_at(LINE_S - 25.0 + 0.5 * k, 5.0), [close.tracked()])
            assert run2.behaviour.state == "Intersection/IntersectionPrioStop"
            cmd = run2.step(3.5, run2.ego_at(stop_front - FRONT, 0.0), [car.tracked()])
            assert cmd.mtc is not None
            mine = [r for r in cmd.mtc.vehicles if r.vehicle_id == "b@2.2.4>1.2.1"]
            assert len(mine) == 1
            r = mine[0]
            a = DriveOff(0.0, params.v_desired_mps, params.accel_sat_mps2)
            assert r.t_b_mp_s == pytest.approx(d_b / v_b, rel=0.02)
            assert r.t_a_mp_s == pytest.approx(a.time_to_travel_s(params.d_a1_m), rel=0.02)
            if r.free:
                approved += 1
                # point masses on a 10 ms grid: never A in [P_A1, P_A2] while B in [P_B1, P_B2]
                for tt in np.arange(0.0, 40.0, 0.01):
                    a_pos = a.distance_m(float(tt)) - params.d_a1_m  # A's front relative to MP
                    b_pos = v_b * tt - d_b
                    a_in = -params.d_a1_m <= a_pos <= params.d_a2_m
                    b_in = -params.d_b1_m <= b_pos <= params.d_b2_m
                    assert not (a_in and b_in), (d_b, v_b, tt)
            else:
                refused += 1
            t += 1.0
    assert approved and refused


def test_merging_into_moving_traffic() -> None:
    """From the south arm's stop line, right into the eastbound priority lane: traffic from our left at
    10 m/s, 30 m apart, then a gap. We wait at the line (case a: the MTC's merge set) and pull in only
    into the gap, keeping rules 5.2's 8 m fore and aft."""
    net = cross_network([7, 2], stops="ns")
    wps = ["1.1.1", "1.1.2", "1.1.3", "1.1.4", "2.1.1", "2.1.2", "2.1.3", "2.1.4"]
    cars = [
        car_on(net.graph, f"e{k}", wps, 60.0 - 30.0 * k - (150.0 if k >= 5 else 0.0), constant(10.0), 10.0)
        for k in range(7)
    ]
    sim = Sim(net, cars=cars)
    assert sim.run_until(lambda s: s.state == "MissionComplete", 150.0)
    assert sim.collisions == [] and sim.faults == []
    assert "IntersectionWait" in sim.leaves() and "IntersectionDriveInside" in sim.leaves()
    go = sim.first_time("IntersectionDriveInside")
    # car 4 passes our merge point (x ~ 2) at (142 + 8 + 2 - (60 - 120)) / 10 = 21.2 s; car 5 ~ 15 s later
    assert go is not None and go > 21.2
    inside = [f for f in sim.frames if f.state.startswith("Intersection/IntersectionDriveInside")]
    assert min(f.min_gap_m for f in inside) > 5.0
