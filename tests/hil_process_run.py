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
    assert proc.returncode == 0, proc.stdout + proc.stderr + json.dumps(result.get("checks"), indent=1)
    m = result["metrics"]
    assert all(code == 0 for name, code in m["exit_codes"].items() if not name.startswith("bus")), m[
        "exit_codes"
    ]
    return result, report
