"""The Zone states' plans on wall time: solved in a worker process (the behaviour only polls), the same
reply the inline planner gives step by step, and a request that raises comes back as a reply saying so."""

from __future__ import annotations

import time

import numpy as np

from bywire.host.behaviour.path_planning import InlinePathPlanner, PlanReply, PlanRequest
from bywire.host.modules.planning.path_planner_process import ProcessPathPlanner
from bywire.host.navigation.cspace import PASSAT_FOOTPRINT


def _request(occupied: np.ndarray) -> PlanRequest:
    return PlanRequest(
        occupied, (0.0, 0.0), PASSAT_FOOTPRINT, (5.0, 10.0, 0.0), (20.0, 20.0, 1.57), None, 0.0
    )


def _wait(planner: ProcessPathPlanner, ticket: int) -> PlanReply:
    """The reply, however long the worker takes on a loaded machine (a lost reply hangs the test)."""
    while (reply := planner.poll(ticket)) is None:
        time.sleep(0.01)
    return reply


def test_the_worker_solves_what_the_inline_planner_solves_and_reports_failures() -> None:
    occupied = np.zeros((150, 150), dtype=bool)
    occupied[:, :3] = True
    inline = InlinePathPlanner()
    ticket = inline.submit(_request(occupied))
    polls = 0
    while (expected := inline.poll(ticket)) is None:
        polls += 1
    assert polls >= 2 and not expected.reason  # a map, then the search: more than one step
    planner = ProcessPathPlanner()
    try:
        reply = _wait(planner, planner.submit(_request(occupied)))
        assert not reply.reason and reply.length_m == expected.length_m
        assert [d for _, d in reply.stretches] == [d for _, d in expected.stretches]
        assert all(
            np.array_equal(a, b) for (a, _), (b, _) in zip(reply.stretches, expected.stretches, strict=True)
        )
        bad = _wait(planner, planner.submit(_request(np.zeros((150, 150)))))  # floats: not a grid
        assert bad.stretches == () and "ValueError" in bad.reason and "2-D bool" in bad.reason
        assert "no request 99" in (planner.poll(99) or PlanReply((), 0, 0, 0, "")).reason
    finally:
        planner.close()
