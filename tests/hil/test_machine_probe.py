"""The machine probe (`bywire.hil.machine_probe`) and the HIL tests' rule for a run the machine spoiled
(tests/hil_process_run.py): the probe's bookkeeping, the real process, and how a watchdog stop is joined
with the machine's stalls."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from hil_process_run import MACHINE_STALL_MS, spoiled_by_the_machine

from bywire.hil.machine_probe import MachineProbe, merge_summaries, steal_s
from bywire.hil.stall_report import culprits, machine_stall_ms
from bywire.protocol.ecu_types import EcuState, Fault

STAT = "cpu  100 0 50 9000 10 0 3 {steal} 0 0\ncpu0 50 0 25 4500 5 0 1 1 0 0\nintr 1\n"


def test_steal_is_the_eighth_value_of_the_aggregate_cpu_line_in_clock_ticks() -> None:
    import os

    ticks = os.sysconf("SC_CLK_TCK")
    assert steal_s(STAT.format(steal=250)) == pytest.approx(250 / ticks)
    assert steal_s("cpu  1 2 3 4\n") is None  # an old kernel without the column
    assert steal_s("intr 1\n") is None


def test_only_a_wake_late_by_the_threshold_is_a_stall_and_it_carries_the_steal_meanwhile() -> None:
    probe = MachineProbe(period_s=0.002, stall_ms=5.0)
    steal = iter([1.000, 1.012])
    probe.start(0.990)
    for k in range(100):  # a healthy rhythm, 50 us late
        probe.woke(k * 0.002, k * 0.002 + 50e-6, read_steal=lambda: pytest.fail("read only after a stall"))
    probe.woke(0.200, 0.2049)  # 4.9 ms: late, not a stall
    probe.woke(0.206, 0.236, read_steal=lambda: next(steal))  # 30 ms
    probe.woke(0.300, 0.308, read_steal=lambda: next(steal))  # 8 ms
    doc = probe.summary("SCHED_FIFO 99: yes", 1.020)
    assert [s["late_ms"] for s in doc["stalls"]] == [30.0, 8.0]
    assert [s["from_s"] for s in doc["stalls"]] == [0.206, 0.300]
    assert [s["steal_ms_since_last"] for s in doc["stalls"]] == [10.0, 12.0]
    assert doc["steal_ms"] == pytest.approx(30.0)
    assert doc["wakes"] == 103 and doc["late_ms"]["max"] == pytest.approx(30.0)
    assert doc["late_ms"]["p50"] <= 0.1 and doc["realtime"] == "SCHED_FIFO 99: yes"
    json.dumps(doc)  # what the runner reads back


def test_the_probe_process_records_a_stall_it_could_not_run_through(tmp_path: Path) -> None:
    """SIGSTOP holds the probe as a stalled machine would: the wake due meanwhile comes at SIGCONT."""
    out = tmp_path / "probe.json"
    proc = subprocess.Popen(
        [sys.executable, "-m", "bywire.hil.machine_probe", "--cpu", "0", "--out", str(out)],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "ready"
        time.sleep(0.2)
        proc.send_signal(signal.SIGSTOP)
        time.sleep(0.06)
        proc.send_signal(signal.SIGCONT)
        time.sleep(0.2)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(20) == 0
    finally:
        proc.kill()
    doc = json.loads(out.read_text())
    assert doc["wakes"] > 10 and doc["cpu"] == 0
    assert "SCHED_FIFO 99: yes" in doc["realtime"] and "CPU affinity 0: yes" in doc["realtime"]
    assert max(s["late_ms"] for s in doc["stalls"]) >= 40.0  # at least the 60 ms held, less a period


def test_the_cpus_probes_merge_into_one_summary_in_run_time() -> None:
    docs = []
    for cpu, late_s in ((0, 0.030), (1, 0.012)):
        probe = MachineProbe()
        probe.start(None)
        probe.woke(100.0, 100.0 + 1e-4)
        probe.woke(100.5 - cpu * 0.4, 100.5 - cpu * 0.4 + late_s, read_steal=lambda: None)
        docs.append(probe.summary(f"SCHED_FIFO 99: yes; CPU affinity {cpu}: yes", None, cpu))
    doc = merge_summaries(docs, t0=100.0)
    assert [(s["cpu"], s["from_s"], s["late_ms"]) for s in doc["stalls"]] == [(1, 0.1, 12.0), (0, 0.5, 30.0)]
    # A probe refused SCHED_FIFO waited behind ordinary processes: its late wakes are not the machine's.
    docs[1]["fifo"] = False
    assert [s["cpu"] for s in merge_summaries(docs, t0=100.0)["stalls"]] == [0]
    assert doc["wakes"] == 4 and doc["late_ms"]["max"] == pytest.approx(30.0) and doc["steal_ms"] is None
    assert doc["cpus"]["1"]["late_ms"]["max"] == pytest.approx(12.0) and doc["cpus"]["0"]["wakes"] == 2
    json.dumps(doc)


def _one_stop_at_1_2_s() -> tuple[dict[str, np.ndarray], float]:
    t = np.arange(0.0, 2.0, 0.1)
    state = np.full_like(t, int(EcuState.READY))
    state[(t >= 0.5) & (t < 1.2)] = int(EcuState.ENGAGED)
    state[t >= 1.2] = int(EcuState.SAFE_STOP)
    faults = np.where(t >= 1.2, int(Fault.LOOP_STALL), 0)
    return {"t_s": t, "ecu_faults": faults, "ecu_state": state}, float(t[t >= 1.2][0])


def test_a_watchdog_stop_is_joined_with_the_machine_stalls_of_its_lookback() -> None:
    trace, t_stop = _one_stop_at_1_2_s()
    machine = {
        "stalls": [
            {"from_s": 0.3, "late_ms": 80.0},  # long before: not this stop's
            {"from_s": t_stop - 0.1, "late_ms": 25.0},
            {"from_s": t_stop - 0.05, "late_ms": 12.0},
            {"from_s": t_stop + 0.01, "late_ms": 90.0},  # after the stop was seen: not its cause
        ]
    }
    assert machine_stall_ms(machine, t_stop) == 25.0
    (stop,) = culprits(trace, {}, 0.0, machine=machine)
    assert stop["fault"] == "LOOP_STALL" and stop["machine_stall_ms"] == 25.0
    (stop,) = culprits(trace, {}, 0.0, machine={"stalls": []})
    assert stop["machine_stall_ms"] == 0.0
    (stop,) = culprits(trace, {}, 0.0)  # no probe ran: no claim either way
    assert "machine_stall_ms" not in stop


def test_a_run_is_spoiled_by_the_machine_only_when_it_explains_every_watchdog_stop() -> None:
    big, small = MACHINE_STALL_MS + 5.0, MACHINE_STALL_MS - 5.0
    assert spoiled_by_the_machine({"watchdog_culprits": [{"machine_stall_ms": big}]})
    assert spoiled_by_the_machine(
        {"watchdog_culprits": [{"machine_stall_ms": big}, {"machine_stall_ms": big}]}
    )
    assert not spoiled_by_the_machine(
        {"watchdog_culprits": [{"machine_stall_ms": big}, {"machine_stall_ms": small}]}
    )
    assert not spoiled_by_the_machine({"watchdog_culprits": [{"machine_stall_ms": None}]})
    assert not spoiled_by_the_machine({"watchdog_culprits": [{"fault": "LOOP_STALL"}]})  # no probe
    assert not spoiled_by_the_machine({"watchdog_culprits": []})  # a failure without a watchdog stop
    assert not spoiled_by_the_machine({})
