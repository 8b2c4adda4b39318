"""What the host perceived, judged against the simulator's truth (`hil.world.urban` bookkeeping).

- `perception_tracks`: distinct object ids the behaviour was given over the run.
- `perception_false_objects`, `perception_missed_objects`: per object list the behaviour read (sampled
  every 0.5 s of their stamps, `host.modules.urban_log`), the objects with no car of the world within
  `MATCH_M` of them, and the world's cars within `RANGE_M` of our car that no object matched; both as
  the mean per list (`perception_lists`: how many lists). A car hidden behind another counts as missed:
  the metric says what the behaviour knew, not what the sensor could have seen.
- `lane_offset_error_m`: RMS over the run of the map offset the controller applied minus the map's true
  lateral offset from the road (the scenario's `urban.pose.map_offset_m` across our heading); with a
  map that is right and no offset applied, 0.

Positions the host reports are in its map's frame: the world's plus the map offset.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

MATCH_M = 2.5  # a car's centre seen within half a car length of where it is
RANGE_M = 30.0  # the cars the behaviour must know of: the intersection, the lead, the oncoming lane


def _truth_at(tracks: dict[str, list[list[float]]], t_s: float) -> dict[str, tuple[float, float]]:
    """Every vehicle's sampled position nearest `t_s` (within one sample)."""
    out: dict[str, tuple[float, float]] = {}
    for name, rows in tracks.items():
        if not rows:
            continue
        times = np.array([r[0] for r in rows])
        i = int(np.argmin(np.abs(times - t_s)))
        if abs(times[i] - t_s) <= 0.5:
            out[name] = (float(rows[i][1]), float(rows[i][2]))
    return out


def perception_metrics(
    urban: dict[str, Any], host: dict[str, Any], map_offset_m: tuple[float, float], t0_host_s: float = 0.0
) -> dict[str, Any]:
    tracks = urban.get("tracks", {})
    dx, dy = map_offset_m
    ids: set[str] = set()
    false_n: list[int] = []
    missed_n: list[int] = []
    for t_s, objs in host.get("perceived", []):
        truth = _truth_at(tracks, float(t_s))
        ego = truth.pop("ego", None)
        if ego is None:
            continue
        cars = np.array([v for v in truth.values()], float).reshape(-1, 2)
        seen = np.array([[o[1] - dx, o[2] - dy] for o in objs], float).reshape(-1, 2)
        ids.update(str(o[0]) for o in objs)
        matched_truth: set[int] = set()
        matched_seen: set[int] = set()
        if len(cars) and len(seen):
            d = np.hypot(seen[:, None, 0] - cars[None, :, 0], seen[:, None, 1] - cars[None, :, 1])
            rows, cols = linear_sum_assignment(np.where(d <= MATCH_M, d, 1e6))
            for r, c in zip(rows, cols, strict=True):
                if d[r, c] <= MATCH_M:
                    matched_seen.add(int(r))
                    matched_truth.add(int(c))
        false_n.append(len(seen) - len(matched_seen))
        near_idx = np.flatnonzero(np.hypot(cars[:, 0] - ego[0], cars[:, 1] - ego[1]) <= RANGE_M)
        missed_n.append(sum(1 for i in near_idx if int(i) not in matched_truth))
    m: dict[str, Any] = {
        "perception_lists": len(false_n),
        "perception_tracks": len(ids),
        "perception_false_objects": round(float(np.mean(false_n)), 3) if false_n else None,
        "perception_missed_objects": round(float(np.mean(missed_n)), 3) if missed_n else None,
    }
    m["lane_offset_error_m"] = _lane_offset_error(urban, host, map_offset_m, t0_host_s)
    return m


def _lane_offset_error(
    urban: dict[str, Any], host: dict[str, Any], map_offset_m: tuple[float, float], t0_host_s: float
) -> float | None:
    """RMS of (applied - true) lateral offset while the car drives (see the module docstring)."""
    ego = urban.get("tracks", {}).get("ego", [])
    samples = host.get("lane_offsets", [])
    if len(ego) < 2 or not samples:
        return None
    e = np.array(ego, float)
    heading = np.arctan2(np.gradient(e[:, 2]), np.gradient(e[:, 1]))
    moving = np.hypot(np.gradient(e[:, 1]), np.gradient(e[:, 2])) > 0.2  # 0.4 m/s: a heading to speak of
    dx, dy = map_offset_m
    errors = []
    for t_rt, applied, _valid in samples:
        t = float(t_rt) - t0_host_s
        i = int(np.argmin(np.abs(e[:, 0] - t)))
        if abs(e[i, 0] - t) > 0.5 or not moving[i]:
            continue
        h = heading[i]
        # the road lies `true_lateral` to the left of the map's lane: the offset to apply
        true_lateral = -dx * math.sin(h) + dy * math.cos(h)
        errors.append(float(applied) - true_lateral)
    return round(float(np.sqrt(np.mean(np.square(errors)))), 3) if errors else None


__all__ = ["MATCH_M", "RANGE_M", "perception_metrics"]
