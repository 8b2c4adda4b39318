"""Cyclic executive (deadlines, overrun policy), cycle statistics and the real-time set-up report."""

from __future__ import annotations

import errno
import itertools
import json
import subprocess
import sys
import tracemalloc

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bywire.clock import SimClock, WallClock
from bywire.ecu.executive import CycleStats, CyclicExecutive
from bywire.realtime import apply_realtime

PERIOD_S = 0.001


class ScriptedClock:
    """Simulated time in which sleeping wakes late by a scripted amount and steps take time.

    Wake latencies are taken one per sleep_until call from `wake_late_s` (then 0).
    """

    def __init__(self, start_s: float = 0.0, wake_late_s: list[float] | None = None) -> None:
        self.t = start_s
        self.wake_late_s = list(wake_late_s or [])
        self.sleeps: list[float] = []

    def now(self) -> float:
        return self.t

    def sleep_until(self, t_s: float) -> None:
        self.sleeps.append(t_s)
        late = self.wake_late_s.pop(0) if self.wake_late_s else 0.0
        self.t = max(self.t, t_s) + late

    def spend(self, dt_s: float) -> None:
        self.t += dt_s


def make_executive(clock, compute_s_by_cycle: dict[int, float], period_s: float = 1.0, capacity=1024):
    """An executive whose step k takes compute_s_by_cycle.get(k, 0) on `clock`; returns (exe, deadlines)."""
    deadlines: list[float] = []

    def step(now_s: float) -> None:
        k = len(deadlines)
        deadlines.append(now_s)
        clock.spend(compute_s_by_cycle.get(k, 0.0))

    return CyclicExecutive(period_s, clock, step, CycleStats(capacity=capacity)), deadlines


# --- deadlines on a simulated clock ------------------------------------------------------------


def test_simclock_runs_exact_count_on_absolute_deadlines() -> None:
    clock = SimClock(start_s=5.0)
    deadlines: list[float] = []
    stats = CycleStats()
    exe = CyclicExecutive(PERIOD_S, clock, deadlines.append, stats)

    ran = exe.run(max_cycles=1000)

    assert ran == 1000
    assert stats.cycles == 1000
    assert stats.overruns == 0 and stats.missed_deadlines == 0
    # t_k = t0 + k * period exactly: multiplication, not an accumulated sum that drifts.
    assert deadlines == [5.0 + k * PERIOD_S for k in range(1000)]
    assert clock.now() == 5.0 + 999 * PERIOD_S
    assert stats.percentile("lateness_us", 100.0) == 0.0
    assert exe.next_index == 1000


def test_stop_and_progress_callbacks() -> None:
    clock = SimClock()
    seen: list[int] = []
    exe = CyclicExecutive(PERIOD_S, clock, lambda _t: None, CycleStats())

    ran = exe.run(stop=lambda: len(seen) >= 7, progress=seen.append)

    assert ran == 7
    assert seen == [1, 2, 3, 4, 5, 6, 7]
    assert exe.run(max_cycles=0) == 0


def test_run_once_records_lockstep_cycles() -> None:
    clock = SimClock()
    calls: list[float] = []
    stats = CycleStats()
    exe = CyclicExecutive(PERIOD_S, clock, calls.append, stats)
    for k in range(5):
        clock.advance_to(k * PERIOD_S)
        exe.run_once(k * PERIOD_S)
    assert calls == [k * PERIOD_S for k in range(5)]
    assert stats.cycles == 5 and stats.overruns == 0
    assert stats.values("lateness_us") == [0.0] * 5


def test_run_once_flags_a_step_longer_than_the_period() -> None:
    clock = ScriptedClock()
    exe, _ = make_executive(clock, {0: 2.5})
    exe.run_once(0.0)
    assert exe.stats.overruns == 1
    assert exe.stats.values("compute_us") == [2.5e6]


# --- injected lateness and long steps ------------------------------------------------------------


def test_injected_wake_lateness_is_measured_and_does_not_shift_the_grid() -> None:
    clock = ScriptedClock(wake_late_s=[0.0, 0.25, 0.0, 0.5])
    exe, deadlines = make_executive(clock, {})

    exe.run(max_cycles=6)

    assert deadlines == [0.0, 1.0, 2.0, 3.0, 4.0, 5.0]
    # First cycle: deadline == now, no sleep. The scripted latencies apply to sleeps 1..4.
    assert exe.stats.values("lateness_us") == pytest.approx([0.0, 0.0, 0.25e6, 0.0, 0.5e6, 0.0])
    assert exe.stats.overruns == 0


def test_overrun_within_one_period_runs_next_cycle_late_without_skipping() -> None:
    clock = ScriptedClock()
    exe, deadlines = make_executive(clock, {3: 1.5})

    exe.run(max_cycles=7)

    assert deadlines == [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
    stats = exe.stats
    assert stats.overruns == 1
    assert stats.missed_deadlines == 0
    assert stats.overrun_flags() == [False, False, False, True, False, False, False]
    assert stats.values("lateness_us") == pytest.approx([0, 0, 0, 0, 0.5e6, 0, 0])
    assert stats.values("compute_us")[3] == pytest.approx(1.5e6)


def test_overrun_by_more_than_a_period_skips_and_rephases_without_burst() -> None:
    clock = ScriptedClock()
    exe, deadlines = make_executive(clock, {3: 3.5})

    ran = exe.run(max_cycles=6)

    # Cycle 3 ends at 6.5: deadlines 4, 5, 6 are past and counted missed, next is 7 on the grid.
    assert ran == 6
    assert deadlines == [0.0, 1.0, 2.0, 3.0, 7.0, 8.0]
    assert exe.stats.missed_deadlines == 3
    assert exe.stats.overruns == 1
    assert exe.stats.values("lateness_us")[4] == 0.0
    # Re-phasing sleeps to the future deadline: it neither spins nor runs the past ones.
    assert 7.0 in clock.sleeps


def test_overrun_ending_exactly_on_a_deadline_counts_that_deadline_missed() -> None:
    clock = ScriptedClock()
    exe, deadlines = make_executive(clock, {0: 3.0})
    exe.run(max_cycles=3)
    # Ends at 3.0 == t3: t1, t2, t3 are not in the future any more.
    assert deadlines == [0.0, 4.0, 5.0]
    assert exe.stats.missed_deadlines == 3


def test_overrun_streak_grows_with_inherited_lateness_and_resets() -> None:
    clock = ScriptedClock()
    exe, deadlines = make_executive(clock, {2: 1.2, 3: 1.2, 4: 1.2, 5: 0.1})

    exe.run(max_cycles=8)

    stats = exe.stats
    # 2 runs 2.0-3.2; 3 runs 3.2-4.4; 4 runs 4.4-5.6; 5 runs 5.6-5.7; 6 back on the grid at 6.0.
    assert deadlines == [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0]
    assert stats.overrun_flags() == [False, False, True, True, True, False, False, False]
    assert stats.overruns == 3
    assert stats.max_overrun_streak == 3
    assert stats.overrun_streak == 0
    assert stats.missed_deadlines == 0
    assert stats.values("lateness_us") == pytest.approx([0, 0, 0, 0.2e6, 0.4e6, 0.6e6, 0, 0])


def test_persistent_overrun_is_reported_as_current_streak() -> None:
    clock = ScriptedClock()
    exe, _ = make_executive(clock, {k: 2.5 for k in range(10)})
    exe.run(max_cycles=10)
    assert exe.stats.overrun_streak == 10
    assert exe.stats.overruns == 10
    # Each cycle ends 1.5 periods after its successor's deadline: 2 deadlines skipped each time.
    assert exe.stats.missed_deadlines == 20


def test_rejects_bad_period() -> None:
    with pytest.raises(ValueError, match="period_s"):
        CyclicExecutive(0.0, SimClock(), lambda _t: None, CycleStats())


# --- statistics ---------------------------------------------------------------------------------


def test_percentiles_match_numpy_on_random_data_with_wraparound() -> None:
    rng = np.random.default_rng(7)
    capacity = 5000
    stats = CycleStats(capacity=capacity)
    lateness_s = rng.lognormal(mean=-10, sigma=1.0, size=12_345)
    compute_s = rng.gamma(2.0, 1e-4, size=12_345)
    for lat, comp in zip(lateness_s, compute_s, strict=True):
        stats.record(float(lat), float(comp), False)

    kept_lat = lateness_s[-capacity:] * 1e6
    kept_comp = compute_s[-capacity:] * 1e6
    for p in (0.0, 1.0, 50.0, 90.0, 99.0, 99.9, 100.0):
        assert stats.percentile("lateness_us", p) == pytest.approx(np.percentile(kept_lat, p), rel=1e-12)
        assert stats.percentile("compute_us", p) == pytest.approx(np.percentile(kept_comp, p), rel=1e-12)
    assert sorted(stats.values("lateness_us")) == pytest.approx(sorted(kept_lat))
    # max is since start, not just over the retained ring.
    assert stats.lateness_max_us == pytest.approx(lateness_s.max() * 1e6)
    assert stats.compute_max_us == pytest.approx(compute_s.max() * 1e6)


@settings(max_examples=60, deadline=None)
@given(
    samples=st.lists(st.floats(-1e-3, 1e-2, allow_nan=False), min_size=1, max_size=300),
    capacity=st.integers(1, 64),
    p=st.floats(0.0, 100.0),
)
def test_percentile_property_matches_numpy(samples: list[float], capacity: int, p: float) -> None:
    stats = CycleStats(capacity=capacity)
    for s in samples:
        stats.record(s, s, False)
    ref = np.percentile(np.array(samples[-capacity:]) * 1e6, p)
    assert stats.percentile("lateness_us", p) == pytest.approx(ref, rel=1e-9, abs=1e-9)
    assert stats.values("compute_us") == pytest.approx([s * 1e6 for s in samples[-capacity:]])


def test_snapshot_has_exactly_the_contract_shape() -> None:
    stats = CycleStats()
    for k in range(100):
        stats.record(k * 1e-6, 2e-6, overrun=(k % 10 == 0))
    snap = stats.snapshot()

    assert set(snap) == {"cycles", "overruns", "missed_deadlines", "lateness_us", "compute_us"}
    assert set(snap["lateness_us"]) == {"p50", "p99", "p999", "max"}
    assert set(snap["compute_us"]) == {"p50", "p99", "max"}
    assert snap["cycles"] == 100 and snap["overruns"] == 10
    assert snap["lateness_us"]["max"] == pytest.approx(99.0)
    assert snap["lateness_us"]["p50"] == pytest.approx(49.5)
    assert snap["compute_us"]["p99"] == pytest.approx(2.0)
    assert json.loads(json.dumps(snap)) == snap


def test_empty_stats_read_as_zero_and_reject_bad_arguments() -> None:
    stats = CycleStats(capacity=8)
    assert stats.snapshot()["lateness_us"] == {"p50": 0.0, "p99": 0.0, "p999": 0.0, "max": 0.0}
    assert stats.window_p99_lateness_us() == 0.0
    with pytest.raises(ValueError, match="unknown statistic 'jitter_us'"):
        stats.percentile("jitter_us", 50.0)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="p 101"):
        stats.percentile("lateness_us", 101.0)
    with pytest.raises(ValueError, match="capacity"):
        CycleStats(capacity=0)


def test_window_values_are_cached_between_refreshes() -> None:
    stats = CycleStats(capacity=4096, window=1000, window_every=1000)
    rng = np.random.default_rng(3)
    first = rng.uniform(0, 100e-6, size=1000)
    for s in first:
        stats.record(float(s), float(s) / 2, False)
    p99 = stats.window_p99_lateness_us()
    assert p99 == pytest.approx(np.percentile(first * 1e6, 99))
    assert stats.max_compute_us_window() == pytest.approx(first.max() * 1e6 / 2)

    for _ in range(999):
        stats.record(1.0, 1.0, False)  # huge, but inside the caching interval
    assert stats.window_p99_lateness_us() == p99

    stats.record(1.0, 1.0, False)  # 1000 cycles since the last refresh
    assert stats.window_p99_lateness_us() == pytest.approx(1e6)
    assert stats.max_compute_us_window() == pytest.approx(1e6)


def test_record_does_not_allocate_per_cycle() -> None:
    stats = CycleStats(capacity=1024)
    for k in range(2048):  # wrap once so every slot has been written
        stats.record(k * 1e-7, 1e-6, k % 3 == 0)
    tracemalloc.start()
    try:
        before, _ = tracemalloc.get_traced_memory()
        for k in range(20_000):
            stats.record(k * 1e-7, 1e-6, k % 3 == 0)
        after, _ = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert after - before < 2048  # bytes: a growing list would hold >= 8 bytes per cycle


# --- wall clock -----------------------------------------------------------------------------------


def test_wall_clock_run_counts_and_monotonic_deadlines() -> None:
    stats = CycleStats()
    deadlines: list[float] = []
    exe = CyclicExecutive(PERIOD_S, WallClock(), deadlines.append, stats)

    ran = exe.run(max_cycles=200)

    assert ran == 200 == stats.cycles == len(deadlines)
    assert all(b > a for a, b in itertools.pairwise(deadlines))
    # Deadlines stay on the grid t0 + k * period, whatever the machine's jitter.
    k = [round((d - deadlines[0]) / PERIOD_S) for d in deadlines]
    assert k == sorted(set(k))
    assert stats.missed_deadlines == k[-1] - 199
    assert len(stats.values("lateness_us")) == 200


# --- real-time set-up report ----------------------------------------------------------------------


class FakeSystem:
    def __init__(self, fail: dict[str, int]) -> None:
        self.fail = fail
        self.calls: list[tuple[str, int | None]] = []

    def _maybe_fail(self, name: str, arg: int | None = None) -> None:
        self.calls.append((name, arg))
        if name in self.fail:
            raise OSError(self.fail[name], "refused")

    def set_fifo(self, priority: int) -> None:
        self._maybe_fail("fifo", priority)

    def set_affinity(self, cpu: int) -> None:
        self._maybe_fail("affinity", cpu)

    def lock_memory(self) -> None:
        self._maybe_fail("mlock")

    def freeze_gc(self) -> None:
        self._maybe_fail("gc")


def test_realtime_report_records_failures_instead_of_raising() -> None:
    system = FakeSystem({"mlock": errno.EPERM})
    report = apply_realtime(priority=80, system=system)

    assert report.summary() == (
        "SCHED_FIFO 80: yes; CPU affinity: no (not requested); "
        "mlockall: no (EPERM: run as root or set CAP_IPC_LOCK/ulimit -l); gc frozen: yes"
    )
    assert not report.fully_applied
    assert system.calls == [("fifo", 80), ("mlock", None), ("gc", None)]


def test_realtime_report_all_failures_and_all_success() -> None:
    failing = FakeSystem({"fifo": errno.EPERM, "affinity": errno.EINVAL, "mlock": errno.ENOMEM})
    report = apply_realtime(priority=50, cpu=7, system=failing)
    assert report.sched_fifo.reason.startswith("EPERM")
    assert report.affinity.label == "CPU affinity 7" and report.affinity.reason.startswith("EINVAL")
    assert "ulimit -l" in report.mlockall.reason
    assert report.gc_frozen.applied

    ok = apply_realtime(priority=80, cpu=1, system=FakeSystem({}))
    assert ok.fully_applied
    assert ok.summary() == "SCHED_FIFO 80: yes; CPU affinity 1: yes; mlockall: yes; gc frozen: yes"

    unknown = apply_realtime(
        priority=10, lock_memory=False, freeze_gc=False, system=FakeSystem({"fifo": 1234})
    )
    assert not unknown.sched_fifo.applied and unknown.sched_fifo.reason
    assert unknown.mlockall.describe() == "mlockall: no (not requested)"


def test_realtime_rejects_impossible_arguments() -> None:
    with pytest.raises(ValueError, match="priority 150"):
        apply_realtime(priority=150, system=FakeSystem({}))
    with pytest.raises(ValueError, match="cpu -1"):
        apply_realtime(cpu=-1, system=FakeSystem({}))


def test_real_apply_in_a_child_process_reports_every_step() -> None:
    # In a child: SCHED_FIFO, mlockall and a disabled GC must not leak into the test process.
    code = (
        "from bywire.realtime import apply_realtime\n"
        "import gc\n"
        "r = apply_realtime(priority=1, cpu=0)\n"
        "print(r.summary())\n"
        "print(gc.isenabled())\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    summary, gc_enabled = out.stdout.strip().splitlines()
    parts = summary.split("; ")
    assert [p.split(":")[0] for p in parts] == ["SCHED_FIFO 1", "CPU affinity 0", "mlockall", "gc frozen"]
    assert all(p.endswith(": yes") or ": no (" in p for p in parts)
    assert parts[3] == "gc frozen: yes" and gc_enabled == "False"
