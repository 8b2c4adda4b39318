"""Lockstep with a process worker: simulated time waits for a step the machine kept off the CPU.

A starved child is made by hand: its step sleeps past the lockstep wait while the host's view of it
says "runnable, no CPU used" (`ProcessWorker.cpu_time_s` and `run_state` patched), which is what
/proc shows of a child that other processes keep off the CPU. The lockstep wait used to end on the
wall clock there, simulated time ran on while the child still computed, and its output reached its
consumer as many cycles late as the machine happened to allow (in SIL on LIDAR: a perception frame
late by a wall-clock-dependent number of cycles, so the run was not repeatable).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import pytest

from bywire.clock import SimClock
from bywire.host.runtime.module import FailurePolicy, Module, ModuleContext, ModuleSpec
from bywire.host.runtime.process_worker import ProcessWorker, process_worker_maker
from bywire.host.runtime.runtime import Runtime
from bywire.host.runtime.store import ObjectStore

HOLD_AT_S = 0.04
HOLD_S = 0.5  # wall time the held step takes: five lockstep waits


@dataclass(frozen=True)
class Frame:
    t_s: float
    n: int


class Producer(Module):
    """Publishes a count every release; the release at HOLD_AT_S takes HOLD_S of wall time."""

    def __init__(self) -> None:
        self.n = 0

    def step(self, ctx: ModuleContext) -> None:
        if round(ctx.now_s, 6) == HOLD_AT_S:
            time.sleep(HOLD_S)
        self.n += 1
        ctx.publish("/p", Frame(ctx.now_s, self.n))


class Consumer(Module):
    """Republishes the producer's newest count as it sees it at its own release."""

    def step(self, ctx: ModuleContext) -> None:
        p = ctx.latest("/p")
        ctx.publish("/c", Frame(ctx.now_s, -1 if p is None else p.n))


def build_producer(kind: str, params: dict[str, Any]) -> Module:
    return Producer()


def test_lockstep_waits_for_a_starved_process_worker(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(ProcessWorker, "cpu_time_s", lambda self: 0.0)
    monkeypatch.setattr(ProcessWorker, "run_state", lambda self: "R")
    store = ObjectStore()
    rt = Runtime(
        store,
        SimClock(),
        lockstep=True,
        lockstep_timeout_s=0.1,
        process_worker=process_worker_maker(lockstep=True, build=build_producer),
    )
    policy = FailurePolicy(hang_after_s=0.05)
    rt.add_module(
        ModuleSpec("p", outputs=("/p",), period_s=0.02, deadline_s=0.01, policy=policy, isolation="process"),
        Producer,
        {"kind": "producer"},
    )
    rt.add_module(ModuleSpec("c", inputs=("/p",), outputs=("/c",), period_s=0.02, deadline_s=0.01), Consumer)
    seen: list[tuple[float, int]] = []
    assert rt.prestart()
    rt.start(0.0)
    try:
        for k in range(101):
            rt.clock.advance_to(k * 0.001)  # type: ignore[attr-defined]
            rt.tick(k * 0.001)
            c = store.latest("/c")
            if c is not None and (not seen or seen[-1][0] != round(c.t_s, 6)):
                seen.append((round(c.t_s, 6), c.n))
    finally:
        rt.close()
    # every cycle's consumer saw that cycle's frame, the held one too, and the held step was no hang
    assert seen == [(round(0.02 * i, 6), i + 1) for i in range(6)]
    assert rt.events == []
