"""The Zone states' plans solved in a worker process on wall time (seed 000 Sec. 10: the navigation module
ran in a process of its own): a plan takes 0.1-0.5 s of pure Python here, which in the behaviour's
thread would hold the host's GIL and its rhythm (seen in HIL: the control requests went stale and the ECU
stopped the car). The behaviour submits a `PlanRequest`, holds the car ("zone: planning") and polls
every cycle; the reply arrives a few cycles later.

The worker is spawned once, when the behaviour module starts, and leaves the host's real-time class for
the normal one at a lower priority before it imports anything heavy: a search (or numpy's import) must
never take the CPU from the ECU link, the plant or the bus servers. A request that raises comes back as
a reply saying so (the stand-in then drives).
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
from concurrent.futures import Future, ProcessPoolExecutor
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the worker imports the planner only after it has left the real-time class
    from bywire.host.behaviour.path_planning import PlanReply, PlanRequest

__all__ = ["ProcessPathPlanner"]

WORKER_NICE = 5


def _leave_real_time() -> None:
    """In the worker: the normal scheduling class, a little below the normal priority."""
    with contextlib.suppress(OSError, AttributeError):  # not on Linux, or not allowed: it stays
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    os.nice(WORKER_NICE)


def _warm() -> bool:
    """Imports the planner in the worker (at its normal priority) before the first request needs it."""
    import bywire.host.behaviour.path_planning  # noqa: F401
    from bywire.host.navigation.hybrid_astar import warm_up

    warm_up()  # the compiled search and Reeds-Shepp kernels, not in the first plan
    return True


def _solve(request: PlanRequest) -> PlanReply:
    from bywire.host.behaviour.path_planning import solve

    return solve(request)


def _failed(reason: str) -> PlanReply:
    from bywire.host.behaviour.path_planning import PlanReply

    return PlanReply((), 0.0, 0, 0.0, reason)


class ProcessPathPlanner:
    """`path_planning.PathPlanner` on a one-process pool (see the module docstring)."""

    def __init__(self) -> None:
        self._pool = ProcessPoolExecutor(
            max_workers=1, mp_context=multiprocessing.get_context("spawn"), initializer=_leave_real_time
        )
        self._pool.submit(_warm)
        self._futures: dict[int, Future[PlanReply]] = {}
        self._next = 0

    def submit(self, request: PlanRequest) -> int:
        ticket, self._next = self._next, self._next + 1
        self._futures[ticket] = self._pool.submit(_solve, request)
        return ticket

    def poll(self, ticket: int) -> PlanReply | None:
        future = self._futures.get(ticket)
        if future is None:
            return _failed(f"zone planner: no request {ticket}")
        if not future.done():
            return None
        del self._futures[ticket]
        try:
            return future.result()
        except Exception as exc:
            return _failed(f"zone planner process: {type(exc).__name__}: {exc}")

    def close(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)
