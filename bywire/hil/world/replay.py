"""`bywire hil run NAME --leader-profile CSV`: a real leader's speed replayed by the world's `replay` car.

The CSV is an OpenACC (ZalaZone, AstaZero) or CARMA recording, its layout detected from the header by
`host.platoon.string_stability.load_platoon_csv` (which also cuts gaps and reorders rows, see its
notes). The first vehicle's speed becomes a piecewise-linear profile from t = 0, resampled at
`PROFILE_HZ` (the recordings are 10 Hz; the string-stability band ends at 1 Hz), clipped to 0 .. 70 m/s.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bywire.hil.scenario import Scenario, ScenarioError
from bywire.host.platoon.string_stability import PlatoonCsvError, load_platoon_csv

PROFILE_HZ = 10.0


def leader_profile_from_csv(scenario: Scenario, path: Path) -> tuple[tuple[float, float], ...]:
    """The first vehicle's speed of a platoon CSV as a profile; refuses a scenario that cannot use it."""
    world = scenario.world
    if world is None or not any(v.driver.kind == "scripted" and v.driver.replay for v in world.vehicles):
        raise ScenarioError(
            scenario.source,
            "world.vehicles",
            "--leader-profile needs a world vehicle with driver {kind: scripted, replay: true}",
        )
    try:
        platoon = load_platoon_csv(path)
    except (PlatoonCsvError, OSError) as exc:
        raise ScenarioError(str(path), "", f"cannot read the leader profile: {exc}") from exc
    t = platoon.time_s - platoon.time_s[0]
    v = platoon.vehicles[0].speed_mps
    grid = np.arange(0.0, t[-1] + 1e-9, 1.0 / PROFILE_HZ)
    speed = np.clip(np.interp(grid, t, v), 0.0, 70.0)
    return tuple((float(a), float(b)) for a, b in zip(grid, speed, strict=True))


__all__ = ["leader_profile_from_csv"]
