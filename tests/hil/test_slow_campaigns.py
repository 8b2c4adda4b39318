"""Long campaigns, outside the default suite (`pytest -m slow`): CI runs the bounded versions."""

from __future__ import annotations

import pytest

from bywire.hil.evaluate import evaluate
from bywire.hil.scenario import parse_scenario
from bywire.hil.sil import run_sil

pytestmark = pytest.mark.slow


def test_pause_holds_the_car_for_an_hour_on_a_ten_percent_slope() -> None:
    """DARPA rules 3.4.2: a paused vehicle stays put, brakes holding it, "possibly for hours"."""
    hold_s = 3600.0
    scenario = parse_scenario(
        {
            "name": "estop_pause_hour",
            "duration_s": hold_s + 20.0,
            "vehicle": {"v0_mps": 12.0},
            "plant": {"grade_pct": [[0.0, 0.0], [6.0, 0.0], [7.0, 10.0]]},
            "host": {"mode": "script", "engage_at_s": 0.3, "accel_profile": [[0.0, 0.0]]},
            "faults": [
                {"at_s": 3.0, "kind": "estop", "mode": "PAUSE"},
                {"at_s": hold_s + 10.0, "kind": "estop", "mode": "RUN"},
            ],
            "hold_until_s": hold_s + 10.0,
            "checks": [
                {"metric": "standstill_held", "equals": True},
                {"metric": "final_state", "equals": "ENGAGED"},
            ],
        },
        "<test>",
    )
    result = run_sil(scenario)
    doc = evaluate(scenario, result.plant, result.host, result.extra)
    assert doc["verdict"] == "pass", doc["checks"]
    assert doc["metrics"]["standstill_duration_s"] >= hold_s
