"""Exits tighter than full lock (`behaviour.exit_turn`): planned on their own lanes, driven in moves,
handed back to the route; judged against the same exit followed on the graph's curve."""

from __future__ import annotations

import pytest
from hsm_sim import LaneSpec, Network, Sim, W, corners, network, rndf_text

from bywire.host.behaviour import exit_turn
from bywire.host.roadnet.road_area import RoadArea


def tee() -> Network:
    """A stop at the top of a northbound lane, then right into an eastbound lane only 3.5 m east and 4.5 m
    north of it: the exit's curve asks for a 2.4 m radius (the car: 4.6 m at full lock). 16 ft lanes."""
    segments = {
        1: {1: LaneSpec([(0, -80), (0, -40), (0, 0)], (3,), {1: 1}, ((3, "2.1.1"),), 16)},
        2: {1: LaneSpec([(3.5, 4.5), (40, 4.5), (90, 4.5)], (), {3: 2}, (), 16)},
    }
    return network(rndf_text("tee", segments), (1, 2), {1: (0, 25), 2: (0, 25)})


def off_own_lanes(sim: Sim, net: Network) -> float:
    """How far a corner of the car ever lay outside the lanes and exits running its way."""
    area = RoadArea.of(net.graph)
    return max(float(area.excess_m(*corners(f).T, f.heading_rad).max()) for f in sim.frames)


def test_the_exit_is_unsteerable_by_the_graphs_own_limit() -> None:
    net = tee()
    sim = Sim(net)
    edge = net.graph.edge(W("1.1.3"), W("2.1.1"))
    assert exit_turn.unsteerable(sim.behaviour.ctx, edge)
    assert not exit_turn.unsteerable(sim.behaviour.ctx, net.graph.edge(W("2.1.1"), W("2.1.2")))


def test_a_tight_exit_is_driven_in_planned_moves_within_its_lanes() -> None:
    net = tee()
    sim = Sim(net)
    assert sim.run_until(lambda s: s.state == "MissionComplete", 120.0)
    assert sim.collisions == [] and sim.faults == []
    reasons = [r for f in sim.frames for r in f.command.reason.split("; ")]
    planned = next(r for r in reasons if "tighter than full lock: planned" in r)
    moves = int(planned.split("planned in ")[1].split()[0])
    assert moves >= 2  # the corner is too tight for one sweep inside the lanes
    backward = [f for f in sim.frames if f.command.direction == -1]
    assert backward and all("exit turn" in f.command.reason for f in backward)
    assert off_own_lanes(sim, net) <= 0.0
    # handed back to the route: the rest of the way on the lane, to the checkpoint at its end
    assert sim.frames[-1].command.checkpoints_reached == (1, 2)
    assert sim.frames[-1].y_m == pytest.approx(4.5, abs=0.2)


def test_on_the_graphs_curve_the_car_leaves_its_lanes(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(exit_turn, "unsteerable", lambda ctx, edge: False)
    net = tee()
    sim = Sim(net)
    assert sim.run_until(lambda s: s.state == "MissionComplete", 120.0)
    assert off_own_lanes(sim, net) > 0.2
