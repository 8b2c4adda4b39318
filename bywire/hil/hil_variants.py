"""Shipped scenarios bounded for a three-process HIL run: the same document, cut to a length a test
suite or a load benchmark can repeat, with the checks that need the whole scenario left to SIL.

The GCDC heat (seed 003) lasts 300 s in SIL; in HIL its first `duration_s` are driven, with our own
GPS receiver's bridge outage moved inside them, and the string-stability estimate (which needs the
whole heat) and the speed-limit zone (at ~280 s) judged in SIL only. The urban four-way stop with one
car waiting (seed 000 section 8) is short enough to run whole.
"""

from __future__ import annotations

from typing import Any

import yaml

from bywire.hil.scenario import builtin_scenarios

GCDC_HIL_S = 60.0
GCDC_SIL_ONLY_CHECKS = ("string_stability", "speed_limit_excess_mps")


def gcdc_heat_hil(duration_s: float = GCDC_HIL_S, name: str = "gcdc_heat_hil") -> dict[str, Any]:
    doc: dict[str, Any] = yaml.safe_load(builtin_scenarios()["gcdc_heat"].read_text(encoding="utf-8"))
    doc["name"] = name
    doc["duration_s"] = float(duration_s)
    outages = doc["world"]["gps"]["outages"]
    bridge = next(o for o in outages if o["kind"] == "frozen")
    bridge["at_s"] = min(float(bridge["at_s"]), max(0.0, duration_s - 20.0))
    doc["checks"] = [c for c in doc["checks"] if c["metric"] not in GCDC_SIL_ONLY_CHECKS]
    return doc


def four_way_stop_hil(name: str = "four_way_stop_1_hil") -> dict[str, Any]:
    path = builtin_scenarios()["four_way_stop_1"]
    doc: dict[str, Any] = yaml.safe_load(path.read_text(encoding="utf-8"))
    doc["name"] = name
    for key in ("rndf", "mdf"):  # a copy lives elsewhere: the shipped network by absolute path
        doc["urban"][key] = str(path.parent / doc["urban"][key])
    return doc
