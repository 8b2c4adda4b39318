"""The scheduler and the supervisor: run every module on time, and notice when one stops doing its job.

Scheduling (seed 000 section 3's modules on KogMo-RTDB, with deadlines made explicit): a periodic
module is released at `start + k * period`, a triggered one on every new object of its trigger
topic; each release runs on the module's worker and is measured (execution time, completion,
deadline miss, overrun when the previous release is still running). The modules due at one tick
form a chain, released in dependency order, each waited for: in lockstep (SIL, replay) until it is
done, so a run is deterministic; on wall time (HIL, the car) for a few milliseconds at most
(`CHAIN_WAIT_S`). A module still busy holds back its consumers until it is done, instead of
letting them run on old data; they are released the moment it completes. The sinks that must run
every period (`always_release`: the ECU link, whose heartbeat is the host's sign of life to the
ECU's watchdog) are never held and never wait behind a computing module (see `tick`).

Supervision — the watchdog AnnieWAY lacked (seed 000 section 12: a module hung after an exception,
its process stayed alive, and a watchdog that only checked that processes existed never noticed).
Ours judges each module from the outside, by data flow and timing alone:

- exception: the step raised (the worker records it and stops; it never limps on);
- crashed: the worker thread or process is gone;
- hang / deadlock: a release has not completed after `hang_after_s`; the worker's CPU time tells
  a spinning loop (hang) from a blocked one (deadlock);
- slow: `slow_misses` deadline misses within the last `slow_window` releases;
- stale: `silent_releases` completed releases in a row without a publication (it runs but
  produces nothing).

and acts on the module's `FailurePolicy`: restart it and its dependants in dependency order with
exponential back-off (escalating when restarts keep failing), degrade (a speed limit on
`/supervisor/limit`), or stop (a controlled stop request to the ECU on `/supervisor/stop`). Every
detection and action is a `SupervisorEvent` on `/supervisor/events` and in the log. Detection runs
on the runtime clock, so the bounds hold in simulated time (SIL) and wall time (HIL) alike; the
execution time is always measured on the wall (it is CPU cost, not simulated time).

The last line of defence stays in the ECU: if the host as a whole stops, the ECU's heartbeat
watchdog stops the car (DESIGN section 4), whatever happened to this supervisor.
"""

from __future__ import annotations

import collections
import itertools
import logging
import math
import time
from collections import deque
from collections.abc import Callable, Mapping, Reversible
from dataclasses import dataclass, field
from typing import Any, Protocol

from bywire.clock import Clock
from bywire.host.runtime.inline_worker import InlineWorker, inline_possible
from bywire.host.runtime.module import ModuleSpec, dependants, dependency_order
from bywire.host.runtime.store import ObjectStore, Subscription
from bywire.host.runtime.topics import (
    MODULE_HEALTH,
    SAFETY_LIMIT,
    STOP_REQUEST,
    SUPERVISOR_EVENTS,
    ModuleHealth,
    SafetyLimit,
    StopRequest,
    SupervisorEvent,
)
from bywire.host.runtime.worker import ModuleFactory, ThreadWorker, Worker

log = logging.getLogger("bywire.supervisor")

# On wall time one tick waits at most this long, in all, for the modules it releases: the fast
# chain still runs in one tick (status -> controller -> request), while a module that computes
# longer (a world model's transforms, a QP) is left running and its consumers follow it when it is
# done. The ECU link, last in the chain, is then never more than this late for its 20 ms period,
# whatever the computing modules do: a late controller is a stale request, which the link answers
# with a controlled stop, never a missing heartbeat (DESIGN section 4: the two faults differ).
CHAIN_WAIT_S = 0.004
MIN_SPIN_SAMPLE_S = 0.005  # real time over which a hung worker's CPU use is judged
STARVED_PATIENCE = 10.0  # a module starved of the CPU is judged hung after this many hang_after_s
SPIN_CPU_SHARE = 0.2  # a hung worker using more than this share of a CPU is spinning, not blocked
START_TIMEOUT_S = 30.0  # wall time a worker may take to start (a process worker imports numpy...)
HEALTH_WINDOW = 100  # releases the health topic's execution-time statistics cover (2 s at 50 Hz)


def exec_stats_ms(exec_s: Reversible[float], window: int | None) -> tuple[float, float, float]:
    """(p50, p99, max) in ms of the newest `window` execution times (all with None); zeros if none.

    Percentiles by the nearest-rank method on the sorted window (no interpolation). Only the window
    is copied: the history holds a thousand samples, the health topic looks at a hundred, ten
    times a second for every module.
    """

    # A worker's thread appends to the history while the health topic reads it: iterating the deque
    # itself raised "deque mutated during iteration" and ended the host process in a HIL run. Its
    # copy() is one C call under the GIL, so the window is taken from a snapshot when the whole
    # history is asked for, or when reading the window alone was cut short by an append; the window
    # read alone (a tenth of the history) is C too and so mostly not interrupted, and a copy of the
    # whole history ten times a second for every module was the health topic's main cost.
    def snapshot() -> Reversible[float]:
        return exec_s.copy() if isinstance(exec_s, collections.deque) else exec_s

    if window is None:
        samples = list(snapshot())
    else:
        try:
            samples = list(itertools.islice(reversed(exec_s), window))
        except RuntimeError:  # mutated during the read: the same window of a snapshot
            samples = list(itertools.islice(reversed(snapshot()), window))
    if not samples:
        return 0.0, 0.0, 0.0
    samples.sort()
    n = len(samples)
    p50 = samples[(n - 1) // 2] if n % 2 else 0.5 * (samples[n // 2 - 1] + samples[n // 2])
    p99 = samples[min(n - 1, math.ceil(0.99 * n) - 1)]
    return round(p50 * 1e3, 4), round(p99 * 1e3, 4), round(samples[-1] * 1e3, 4)


class Injector(Protocol):
    """Fault injection for tests and scenarios (see `hil.module_faults`)."""

    def before_step(self, module: str, ctx: Any) -> None: ...

    def tick(self, runtime: Runtime, now_s: float) -> None: ...


WorkerMaker = Callable[["Entry", ObjectStore, Clock, "Injector | None"], Worker]


@dataclass
class Entry:
    """The runtime's record of one module: its declaration, its current worker and its history."""

    spec: ModuleSpec
    factory: ModuleFactory
    params: Mapping[str, Any]
    worker: Worker | None = None
    generation: int = 0
    state: str = "starting"
    release_k: int = 0
    pending: bool = False
    owed_tick: int | None = None  # the tick of a release held back while a producer computed
    released_tick: int = -1  # the tick of its newest release
    rejudge: bool = False  # its late release was starved, not hung, when last looked at
    trigger_sub: Subscription[Any] | None = None
    restart_at_s: float | None = None
    restart_times: deque[float] = field(default_factory=deque)
    restarts: int = 0
    started_s: float = 0.0
    busy_mark: tuple[float, float | None, float] | None = None  # (wall, cpu, busy_since) when first late
    recovering_from: float | None = None  # onset of the failure a restart is recovering from
    seen_completed: int = 0  # completions already judged for slowness and silence
    reported: set[str] = field(default_factory=set)
    cause: str = ""  # of the last failure handled


def thread_worker(
    entry: Entry,
    store: ObjectStore,
    clock: Clock,
    injector: Injector | None,
    lockstep_timeout_s: float | None,
) -> Worker:
    """A worker in this process: stepped inline under a watchdog in lockstep on the main thread
    (`inline_worker`: no thread switches), else on a thread of its own."""
    inject = None
    if injector is not None:
        name = entry.spec.name

        def inject(ctx: Any) -> None:
            injector.before_step(name, ctx)

    if lockstep_timeout_s is not None and inline_possible():
        return InlineWorker(
            entry.spec,
            entry.factory,
            store,
            clock,
            entry.params,
            entry.generation,
            lockstep_timeout_s,
            inject,
        )
    return ThreadWorker(entry.spec, entry.factory, store, clock, entry.params, entry.generation, inject)


class Runtime:
    """Modules on one store and one clock; call `tick(now_s)` (lockstep) or `run_wall(...)`."""

    def __init__(
        self,
        store: ObjectStore,
        clock: Clock,
        *,
        lockstep: bool = False,
        lockstep_timeout_s: float = 1.0,
        injector: Injector | None = None,
        health_period_s: float = 0.1,
        process_worker: WorkerMaker | None = None,
    ) -> None:
        self.store = store
        self.clock = clock
        self.lockstep = lockstep
        self.lockstep_timeout_s = lockstep_timeout_s
        self.injector = injector
        self.health_period_s = health_period_s
        self._process_worker = process_worker
        self.entries: dict[str, Entry] = {}
        self._order: list[Entry] = []
        self._consumers: dict[str, frozenset[str]] = {}  # per module: whose inputs derive from its outputs
        self._producers: dict[str, tuple[Entry, ...]] = {}  # per module: whose outputs its inputs derive from
        self._tick_n = 0
        self.events: list[SupervisorEvent] = []
        self.start_s: float | None = None
        self._next_health_s = 0.0
        self._quiet_until_s = -math.inf
        self.limit: SafetyLimit | None = None
        self.stop_requested: StopRequest | None = None
        for topic, kind in (
            (SUPERVISOR_EVENTS, SupervisorEvent),
            (SAFETY_LIMIT, SafetyLimit),
            (STOP_REQUEST, StopRequest),
            (MODULE_HEALTH, ModuleHealth),
        ):
            store.declare(topic, kind)

    # -- set-up --------------------------------------------------------------------------------------

    def add_module(
        self, spec: ModuleSpec, factory: ModuleFactory, params: Mapping[str, Any] | None = None
    ) -> None:
        if self.start_s is not None:
            raise RuntimeError("modules are added before start()")
        if spec.name in self.entries:
            raise ValueError(f"two modules named {spec.name!r}")
        self.entries[spec.name] = Entry(spec, factory, dict(params or {}))

    @property
    def specs(self) -> list[ModuleSpec]:
        return [e.spec for e in self.entries.values()]

    def prestart(self, timeout_s: float = START_TIMEOUT_S) -> bool:
        """Start the workers ahead of the run and wait until they are ready.

        A worker process takes about a second to start (a Python interpreter importing numpy and
        the project), on the same cores as everything else; a module's constructor and `start` may
        load files or build native objects (holding the GIL for tens of ms): done during the run,
        either would coincide with the first cycles of driving. Their release grid still begins at
        `start`.
        """
        self._plan()
        ready = True
        for e in self._order:
            if e.worker is None:
                self._spawn(e, 0.0)
        for e in self._order:
            wait = getattr(e.worker, "wait_started", None)
            if wait is not None:
                ready = wait(timeout_s) and ready
        return ready

    def start(self, now_s: float) -> None:
        """Start every module's worker (in dependency order; in lockstep wait until each is ready)."""
        self._plan()
        self.start_s = now_s
        self._next_health_s = now_s
        for e in self._order:
            if e.worker is None:
                self._spawn(e, now_s)
            else:  # prestarted: on the run's grid and clock from now on
                e.release_k = 0
                e.started_s = now_s

    def _plan(self) -> None:
        """The chain's order and each module's consumers, once (the graph library's import alone takes
        a quarter of a second: done in `prestart` it does not delay the first tick)."""
        if self._order:
            return
        self._order = [self.entries[s.name] for s in dependency_order(self.specs)]
        self._consumers = {s.name: frozenset(dependants(self.specs, s.name)) for s in self.specs}
        producers: dict[str, list[Entry]] = {}
        for e in self._order:
            for consumer in self._consumers[e.spec.name]:
                producers.setdefault(consumer, []).append(e)
        self._producers = {name: tuple(p) for name, p in producers.items()}

    def _spawn(self, e: Entry, now_s: float) -> None:
        e.generation += 1
        if e.spec.isolation == "process":
            if self._process_worker is None:
                raise RuntimeError(f"module {e.spec.name} wants a process worker, and none is configured")
            e.worker = self._process_worker(e, self.store, self.clock, self.injector)
        else:
            timeout = self.lockstep_timeout_s if self.lockstep else None
            e.worker = thread_worker(e, self.store, self.clock, self.injector, timeout)
        # A restarted module starts on the period grid, not at a time of its own.
        if e.spec.period_s is not None and self.start_s is not None:
            e.release_k = max(e.release_k, math.ceil((now_s - self.start_s) / e.spec.period_s - 1e-9))
        e.trigger_sub = self.store.subscribe(e.spec.trigger) if e.spec.trigger else None
        e.pending = False
        e.owed_tick = None
        e.started_s = now_s
        e.busy_mark = None
        e.seen_completed = 0
        e.restart_at_s = None
        e.state = "starting"
        e.reported.clear()
        if self.lockstep:
            # Deterministic runs wait for the start (a process worker's start-up takes no simulated
            # time); on wall time a starting worker is simply not released until it is ready.
            wait = getattr(e.worker, "wait_started", None)
            if wait is not None:
                wait(START_TIMEOUT_S)

    def close(self) -> None:
        for e in reversed(self._order):
            if e.worker is not None:
                self._take_down(e)
        for e in self._order:
            join = getattr(e.worker, "join", None)  # process workers end on a thread of their own
            if join is not None:
                join(2.0)

    # -- the loop --------------------------------------------------------------------------------------

    def tick(self, now_s: float) -> None:
        """Release what is due, in dependency order, each release waited for; then supervise.

        The wait makes a cycle's modules a chain (the controller sees this cycle's status, the link
        sends this cycle's request): in lockstep it lasts until the step is done (deterministic
        runs); on wall time `CHAIN_WAIT_S` in all. A module still computing (late in this tick, or
        released earlier and not done) holds back its consumers rather than letting them run on
        data it is about to replace, so the data flow stays causal and a recording of a wall-time
        run replays exactly; a held release is owed, and runs in the first tick after its producers
        are done (its release time is then, so its age says how late it is). The supervisor judges
        the computing module at its deadline and `hang_after_s`. The ECU link (`always_release`) is
        never held: it sends its heartbeat and the newest request every period (refusing one too
        old, asking for a controlled stop instead), so a module that is late or restarting cannot
        make the host look dead to the ECU's watchdog.

        Supervision comes after the releases, so everything the supervisor publishes at `now_s`
        (limits, stop requests, events, restarts) takes effect from the next releases on: a replay
        can order it exactly.
        """
        if self.injector is not None:
            self.injector.tick(self, now_s)
        if self.lockstep and now_s < self._quiet_until_s:
            return  # lockstep fast path: nothing is due, running or failing (see _quiet_until)
        self._tick_n += 1
        wait_until = None if self.lockstep else self.clock.now() + CHAIN_WAIT_S
        for e in self._order:
            w = e.worker
            if w is None or e.state in ("restarting", "stopped", "failed"):
                continue
            if e.state == "starting":
                if not w.ready():
                    continue
                e.state = "running"
            due = self._due(e, now_s)
            if not due and e.owed_tick is None:
                continue
            since = self._tick_n if e.owed_tick is None else e.owed_tick
            if not e.spec.always_release and self._input_computing(e, since):
                # Its input is still being computed: released when that is done, never on the data
                # it replaces (the run stays causal, so it replays exactly). Only what was released
                # by the tick it became due holds it, so a busy producer that keeps being triggered
                # cannot starve it; due again meanwhile is one release lost, counted as an overrun.
                if due and e.owed_tick is not None and e.spec.trigger is None:
                    w.stats.skipped += 1
                e.owed_tick = since
                e.pending = False
                continue
            e.owed_tick = None
            if w.release(now_s):
                e.released_tick = self._tick_n
                if wait_until is None:
                    w.wait_done(self.lockstep_timeout_s)
                else:
                    w.wait_done(min(e.spec.deadline_s, max(0.0, wait_until - self.clock.now())))
            e.pending = False
        self.supervise(now_s)
        if now_s >= self._next_health_s:
            self._publish_health(now_s)
            self._next_health_s += self.health_period_s * max(
                1, math.ceil((now_s - self._next_health_s) / self.health_period_s + 1e-9)
            )
        if self.lockstep:
            self._quiet_until_s = self._quiet_until(now_s)

    def _input_computing(self, e: Entry, since_tick: int) -> bool:
        """Whether a module that `e`'s inputs derive from is still computing a release of tick
        `since_tick` or earlier (never in lockstep, where each release is waited for until done)."""
        if self.lockstep:
            return False
        for p in self._producers.get(e.spec.name, ()):
            w = p.worker
            if (
                w is not None
                and w.busy_since_s is not None
                and p.released_tick <= since_tick
                and p.state in ("running", "degraded")
            ):
                return True
        return False

    def _quiet_until(self, now_s: float) -> float:
        """In lockstep nothing happens between ticks except what the scheduler starts: until the next
        release, restart, staleness or health instant, with no worker busy, failed or recovering and
        no trigger pending, a tick has nothing to do. (On wall time workers fail on their own.)"""
        until = self._next_health_s
        for e in self._order:
            w = e.worker
            if e.state == "restarting":
                until = min(until, e.restart_at_s if e.restart_at_s is not None else now_s)
                continue
            if w is None or e.state in ("stopped", "failed"):
                continue
            if (
                e.state == "starting"
                or e.spec.trigger is not None
                or w.busy_since_s is not None
                or w.failure is not None
                or e.recovering_from is not None
            ):
                return now_s
            assert e.spec.period_s is not None and self.start_s is not None
            until = min(until, self.start_s + e.release_k * e.spec.period_s - 1e-9)
        return until

    def _due(self, e: Entry, now_s: float) -> bool:
        if e.trigger_sub is not None:
            for _ in e.trigger_sub:
                e.pending = True
            return e.pending and e.worker is not None and e.worker.busy_since_s is None
        assert e.spec.period_s is not None and self.start_s is not None
        due_s = self.start_s + e.release_k * e.spec.period_s
        if now_s + 1e-9 < due_s:
            return False
        # Skip releases that are already past (a stall): they are counted as overruns, not queued.
        behind = math.floor((now_s - due_s) / e.spec.period_s + 1e-9)
        if behind > 0 and e.worker is not None:
            e.worker.stats.skipped += behind
        e.release_k += behind + 1
        return True

    def run_wall(
        self,
        until_s: float,
        stop: Callable[[], bool] = lambda: False,
        tick_s: float = 0.001,
        beat: Callable[[float], None] | None = None,
    ) -> None:
        """Tick on the clock every `tick_s` until `until_s` (HIL and the car); `beat(now)` after each
        tick (a stall recorder's)."""
        next_s = self.clock.now()
        while not stop():
            now = self.clock.now()
            if now >= until_s:
                break
            self.tick(now)
            if beat is not None:
                beat(now)
            next_s += tick_s
            if next_s < now:
                next_s = now + tick_s
            self.clock.sleep_until(next_s)

    # -- supervision -------------------------------------------------------------------------------

    def supervise(self, now_s: float) -> None:
        for e in self._order:
            if e.state == "restarting":
                if e.restart_at_s is not None and now_s >= e.restart_at_s:
                    self._spawn(e, now_s)
                continue
            w = e.worker
            if w is None or e.state in ("stopped", "failed"):
                continue
            found = self._detect(e, w, now_s)
            if found is not None:
                self._handle(e, now_s, *found)
            elif e.recovering_from is not None and w.stats.completed > 0 and not w.stats.missed[-1]:
                self._event(
                    e,
                    now_s,
                    "recovered",
                    "first release of the new instance met its deadline",
                    "none",
                    e.recovering_from,
                )
                e.recovering_from = None

    def _detect(self, e: Entry, w: Worker, now_s: float) -> tuple[str, str, float] | None:
        spec = e.spec
        if w.failure is not None:
            return w.failure.cause, w.failure.detail, w.failure.t_s
        if not w.ready():
            if not w.alive():
                return "crashed", "worker ended before it was ready", e.started_s
            return None
        if not w.alive():
            last = w.stats.last_done_s if w.stats.last_done_s is not None else e.started_s
            return "crashed", "worker is gone without an exception (killed?)", last
        busy = w.busy_since_s
        if busy is None:
            e.rejudge = False
        else:
            late = now_s - busy
            if late > spec.deadline_s and (e.busy_mark is None or e.busy_mark[2] != busy):
                e.busy_mark = (time.perf_counter(), w.cpu_time_s(), busy)
            if late > spec.hang_after_s:
                if (
                    e.rejudge
                    and e.busy_mark is not None
                    and time.perf_counter() - e.busy_mark[0] < MIN_SPIN_SAMPLE_S
                ):
                    return None  # starved at the last look: a fresh window is being measured
                cause, detail, onset = self._classify_hang(e, w, busy, late)
                if cause == "starved":
                    # In lockstep the runtime's time is the simulation's: a wall-clock starvation
                    # does not move it, and a runnable worker is judged hung at once.
                    if not self.lockstep and late <= STARVED_PATIENCE * spec.hang_after_s:
                        # Kept off the CPU with the rest of the process (a loaded machine, a stalled
                        # VM) is no fault of the module's, and a restart would only add work: look
                        # again over a fresh window. A spinning one uses the CPU it gets: a hang.
                        e.busy_mark = (time.perf_counter(), w.cpu_time_s(), busy)
                        e.rejudge = True
                        return None
                    cause = "hang"  # starved for this long: no longer worth waiting for
                return cause, detail, onset
            return None
        if w.stats.completed == e.seen_completed:
            return None  # slowness and silence are judged once per completed release
        e.seen_completed = w.stats.completed
        if w.stats.silent >= spec.policy.silent_releases and "stale" not in e.reported:
            return (
                "stale",
                f"{w.stats.silent} releases in a row published none of {', '.join(spec.outputs)}",
                w.stats.silent_since_s if w.stats.silent_since_s is not None else now_s,
            )
        # Judged after every completed release: look only at the window, and only once there
        # have been enough misses in all for the window to hold them.
        if "slow" not in e.reported and w.stats.misses >= spec.policy.slow_misses:
            recent = list(itertools.islice(reversed(w.stats.missed), spec.policy.slow_window))
            if sum(recent) >= spec.policy.slow_misses:
                n = spec.policy.slow_misses
                onset = w.stats.miss_times_s[-n]
                exec_max_ms = 1e3 * max(itertools.islice(reversed(w.stats.exec_s), len(recent)))
                return (
                    "slow",
                    f"{sum(recent)} of the last {len(recent)} releases missed the "
                    f"{spec.deadline_s * 1e3:.0f} ms deadline (exec max {exec_max_ms:.1f} ms)",
                    onset,
                )
        return None

    def _classify_hang(self, e: Entry, w: Worker, busy_s: float, late_s: float) -> tuple[str, str, float]:
        measured = getattr(w, "hang_cpu_share", None)  # an inline worker sampled it before interrupting
        if measured is not None:
            where = f"release at {busy_s - (self.start_s or 0.0):.3f} s not done after {late_s * 1e3:.0f} ms"
            if measured > SPIN_CPU_SHARE:
                return "hang", f"{where}, spinning ({measured:.0%} of a CPU)", busy_s
            if getattr(w, "hang_runnable", False):  # it had its timeout's CPU and wants more: starved
                return "hang", f"{where}, spinning, runnable but kept off the CPU ({measured:.0%})", busy_s
            return "deadlock", f"{where}, blocked ({measured:.0%} of a CPU): deadlock or endless wait", busy_s
        if e.busy_mark is None or time.perf_counter() - e.busy_mark[0] < MIN_SPIN_SAMPLE_S:
            # Lockstep ticks can pass faster than the CPU share can be judged: sample once more,
            # over a little real time (this happens once per hang, not per tick).
            e.busy_mark = (time.perf_counter(), w.cpu_time_s(), busy_s)
            time.sleep(MIN_SPIN_SAMPLE_S)
        cpu_now = w.cpu_time_s()
        wall_now = time.perf_counter()
        share = None
        if e.busy_mark is not None and e.busy_mark[1] is not None and cpu_now is not None:
            wall_span = wall_now - e.busy_mark[0]
            if wall_span > 0:
                share = (cpu_now - e.busy_mark[1]) / wall_span
        where = f"release at {busy_s - (self.start_s or 0.0):.3f} s not done after {late_s * 1e3:.0f} ms"
        if share is None:
            return "hang", f"{where} (CPU use unknown)", busy_s
        if share > SPIN_CPU_SHARE:
            return "hang", f"{where}, spinning ({share:.0%} of a CPU)", busy_s
        # Little CPU is not yet blocked: a thread that is runnable wants the CPU and was kept off it
        # (other processes, a stalled VM). A runnable thread is spinning or starved, never deadlocked.
        if w.run_state() == "R":
            return "starved", f"{where}, runnable but kept off the CPU ({share:.0%} of a CPU)", busy_s
        return "deadlock", f"{where}, blocked ({share:.0%} of a CPU): deadlock or endless wait", busy_s

    def _handle(self, e: Entry, now_s: float, cause: str, detail: str, onset_s: float) -> None:
        policy = e.spec.policy
        action = policy.on_slow if cause == "slow" and policy.on_slow is not None else policy.action
        if action == "restart":
            while e.restart_times and now_s - e.restart_times[0] > policy.restart_window_s:
                e.restart_times.popleft()
            if len(e.restart_times) >= policy.max_restarts:
                detail += f"; {len(e.restart_times)} restarts within {policy.restart_window_s:.0f} s"
                action = policy.escalate_to
        if e.state == "degraded" and action == "degrade":
            action = "restart"  # already degraded: a dead module must still come back
        self._event(e, now_s, cause, detail, action, onset_s)
        e.reported.add(cause)
        e.cause = cause
        if action == "degrade":
            self._degrade(e, now_s, f"{e.spec.name}: {cause}")
            if cause in ("slow", "stale"):
                e.state = "degraded"  # it still runs, only late: keep it, at a safe speed
                return
            action = "restart"
        if action == "stop":
            self._request_stop(now_s, f"{e.spec.name}: {cause}")
            self._take_down(e)
            e.state = "stopped"
            return
        self._schedule_restart(e, now_s, onset_s)
        for name in dependants(self.specs, e.spec.name):
            d = self.entries[name]
            if d.state in ("restarting", "stopped", "failed") or not d.spec.policy.restart_as_dependant:
                continue
            self._event(d, now_s, "dependant", f"consumes outputs of {e.spec.name}", "restart", now_s)
            d.cause = "dependant"
            self._schedule_restart(d, now_s, None, at_s=e.restart_at_s)

    def _schedule_restart(
        self, e: Entry, now_s: float, onset_s: float | None, at_s: float | None = None
    ) -> None:
        """Take `e` down and start it again after its back-off (or at `at_s`, a producer's restart);
        `onset_s` None: a dependant's restart, which reports no recovery of its own."""
        policy = e.spec.policy
        delay = (
            min(policy.backoff_max_s, policy.backoff_s * 2.0 ** len(e.restart_times))
            if policy.backoff_s
            else 0.0
        )
        self._take_down(e)
        e.restart_times.append(now_s)
        e.restarts += 1
        e.recovering_from = onset_s
        e.state = "restarting"
        e.restart_at_s = now_s + delay if at_s is None else at_s
        if e.restart_at_s <= now_s and at_s is None:
            self._spawn(e, now_s)

    def _take_down(self, e: Entry) -> None:
        w = e.worker
        if w is None:
            return
        if w.busy_since_s is not None:
            # Cancel only a spinning thread: one blocked in a call would get the exception when the
            # call returns, at an arbitrary point inside whatever adapter it was using.
            w.abandon(cancel=e.cause == "hang")
        else:
            w.retire()

    def _degrade(self, e: Entry, now_s: float, reason: str) -> None:
        limit = e.spec.policy.degrade_speed_mps
        if self.limit is None or limit < self.limit.max_speed_mps:
            self.limit = SafetyLimit(now_s, limit, reason)
            self.store.publish(SAFETY_LIMIT, self.limit)

    def _request_stop(self, now_s: float, reason: str) -> None:
        if self.stop_requested is None:
            self.stop_requested = StopRequest(now_s, reason)
            self.store.publish(STOP_REQUEST, self.stop_requested)

    def _event(self, e: Entry, now_s: float, cause: str, detail: str, action: str, onset_s: float) -> None:
        # On wall time a failure can happen after this tick began (during the chain's releases).
        now_s = max(now_s, self.clock.now())
        event = SupervisorEvent(
            t_s=now_s,
            module=e.spec.name,
            generation=e.generation,
            cause=cause,
            detail=detail,
            action=action,
            onset_s=onset_s,
            detect_ms=round((now_s - onset_s) * 1e3, 3),
        )
        self.events.append(event)
        self.store.publish(SUPERVISOR_EVENTS, event)
        rel = now_s - (self.start_s or 0.0)
        level = logging.INFO if cause in ("recovered", "dependant") else logging.WARNING
        log.log(
            level,
            "t=%.3f s %s#%d %s (%s) -> %s, detected after %.1f ms",
            rel,
            e.spec.name,
            e.generation,
            cause,
            detail,
            action,
            event.detect_ms,
        )

    # -- health ------------------------------------------------------------------------------------

    def module_health(self, e: Entry, now_s: float, window: int | None = HEALTH_WINDOW) -> ModuleHealth:
        """`window`: the execution-time statistics cover the newest `window` releases (None: all kept).

        The periodic health topic looks at a recent window with plain `sorted`: it is published ten
        times a second for every module, and numpy over the whole history cost a tenth of a lockstep
        run. The run's summary covers everything kept.
        """
        w = e.worker
        s = w.stats if w is not None else None
        exec_p50, exec_p99, exec_max = exec_stats_ms(s.exec_s if s is not None else (), window)
        ages = [now_s - o.t_s for t in e.spec.outputs if (o := self.store.latest(t)) is not None]
        return ModuleHealth(
            t_s=now_s,
            module=e.spec.name,
            generation=e.generation,
            state=e.state,
            releases=s.releases if s else 0,
            completed=s.completed if s else 0,
            misses=s.misses if s else 0,
            skipped=s.skipped if s else 0,
            restarts=e.restarts,
            exec_ms_p50=exec_p50,
            exec_ms_p99=exec_p99,
            exec_ms_max=exec_max,
            output_age_ms=round(max(ages) * 1e3, 3) if ages else -1.0,
        )

    def _publish_health(self, now_s: float) -> None:
        for e in self._order:
            self.store.publish(MODULE_HEALTH, self.module_health(e, now_s))

    def summary(self, now_s: float | None = None) -> dict[str, Any]:
        """Per-module timing and state, and the supervisor's events, for the run's JSON."""
        now = self.clock.now() if now_s is None else now_s
        return {
            "modules": {
                e.spec.name: {
                    k: v
                    for k, v in vars(self.module_health(e, now, window=None)).items()
                    if k not in ("t_s", "module")
                }
                for e in self._order
            },
            "events": [
                vars(ev) | {"t_rel_s": round(ev.t_s - (self.start_s or 0.0), 4)} for ev in self.events
            ],
        }
