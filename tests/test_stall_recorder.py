"""The stall recorder names the thread and the call in flight when a process misses its rhythm."""

from __future__ import annotations

import math
import threading
import time

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from bywire.hil.stall_report import culprits, watchdog_stops
from bywire.protocol.ecu_types import EcuState, Fault
from bywire.rhythm import GapHistogram
from bywire.stall_recorder import StallRecorder


def spin_in_a_module(seconds: float) -> None:
    """A module's release that computes for far longer than the rhythm allows (pure Python)."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        pass


def test_a_silent_channel_is_recorded_with_the_thread_and_the_call_that_held_it() -> None:
    rec = StallRecorder("host", {"scheduler": 0.02}, poll_s=0.002, sample_s=0.01)
    done = threading.Event()

    def scheduler() -> None:
        for _ in range(50):  # a healthy rhythm first
            rec.beat("scheduler")
            time.sleep(0.001)
        spin_in_a_module(0.25)  # then a release that holds the loop
        for _ in range(20):
            rec.beat("scheduler")
            time.sleep(0.001)
        done.set()

    worker = threading.Thread(target=scheduler, name="scheduler-thread")
    rec.start()
    worker.start()
    worker.join(30)
    rec.close()
    assert done.is_set()
    stalls = rec.summary()["stalls"]
    assert stalls, "the 250 ms silence was not recorded"
    first = stalls[0]
    assert first["channel"] == "scheduler"
    assert first["gap_ms"] is not None and first["gap_ms"] >= 200  # closed by the next beat
    spinner = first["threads"]["scheduler-thread"]
    assert any("spin_in_a_module" in frame for frame in spinner["stack"]), spinner
    assert spinner["state"] in ("R", "S")  # running, or waiting for the GIL the watchdog held
    assert first["busiest_thread"] == "scheduler-thread"
    # One record per stall, not one per look of the watchdog.
    assert len([s for s in stalls if s["channel"] == "scheduler"]) == 1


def test_a_healthy_rhythm_records_nothing() -> None:
    rec = StallRecorder("plant", {"step": 0.05}, poll_s=0.002)
    rec.start()
    for _ in range(100):
        rec.beat("step")
        time.sleep(0.001)
    rec.close()
    assert rec.summary()["stalls"] == []


def test_a_watchdog_fault_is_joined_with_the_stalls_open_before_it() -> None:
    t = np.arange(0.0, 2.0, 0.02)
    faults = np.zeros_like(t)
    faults[t < 0.1] = int(Fault.HOST_HEARTBEAT)  # start-up, before the host's first heartbeat: no stop
    faults[t >= 1.2] = int(Fault.HOST_HEARTBEAT)
    state = np.full_like(t, int(EcuState.READY))
    state[(t >= 0.5) & (t < 1.2)] = int(EcuState.ENGAGED)
    state[t >= 1.2] = int(EcuState.SAFE_STOP)
    host_trace = {"t_s": t, "ecu_faults": faults, "ecu_state": state}
    assert watchdog_stops(host_trace) == [("HOST_HEARTBEAT", t[t >= 1.2][0])]
    t0 = 100.0
    host = {
        "stalls": [
            {  # open from 1.05 s for 150 ms: before the fault, inside the lookback
                "channel": "ecu_link",
                "last_beat_s": t0 + 1.05,
                "gap_ms": 150.0,
                "seen_after_ms": 40.0,
                "watchdog_late_ms": 90.0,
                "process_cpu_ms": 3.0,
                "busiest_thread": "module-world_model#1",
                "threads": {"module-world_model#1": {"state": "R", "stack": ["qp.py:10 solve"]}},
            },
            {"channel": "scheduler", "last_beat_s": t0 + 0.2, "gap_ms": 12.0, "seen_after_ms": 11.0},
        ]
    }
    plant = {"stalls": [{"channel": "step", "last_beat_s": t0 + 1.9, "gap_ms": 6.0, "seen_after_ms": 5.5}]}
    (c,) = culprits(host_trace, {"host": host, "plant": plant}, t0)
    assert c["fault"] == "HOST_HEARTBEAT" and c["fell_behind"] == ["host"]
    (r,) = c["stalls"]["host"]
    assert r["busiest_thread"] == "module-world_model#1" and r["suspect_stack"] == ["qp.py:10 solve"]
    assert culprits(None, {"host": host}, t0) == []


def test_a_stop_whose_engagement_the_trace_never_saw_is_still_a_stop() -> None:
    """The host samples the ECU's status at 10 Hz: READY then SAFE_STOP is an engagement cut short."""
    t = np.arange(0.0, 1.0, 0.1)
    state = np.full_like(t, int(EcuState.READY))
    state[t >= 0.45] = int(EcuState.SAFE_STOP)
    faults = np.where(t >= 0.45, int(Fault.HOST_HEARTBEAT | Fault.REQUEST_INVALID), 0)
    stops = watchdog_stops({"t_s": t, "ecu_faults": faults, "ecu_state": state})
    assert stops == [("HOST_HEARTBEAT|REQUEST_INVALID", t[t >= 0.45][0])]


def test_the_rhythm_of_a_channel_is_its_gap_distribution() -> None:
    rec = StallRecorder("host", {"scheduler": 0.02})
    for k in range(1000):  # a 1 ms rhythm on a simulated clock, with one 30 ms hole
        rec.beat("scheduler", k * 1e-3 + (0.029 if k >= 500 else 0.0))
    rhythm = rec.summary()["rhythm_ms"]["scheduler"]
    assert rhythm["count"] == 999 and rhythm["max"] == pytest.approx(30.0)
    assert rhythm["p50"] == pytest.approx(1.0, abs=0.11) and rhythm["p99"] == pytest.approx(1.0, abs=0.11)
    assert rhythm["max_at_s"] == pytest.approx(0.529)
    merged = GapHistogram.from_json(rhythm)
    merged.merge(GapHistogram.from_json(rhythm))
    assert merged.summary() == {**{k: rhythm[k] for k in ("p50", "p99", "p999", "max")}, "count": 1998}


@given(st.lists(st.floats(0.0, 2.0), min_size=1, max_size=300), st.floats(0.0, 1.0))
def test_a_gap_quantile_is_within_one_bin_of_the_exact_one(gaps_s: list[float], q: float) -> None:
    h = GapHistogram()
    for g in gaps_s:
        h.add(g)
    ordered = sorted(gaps_s)
    exact_ms = ordered[max(1, math.ceil(q * len(ordered) - 1e-9)) - 1] * 1e3
    got_ms = h.quantile_ms(q)
    assert got_ms <= max(ordered) * 1e3 + 1e-3  # reported to the microsecond
    if exact_ms < 1000.0:  # beyond the span only the maximum is exact
        assert exact_ms - 1e-3 <= got_ms <= exact_ms + 0.1 + 1e-3
