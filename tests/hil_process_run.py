"""Run a scenario document in the three-process HIL exactly as a user does (`python -m bywire hil run
FILE --mode hil --json --report`), and return its result document and report folder.

A run the machine spoiled is run again, at most `RERUNS` times, and said so: on these shared VMs (a kernel
without preemption, two cores) the machine itself sometimes stalls for tens of ms, every process of the
run at once, the ECU at SCHED_FIFO 80 too, and the ECU's watchdogs then rightly stop the car. Such a run
proves nothing about our code. "Spoiled" is judged on independent evidence, never on the failure itself:
every watchdog stop of the run coincides with a stall of the machine probe (`bywire.hil.machine_probe`,
SCHED_FIFO 99, above every process of ours) of `MACHINE_STALL_MS` or more. A failure without a watchdog
stop, or with one the machine does not explain, fails at once.
"""

from __future__ import annotations

import json
import subprocess
import sys
import warnings
from pathlib import Path
from typing import Any

import yaml

# Half the ECU's own loop-stall bound (20 ms): for that long not even the highest priority could run.
MACHINE_STALL_MS = 10.0
RERUNS = 2


class MachineStallRerun(UserWarning):
    """A HIL run was repeated because the machine stalled under it (shown in pytest's summary)."""


def spoiled_by_the_machine(result: dict[str, Any]) -> bool:
    """True when the run stopped on watchdogs only, each at a stall of the machine itself."""
    stops = result.get("watchdog_culprits") or []
    return bool(stops) and all((s.get("machine_stall_ms") or 0.0) >= MACHINE_STALL_MS for s in stops)


def hil_command(
    args: list[str], report: Path, timeout_s: float, label: str
) -> tuple[subprocess.CompletedProcess[str], dict[str, Any], Path]:
    """`python -m bywire hil run ARGS --report REPORT --json REPORT/result.json`, run again into
    REPORT-rerunN when the machine spoiled it: the last attempt's process, result document and report."""
    for attempt in range(RERUNS + 1):
        run_report = report if attempt == 0 else report.with_name(f"{report.name}-rerun{attempt}")
        out = run_report / "result.json"
        proc = subprocess.run(
            [
                sys.executable,
                "-m",
                "bywire",
                "hil",
                "run",
                *args,
                "--report",
                str(run_report),
                "--json",
                str(out),
            ],
            capture_output=True,
            text=True,
            timeout=timeout_s,
        )
        result: dict[str, Any] = json.loads(out.read_text()) if out.exists() else {}
        if proc.returncode == 0 or attempt == RERUNS or not spoiled_by_the_machine(result):
            return proc, result, run_report
        stalls = [s.get("machine_stall_ms") for s in result.get("watchdog_culprits", [])]
        warnings.warn(
            f"{label}: the machine stalled under the run ({stalls} ms at its watchdog stops); run again",
            MachineStallRerun,
            stacklevel=2,
        )
    raise AssertionError("unreachable")


def run_in_hil(doc: dict[str, Any], tmp_path: Path, timeout_s: float = 400.0) -> tuple[dict[str, Any], Path]:
    scenario = tmp_path / f"{doc['name']}.yaml"
    scenario.write_text(yaml.safe_dump(doc, sort_keys=False))
    args = [str(scenario), "--mode", "hil", "--quiet"]
    proc, result, report = hil_command(args, tmp_path / "report", timeout_s, doc["name"])
    assert proc.returncode == 0, proc.stdout + proc.stderr + diagnosis(result, report)
    m = result["metrics"]
    assert all(code == 0 for name, code in m["exit_codes"].items() if not name.startswith("bus")), diagnosis(
        result, report
    )
    return result, report


def diagnosis(result: dict[str, Any], report: Path, log_lines: int = 12) -> str:
    """What a failed run did, for the test's message: CI keeps only what the test prints, not the report
    folder, so a failure must carry its own evidence (states, faults, exit codes, the logs' last lines)."""
    m = result.get("metrics", {})
    keys = (
        "final_state", "exit_codes", "engaged_s", "final_speed_mps", "checkpoints_reached_list",
        "behaviour_faults", "heartbeat_gap_at_ecu_max_ms", "host_link_gap_max_ms", "supervisor_events",
    )  # fmt: skip
    parts = ["\n--- diagnosis ---", json.dumps({k: m.get(k) for k in keys}, default=str)]
    parts.append("checks failed: " + json.dumps([c for c in result.get("checks", []) if not c.get("passed")]))
    parts.append("state history: " + json.dumps(result.get("state_history", [])[-12:]))
    ecu = m.get("ecu_health") or {}
    parts.append("ECU faults: " + json.dumps(ecu.get("faults", ecu), default=str)[:1500])
    parts.append("watchdog culprits: " + json.dumps(result.get("watchdog_culprits"), default=str)[:1500])
    machine = m.get("machine") or {}
    parts.append(f"machine probe: late {machine.get('late_ms')} ms, {len(machine.get('stalls', []))} stalls")
    behaviour = (result.get("urban") or {}).get("behaviour_faults")
    if behaviour:
        parts.append("behaviour faults: " + json.dumps(behaviour, default=str)[:1500])
    for name in ("host.log", "ecu.log", "plant.log"):
        path = report / name
        if path.exists():
            tail = path.read_text(encoding="utf-8", errors="replace").splitlines()[-log_lines:]
            parts.append(f"--- {name} (last {len(tail)} lines) ---\n" + "\n".join(tail))
    return "\n".join(parts)
