"""Run a scenario document in the three-process HIL exactly as a user does (`python -m bywire hil run
FILE --mode hil --json --report`), and return its result document and report folder."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import yaml


def run_in_hil(doc: dict[str, Any], tmp_path: Path, timeout_s: float = 400.0) -> tuple[dict[str, Any], Path]:
    scenario = tmp_path / f"{doc['name']}.yaml"
    scenario.write_text(yaml.safe_dump(doc, sort_keys=False))
    report = tmp_path / "report"
    out = report / "result.json"
    proc = subprocess.run(
        [sys.executable, "-m", "bywire", "hil", "run", str(scenario), "--mode", "hil", "--json", str(out),
         "--report", str(report), "--quiet"],
        capture_output=True,
        text=True,
        timeout=timeout_s,
    )  # fmt: skip
    result: dict[str, Any] = json.loads(out.read_text()) if out.exists() else {}
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
    behaviour = (result.get("urban") or {}).get("behaviour_faults")
    if behaviour:
        parts.append("behaviour faults: " + json.dumps(behaviour, default=str)[:1500])
    for name in ("host.log", "ecu.log", "plant.log"):
        path = report / name
        if path.exists():
            tail = path.read_text(encoding="utf-8", errors="replace").splitlines()[-log_lines:]
            parts.append(f"--- {name} (last {len(tail)} lines) ---\n" + "\n".join(tail))
    return "\n".join(parts)
