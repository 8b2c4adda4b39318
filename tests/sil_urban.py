"""An urban scenario run in SIL and judged, for the tests of tests/hil/test_urban_*.py."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from bywire.hil.evaluate import evaluate
from bywire.hil.scenario import Scenario
from bywire.hil.sil import run_sil


def run(scenario: Scenario, run_dir: Path | None = None, record: Path | None = None) -> dict[str, Any]:
    """The scenario's judged JSON document, with the run's extras under `_extra`."""
    result = run_sil(scenario, run_dir, record=record)
    doc = evaluate(scenario, result.plant, result.host, result.extra, "sil", result.traffic)
    doc["_extra"] = result.extra
    return doc


def failed(doc: dict[str, Any]) -> str:
    """The failed checks and the HSM's states, for an assertion's message."""
    return json.dumps([c for c in doc["checks"] if not c["passed"]], indent=1) + json.dumps(
        doc.get("state_history", [])
    )
