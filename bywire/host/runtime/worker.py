"""Workers: where one module instance runs, and what the supervisor can observe of it from outside.

A worker runs one instance of one module: in a thread of the host process (the default on wall
time), in a process of its own (`ProcessWorker`, in `process_worker`), or, in lockstep, right on
the scheduler's thread under a watchdog (`InlineWorker`, in `inline_worker`). The scheduler
`release`s it; the worker runs `step`, measures the execution time and records completions,
deadline misses and the exception that ended it, if any. Everything the supervisor needs is
readable without the worker's cooperation — a hung module cannot be asked whether it is hung
(seed 000 section 12: the module that ended AnnieWAY's final was alive and silent):

- `busy_since_s`: the release in progress, on the runtime clock (a hang is a release that never ends);
- `cpu_time_s()`: the worker's own CPU time from /proc, which tells a spinning loop (CPU advances)
  from a deadlock (blocked, CPU still);
- `failure`: the exception or death that ended it.

A thread cannot be killed. A hung thread is `abandon`ed: its context is fenced (nothing it still
publishes reaches the store); if it spins, an asynchronous `ModuleCancelled` is raised in it, which
ends a pure-Python busy loop at its next bytecode. A blocked one (a deadlock, a call that never
returns) is left behind as a daemon, costing no CPU, without an exception: it would be raised when
the call returns, at an arbitrary point inside whatever adapter it was using. Fencing covers the
store, not a zombie's side effects on an adapter it shares with its replacement: modules that may
hang in native code belong in a process worker, which can be killed.
"""

from __future__ import annotations

import contextlib
import ctypes
import math
import os
import threading
import time
import traceback
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from bywire.clock import Clock
from bywire.host.runtime.module import Module, ModuleContext, ModuleSpec
from bywire.host.runtime.store import ObjectStore
from bywire.process_util import task_cpu_time_s, task_state

HISTORY = 1000  # releases kept for execution-time statistics


class ModuleCancelled(BaseException):
    """Raised asynchronously in an abandoned module thread (a BaseException so `except Exception` in
    the module cannot swallow it)."""


@dataclass(frozen=True)
class Failure:
    cause: str  # "exception" | "crashed"
    detail: str
    t_s: float  # when it happened, on the runtime clock


@dataclass
class ReleaseStats:
    """Counters and recent timings of one worker (one module instance)."""

    releases: int = 0
    completed: int = 0
    misses: int = 0
    skipped: int = 0  # releases due while the previous one was still running (overruns)
    last_release_s: float | None = None
    last_done_s: float | None = None
    silent: int = 0  # completed releases in a row that published nothing
    silent_since_s: float | None = None  # release time of the first of them

    def __post_init__(self) -> None:
        self.exec_s: deque[float] = deque(maxlen=HISTORY)
        self.missed: deque[bool] = deque(maxlen=HISTORY)
        self.miss_times_s: deque[float] = deque(maxlen=HISTORY)


class Worker(Protocol):
    spec: ModuleSpec
    generation: int
    stats: ReleaseStats
    failure: Failure | None
    busy_since_s: float | None

    def release(self, now_s: float) -> bool: ...

    def wait_done(self, timeout_s: float) -> bool: ...

    def alive(self) -> bool: ...

    def cpu_time_s(self) -> float | None: ...

    def run_state(self) -> str | None:
        """The scheduler state of the thread or process running the module (`task_state`)."""
        ...

    def ready(self) -> bool: ...

    def abandon(self, cancel: bool = False) -> None: ...

    def retire(self) -> None: ...


ModuleFactory = Callable[[], Module]


MODULE_PRIORITY_BELOW = 2  # real-time priority steps between the scheduler thread and its modules


def below_scheduler(steps: int = MODULE_PRIORITY_BELOW) -> None:
    """Run the calling (worker) thread `steps` below the scheduler's real-time priority, if it has one.

    The scheduler is also the supervisor: a module spinning at the scheduler's own SCHED_FIFO
    priority keeps it off the CPU (and holds the GIL), delaying the detection of exactly that
    module by tens of milliseconds on two cores. One priority step below, the scheduler preempts
    it whenever it wakes. Threads inherit the policy of their creator; normal scheduling is left as is.
    """
    try:
        policy = os.sched_getscheduler(0)
        if policy not in (os.SCHED_FIFO, os.SCHED_RR):
            return
        prio = os.sched_getparam(0).sched_priority
        os.sched_setscheduler(0, policy, os.sched_param(max(1, prio - steps)))
    except (OSError, AttributeError):
        pass  # not Linux, or not allowed: modules stay where they are


def describe_exception(exc: BaseException) -> str:
    """`Type: message at file:line` of the innermost frame: what an event's detail says."""
    frames = traceback.extract_tb(exc.__traceback__)
    at = f" at {Path(frames[-1].filename).name}:{frames[-1].lineno}" if frames else ""
    return f"{type(exc).__name__}: {exc}{at}"


class WorkerState:
    """What every worker keeps for the supervisor to read (the data of the `Worker` protocol)."""

    def __init__(self, spec: ModuleSpec, generation: int, clock: Clock) -> None:
        self.spec = spec
        self.generation = generation
        self.stats = ReleaseStats()
        self.failure: Failure | None = None
        self.busy_since_s: float | None = None
        self._clock = clock

    def _fail(self, cause: str, exc: BaseException, where: str) -> None:
        self.failure = Failure(cause, f"{where}: {describe_exception(exc)}", self._clock.now())


class ThreadWorker(WorkerState):
    """One module instance on a daemon thread of the host process."""

    def __init__(
        self,
        spec: ModuleSpec,
        factory: ModuleFactory,
        store: ObjectStore,
        clock: Clock,
        params: Mapping[str, Any],
        generation: int,
        inject: Callable[[ModuleContext], None] | None = None,
    ) -> None:
        super().__init__(spec, generation, clock)
        self.ctx = ModuleContext(spec, store, params, generation)
        self._factory = factory
        self._inject = inject
        # Raw locks as binary semaphores: the cheapest hand-over CPython has (an Event allocates a
        # lock per wait), and lockstep SIL hands over every release of every module.
        self._go = threading.Lock()
        self._go.acquire()  # held by the scheduler until a release: the worker blocks on it
        self._done = threading.Lock()  # held by the worker while a step runs
        self._started = threading.Event()
        self._ended = False
        self._retiring = False
        self._native_id: int | None = None
        self.thread = threading.Thread(target=self._run, name=f"module-{spec.name}#{generation}", daemon=True)
        self.thread.start()

    # -- scheduler side ------------------------------------------------------------------------------

    def ready(self) -> bool:
        return self._started.is_set()

    def release(self, now_s: float) -> bool:
        """Start a step at `now_s`; False (and an overrun counted) if the previous one still runs."""
        if self.failure is not None or not self._started.is_set():
            return False
        if self.busy_since_s is not None:
            self.stats.skipped += 1
            return False
        self._done.acquire()
        self.busy_since_s = self._clock.now()  # the real release instant (a chain releases late)
        self.ctx.release(now_s)
        self.stats.releases += 1
        self.stats.last_release_s = now_s
        self._go.release()
        return True

    def wait_done(self, timeout_s: float) -> bool:
        if not self._done.acquire(timeout=timeout_s):
            return False
        self._done.release()
        return True

    def _wake(self) -> None:
        with contextlib.suppress(RuntimeError):  # already released: the worker is awake anyway
            self._go.release()

    def wait_started(self, timeout_s: float) -> bool:
        return self._started.wait(timeout_s)

    def alive(self) -> bool:
        return not self._ended

    def cpu_time_s(self) -> float | None:
        return None if self._native_id is None else task_cpu_time_s("self", self._native_id)

    def run_state(self) -> str | None:
        return None if self._native_id is None else task_state("self", self._native_id)

    def abandon(self, cancel: bool = False) -> None:
        """Give up on a hung instance: fence its outputs; `cancel` a spinning one (see the module doc)."""
        self.ctx.fenced = True
        self._retiring = True
        ident = self.thread.ident
        if cancel and ident is not None and self.thread.is_alive():
            ctypes.pythonapi.PyThreadState_SetAsyncExc(
                ctypes.c_ulong(ident), ctypes.py_object(ModuleCancelled)
            )
        self._wake()

    def retire(self) -> None:
        """Stop a healthy (or failed) instance at its next release point."""
        self.ctx.fenced = True
        self._retiring = True
        self._wake()  # not joined: the instance is fenced, and the scheduler must not wait for it

    # -- worker thread ---------------------------------------------------------------------------

    def _run(self) -> None:
        self._native_id = threading.get_native_id()
        # The ECU link (always_release) sends the heartbeat the ECU's watchdog judges the host by: it
        # preempts the computing modules (a 10 Hz world model's step may take tens of ms on a busy
        # machine), still below the scheduler that supervises it.
        below_scheduler(1 if self.spec.always_release else MODULE_PRIORITY_BELOW)
        try:
            self._serve()
        except ModuleCancelled:
            pass
        finally:
            self._ended = True

    def _serve(self) -> None:
        try:
            module = self._factory()
            module.start(self.ctx)
        except ModuleCancelled:
            raise
        except BaseException as exc:
            self._fail("exception", exc, "start")
            self._started.set()
            return
        self._started.set()
        while True:
            self._go.acquire()
            if self._retiring:
                break
            wall0 = time.perf_counter()
            published_before = self.ctx.published
            try:
                if self._inject is not None:
                    self._inject(self.ctx)
                module.step(self.ctx)
            except ModuleCancelled:
                raise
            except BaseException as exc:
                self._fail("exception", exc, "step")
                self._done.release()
                self.busy_since_s = None
                return
            exec_s = time.perf_counter() - wall0
            published = self.ctx.published != published_before
            complete_on_record(self.spec, self.stats, self.busy_since_s, self._clock.now(), exec_s, published)
            self._done.release()
            self.busy_since_s = None
        with contextlib.suppress(Exception):  # a failing close of a retired instance changes nothing
            module.close()


def complete_on_record(
    spec: ModuleSpec,
    stats: ReleaseStats,
    release_s: float | None,
    done_s: float,
    exec_s: float,
    published: bool,
) -> None:
    """Book one completed release: a miss when the wall execution time or the release-to-done time
    on the runtime clock exceeds the deadline (the first catches slow code in lockstep SIL, where
    simulated time stands still during a step; the second catches scheduling delays in HIL)."""
    response_s = exec_s if release_s is None else max(exec_s, done_s - release_s)
    missed = response_s > spec.deadline_s or not math.isfinite(response_s)
    stats.completed += 1
    stats.last_done_s = done_s
    stats.exec_s.append(exec_s)
    stats.missed.append(missed)
    if published:
        stats.silent, stats.silent_since_s = 0, None
    else:
        stats.silent += 1
        if stats.silent_since_s is None:
            stats.silent_since_s = release_s if release_s is not None else done_s
    if missed:
        stats.misses += 1
        stats.miss_times_s.append(done_s)
