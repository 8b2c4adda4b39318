"""The Drive family (seed 000 Sec. 8): lane following with MDF limits and curve speed, following a slower
car at DARPA's distance and stopping behind it, passing a parked car (out, by, back in, with oncoming
traffic), a lane change under the MTC, a blocked road (detect, mark, K-turn, replan), an unreachable
checkpoint that forgets blockades, getting off track, and the family's recovery escalating to the
global one."""

from __future__ import annotations

import itertools
import math

import pytest
from hsm_sim import (
    EGO_LENGTH_M,
    EGO_REAR_OVERHANG_M,
    Script,
    Sim,
    W,
    car_on,
    constant,
    corners,
    cross_network,
    parked,
    ring_network,
    two_lane_network,
)

from bywire.host.behaviour import rules
from bywire.host.behaviour.situation import BlockedRoad, EgoState, RequestKind, TrackedObject
from bywire.host.roadnet.graph import EdgeKind
from bywire.host.roadnet.road_area import RoadArea

FRONT = rules.PASSAT_REAR_AXLE_TO_FRONT_M
LANE_1_1 = ["1.1.1", "1.1.2", "1.1.3", "1.1.4", "1.1.5", "1.1.6", "1.1.7"]


def test_lane_following_speed_limits_and_curve_speed() -> None:
    net = ring_network(mph=15)
    sim = Sim(net)
    assert sim.run_until(lambda s: s.state == "MissionComplete", 150.0)
    assert sim.collisions == [] and sim.faults == [] and sim.frames[-1].command.checkpoints_reached == (1, 2)
    limit = 15 * rules.MPH_MPS
    assert max(f.speed_mps for f in sim.frames) <= limit + 0.05  # the MDF's limit
    assert max(f.speed_mps for f in sim.frames) > limit - 0.3  # ... and we use it
    # in the corners the speed is that of 2 m/s² lateral (the route's curvature at our position)
    view = sim.behaviour.route_view
    worst, s = 0.0, 0.0
    for f in sim.frames:
        s, _, _ = view.locate(f.x_m, f.y_m, s)
        k = abs(float(view.kappa[view.window(s, s)].max(initial=0.0)))
        if k > 0.05:
            worst = max(worst, f.speed_mps - math.sqrt(rules.CURVE_LATERAL_ACCEL_MPS2 / k))
    assert worst < 0.5


def test_following_a_slower_car_then_stopping_behind_it() -> None:
    net = two_lane_network((1, 3))
    lead = car_on(net.graph, "lead", LANE_1_1, 35.0, lambda t, s: 5.0 if s < 200.0 else 0.0, 5.0)
    sim = Sim(net, cars=[lead])
    assert sim.run_until(lambda s: lead.speed_mps == 0.0 and abs(s.speed) < 0.01 and s.t > 5.0, 120.0)
    assert sim.collisions == []
    # following at 5 m/s: DARPA's one length plus one per 10 mph (seed 000 Sec. 11.2.1)
    rule = rules.forward_following_distance_m(5.0)
    gaps = [
        (lead_x - 2.25) - (f.x_m + FRONT)
        for f, lead_x in ((f, 35.0 + 5.0 * f.t_s) for f in sim.frames)
        if f.t_s > 30.0 and lead_x < 190.0
    ]
    assert gaps and all(abs(g - rule) < 1.0 for g in gaps)
    assert all(f.command.lead is not None and f.command.lead.object_id == "lead" for f in sim.frames[100:])
    # stopped behind the stopped lead: rules 5.2, 5 to 10 m
    gap = (lead.tracked().x_m - 2.25) - sim.front_xy[0]
    assert rules.STOPPED_LEAD_GAP_MIN_M <= gap <= rules.STOPPED_LEAD_GAP_MAX_M
    assert sim.state == "Drive/DriveOnLane" and "stopped behind still lead" in sim.frames[-1].command.reason


@pytest.fixture(scope="module")
def passing():  # type: ignore[no-untyped-def]
    net = ring_network()
    sim = Sim(net, cars=[parked("parked", 110.0, -2.0, 0.0)])
    assert sim.run_until(lambda s: s.state == "MissionComplete", 150.0)
    return sim


def test_passing_a_parked_car(passing) -> None:  # type: ignore[no-untyped-def]
    sim = passing
    assert sim.collisions == [] and sim.faults == []
    leaves = sim.leaves()
    i = leaves.index("PassObstacleOut")
    assert leaves[i : i + 3] == ["PassObstacleOut", "PassObstacleBy", "PassObstacleBack"]
    assert leaves[i + 3] in ("DriveOnLane", "IntersectionApproach")
    # we stood behind it for PASS_STILL_S, 5-10 m back, then left the lane and came back within 40 m
    stood = next(f for f in sim.frames if f.state.startswith("Drive/PassObstacle"))
    gap = (110.0 - 2.25) - (stood.x_m + FRONT)
    assert rules.STOPPED_LEAD_GAP_MIN_M <= gap <= rules.STOPPED_LEAD_GAP_MAX_M
    out = [f for f in sim.frames if f.y_m > -1.9 and 60.0 < f.x_m < 180.0]
    assert max(f.y_m for f in out) == pytest.approx(2.0, abs=0.1)  # the centre of the other lane
    assert out[-1].x_m - out[0].x_m <= rules.PASSING_MANEUVER_MAX_LENGTH_M
    # back in our lane at least PASSING_SEPARATION_M ahead of it
    back = next(
        f for f in sim.frames if f.x_m > 112.25 and f.y_m < 1.9 and f.state.endswith("PassObstacleBack")
    )
    assert back.x_m - 1.1 - (110.0 + 2.25) >= rules.PASSING_SEPARATION_M - 1.2


def test_passing_waits_for_oncoming_traffic() -> None:
    net = ring_network()
    westbound = ["1.2.1", "1.2.2", "1.2.3", "1.2.4", "1.2.5"]
    oncoming = car_on(net.graph, "oncoming", westbound, -120.0, constant(8.0), 8.0)
    sim = Sim(net, cars=[parked("parked", 110.0, -2.0, 0.0), oncoming])
    assert sim.run_until(lambda s: s.state.endswith("PassObstacleBy"), 80.0)
    assert sim.collisions == [] and sim.faults == []
    waiting = [f for f in sim.frames if f.state.endswith("PassObstacleWait")]
    assert waiting and waiting[0].command.mtc is not None and not waiting[0].command.mtc.free
    assert "oncoming traffic" in waiting[0].command.reason
    # we are ready at ~19 s; pulled out only once the oncoming car had gone by (x = 100 at 26 s)
    out = sim.first_time("PassObstacleOut")
    wait = sim.first_time("PassObstacleWait")
    assert wait is not None and wait < 21.0
    assert out is not None and out > (188.0 - 100.0 + 120.0) / 8.0


def test_lane_change_waits_for_a_gap() -> None:
    net = two_lane_network((1, 2))
    assert EdgeKind.LANE_CHANGE in {e.kind for e in net.planner.plan().edges}
    right = ["1.2.1", "1.2.2", "1.2.3", "1.2.4", "1.2.5", "1.2.6", "1.2.7"]
    beside = car_on(net.graph, "beside", right, 30.0, constant(8.0), 8.0)
    sim = Sim(net, cars=[beside])
    assert sim.run_until(lambda s: s.state == "MissionComplete", 120.0)
    assert sim.collisions == [] and sim.faults == []
    changing = [f for f in sim.frames if f.state.endswith("LaneChange")]
    refused = [f for f in changing if f.command.mtc is not None and not f.command.mtc.free]
    assert refused and "waits" in refused[0].command.reason
    # we were held before the change while the car in the target lane was beside us
    assert all(f.y_m > -0.1 for f in refused)
    free = next(f for f in changing if f.command.mtc is not None and f.command.mtc.free)
    assert free.command.mtc is not None and free.command.mtc.vehicles[0].decided_by == "they_first"
    assert sim.frames[-1].y_m == pytest.approx(-3.66, abs=0.15)


@pytest.fixture(scope="module")
def blocked():  # type: ignore[no-untyped-def]
    net = ring_network()
    barrier = [
        parked("barrier_e", 110.0, -2.0, 0.0, 3.0, 2.5),
        parked("barrier_w", 110.0, 2.0, math.pi, 3.0, 2.5),
    ]
    sim = Sim(net, cars=barrier)
    assert sim.run_until(lambda s: s.state == "MissionComplete", 200.0)
    return sim, net


def test_blocked_road_kturn_and_replan(blocked) -> None:  # type: ignore[no-untyped-def]
    sim, net = blocked
    assert sim.collisions == [] and sim.faults == []
    requests = [r for f in sim.frames for r in f.command.requests]
    marked = [r for r in requests if r.kind == RequestKind.EDGE_BLOCKED]
    assert [r.edge for r in marked] == [(W("1.1.3"), W("1.1.4"))]
    assert net.graph.edge(W("1.1.3"), W("1.1.4")).blocked
    # detected after the obstacle stood BLOCKADE_STILL_S with us behind it
    stop = next(f for f in sim.frames if f.x_m > 50.0 and abs(f.speed_mps) < rules.STOPPED_SPEED_MPS)
    detect = next(f for f in sim.frames if f.command.requests)
    assert detect.t_s == pytest.approx(stop.t_s + rules.BLOCKADE_STILL_S, abs=1.0)
    leaves = sim.leaves()
    # planned on the road: legs alternating forward and backward at their cusps, the last into the lane
    i = leaves.index("DriveKTurnPlanning")
    j = leaves.index("DriveKTurnFinish", i)
    turn = leaves[i + 1 : j]
    assert turn[0] == "DriveKTurnForward" and len(turn) >= 2
    assert all(a != b for a, b in itertools.pairwise(turn))
    assert leaves[j + 1] == "DriveOnLane"
    # a 7.7 m street (two 12 ft lanes 4 m apart): no corner of the car reached a curb (0.3 m outside)
    area = RoadArea.of(net.graph)
    worst = max(float(area.excess_m(*corners(f).T).max()) for f in sim.frames)
    assert worst < 0.3
    backward = [f for f in sim.frames if f.state.endswith("DriveKTurnBackward")]
    assert all(f.command.direction == -1 for f in backward) and min(f.speed_mps for f in backward) < -0.5
    replans = [r for r in requests if r.kind == RequestKind.REPLAN]
    assert len(replans) == 2  # once at the blockade, once turned around
    # turned around on the opposite lane, and around the block to the mission's end
    after = next(f for f in sim.frames if f.t_s > sim.first_time("DriveOnLane", after=detect.t_s + 1.0))
    assert after.y_m == pytest.approx(2.0, abs=0.3) and math.cos(after.heading_rad) < -0.95
    assert sim.frames[-1].command.checkpoints_reached == (1, 2)
    assert W("4.2.2") in sim.behaviour.route.vertices


def test_a_kturn_blocked_on_its_way_is_planned_again_from_where_the_car_stands(blocked) -> None:  # type: ignore[no-untyped-def]
    """The blocked ring again, and a box set down where the K-turn's first leg ends just as the car sets
    off on it: the turn is checked against what stands every cycle, so the car stops, plans the rest of
    the turn from where it stands, and turns around without touching the box (without the check it
    would stop before the box short of the leg's end, and stand there)."""
    first, _ = blocked
    start = first.first_time("DriveKTurnForward")
    assert start is not None
    leg = [f for f in first.frames if f.t_s >= start]
    end = next(f for f, g in itertools.pairwise(leg) if not g.state.endswith("DriveKTurnForward"))
    ahead = EGO_LENGTH_M - EGO_REAR_OVERHANG_M + 0.3  # just past the front bumper at the leg's end
    box = parked(
        "box", end.x_m + ahead * math.cos(end.heading_rad), end.y_m + ahead * math.sin(end.heading_rad),
        end.heading_rad, 0.6, 0.6,
    )  # fmt: skip
    box.appears_at_s = start + 0.5
    barrier = [
        parked("barrier_e", 110.0, -2.0, 0.0, 3.0, 2.5),
        parked("barrier_w", 110.0, 2.0, math.pi, 3.0, 2.5),
    ]
    sim = Sim(ring_network(), cars=[*barrier, box])
    assert sim.run_until(lambda s: s.state == "MissionComplete", 240.0), sim.leaves()
    assert sim.collisions == [] and sim.faults == []
    leaves = sim.leaves()
    i = leaves.index("DriveKTurnPlanning")
    assert "DriveKTurnPlanning" in leaves[i + 1 :]  # planned again once the box stood in the way
    replanned = [f for f in sim.frames if "replanning from here" in f.command.reason]
    assert replanned and replanned[0].t_s >= box.appears_at_s
    assert sim.frames[-1].command.checkpoints_reached == (1, 2)


def test_an_unreachable_checkpoint_forgets_blockades() -> None:
    """Perception reports the only road to the next checkpoint blocked: we mark it, the planner finds
    the checkpoint unreachable and forgets every blockade (its rule), and we say so."""
    net = ring_network()
    run = Script(net)
    run.step(0.0, run.ego_at(40.0, 8.0))
    spur = (W("5.1.2"), W("5.1.3"))  # the only way to checkpoint 2
    cmd = run.step(0.1, run.ego_at(40.8, 8.0), blocked=[BlockedRoad(280.0, 98.0, spur, "barrels")])
    kinds = [r.kind for r in cmd.requests]
    assert kinds == [RequestKind.EDGE_BLOCKED, RequestKind.REPLAN, RequestKind.BLOCKADES_FORGOTTEN]
    assert cmd.requests[0].edge == spur and "barrels" in cmd.requests[0].detail
    assert net.graph.blocked_edges() == []
    assert cmd.state == "Drive/DriveOnLane" and run.behaviour.route.reached_all
    assert run.behaviour.route_view.lead_in is not None  # the edge we are on leads into the new route


def test_off_track_replans_from_where_we_are() -> None:
    net = ring_network()
    run = Script(net)
    run.step(0.0, run.ego_at(30.0, 5.0))
    cmd = run.step(0.1, EgoState(60.0, 4.0, math.pi, 3.0))  # on the westbound lane, facing west
    assert cmd.transitions[:2] == (
        "DriveOnLane -> Replan (off the route by > 5 m)",
        "Replan -> Drive (new route)",
    )
    assert cmd.fault is None and not cmd.state.startswith("GlobalRecovery")
    assert [r.kind for r in cmd.requests] == [RequestKind.REPLAN]
    assert run.behaviour.route.start == W("1.2.4") and "off the route" in cmd.requests[0].detail


def test_drive_recovery_then_global_recovery() -> None:
    """Standing in the lane with nothing around (the car does not respond): after DRIVE_NO_PROGRESS_S the
    family's recovery creeps; RECOVERY_NO_PROGRESS_S later without headway the global recovery takes
    over, holds and replans from where we are."""
    net = ring_network()
    run = Script(net)
    for k in range(int(70 / 0.5)):
        run.step(0.5 * k, run.ego_at(50.0, 0.0))
    rec, glob = run.first("DriveRecovery"), run.first("GlobalRecovery")
    assert rec is not None and glob is not None
    assert rec.t_s == pytest.approx(rules.DRIVE_NO_PROGRESS_S, abs=0.51)
    assert glob.t_s == pytest.approx(rec.t_s + rules.RECOVERY_NO_PROGRESS_S, abs=0.51)
    creeping = [c for c in run.commands if c.state.endswith("DriveRecovery") and c.t_s > rec.t_s + 1.0]
    assert creeping and all(
        c.desired_speed_mps == pytest.approx(rules.RECOVERY_CREEP_SPEED_MPS) for c in creeping
    )
    assert glob.desired_speed_mps == 0.0 and "no progress" in glob.transitions[0]
    after = [c for c in run.commands if c.t_s > glob.t_s]
    replanned = next(c for c in after if any(r.kind == RequestKind.REPLAN for r in c.requests))
    assert replanned.t_s == pytest.approx(glob.t_s + rules.RECOVERY_SETTLE_S, abs=0.51)
    nxt = run.commands[run.commands.index(replanned) + 1]
    assert nxt.state == "Drive/DriveOnLane" and nxt.transitions == (
        "GlobalRecovery -> Drive (back on a route)",
    )


def test_waiting_on_moving_traffic_is_not_lack_of_progress() -> None:
    net = ring_network()
    run = Script(net)
    for k in range(int(70 / 0.5)):
        t = 0.5 * k
        mover = TrackedObject("mover", 120.0 - 3.0 * t % 100.0, 2.0, math.pi, 3.0, 4.5, 1.8)
        run.step(t, run.ego_at(50.0, 0.0), [mover])
    assert run.first("DriveRecovery") is None


def test_drive_recovery_declares_an_obstacle_in_reach_a_blockade() -> None:
    """A car stands 12 m ahead in our lane and has moved a little every few seconds, so neither passing
    nor the blockade rule applied; once no progress was made for DRIVE_NO_PROGRESS_S the recovery finds
    it inside RECOVERY_LEAP_M and declares the road blocked there."""
    net = ring_network()
    run = Script(net)
    kinds: list[RequestKind] = []
    for k in range(int(45 / 0.5)):
        t = 0.5 * k
        jitter = 1.5 * ((k // 8) % 2)  # it moves 1.5 m back and forth every 4 s: never still for long
        car = TrackedObject("creeper", 50.0 + FRONT + 12.0 + 2.25 + jitter, -2.0, 0.0, 0.0, 4.5, 1.8)
        cmd = run.step(t, run.ego_at(50.0, 0.0), [car])
        kinds += [r.kind for r in cmd.requests]
    assert run.first("DriveRecovery") is not None
    assert RequestKind.EDGE_BLOCKED in kinds
    assert any("Replan (obstacle within 15 m)" in t for c in run.commands for t in c.transitions)


def test_no_passing_vehicles_queued_at_an_intersection() -> None:
    """rules 1.7: eight still cars in a row up to a stop line, we stand behind the last one, 68 m before
    the line: they are queued, so neither passed nor taken for a blockade."""
    net = cross_network([1, 2])
    run = Script(net)
    queue = [TrackedObject(f"q{k}", -8.0 - 0.3 - 2.25 - 8.0 * k, -2.0, 0.0, 0.0, 4.5, 1.8) for k in range(8)]
    ego_s = (150.0 - 8.0 - 0.3 - 4.5 - 8.0 * 7) - rules.STOPPED_LEAD_STANDOFF_M - FRONT
    for k in range(int(25 / 0.25)):
        cmd = run.step(0.25 * k, run.ego_at(ego_s, 0.0), queue)
        assert not cmd.requests
    assert set(run.leaves()) == {"DriveOnLane"}
    assert run.commands[-1].lead is not None and run.commands[-1].lead.object_id == "q7"
    assert "stopped behind still q7" in run.commands[-1].reason
