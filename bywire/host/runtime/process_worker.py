"""A module in a worker process of its own: crash-isolated, killable, supervised like a thread worker.

For modules that may crash the interpreter or hang in native code (a perception stack, say): the
module runs in a child process with its own object store, connected to the host's store through the
runtime's transport (`transport`: its inputs flow in, its outputs flow out, each on one ordered
stream). The scheduler drives it with the same release / done protocol as a thread worker, as
objects on a control topic in the same streams, so a release always reaches the child after the
inputs published before it, and its outputs reach the host before its "done" (lockstep SIL stays
deterministic).

The child is started with the "spawn" method (the host has threads; fork would copy their locks)
and builds its module with the builder the host hands to `process_worker_maker` (a module-level
function, pickled by name: `host.modules.build_isolated`), so only modules that need no host resources
(buses, trace) can be isolated; the runtime itself knows no module. A handshake (ready -> hello ->
started) makes sure both streams are connected before the first release: a subscriber that joins late
misses what was sent before. After the handshake the host sends the newest object of every input topic.

In lockstep (SIL) the run must not depend on the machine, as with the inline worker
(`inline_worker`): a step kept off the CPU by other processes is charged the CPU time it used, not
the wall time it waited (`charged_time_s`, in the child), and the scheduler's wait for it ends at
the lockstep timeout only once the child has had that much CPU (spinning) or nothing of it is
runnable (blocked): a starved child is waited for. Ending the wait on the wall clock alone let
simulated time run on while the child still computed, so its objects reached the behaviour after
as many cycles as the machine happened to allow.

The supervisor sees a killed or crashed child as a dead worker (`alive()` false), a raising step as
an exception, and a hung one by its CPU time from /proc, exactly like a thread; `abandon` kills the
process. Scenario fault injection reaches process workers only by `module_kill`: exceptions, hangs
and slow-downs are injected into thread workers.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from bywire.clock import Clock
from bywire.host.runtime.inline_worker import charged_time_s, voluntary_switches
from bywire.host.runtime.log_schema import register_type
from bywire.host.runtime.module import Module, ModuleContext, ModuleSpec
from bywire.host.runtime.store import ObjectStore
from bywire.host.runtime.worker import (
    Failure,
    WorkerState,
    below_scheduler,
    complete_on_record,
    describe_exception,
)
from bywire.process_util import process_cpu_time_s, runnable_tasks, task_state

# (kind, parameters) -> a fresh module; a module-level function, so that it reaches the child by name.
ModuleBuilder = Callable[[str, dict[str, Any]], Module]

HANDSHAKE_PERIOD_S = 0.01
DEATH_POLL_S = 0.002  # how often a wait for a step also checks that the child is still alive
PARENT_CHECK_S = 0.5  # how often an idle child checks that its host still exists


@register_type
@dataclass(frozen=True)
class WorkerSignal:
    """Control between host and child: hello / step / stop down, ready / started / done / error up."""

    t_s: float
    kind: str
    seq: int = 0
    pid: int = 0
    exec_s: float = 0.0
    error: str = ""
    published: int = 0  # publications of the step ("done")


def _topics(name: str, generation: int) -> tuple[str, str]:
    return f"/runtime/worker/{name}/{generation}/ctl", f"/runtime/worker/{name}/{generation}/status"


def _realtime_priority() -> int:
    """The calling thread's SCHED_FIFO/RR priority (0: normal scheduling or unknown)."""
    try:
        if os.sched_getscheduler(0) not in (os.SCHED_FIFO, os.SCHED_RR):
            return 0
        return int(os.sched_getparam(0).sched_priority)
    except (OSError, AttributeError):
        return 0


def _drop_realtime() -> int:
    """Put the calling thread on normal scheduling; return the real-time priority it had (0: none).

    A child inherits the scheduling of the thread that forks it, and a spawned interpreter spends
    its first second importing: at SCHED_FIFO that would take a CPU from the simulator and the
    buses (seen: the ECU's vehicle-report watchdog stopping the car). So the child starts at
    normal priority and takes its real-time priority only once it is ready to run steps.
    """
    try:
        if os.sched_getscheduler(0) not in (os.SCHED_FIFO, os.SCHED_RR):
            return 0
        prio = os.sched_getparam(0).sched_priority
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        return int(prio)
    except (OSError, AttributeError):
        return 0


def _restore_realtime(priority: int, all_threads: bool = False) -> None:
    """SCHED_FIFO `priority` for the calling thread, or for every thread of the process.

    The child needs it on all its threads: its transport's I/O threads were created while it
    imported at normal priority, and a thread left there is starved by the real-time tasks on a busy
    machine: messages stall, and even a SIGKILL takes effect only when every thread has run (seen:
    a killed worker still "alive", hence judged deadlocked, 60 ms later)."""
    if not priority:
        return
    tids = [0]
    if all_threads:
        with contextlib.suppress(OSError):
            tids = [int(t) for t in os.listdir("/proc/self/task")]
    for tid in tids:
        with contextlib.suppress(OSError, AttributeError):
            os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))


def _child_main(
    spec: ModuleSpec,
    kind: str,
    params: dict[str, Any],
    generation: int,
    in_ep: str,
    out_ep: str,
    rt_priority: int = 0,
    build: ModuleBuilder | None = None,
    lockstep: bool = False,
) -> None:
    from bywire.host.runtime.transport import TopicPublisher, TopicSubscriber

    ctl_topic, status_topic = _topics(spec.name, generation)
    store = ObjectStore()
    sub = TopicSubscriber(in_ep, store)
    pub = TopicPublisher(out_ep)
    pub.attach(store, spec.outputs)
    ctl = store.subscribe(ctl_topic)
    parent = os.getppid()
    pid = os.getpid()
    try:
        while True:  # handshake: both streams connected once the host's hello gets through
            pub.send(status_topic, WorkerSignal(0.0, "ready", pid=pid))
            msg = ctl.wait(HANDSHAKE_PERIOD_S)
            if msg is not None and msg.kind == "hello":
                break
            if os.getppid() != parent:
                return
        ctx = ModuleContext(spec, store, params, generation)
        try:
            assert build is not None
            module = build(kind, params)
            module.start(ctx)
        except Exception as exc:
            pub.send(
                status_topic, WorkerSignal(0.0, "error", pid=pid, error=f"start: {describe_exception(exc)}")
            )
            time.sleep(0.1)  # let the report leave before the process ends
            return
        # The module's step (and the transport's threads) run at the priority of the host's module
        # threads from here on.
        _restore_realtime(rt_priority, all_threads=True)
        pub.send(status_topic, WorkerSignal(0.0, "started", pid=pid))
        while True:
            msg = ctl.wait(PARENT_CHECK_S)
            if msg is None:
                if os.getppid() != parent:
                    return  # the host is gone: nobody will ever release us again
                continue
            if msg.kind == "stop":
                module.close()
                return
            if msg.kind != "step":
                continue
            ctx.now_s = msg.t_s
            # The inputs the host published before this release came down the stream before it: the
            # step sees the local store as of the step signal, not what arrived while it waited.
            ctx.as_of = ctl.last_store_seq
            switches0, cpu0 = voluntary_switches(), time.thread_time()
            wall0 = time.perf_counter()
            before = ctx.published
            try:
                module.step(ctx)
            except Exception as exc:
                pub.send(
                    status_topic,
                    WorkerSignal(msg.t_s, "error", msg.seq, pid, error=f"step: {describe_exception(exc)}"),
                )
                time.sleep(0.1)
                return
            exec_s = time.perf_counter() - wall0
            if lockstep:  # the time others took from the step is not its own (see the module docstring)
                exec_s = charged_time_s(exec_s, cpu0, switches0, spec.deadline_s)
            pub.send(
                status_topic,
                WorkerSignal(msg.t_s, "done", msg.seq, pid, exec_s, published=ctx.published - before),
            )
    finally:
        sub.close()
        pub.close()


class ProcessWorker(WorkerState):
    """The host's handle on one module instance in a child process (the `Worker` protocol).

    Starting a process (spawn, then the child's imports) takes hundreds of milliseconds, far longer
    than a tick, and ending one waits for it. So the start and the end of a worker happen on
    a thread of their own, never on the scheduler's: the rest of the host keeps its rhythm while a
    perception process restarts. Until the child has answered the handshake the worker is not
    ready, and the scheduler does not release it.
    """

    def __init__(
        self,
        spec: ModuleSpec,
        kind: str,
        params: dict[str, Any],
        store: ObjectStore,
        clock: Clock,
        generation: int,
        build: ModuleBuilder | None = None,
        lockstep: bool = False,
    ) -> None:
        super().__init__(spec, generation, clock)
        self._build = build
        self.lockstep = lockstep
        self._release_cpu_s: float | None = None  # the child's CPU time at the release (lockstep)
        self.pid: int | None = None
        self.process: Any = None
        self._store = store
        self._kind = kind
        self._params = {k: v for k, v in params.items() if k != "kind"}
        self._ctl_topic, status_topic = _topics(spec.name, generation)
        store.declare(status_topic, WorkerSignal, history=64)
        self._status = store.subscribe(status_topic)
        self._pub: Any = None
        self._sub: Any = None
        self._seq = 0
        self._started = False
        self._closed = False
        self._booted = threading.Event()
        self._ending: threading.Thread | None = None
        threading.Thread(target=self._boot, name=f"boot-{spec.name}#{generation}", daemon=True).start()

    def _boot(self) -> None:
        from bywire.host.runtime.transport import TopicPublisher, TopicSubscriber, new_endpoint

        # The boot thread runs just below the scheduler: whatever it does with the GIL in hand
        # (pickling the child's arguments, the transport's set-up) it must not be preempted there by
        # the simulator or the buses while the scheduler waits for the GIL (seen with an earlier
        # transport: 100 ms without a heartbeat). Only the fork itself runs on normal priority,
        # which the child inherits (see _drop_realtime).
        below_scheduler()
        rt_priority = _realtime_priority()  # what the child takes once it is ready (0: none)
        try:
            if self._closed:
                return  # given up before it started
            in_ep = new_endpoint(f"{self.spec.name}-{self.generation}-in")
            out_ep = new_endpoint(f"{self.spec.name}-{self.generation}-out")
            self._pub = TopicPublisher(in_ep)
            self._pub.attach(self._store, self.spec.inputs + self.spec.sampled)
            self._sub = TopicSubscriber(out_ep, self._store)
            ctx = mp.get_context("spawn")
            self.process = ctx.Process(
                target=_child_main,
                args=(
                    self.spec,
                    self._kind,
                    self._params,
                    self.generation,
                    in_ep,
                    out_ep,
                    rt_priority,
                    self._build,
                    self.lockstep,
                ),
                name=f"bywire-{self.spec.name}#{self.generation}",
                daemon=True,
            )
            dropped = _drop_realtime()
            try:
                self.process.start()
            finally:
                _restore_realtime(dropped)
            self.pid = self.process.pid
        except Exception as exc:  # a worker that cannot start is a crashed worker
            self.failure = Failure(
                "crashed", f"could not start the worker process: {describe_exception(exc)}", self._clock.now()
            )
        finally:
            self._booted.set()

    # -- the control stream --------------------------------------------------------------------------

    def _pump(self) -> None:
        if self._booted.is_set() and not self._closed:
            for sig in self._status:
                self._handle_one(sig)

    def ready(self) -> bool:
        self._pump()
        return self._started or self.failure is not None

    def wait_started(self, timeout_s: float) -> bool:
        end = time.monotonic() + timeout_s
        if not self._booted.wait(timeout_s):
            return False
        while not self.ready():
            if self.process is None or not self.process.is_alive() or time.monotonic() > end:
                return False
            self._status_wait(min(HANDSHAKE_PERIOD_S, end - time.monotonic()))
        return True

    def _status_wait(self, timeout_s: float) -> None:
        sig = self._status.wait(max(0.0, timeout_s))
        if sig is not None:
            self._handle_one(sig)

    def _handle_one(self, sig: WorkerSignal) -> None:
        if sig.kind == "ready":
            # Answered every time: the child may not have been listening for the first hello.
            self._pub.send(self._ctl_topic, WorkerSignal(0.0, "hello"))
        elif sig.kind == "started" and not self._started:
            self._started = True
            for topic in self.spec.inputs + self.spec.sampled:
                obj = self._store.latest(topic)
                if obj is not None:
                    self._pub.send(topic, obj)
        elif sig.kind == "done" and sig.seq == self._seq and self.busy_since_s is not None:
            complete_on_record(
                self.spec, self.stats, self.busy_since_s, self._clock.now(), sig.exec_s, sig.published > 0
            )
            self.busy_since_s = None
        elif sig.kind == "error":
            self.failure = Failure("exception", sig.error, self._clock.now())
            self.busy_since_s = None

    # -- the Worker protocol -------------------------------------------------------------------------

    def release(self, now_s: float) -> bool:
        self._pump()
        if self.failure is not None or not self._started or not self.process.is_alive():
            return False  # a dead child is the supervisor's to find, not a release to wait for
        if self.busy_since_s is not None:
            self.stats.skipped += 1
            return False
        self._seq += 1
        self.busy_since_s = self._clock.now()  # the real release instant (a chain releases late)
        self.stats.releases += 1
        self.stats.last_release_s = now_s
        if self.lockstep:
            self._release_cpu_s = self.cpu_time_s()
        self._pub.send(self._ctl_topic, WorkerSignal(now_s, "step", self._seq))
        return True

    def wait_done(self, timeout_s: float) -> bool:
        end = time.monotonic() + timeout_s
        self._pump()
        while self.busy_since_s is not None and self.failure is None:
            remaining = end - time.monotonic()
            if remaining <= 0 and self.lockstep and self._starved(timeout_s):
                remaining = DEATH_POLL_S  # kept off the CPU, not stuck: simulated time waits for it
            if remaining <= 0 or not self.process.is_alive():
                self._pump()
                return self.busy_since_s is None
            self._status_wait(min(remaining, DEATH_POLL_S))
        return True

    def _starved(self, timeout_s: float) -> bool:
        """Late on the wall clock, yet a thread of the child is runnable and it has had less than
        `timeout_s` of CPU since the release: other processes had the CPU (`inline_worker`'s rule)."""
        cpu = self.cpu_time_s()
        if cpu is None or self._release_cpu_s is None or cpu - self._release_cpu_s >= timeout_s:
            return False
        return self.run_state() == "R"

    def alive(self) -> bool:
        if not self._booted.is_set():
            return True  # still starting: not ready, not dead
        self._pump()
        return self.process is not None and self.process.is_alive()

    def cpu_time_s(self) -> float | None:
        # every thread of the child: a step's helper threads (an FFT's workers, a BLAS pool) work for
        # it while its own thread waits for them in a join
        return None if self.pid is None else process_cpu_time_s(self.pid)

    def run_state(self) -> str | None:
        """R while any thread of the child is runnable (the step or a helper it waits for)."""
        if self.pid is None:
            return None
        return "R" if runnable_tasks(self.pid) else task_state(self.pid, self.pid)

    def abandon(self, cancel: bool = False) -> None:
        """Kill the child (hung, or its instance given up) and close the streams, off the scheduler."""
        self._end(kill=True)

    def retire(self) -> None:
        """Ask the child to stop after its current step; kill it if it does not, off the scheduler."""
        self._end(kill=False)

    def _end(self, kill: bool) -> None:
        if self._closed:
            return
        self._closed = True  # _pump stops handing over the child's signals at once (never blocks)
        self._ending = threading.Thread(
            target=self._shutdown, args=(kill,), name=f"end-{self.spec.name}", daemon=True
        )
        self._ending.start()

    def join(self, timeout_s: float) -> None:
        """Wait for a retired or abandoned worker's process to be gone (the host's own shutdown)."""
        if self._ending is not None:
            self._ending.join(timeout_s)

    def _shutdown(self, kill: bool) -> None:
        self._booted.wait()
        if self._sub is not None:
            self._sub.close()  # first: nothing of this instance reaches the store any more (the fence)
        proc = self.process
        if proc is not None and proc.is_alive():
            if kill:
                proc.kill()
            else:
                with contextlib.suppress(Exception):
                    self._pub.send(self._ctl_topic, WorkerSignal(self._clock.now(), "stop"))
                proc.join(timeout=0.5)
                if proc.is_alive():
                    proc.kill()
        if self._pub is not None:
            self._pub.close()
        if proc is not None and proc.pid is not None:  # one that never started has nothing to join
            proc.join(timeout=1.0)


def process_worker_maker(lockstep: bool, build: ModuleBuilder) -> Any:
    """The `Runtime`'s factory for process workers (kind and parameters come from the entry; `build`
    makes the module in the child from them)."""

    def make(entry: Any, store: ObjectStore, clock: Clock, injector: Any) -> ProcessWorker:
        params = dict(entry.params)
        return ProcessWorker(
            entry.spec, str(params.get("kind")), params, store, clock, entry.generation, build, lockstep
        )

    return make
