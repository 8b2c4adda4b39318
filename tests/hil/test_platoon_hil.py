"""The 10-vehicle GCDC heat in the three-process HIL (cooperative driving, seed 003), through `bywire hil run
--mode hil` as a user runs it: bus servers, ECU, plant (with the world, its V2V broadcasts on loopback UDP and
the GPS receiver on a pty) and host (the `gcdc` configuration) as separate processes. One bounded run: the
heat's first 60 s, with our own receiver's bridge moved inside them; behaviour is judged, never timing.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from hil_process_run import run_in_hil

from bywire.hil.hil_variants import gcdc_heat_hil

pytestmark = pytest.mark.hil


def test_gcdc_heat_in_three_processes(tmp_path: Path) -> None:
    doc = gcdc_heat_hil()  # the heat's first 60 s, its bridge outage moved inside them
    result, report = run_in_hil(doc, tmp_path)
    m = result["metrics"]
    assert m["collisions"] == 0 and m["limit_violations"] == 0 and m["final_state"] == "ENGAGED"
    # Every link carried its traffic: V2V both ways (UDP broadcast), the GPS line (pty), and the flood.
    assert m["v2v_accepted"] > 1000 and m["cam_sent"] > 400 and m["fuzz_sent"] >= 2900
    assert m["v2v_rejected"].get("own_station", 0) > 400  # our own CAMs come back on the broadcast
    assert m["frozen_fixes"] >= 1 and m["nmea_dropped"] == 0
    assert len(m["vehicles"]) == 10
    for suffix in ("path_time", "headway", "string_stability"):
        assert (report / f"gcdc_heat_hil_{suffix}.png").stat().st_size > 10_000
    assert (report / "traffic.csv").stat().st_size > 100_000
