"""Scheduler and supervisor on toy modules: every failure kind is detected within its bound and handled.

Lockstep on a simulated clock, as in SIL: detection times are simulated milliseconds, so the
bounds are exact and these tests do not depend on how busy the machine is (only the hang/deadlock
tell-apart reads real CPU time, over the real wall time the lockstep wait gives it).
"""

from __future__ import annotations

import collections
import math
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass

import pytest
from hypothesis import given
from hypothesis import strategies as st

from bywire.clock import SimClock
from bywire.host.runtime.inline_worker import background
from bywire.host.runtime.module import (
    FailurePolicy,
    Module,
    ModuleContext,
    ModuleSpec,
    dependants,
    dependency_order,
)
from bywire.host.runtime.runtime import Runtime, exec_stats_ms
from bywire.host.runtime.store import ObjectStore, StoreError
from bywire.host.runtime.topics import SAFETY_LIMIT, STOP_REQUEST
from bywire.host.runtime.worker import ReleaseStats


@dataclass(frozen=True)
class Tick:
    t_s: float
    n: int


class Counter(Module):
    """Publishes a count every release; misbehaves on command."""

    def __init__(self, out: str, fail: dict[str, float] | None = None, src: str | None = None) -> None:
        self.n = 0
        self.out = out
        self.src = src
        self.fail = fail or {}

    def step(self, ctx: ModuleContext) -> None:
        t = ctx.now_s
        if "raise_at" in self.fail and t >= self.fail["raise_at"]:
            self.fail.pop("raise_at")  # transient: the restarted instance gets a fresh dict anyway
            raise RuntimeError("injected")
        if "spin_at" in self.fail and t >= self.fail["spin_at"]:
            self.fail.pop("spin_at")
            while True:
                pass
        if "block_at" in self.fail and t >= self.fail["block_at"]:
            self.fail.pop("block_at")
            lock = threading.Lock()
            lock.acquire()
            lock.acquire()
        if "helper_spin_at" in self.fail and t >= self.fail["helper_spin_at"]:
            self.fail.pop("helper_spin_at")
            # the step waits in a join for a helper thread that works for it (as scipy's FFT with
            # workers=-1 does); the helper gives up after 2 s so that no test leaves it burning
            end = time.monotonic() + 2.0
            helper = threading.Thread(target=_spin_until, args=(end,), name="step-helper", daemon=True)
            helper.start()
            helper.join()
        if "background_spin_at" in self.fail and t >= self.fail["background_spin_at"]:
            self.fail.pop("background_spin_at")
            with background():  # work that on wall time runs beside the step (the zone planner)
                _spin_for(0.15)
        if "interrupt_at" in self.fail and t >= self.fail["interrupt_at"]:
            self.fail.pop("interrupt_at")
            raise KeyboardInterrupt  # Ctrl-C (or SIGINT/SIGTERM, process_util) landing in this step
        if "spin_for" in self.fail and t >= self.fail["spin_for"]:
            self.fail.pop("spin_for")
            _spin_for(0.15)
        if "slow_from" in self.fail and t >= self.fail["slow_from"]:
            time.sleep(self.fail["slow_s"])
        if "mute_from" in self.fail and t >= self.fail["mute_from"]:
            return
        if self.src is not None:
            ctx.new(self.src)
        self.n += 1
        ctx.publish(self.out, Tick(t, self.n))


_HELPERS_STOP = threading.Event()


def _spin_for(seconds: float) -> None:
    end = time.thread_time() + seconds
    while time.thread_time() < end:
        pass


def _spin_until(end_s: float) -> None:
    while time.monotonic() < end_s and not _HELPERS_STOP.is_set():
        pass


def make_runtime(
    fail_a: dict[str, float], policy: FailurePolicy | None = None
) -> tuple[Runtime, ObjectStore]:
    store = ObjectStore()
    rt = Runtime(store, SimClock(), lockstep=True, lockstep_timeout_s=0.05)
    pol = policy or FailurePolicy()
    spec_a = ModuleSpec("a", outputs=("/a",), period_s=0.02, deadline_s=0.01, policy=pol)
    spec_b = ModuleSpec("b", inputs=("/a",), outputs=("/b",), trigger="/a", deadline_s=0.01)
    # A fresh fault dict per instance would make every fault transient; share one so a consumed
    # one-shot fault stays consumed across restarts, like a real transient event.
    rt.add_module(spec_a, lambda: Counter("/a", fail_a))
    rt.add_module(spec_b, lambda: Counter("/b", src="/a"))
    return rt, store


def run(rt: Runtime, seconds: float) -> None:
    rt.start(0.0)
    try:
        for k in range(round(seconds / 0.001) + 1):
            rt.clock.advance_to(k * 0.001)  # type: ignore[attr-defined]
            rt.tick(k * 0.001)
    finally:
        rt.close()


def causes(rt: Runtime) -> list[tuple[str, str, str]]:
    return [(e.module, e.cause, e.action) for e in rt.events]


def test_healthy_modules_run_on_time_and_in_dependency_order() -> None:
    rt, store = make_runtime({})
    run(rt, 1.0)
    assert rt.events == []
    a = store.history("/a")
    assert [o.t_s for o in a[:3]] == pytest.approx([0.0, 0.02, 0.04])
    assert len(a) == 51
    # b is triggered by every /a and, in lockstep, runs in the same tick
    assert [o.t_s for o in store.history("/b")] == [o.t_s for o in a]
    health = rt.summary(1.0)["modules"]["a"]
    assert health["completed"] == 51 and health["misses"] == 0 and health["state"] == "running"


def test_exception_is_detected_at_once_and_the_module_restarted_with_its_dependants() -> None:
    rt, store = make_runtime({"raise_at": 0.5})
    run(rt, 1.0)
    first = rt.events[0]
    assert (first.module, first.cause, first.action) == ("a", "exception", "restart")
    assert "RuntimeError: injected" in first.detail
    assert first.detect_ms <= 1.0
    assert ("b", "dependant", "restart") in causes(rt)
    assert ("a", "recovered", "none") in causes(rt)
    # the restarted instance starts counting again, on the period grid
    after = [o for o in store.history("/a") if o.t_s > 0.5]
    assert after[0].n == 1 and after[0].t_s == pytest.approx(0.52)


@pytest.mark.parametrize("where", ["inline", "threads"])
@pytest.mark.parametrize(("fault", "cause"), [("spin_at", "hang"), ("block_at", "deadlock")])
def test_hang_and_deadlock_are_told_apart_and_detected_within_the_bound(
    fault: str, cause: str, where: str
) -> None:
    """Inline: lockstep on the main thread (the watchdog interrupts the step); threads: the same
    scheduler driven from another thread, so each module runs on a thread of its own."""
    policy = FailurePolicy(hang_after_s=0.06)
    rt, store = make_runtime({fault: 0.3}, policy)
    before = set(threading.enumerate())
    if where == "inline":
        run(rt, 0.6)
    else:
        driver = threading.Thread(target=run, args=(rt, 0.6))
        driver.start()
        driver.join(30)
    ev = rt.events[0]
    assert (ev.module, ev.cause, ev.action) == ("a", cause, "restart"), ev.detail
    assert 60.0 < ev.detect_ms <= 62.0
    # the replacement runs; the zombie's outputs (if any) are fenced
    assert store.latest("/a").t_s == pytest.approx(0.6)
    # a spinning zombie thread is cancelled (no CPU burnt for ever); a blocked one is left alone,
    # since an exception raised into it would fire when its call returns, wherever that is
    time.sleep(0.05)
    zombies = [t for t in threading.enumerate() if t.name == "module-a#1" and t not in before]
    assert len(zombies) == (1 if (cause, where) == ("deadlock", "threads") else 0)


def test_a_step_that_waits_for_its_busy_helper_thread_is_spinning_not_deadlocked() -> None:
    """Lockstep counts the process's CPU for the step on the main thread: a step asleep in a join while
    its helper thread computes for it is busy. Judged by the main thread alone it was a 'deadlock at
    0% of a CPU' (a C-space convolution with workers=-1 restarted six times in one loaded run)."""
    policy = FailurePolicy(hang_after_s=0.06)
    rt, _ = make_runtime({"helper_spin_at": 0.3}, policy)
    _HELPERS_STOP.clear()
    try:
        run(rt, 0.6)
    finally:
        _HELPERS_STOP.set()  # the interrupted step's helper would spin on, taking the GIL from others
    ev = rt.events[0]
    assert (ev.module, ev.cause) == ("a", "hang"), ev.detail
    assert "spinning" in ev.detail


@pytest.mark.parametrize("marked", [True, False])
def test_background_work_of_a_lockstep_step_is_neither_charged_nor_judged(marked: bool) -> None:
    """150 ms of CPU in a step with a 10 ms deadline and a 50 ms lockstep wait: marked background (the
    zone planner's step in SIL, a worker process on wall time), the step is on time and nothing is
    detected; the same work unmarked is a hang."""
    fault = "background_spin_at" if marked else "spin_for"
    rt, _ = make_runtime({fault: 0.3}, FailurePolicy(hang_after_s=0.06))
    run(rt, 0.6)
    if marked:
        assert rt.events == []
        health = rt.summary(0.6)["modules"]["a"]
        assert health["misses"] == 0 and health["completed"] == 31
    else:
        assert causes(rt)[0] == ("a", "hang", "restart")


def test_ctrl_c_in_a_lockstep_step_stops_the_run_and_is_no_module_fault() -> None:
    """A signal handled like Ctrl-C lands in whatever step the main thread runs: it ends the run (whose
    `finally` writes its files, exit 128 + N), rather than restarting that module as if it had raised
    (then the run went on to its end and exited 0: a flaky CLI test showed it)."""
    rt, store = make_runtime({"interrupt_at": 0.3})
    with pytest.raises(KeyboardInterrupt):
        run(rt, 0.6)
    assert rt.events == []
    assert store.latest("/a").t_s == pytest.approx(0.28)


class _LateWorker:
    """A late worker as the wall-time supervisor samples it: 0.1 ms of CPU per look, in `state`."""

    def __init__(self, state: str) -> None:
        self.state, self.cpu_s = state, 1.0

    def cpu_time_s(self) -> float:
        self.cpu_s += 1e-4
        return self.cpu_s

    def run_state(self) -> str:
        return self.state


@pytest.mark.parametrize(("state", "cause"), [("R", "starved"), ("S", "deadlock"), ("D", "deadlock")])
def test_a_runnable_worker_with_little_cpu_is_starved_or_spinning_never_deadlocked(
    state: str, cause: str
) -> None:
    """On a loaded machine a spinning thread may get a tenth of a CPU: its share alone would call it
    blocked. Its scheduler state tells: runnable (R) wants the CPU; only a sleeping one is stuck."""
    rt, _store = make_runtime({})
    entry = rt.entries["a"]
    entry.busy_mark = None
    got, detail, _ = rt._classify_hang(entry, _LateWorker(state), 0.2, 0.06)  # type: ignore[arg-type]
    assert got == cause, detail
    assert ("kept off the CPU" in detail) == (state == "R")


@pytest.mark.parametrize(("runnable", "cause"), [(True, "hang"), (False, "deadlock")])
def test_a_lockstep_step_that_had_its_cpu_and_still_runs_is_spinning_however_little_the_sample_got(
    runnable: bool, cause: str
) -> None:
    """The lockstep watchdog samples a late step's CPU share before interrupting it; on a loaded
    machine a spinning step got 19 % of a CPU in that sample and was called a deadlock. A step that
    took its timeout's CPU and is still runnable is spinning; only a sleeping one is stuck."""
    rt, _store = make_runtime({})
    worker = _LateWorker("R" if runnable else "S")
    worker.hang_cpu_share, worker.hang_runnable = 0.19, runnable  # type: ignore[attr-defined]
    got, detail, _ = rt._classify_hang(rt.entries["a"], worker, 0.2, 0.06)  # type: ignore[arg-type]
    assert got == cause, detail


class _StarvedWorker(_LateWorker):
    """A release begun at 0 s that is still runnable and barely gets the CPU (a loaded machine)."""

    failure = None
    busy_since_s = 0.0

    def ready(self) -> bool:
        return True

    def alive(self) -> bool:
        return True


def test_a_starved_release_is_watched_not_restarted_until_it_outlasts_the_patience() -> None:
    """A module kept off the CPU with the rest of its process is not hung: a restart would only add
    work to a machine that has too much. It is looked at again over fresh windows, and called hung
    only once it has been starved for STARVED_PATIENCE times its hang bound."""
    from bywire.host.runtime.runtime import MIN_SPIN_SAMPLE_S, STARVED_PATIENCE

    rt, _store = make_runtime({})
    rt.lockstep = False  # on wall time (lockstep judges a runnable worker hung at once)
    rt.start_s = 0.0
    e = rt.entries["a"]
    w = _StarvedWorker("R")
    hang_s = e.spec.hang_after_s
    assert rt._detect(e, w, hang_s + 0.01) is None and e.rejudge  # type: ignore[arg-type]
    assert rt._detect(e, w, hang_s + 0.02) is None  # type: ignore[arg-type] # its window is still open
    time.sleep(2 * MIN_SPIN_SAMPLE_S)
    assert rt._detect(e, w, 5 * hang_s) is None  # type: ignore[arg-type]
    time.sleep(2 * MIN_SPIN_SAMPLE_S)
    cause, detail, onset = rt._detect(e, w, (STARVED_PATIENCE + 1) * hang_s)  # type: ignore[arg-type,misc]
    assert cause == "hang" and "kept off the CPU" in detail and onset == 0.0
    w.busy_since_s = None  # type: ignore[assignment] # done at last: the next release is judged afresh
    w.stats = ReleaseStats()  # type: ignore[attr-defined]
    assert rt._detect(e, w, 2.0) is None and not e.rejudge  # type: ignore[arg-type]


def test_slow_module_is_detected_after_the_configured_misses_and_degraded() -> None:
    policy = FailurePolicy(action="degrade", slow_misses=3, slow_window=5, degrade_speed_mps=4.0)
    rt, store = make_runtime({"slow_from": 0.2, "slow_s": 0.015}, policy)
    run(rt, 0.4)
    ev = rt.events[0]
    assert (ev.module, ev.cause, ev.action) == ("a", "slow", "degrade")
    assert ev.t_s == pytest.approx(0.24)  # the third miss (releases 0.20, 0.22, 0.24), judged at once
    limit = store.latest(SAFETY_LIMIT)
    assert limit.max_speed_mps == 4.0 and "a: slow" in limit.reason
    assert rt.summary(0.4)["modules"]["a"]["state"] == "degraded"
    assert len(rt.events) == 1  # a degraded module is not reported again for the same cause


def test_module_that_runs_but_publishes_nothing_is_stale() -> None:
    rt, _store = make_runtime({"mute_from": 0.5})
    run(rt, 0.7)
    ev = rt.events[0]
    assert (ev.module, ev.cause) == ("a", "stale")
    assert ev.onset_s == pytest.approx(0.50)  # the first release that published nothing
    assert ev.t_s == pytest.approx(0.54)  # judged when the third silent release completes
    assert "3 releases in a row published none of /a" in ev.detail


def test_restarts_escalate_to_a_controlled_stop() -> None:
    policy = FailurePolicy(max_restarts=2, escalate_to="stop", backoff_s=0.01)
    fail = {"slow_from": 0.1, "slow_s": 0.012}  # persistent: every instance is slow
    rt, store = make_runtime(fail, policy)
    run(rt, 2.0)
    actions = [e.action for e in rt.events if e.module == "a" and e.cause == "slow"]
    assert actions == ["restart", "restart", "stop"]
    stop = store.latest(STOP_REQUEST)
    assert stop is not None and "a: slow" in stop.reason
    restarts = [e.t_s for e in rt.events if e.module == "a" and e.cause == "slow"]
    assert restarts[1] - restarts[0] >= 0.01 + 2 * 0.02 - 1e-9  # back-off, then three slow releases


def test_undeclared_topics_are_refused() -> None:
    store = ObjectStore()
    spec = ModuleSpec("m", inputs=("/x",), outputs=("/y",), period_s=0.1)
    from bywire.host.runtime.module import ModuleContext as Ctx

    ctx = Ctx(spec, store, {}, 1)
    with pytest.raises(StoreError, match="m publishes '/z'"):
        ctx.publish("/z", Tick(0.0, 1))
    with pytest.raises(StoreError, match="m reads '/q'"):
        ctx.latest("/q")


def test_dependency_order_and_dependants_with_a_feedback_loop() -> None:
    link = ModuleSpec("link", inputs=("/req",), outputs=("/status",), period_s=0.02)
    odo = ModuleSpec("odo", inputs=("/status",), outputs=("/odo",), period_s=0.02)
    ctl = ModuleSpec("ctl", inputs=("/odo", "/lead"), outputs=("/req",), period_s=0.02)
    track = ModuleSpec("track", inputs=("/radar",), outputs=("/lead",), period_s=0.02)
    log = ModuleSpec("log", inputs=("/req",), outputs=("/log",), period_s=0.02)
    specs = [link, odo, ctl, track, log]
    order = [s.name for s in dependency_order(specs)]
    assert order.index("track") < order.index("ctl") < order.index("log")
    assert dependants(specs, "track") == ["ctl", "log"]
    assert dependants(specs, "ctl") == ["log"]  # link and odo feed back into ctl: not restarted
    with pytest.raises(ValueError, match="output of both"):
        dependency_order([link, ModuleSpec("x", outputs=("/status",), period_s=1.0)])


def test_bad_declarations_are_refused() -> None:
    with pytest.raises(ValueError, match="exactly one of period_s and trigger"):
        ModuleSpec("m")
    with pytest.raises(ValueError, match="trigger '/t' must be one of its inputs"):
        ModuleSpec("m", trigger="/t")
    with pytest.raises(ValueError, match="escalate_to cannot be restart"):
        FailurePolicy(escalate_to="restart")


class SlowReader(Module):
    """Sleeps, then reads its input: on a busy host the input moves on meanwhile."""

    def __init__(self, seen: list[tuple[float, float]]) -> None:
        self.seen = seen

    def step(self, ctx: ModuleContext) -> None:
        time.sleep(0.03)
        tick = ctx.latest("/fast")
        self.seen.append((ctx.now_s, tick.t_s if tick is not None else -1.0))
        ctx.publish("/slow", Tick(ctx.now_s, len(self.seen)))


class SlowConsumer(Module):
    """Logs its release time and the /slow object it computes on."""

    def __init__(self, log: list[tuple[float, float]]) -> None:
        self.log = log

    def step(self, ctx: ModuleContext) -> None:
        tick = ctx.latest("/slow")
        self.log.append((ctx.now_s, tick.t_s if tick is not None else -1.0))
        ctx.publish("/consumer", Tick(ctx.now_s, len(self.log)))


class Sink(Module):
    def __init__(self, log: list[float]) -> None:
        self.log = log

    def step(self, ctx: ModuleContext) -> None:
        self.log.append(ctx.now_s)
        ctx.publish(ctx.spec.outputs[0], Tick(ctx.now_s, len(self.log)))


def test_on_wall_time_a_late_module_reads_its_release_and_holds_back_only_its_consumers() -> None:
    """Wall time (HIL, the car): the chain waits a few milliseconds, not longer. A late module
    computes on the store as of its release (never on what was published while it ran late); a
    consumer of it waits until it is done and then computes on its newest output (never on the one
    being replaced); a sink that must run every period (the ECU link) runs every period."""
    from bywire.clock import WallClock

    clock = WallClock()
    store = ObjectStore()
    rt = Runtime(store, clock, lockstep=False)
    seen: list[tuple[float, float]] = []
    sink_log: list[float] = []
    consumer_log: list[tuple[float, float]] = []
    rt.add_module(
        ModuleSpec("fast", outputs=("/fast",), period_s=0.005, deadline_s=0.004), lambda: Counter("/fast")
    )
    rt.add_module(
        ModuleSpec(
            "slow",
            inputs=("/fast",),
            outputs=("/slow",),
            period_s=0.04,
            deadline_s=0.005,
            policy=FailurePolicy(action="degrade"),  # keeps running, late, for the whole test
        ),
        lambda: SlowReader(seen),
    )
    rt.add_module(
        ModuleSpec("consumer", inputs=("/slow",), outputs=("/consumer",), period_s=0.04, deadline_s=0.005),
        lambda: SlowConsumer(consumer_log),
    )
    rt.add_module(
        ModuleSpec(
            "link",
            inputs=("/slow",),
            outputs=("/link",),
            period_s=0.04,
            deadline_s=0.005,
            always_release=True,
        ),
        lambda: Sink(sink_log),
    )
    rt.prestart()
    t0 = clock.now()
    rt.start(t0)
    rt.run_wall(t0 + 0.5, tick_s=0.001)
    summary = rt.summary(clock.now())["modules"]
    rt.close()
    # What is judged is what the runtime did, not how fast the machine was: a stalled VM may make
    # any module late and skip periods, which the runtime must count, never hide.
    assert len(seen) >= 2
    for release_s, input_t_s in seen:
        # Never one of the /fast published during the 30 ms sleep (up to six of them).
        assert release_s - 0.05 < input_t_s <= release_s
    link = summary["link"]
    assert link["releases"] == len(sink_log)
    assert link["releases"] + link["skipped"] >= 11, (t0, sink_log, link)  # every period of 0.5 s: 12 or 13
    slow_events = [e.cause for e in rt.events if e.module == "slow"]
    assert slow_events == ["slow"], rt.events  # reported once, and degraded: not again
    assert {e.cause for e in rt.events} == {"slow"}, rt.events  # lateness is never called a hang
    # The slow module is late every cycle: its consumer ran after each of its releases, each time on
    # the output of the slow release before it, never on an older one (that is, never while the slow
    # module was computing a newer one).
    assert consumer_log
    slow_releases = [release_s for release_s, _ in seen]
    for release_s, input_t_s in consumer_log:
        before = [s for s in slow_releases if s <= release_s]
        assert before and input_t_s == before[-1], (release_s, input_t_s, slow_releases)


class _InterruptedOnce(collections.deque):  # type: ignore[type-arg]
    """A history whose first read of its window is cut short, as a worker thread's append would."""

    interrupted = False

    def __reversed__(self) -> Iterator[float]:
        if not self.interrupted:
            self.interrupted = True
            raise RuntimeError("deque mutated during iteration")
        return super().__reversed__()

    def copy(self) -> collections.deque[float]:  # type: ignore[override]
        return collections.deque(self)


@given(st.lists(st.floats(0.0, 1.0), max_size=300), st.one_of(st.none(), st.integers(1, 150)))
def test_exec_statistics_of_the_window_are_those_of_a_snapshot(
    samples: list[float], window: int | None
) -> None:
    history = collections.deque(samples, maxlen=1000)
    chosen = samples if window is None else samples[::-1][:window]
    expected = (0.0, 0.0, 0.0)
    if chosen:
        ordered = sorted(chosen)
        n = len(ordered)
        p50 = ordered[(n - 1) // 2] if n % 2 else 0.5 * (ordered[n // 2 - 1] + ordered[n // 2])
        p99 = ordered[min(n - 1, math.ceil(0.99 * n) - 1)]
        expected = (round(p50 * 1e3, 4), round(p99 * 1e3, 4), round(ordered[-1] * 1e3, 4))
    assert exec_stats_ms(history, window) == expected
    assert exec_stats_ms(_InterruptedOnce(samples), window) == expected
