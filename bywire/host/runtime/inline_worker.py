"""The lockstep worker: a module stepped on the scheduler's own thread, with a watchdog for hangs.

In lockstep (SIL, tests) the scheduler waits for every release anyway, so handing each step to a
thread of its own buys nothing but two thread switches per release — measured, they made SIL 2.5x
slower. An `InlineWorker` runs the step right in the scheduler's thread, which must be the main
thread: Python delivers signals there, and a signal is the one thing that interrupts both a
pure-Python endless loop and a blocking lock acquisition.

The watchdog thread looks at the step in progress every `POLL_S`; a step still running after the
lockstep wait (`timeout_s`, wall time) has its CPU share sampled over `SHARE_SAMPLE_S` (spinning or
blocked) and is interrupted with SIGUSR2, whose handler raises `StepInterrupted` in the step. The
worker then stays busy for ever from the release on, exactly as a hung thread would: the
supervisor finds it at `hang_after_s` on the simulated clock and classifies it from the sampled
share. What SIL cannot show this way is a hang's cost to the rest of the process (a spinning thread
taking the GIL); wall-time runs use thread workers, where it is real.

Time taken from the step by others is not the step's. Lockstep runs on a simulated clock, and a
run must come out the same on a busy machine: a step that never blocked (no voluntary context
switch, `getrusage(RUSAGE_THREAD)`) but lost the CPU to another process or to the hypervisor (VM
steal) is charged its own CPU time (`time.thread_time`) for the deadline, not the wall time it
waited; a step that slept, waited on I/O or on a lock is charged the wall time, as before. For
the same reason the watchdog judges a late step only once the process is asleep (blocked: a
deadlock or an endless wait) or the step has had the timeout's worth of CPU (spinning: a hang); a
step that is runnable but has not had that much CPU was starved, not stuck, and is watched on. A
step's CPU is the process's: its helper threads work for it (scipy's FFT with `workers=-1`, a BLAS
pool), and the main thread waiting on them sleeps in a join. So the watchdog counts the process's
CPU time (`time.process_time`, every thread; its own costs nothing) and calls the step runnable while
any thread but its own is (judged by the main thread alone, a C-space convolution starved on a
loaded machine was a "deadlock at 0% of a CPU", interrupted and restarted six times in one run). A
CPU-bound step that is really too slow still misses on its own CPU time. One limit: a voluntary
switch is a voluntary switch, and the GIL handed to the watchdog thread (it wakes every `POLL_S`)
during a long step is one, so such a step is charged its wall time as before.

Work a step does for a part of the system that on wall time runs beside it is marked
`background()`: the zone planner, which in HIL is a worker process of its own and in lockstep runs a
step of its search inside the behaviour's step, so that its reply comes after the same number of
cycles on every machine. A background section is not charged to the step (its wall time, CPU and
voluntary switches are taken out of the step's account) and the watchdog does not judge it before
`BACKGROUND_BOUND_S`; without it, a loaded machine made the behaviour "slow" (degraded) or "hung"
(restarted) in SIL by the planner's cost, and a run's outcome depended on the machine.
"""

from __future__ import annotations

import contextlib
import resource
import signal
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from types import FrameType
from typing import Any

from bywire.clock import Clock
from bywire.host.runtime.module import Module, ModuleContext, ModuleSpec
from bywire.host.runtime.store import ObjectStore
from bywire.host.runtime.worker import (
    Failure,
    ModuleFactory,
    WorkerState,
    complete_on_record,
)
from bywire.process_util import runnable_tasks

POLL_S = 0.05
BACKGROUND_BOUND_S = 30.0  # a background section still running after this is judged like the step
SHARE_SAMPLE_S = 0.005
INTERRUPT_SIGNAL = signal.SIGUSR2


class StepInterrupted(BaseException):
    """Raised in a step the watchdog gave up on (a BaseException: `except Exception` cannot keep it)."""


@dataclass
class _Background:
    """The main thread's `background()` sections: whether one is open, since when, and their totals."""

    depth: int = 0
    since_wall_s: float = 0.0
    wall_s: float = 0.0
    thread_cpu_s: float = 0.0
    switches: int = 0


_BACKGROUND = _Background()


@contextlib.contextmanager
def background() -> Iterator[None]:
    """Mark work of the step in progress as background (see the module docstring). Nested sections
    count once; off the main thread (thread and process workers, wall time) it changes nothing."""
    b = _BACKGROUND
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    if b.depth:
        b.depth += 1
        try:
            yield
        finally:
            b.depth -= 1
        return
    wall0, thread0 = time.perf_counter(), time.thread_time()
    proc0, sw0 = time.process_time(), voluntary_switches()
    b.depth, b.since_wall_s = 1, wall0
    try:
        yield
    finally:
        b.depth = 0
        d_wall, d_proc = time.perf_counter() - wall0, time.process_time() - proc0
        b.wall_s += d_wall
        b.thread_cpu_s += time.thread_time() - thread0
        b.switches += voluntary_switches() - sw0
        wd = _Watchdog._instance
        armed = None if wd is None else wd.armed
        if wd is not None and armed is not None:  # the step's clocks stop while it works in the background
            wd.armed = (armed[0] + d_wall, armed[1], armed[2], armed[3] + d_proc)


def inline_possible() -> bool:
    """Signals reach only the main thread: elsewhere lockstep falls back to thread workers."""
    return threading.current_thread() is threading.main_thread() and hasattr(signal, "pthread_kill")


class _Watchdog:
    """One per process: watches the step in progress on the main thread."""

    _instance: _Watchdog | None = None

    def __init__(self) -> None:
        self.main_ident = threading.main_thread().ident
        # (wall start, timeout, worker, the process's CPU time at the start) of the step running
        self.armed: tuple[float, float, InlineWorker, float] | None = None
        self.firing = False
        previous = signal.getsignal(INTERRUPT_SIGNAL)
        if previous not in (signal.SIG_DFL, signal.SIG_IGN, None):
            raise RuntimeError(f"signal {INTERRUPT_SIGNAL.name} is already in use; lockstep needs it")
        signal.signal(INTERRUPT_SIGNAL, self._on_signal)
        self.watch_native: int | None = None
        threading.Thread(target=self._watch, name="lockstep-watchdog", daemon=True).start()

    @classmethod
    def get(cls) -> _Watchdog:
        if cls._instance is None:
            cls._instance = cls()
        return cls._instance

    def _on_signal(self, signum: int, frame: FrameType | None) -> None:
        if self.firing and self.armed is not None:
            self.firing = False
            raise StepInterrupted

    def _watch(self) -> None:
        self.watch_native = threading.get_native_id()
        while True:
            time.sleep(POLL_S)
            armed = self.armed
            if armed is None or time.perf_counter() - armed[0] < armed[1]:
                continue
            bg = _BACKGROUND
            if bg.depth and time.perf_counter() - bg.since_wall_s < BACKGROUND_BOUND_S:
                continue  # not the step's own work (see `background`)
            worker = armed[2]
            if self._starved(armed[3], armed[1]):
                continue
            wall0, cpu0 = time.perf_counter(), time.process_time()
            time.sleep(SHARE_SAMPLE_S)  # may take longer: a spinning step holds the GIL
            wall1, cpu1 = time.perf_counter(), time.process_time()
            if self.armed is not armed or _BACKGROUND.depth:
                continue  # it finished after all, or went on in the background
            if wall1 > wall0:
                worker.hang_cpu_share = min(1.0, (cpu1 - cpu0) / (wall1 - wall0))
            # a step that took its timeout's CPU and still wants the CPU is spinning, however little of
            # it the machine gave the sample; a blocked one, and every thread it waits for, sleeps
            worker.hang_runnable = _had_its_cpu(armed[3], armed[1]) and self._runnable()
            self.firing = True
            assert self.main_ident is not None
            signal.pthread_kill(self.main_ident, INTERRUPT_SIGNAL)

    def _starved(self, step_cpu0_s: float, timeout_s: float) -> bool:
        """Late on the wall clock, yet runnable and short of the timeout's worth of CPU: the step
        was kept off the CPU (another process, VM steal; then the GIL, which the starved step held),
        it is not stuck. A spinning step gets there on its CPU time; a blocked one sleeps, and so do
        all the threads it could be waiting for (see the module docstring)."""
        return not _had_its_cpu(step_cpu0_s, timeout_s) and self._runnable()

    def _runnable(self) -> bool:
        """A thread of this process other than the watchdog is runnable (the step or a helper of it)."""
        return bool(runnable_tasks("self", exclude=() if self.watch_native is None else (self.watch_native,)))


class InlineWorker(WorkerState):
    """One module instance stepped on the scheduler's (main) thread; the `Worker` protocol."""

    def __init__(
        self,
        spec: ModuleSpec,
        factory: ModuleFactory,
        store: ObjectStore,
        clock: Clock,
        params: Mapping[str, Any],
        generation: int,
        timeout_s: float,
        inject: Callable[[ModuleContext], None] | None = None,
    ) -> None:
        super().__init__(spec, generation, clock)
        self.hang_cpu_share: float | None = None
        self.hang_runnable = False  # sampled with it: a thread of the step still runnable
        self.ctx = ModuleContext(spec, store, params, generation)
        self._timeout_s = timeout_s
        self._inject = inject
        self._watchdog = _Watchdog.get()
        self._module: Module | None = None
        try:
            self._module = self._guarded(lambda: _start(factory, self.ctx))
        except StepInterrupted:
            self.failure = Failure("hang", "start did not return", clock.now())
        except KeyboardInterrupt:
            raise  # Ctrl-C or a signal handled like it (process_util): the run's, not the module's
        except BaseException as exc:
            self._fail("exception", exc, "start")

    def _guarded(self, fn: Callable[[], Any]) -> Any:
        self._watchdog.armed = (time.perf_counter(), self._timeout_s, self, time.process_time())
        try:
            return fn()
        finally:
            self._watchdog.armed = None
            self._watchdog.firing = False

    def release(self, now_s: float) -> bool:
        if self.failure is not None or self._module is None:
            return False
        if self.busy_since_s is not None:
            self.stats.skipped += 1
            return False
        module = self._module
        self.busy_since_s = self._clock.now()
        self.ctx.release(now_s)
        self.stats.releases += 1
        self.stats.last_release_s = now_s
        published_before = self.ctx.published
        bg = _BACKGROUND
        bg0 = (bg.wall_s, bg.thread_cpu_s, bg.switches)
        switches0 = voluntary_switches()
        cpu0 = time.thread_time()
        wall0 = time.perf_counter()

        def step() -> None:
            if self._inject is not None:
                self._inject(self.ctx)
            module.step(self.ctx)

        try:
            self._guarded(step)
        except StepInterrupted:
            self.ctx.fenced = True
            return True  # busy from now on, like a thread that never came back
        except KeyboardInterrupt:
            raise  # Ctrl-C or a signal handled like it lands in whatever step runs: it stops the run
        except BaseException as exc:
            self._fail("exception", exc, "step")
            self.busy_since_s = None
            return True
        complete_on_record(
            self.spec,
            self.stats,
            self.busy_since_s,
            self._clock.now(),
            charged_time_s(
                time.perf_counter() - wall0 - (bg.wall_s - bg0[0]),  # background work is not the step's
                cpu0 + (bg.thread_cpu_s - bg0[1]),
                switches0 + (bg.switches - bg0[2]),
                self.spec.deadline_s,
            ),
            self.ctx.published != published_before,
        )
        self.busy_since_s = None
        return True

    def wait_done(self, timeout_s: float) -> bool:
        return self.busy_since_s is None

    def ready(self) -> bool:
        return True

    def alive(self) -> bool:
        return True

    def cpu_time_s(self) -> float | None:
        return None  # see hang_cpu_share: the step is no longer running when it is judged

    def run_state(self) -> str | None:
        return None  # likewise: the inline watchdog judged the state before interrupting the step

    def abandon(self, cancel: bool = False) -> None:
        self.ctx.fenced = True  # the step was already interrupted; nothing runs any more

    def retire(self) -> None:
        self.ctx.fenced = True
        if self._module is not None and self.failure is None and self.busy_since_s is None:
            with contextlib.suppress(BaseException):  # a failing close of a retired instance changes nothing
                self._guarded(self._module.close)


def _had_its_cpu(step_cpu0_s: float, timeout_s: float) -> bool:
    """The process has had the timeout's worth of CPU since the step began (`time.process_time`)."""
    return time.process_time() - step_cpu0_s >= timeout_s


def voluntary_switches() -> int:
    """Times the calling thread gave up the CPU itself (sleep, I/O, a lock, the GIL)."""
    return resource.getrusage(resource.RUSAGE_THREAD).ru_nvcsw


def charged_time_s(wall_s: float, cpu0_s: float, switches0: int, deadline_s: float) -> float:
    """The execution time a step that took `wall_s` is judged by (see the module docstring): its
    wall time, unless that is over the deadline while the step never blocked, in which case only
    the CPU time it got (`time.thread_time()` since `cpu0_s`) was its own. Call it on the step's
    thread right after the step; `switches0` is `voluntary_switches()` from before it."""
    if wall_s <= deadline_s:
        return wall_s  # on time: nothing to ask (and two system calls saved)
    if voluntary_switches() != switches0:
        return wall_s  # it waited for something itself
    return min(wall_s, time.thread_time() - cpu0_s)


def _start(factory: ModuleFactory, ctx: ModuleContext) -> Module:
    module = factory()
    module.start(ctx)
    return module
