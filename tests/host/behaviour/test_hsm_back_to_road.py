"""GlobalRecovery's last resort (`recovery.back_to_road`): off every lane, planned back onto the nearest
one over whatever is free, then the mission goes on."""

from __future__ import annotations

from hsm_sim import Sim, parked, ring_network


def _reasons(sim: Sim) -> list[str]:
    return [r for f in sim.frames for r in f.command.reason.split("; ")]


def test_off_every_lane_the_planner_drives_back_onto_the_nearest() -> None:
    """Started inside the block, 23 m from the south road: the global recovery plans its way to lane
    1.2 and drives it, the mission follows."""
    net = ring_network()
    sim = Sim(net, start=(100.0, 25.0, 0.5))
    assert sim.run_until(lambda s: s.state == "MissionComplete", 300.0)
    assert sim.collisions == [] and sim.faults == []
    reasons = _reasons(sim)
    assert any("planning back onto 1.2." in r for r in reasons)
    moves = [r for r in reasons if "back onto the road, move" in r]
    assert moves and sim.leaves()[0] == "GlobalRecovery" and sim.leaves()[1] == "DriveOnLane"
    assert sim.frames[-1].command.checkpoints_reached == (1, 2)


def test_the_way_back_goes_around_what_stands() -> None:
    """A parked car right between us and the road: the way back does not touch it."""
    net = ring_network()
    sim = Sim(net, start=(100.0, 14.0, -1.57), cars=[parked("block", 100.0, 8.0, 0.0, 6.0, 2.5)])
    assert sim.run_until(lambda s: s.state == "MissionComplete", 300.0)
    assert sim.collisions == [] and sim.faults == []
    assert any("back onto the road, move" in r for r in _reasons(sim))
