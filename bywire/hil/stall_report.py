"""Which process fell behind when a watchdog fired, and why if its stall recorder knows.

The ECU's watchdog faults (host heartbeat, request, vehicle frames, its own loop) say that a process
went silent, not which or why. The host and the plant record their stalls (`bywire.stall_recorder`:
the silent channel, the threads' states, CPU and stacks); this joins them: for each watchdog fault the
ECU raised when it stopped an engaged car, as the host saw its status (the host trace's `ecu_state` and
`ecu_faults`), the stalls of either process that were open in the `LOOKBACK_S` before it, and the
stalls of the machine's CPUs in that time (`machine_probe`: a CPU withheld from even the highest
real-time priority, by the kernel or the hypervisor).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from bywire.protocol.ecu_types import EcuState, Fault

WATCHDOG_FAULTS = (Fault.HOST_HEARTBEAT, Fault.REQUEST_INVALID, Fault.VEHICLE_TIMEOUT, Fault.LOOP_STALL)
LOOKBACK_S = 0.3  # the ECU's watchdog times (100-200 ms) plus the status' way back to the host


def watchdog_stops(host_trace: dict[str, np.ndarray], limit: int = 5) -> list[tuple[str, float]]:
    """(fault names, run time) of each stop of an engaged car in which a watchdog fault was set, as
    the host saw the ECU's status (faults before the first engagement are start-up, not stops). A
    stop is the end of ENGAGED or the start of SAFE_STOP: the host's trace samples the status at
    10 Hz, and an engagement shorter than that shows only as READY followed by SAFE_STOP."""
    state = host_trace["ecu_state"].astype(int)
    faults = host_trace["ecu_faults"].astype(int)
    mask = 0
    for f in WATCHDOG_FAULTS:
        mask |= int(f)
    engaged, safe_stop = int(EcuState.ENGAGED), int(EcuState.SAFE_STOP)
    ended = (state[:-1] == engaged) & (state[1:] != engaged)
    stopped = (state[:-1] != safe_stop) & (state[1:] == safe_stop)
    out = []
    for i in np.flatnonzero(ended | stopped) + 1:
        hit = int(faults[i]) & mask
        if hit:
            names = "|".join(str(f.name) for f in WATCHDOG_FAULTS if hit & int(f))
            out.append((names, float(host_trace["t_s"][i])))
    return out[:limit]


def brief(record: dict[str, Any], t0: float) -> dict[str, Any]:
    """A stall record in run time, with the busiest thread's stack (the suspect) kept."""
    threads = record.get("threads", {})
    suspect = record.get("busiest_thread")
    return {
        "channel": record["channel"],
        "from_s": round(record["last_beat_s"] - t0, 3),
        "gap_ms": record.get("gap_ms"),
        "watchdog_late_ms": record.get("watchdog_late_ms"),
        "process_cpu_ms": record.get("process_cpu_ms"),
        "busiest_thread": suspect,
        "suspect_stack": threads.get(suspect, {}).get("stack") if suspect else None,
        "states": {name: t.get("state") for name, t in threads.items()},
    }


def machine_stall_ms(machine: dict[str, Any], t_fault: float) -> float:
    """The longest stall of any CPU (`machine_probe`, stalls in run time) open in the lookback before
    `t_fault`: for that long not even the highest real-time priority could run there; 0.0 if none."""
    worst = 0.0
    for stall in machine.get("stalls", []):
        start = stall["from_s"]
        if start <= t_fault and start + stall["late_ms"] / 1e3 >= t_fault - LOOKBACK_S:
            worst = max(worst, float(stall["late_ms"]))
    return worst


def culprits(
    host_trace: dict[str, np.ndarray] | None,
    stalls: dict[str, dict[str, Any]],
    t0: float,
    until_s: float = float("inf"),
    machine: dict[str, Any] | None = None,
) -> list[dict[str, Any]]:
    """For each watchdog stop before `until_s` (the scenario's end, when the plant stops sending): when,
    the stalls of each process open in the lookback before it, and (given the machine probe's summary)
    `machine_stall_ms`, how long a CPU of the machine stalled in that lookback."""
    if host_trace is None:
        return []
    out = []
    for name, t_fault in watchdog_stops(host_trace):
        if t_fault >= until_s:
            continue
        found: dict[str, list[dict[str, Any]]] = {}
        for process, summary in stalls.items():
            for rec in summary.get("stalls", []):
                start = rec["last_beat_s"] - t0
                end = start + (rec["gap_ms"] or rec["seen_after_ms"]) / 1e3
                if start <= t_fault and end >= t_fault - LOOKBACK_S:
                    found.setdefault(process, []).append(brief(rec, t0))
        fell_behind = sorted(found) or ["none recorded (the ECU's own view: see its loop statistics)"]
        stop: dict[str, Any] = {"fault": name, "at_s": round(t_fault, 3), "fell_behind": fell_behind}
        stop["stalls"] = found
        if machine is not None:
            stop["machine_stall_ms"] = machine_stall_ms(machine, t_fault)
        out.append(stop)
    return out
