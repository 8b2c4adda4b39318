"""The Zone family (seed 000 Secs. 8, 10) on the zone planner's paths: approach, enter, pull into the
spot to its checkpoint, back straight out of it (DARPA rules 5.2), on through the perimeter exit and
along the road; the stand-in's straight lines where the planner finds no way; and the family's
recovery escalating to the global one."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hsm_sim import Script, Sim, zone_network

from bywire.host.behaviour import rules

FRONT = rules.PASSAT_REAR_AXLE_TO_FRONT_M


@pytest.fixture(scope="module")
def lot():  # type: ignore[no-untyped-def]
    net = zone_network()
    sim = Sim(net)
    assert sim.run_until(lambda s: s.state == "MissionComplete", 200.0)
    return sim


def test_zone_enter_park_leave(lot) -> None:  # type: ignore[no-untyped-def]
    sim = lot
    assert sim.collisions == [] and sim.faults == []
    assert sim.leaves() == [
        "DriveOnLane",
        "ZoneApproach",
        "ZoneEnter",
        "ZonePark",
        "ZoneLeave",
        "DriveOnLane",
        "MissionComplete",
    ]
    assert sim.frames[-1].command.checkpoints_reached == (1, 2, 3)
    # the spot's checkpoint (145.5, 0) is reached with the front bumper on it, standing
    parked = [
        f for f in sim.frames if f.state == "Zone/ZonePark" and abs(f.speed_mps) < rules.STOPPED_SPEED_MPS
    ]
    assert parked
    f = parked[-1]
    fx, fy = f.x_m + FRONT * math.cos(f.heading_rad), f.y_m + FRONT * math.sin(f.heading_rad)
    assert math.hypot(fx - 145.5, fy) <= rules.STOP_LINE_TOLERANCE_M
    # out of the spot in reverse, then forward to the exit
    leave = [f for f in sim.frames if f.state == "Zone/ZoneLeave"]
    # the planner's step: a hold of a few cycles ("zone: planning"), then straight back
    planning = [f for f in leave if "zone: planning" in f.command.reason]
    assert (
        planning
        and planning[-1].t_s - leave[0].t_s < 1.0
        and all(f.command.desired_speed_mps == 0.0 for f in planning)
    )
    driving = [f for f in leave if "zone: planning" not in f.command.reason]
    assert driving[0].command.direction == -1 and min(f.speed_mps for f in leave) < -0.5
    assert leave[-1].command.direction == 1
    # straight back until the front bumper is out of the spot (140 .. 145.5) by the margin
    backed = [f for f in leave if f.command.direction == -1]
    assert min(f.x_m for f in backed) == pytest.approx(140.0 - rules.ZONE_BACK_OUT_MARGIN_M - FRONT, abs=0.5)
    assert max(abs(f.y_m) for f in backed) < 0.2
    # zone speed: the MDF's 5 mph at most (and half of it in the spot)
    assert max(abs(f.speed_mps) for f in sim.frames if f.state.startswith("Zone/Zone") and f.x_m > 110.0) <= (
        5 * rules.MPH_MPS + 0.05
    )
    # the planner's path, and it says so
    enter = [f.command.reason for f in sim.frames if f.state == "Zone/ZoneEnter"]
    assert enter[0] == "zone: planning" and any("planned path" in r for r in enter)
    # and the road afterwards is driven west to the final checkpoint (3.1.3 at x = 0)
    last = sim.frames[-1]
    assert last.x_m - FRONT == pytest.approx(
        0.0, abs=rules.STOP_LINE_TOLERANCE_M
    ) and last.y_m == pytest.approx(30.0, abs=0.3)


def test_zone_recovery_then_global_recovery() -> None:
    """Stuck at the perimeter entry (the car does not move): ZONE_NO_PROGRESS_S, the family's recovery;
    RECOVERY_NO_PROGRESS_S more, the global one, which replans from where we are (on the exit edge into
    the zone) and so gets back on track: into the zone again."""
    net = zone_network()
    run = Script(net)
    for k in range(int(80 / 0.5)):
        run.step(0.5 * k, run.ego_at(112.0 - FRONT + 1.0, 0.0))
    enter, rec, glob = run.first("ZoneEnter"), run.first("ZoneRecovery"), run.first("GlobalRecovery")
    assert enter is not None and rec is not None and glob is not None
    assert rec.t_s == pytest.approx(enter.t_s + rules.ZONE_NO_PROGRESS_S, abs=0.51)
    assert glob.t_s == pytest.approx(rec.t_s + rules.RECOVERY_NO_PROGRESS_S, abs=0.51)
    assert glob.desired_speed_mps == 0.0
    replanned = next(c for c in run.commands if c.t_s > glob.t_s and c.requests)
    assert replanned.requests[0].detail.startswith("route from 2.0.1")
    back = run.commands[run.commands.index(replanned) + 1]
    assert (
        back.state == "Zone/ZoneEnter" and back.transitions[0] == "GlobalRecovery -> Drive (back on a route)"
    )


def test_a_car_that_stops_on_the_planned_path_is_planned_around() -> None:
    """After the plan into the spot is made, a car comes from the side and stops across it, 10 m ahead
    of us (on LIDAR: a part of a parked car seen only now). Once it stands, the check of the plan ahead
    against what stands finds the blocked section, and the planner finds the way round it, on the map
    that now holds it, before ZONE_REPLAN_STALL_S of standing in front of it: into the spot all the
    same, touching nothing."""
    from hsm_sim import ScriptedCar

    from bywire.host.roadnet.path import Path

    ys = np.linspace(20.0, -20.0, 81)
    crossing = Path(np.full_like(ys, 125.0), ys, np.full_like(ys, -math.pi / 2), np.zeros_like(ys))
    # it waits 20 m north of our way, drives south at 3 m/s once we have planned (18.5 s), and stops
    # across our way about 5 m before our front bumper
    car = ScriptedCar("crosser", crossing, 0.0, lambda t, s: 0.0 if t < 18.5 or s >= 20.0 else 3.0)
    sim = Sim(zone_network(), cars=[car])
    assert sim.run_until(lambda s: s.state == "MissionComplete", 260.0), sim.leaves()
    assert sim.collisions == [] and sim.faults == []
    reasons = [f.command.reason for f in sim.frames if f.state.startswith("Zone/")]
    assert any("replanned" in r for r in reasons)
    blocked = next(f for f in sim.frames if "blocked ahead" in f.command.reason)
    zone = [f for f in sim.frames if f.t_s > 18.5 and f.state.startswith("Zone/")]
    stood = next(f for f in zone if abs(f.speed_mps) < 0.05)
    assert blocked.t_s - stood.t_s < rules.ZONE_REPLAN_STALL_S
    assert "ZoneRecovery" not in sim.leaves()
    assert sim.frames[-1].command.checkpoints_reached == (1, 2, 3)
