"""The ECU's 1 kHz cyclic executive and its timing statistics.

Paper: seed 000 Sec. 3 (1 kHz relay of control commands to the ECU); the scheduling itself is ours.

Timing model. Cycle k has the absolute deadline t_k = t0 + k * period (computed by multiplication,
never by accumulating `period`, so there is no drift). The executive sleeps until t_k on the
injected `Clock` (WallClock: clock_nanosleep TIMER_ABSTIME; SimClock: time jumps), wakes at w_k,
runs `step(t_k)` and ends at e_k:

- lateness_k = w_k - t_k  (scheduler wake-up latency, or the delay inherited from an overrun)
- compute_k  = e_k - w_k  (duration of the step)
- overrun_k  = e_k > t_{k+1}  (the step ended after the next deadline)

Overrun policy (a named, documented behaviour, as ros2_control's controller manager documents its own):

- overrun by at most one period (t_{k+1} < e_k <= t_{k+2}): cycle k+1 runs at once, late; its
  lateness records by how much. No deadline is skipped.
- overrun by more than one period (e_k > t_{k+2}): the deadlines t_{k+1} .. t_j (all <= e_k) are
  NOT run as a catch-up burst (a burst of stale control steps helps nobody and hogs a SCHED_FIFO
  CPU); they are counted in `missed_deadlines` and the executive re-phases to the next future
  deadline t_{j+1} of the original grid, so the phase relative to t0 is kept.
- the current run of consecutive overruns is `overrun_streak`; the safety authority raises
  Fault.OVERRUN on a streak, the executive itself never stops on its own.

The executive never spins: between cycles it always sleeps on the clock, which matters under
SCHED_FIFO where a busy loop starves every other task on that core.

Statistics live in preallocated `array` ring buffers (no per-cycle list growth); percentiles use
linear interpolation between order statistics, numpy's default method. Full percentiles
(`snapshot`) sort the whole ring (tens of ms for 65536 samples): call them from outside the loop.
The status PDO values (`window_p99_lateness_us`, `max_compute_us_window`) are recomputed from the
last `window` samples at most once per `window_every` cycles and cached in between.
"""

from __future__ import annotations

import heapq
import math
from array import array
from collections.abc import Callable
from typing import Literal

from bywire.clock import Clock

__all__ = ["CycleStats", "CyclicExecutive", "StatKind"]

StatKind = Literal["lateness_us", "compute_us"]

_US_PER_S = 1e6
# A clock_nanosleep woken early by a signal returns before the deadline; sleeping again is right,
# but a broken clock whose sleep never reaches the deadline must not turn into a spin.
_MAX_SLEEP_RETRIES = 3


def _percentile_sorted(values: list[float], p: float) -> float:
    """Linear interpolation between closest ranks (numpy.percentile's default 'linear' method)."""
    n = len(values)
    if n == 0:
        return 0.0
    pos = (n - 1) * p / 100.0
    lo = math.floor(pos)
    hi = min(lo + 1, n - 1)
    frac = pos - lo
    return values[lo] + (values[hi] - values[lo]) * frac


def _percentile_top(values: list[float], p: float) -> float:
    """Same as sorting and `_percentile_sorted`, from a partial selection of the largest values.

    For p99 of 1000 samples only the top 11 are needed: heapq.nlargest costs about half a full
    sort (measured side by side), which matters when the status PDO asks inside a cycle.
    """
    n = len(values)
    if n == 0:
        return 0.0
    lo = math.floor((n - 1) * p / 100.0)
    top = heapq.nlargest(n - lo, values)  # descending: top[i] is the (n-1-i)-th order statistic
    top.reverse()  # ascending: top[j] is order statistic lo + j
    pos = (n - 1) * p / 100.0
    hi_val = top[1] if len(top) > 1 else top[0]
    return top[0] + (hi_val - top[0]) * (pos - lo)


class CycleStats:
    """Per-cycle lateness, compute time and overrun flag, in fixed-size rings, plus counters.

    Units: the `record` inputs are seconds; everything read out is microseconds (the status PDO's
    and the JSON snapshot's unit). Empty statistics read as 0.0.
    """

    def __init__(self, capacity: int = 65536, window: int = 1000, window_every: int = 1000) -> None:
        if capacity < 1:
            raise ValueError(f"CycleStats: capacity {capacity} must be >= 1")
        if window < 1 or window_every < 1:
            raise ValueError(f"CycleStats: window {window} and window_every {window_every} must be >= 1")
        self.capacity = capacity
        self.window = min(window, capacity)
        self.window_every = window_every
        self._lateness_us = array("d", bytes(8 * capacity))
        self._compute_us = array("d", bytes(8 * capacity))
        self._overrun = array("B", bytes(capacity))
        self._head = 0  # next slot to write
        self.cycles = 0
        self.overruns = 0
        self.missed_deadlines = 0
        self.overrun_streak = 0
        self.max_overrun_streak = 0
        self.lateness_max_us = 0.0  # since start, not just the retained ring
        self.compute_max_us = 0.0
        self._window_at_cycle = -1
        self._window_p99_lateness_us = 0.0
        self._window_max_compute_us = 0.0

    def record(self, lateness_s: float, compute_s: float, overrun: bool) -> None:
        """Record one cycle (allocation-free apart from CPython's float temporaries)."""
        lateness_us = lateness_s * _US_PER_S
        compute_us = compute_s * _US_PER_S
        i = self._head
        self._lateness_us[i] = lateness_us
        self._compute_us[i] = compute_us
        self._overrun[i] = 1 if overrun else 0
        self._head = i + 1 if i + 1 < self.capacity else 0
        if self.cycles == 0 or lateness_us > self.lateness_max_us:
            self.lateness_max_us = lateness_us
        if self.cycles == 0 or compute_us > self.compute_max_us:
            self.compute_max_us = compute_us
        self.cycles += 1
        if overrun:
            self.overruns += 1
            self.overrun_streak += 1
            if self.overrun_streak > self.max_overrun_streak:
                self.max_overrun_streak = self.overrun_streak
        else:
            self.overrun_streak = 0

    def add_missed(self, n: int) -> None:
        """Count `n` deadlines that were skipped rather than run (see the overrun policy)."""
        if n < 0:
            raise ValueError(f"CycleStats.add_missed: n {n} must be >= 0")
        self.missed_deadlines += n

    @property
    def retained(self) -> int:
        """How many of the most recent cycles the rings still hold."""
        return min(self.cycles, self.capacity)

    def _ring(self, kind: StatKind) -> array[float]:
        if kind == "lateness_us":
            return self._lateness_us
        if kind == "compute_us":
            return self._compute_us
        raise ValueError(f"CycleStats: unknown statistic {kind!r} (expected 'lateness_us' or 'compute_us')")

    def _latest(self, ring: array[float], n: int) -> list[float]:
        """The most recent `n` samples (unordered: only sorted or max-ed afterwards)."""
        n = min(n, self.retained)
        if n == 0:
            return []
        start = self._head - n
        if start >= 0:
            return ring[start : self._head].tolist()
        return ring[start + self.capacity :].tolist() + ring[: self._head].tolist()

    def values(self, kind: StatKind) -> list[float]:
        """The retained samples of `kind`, oldest first (for tests, plots and dumps; allocates)."""
        n = self.retained
        ring = self._ring(kind)
        if self.cycles <= self.capacity:
            return ring[:n].tolist()
        return ring[self._head :].tolist() + ring[: self._head].tolist()

    def overrun_flags(self) -> list[bool]:
        """The retained per-cycle overrun flags, oldest first."""
        n = self.retained
        if self.cycles <= self.capacity:
            flags = self._overrun[:n].tolist()
        else:
            flags = self._overrun[self._head :].tolist() + self._overrun[: self._head].tolist()
        return [bool(f) for f in flags]

    def percentile(self, kind: StatKind, p: float) -> float:
        """The p-th percentile (0..100) of the retained samples of `kind`, in us."""
        if not 0.0 <= p <= 100.0 or math.isnan(p):
            raise ValueError(f"CycleStats.percentile: p {p} outside 0..100")
        data = self._latest(self._ring(kind), self.retained)
        data.sort()
        return _percentile_sorted(data, p)

    def snapshot(self) -> dict[str, object]:
        """The JSON contract: {"cycles", "overruns", "lateness_us": {p50, p99, p999, max},
        "compute_us": {p50, p99, max}}, plus "missed_deadlines" (skipped, not run: see the overrun
        policy). Percentiles over the retained ring, max since start."""
        lat = self._latest(self._lateness_us, self.retained)
        lat.sort()
        comp = self._latest(self._compute_us, self.retained)
        comp.sort()
        return {
            "cycles": self.cycles,
            "overruns": self.overruns,
            "missed_deadlines": self.missed_deadlines,
            "lateness_us": {
                "p50": _percentile_sorted(lat, 50.0),
                "p99": _percentile_sorted(lat, 99.0),
                "p999": _percentile_sorted(lat, 99.9),
                "max": self.lateness_max_us,
            },
            "compute_us": {
                "p50": _percentile_sorted(comp, 50.0),
                "p99": _percentile_sorted(comp, 99.0),
                "max": self.compute_max_us,
            },
        }

    def _refresh_window(self) -> None:
        # Cached between refreshes: at most one sort of `window` samples per `window_every` cycles,
        # i.e. well under a microsecond per cycle amortised for the default 1000/1000.
        if self._window_at_cycle >= 0 and self.cycles - self._window_at_cycle < self.window_every:
            return
        self._window_at_cycle = self.cycles
        lat = self._latest(self._lateness_us, self.window)
        self._window_p99_lateness_us = _percentile_top(lat, 99.0)
        comp = self._latest(self._compute_us, self.window)
        self._window_max_compute_us = max(comp) if comp else 0.0

    def window_p99_lateness_us(self) -> float:
        """p99 lateness of the last `window` cycles, refreshed at most every `window_every` cycles."""
        self._refresh_window()
        return self._window_p99_lateness_us

    def max_compute_us_window(self) -> float:
        """Worst compute time of the last `window` cycles, refreshed like `window_p99_lateness_us`."""
        self._refresh_window()
        return self._window_max_compute_us


class CyclicExecutive:
    """Runs `step(deadline_s)` every `period_s` on absolute deadlines; see the module docstring."""

    def __init__(
        self,
        period_s: float,
        clock: Clock,
        step: Callable[[float], None],
        stats: CycleStats,
    ) -> None:
        if not (period_s > 0.0 and math.isfinite(period_s)):
            raise ValueError(f"CyclicExecutive: period_s {period_s} must be a finite number > 0")
        self.period_s = period_s
        self.clock = clock
        self.step = step
        self.stats = stats
        self.t0_s = 0.0  # phase origin of the current run()
        self.next_index = 0  # k of the next deadline t0 + k * period to run

    def deadline_s(self, k: int) -> float:
        """Absolute time of deadline k of the current run."""
        return self.t0_s + k * self.period_s

    def run_once(self, now_s: float) -> None:
        """One cycle at `now_s`, for SIL lockstep drivers that own time (no sleeping here)."""
        wake_s = self.clock.now()
        self.step(now_s)
        end_s = self.clock.now()
        self.stats.record(wake_s - now_s, end_s - wake_s, end_s > now_s + self.period_s)

    def run(
        self,
        max_cycles: int | None = None,
        stop: Callable[[], bool] | None = None,
        progress: Callable[[int], None] | None = None,
    ) -> int:
        """Run cycles from t0 = clock.now() until `max_cycles` ran or `stop()` is true.

        `stop` is polled before every cycle, `progress(cycles_run)` called after every cycle.
        Returns the number of cycles run in this call (skipped deadlines are not cycles).
        """
        if max_cycles is not None and max_cycles < 0:
            raise ValueError(f"CyclicExecutive.run: max_cycles {max_cycles} must be >= 0")
        clock = self.clock
        period = self.period_s
        stats = self.stats
        step = self.step
        self.t0_s = t0 = clock.now()
        k = 0
        ran = 0
        while (max_cycles is None or ran < max_cycles) and not (stop is not None and stop()):
            deadline = t0 + k * period
            wake = clock.now()
            retries = 0
            while wake < deadline and retries < _MAX_SLEEP_RETRIES:
                clock.sleep_until(deadline)
                wake = clock.now()
                retries += 1
            step(deadline)
            end = clock.now()
            next_deadline = t0 + (k + 1) * period
            stats.record(wake - deadline, end - wake, end > next_deadline)
            ran += 1
            if end > next_deadline + period:
                # Overrun by more than one period: skip every deadline already past, re-phase.
                j = math.floor((end - t0) / period)
                # Guard the float division at the boundary: t_j <= end < t_{j+1} exactly.
                while t0 + j * period > end:
                    j -= 1
                while t0 + (j + 1) * period <= end:
                    j += 1
                stats.add_missed(j - k)
                k = j + 1
            else:
                k += 1
            self.next_index = k
            if progress is not None:
                progress(ran)
        return ran
