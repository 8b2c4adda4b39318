"""Metrics of an urban run, all from the plant's ground truth (`hil.world.urban` bookkeeping),
judged against the DARPA Urban Challenge rules the behaviour claims to follow.

- `checkpoints_reached`: how many of the MDF's checkpoints our car passed, in the MDF's order (front
  bumper or car centre within 1.5 m; the first: where we start); `checkpoints_reached_list` which,
  `checkpoints_total` of how many, `mission_complete` all of them.
- `precedence_violations`: we left a stop line while a car that had arrived at that intersection before
  us (by more than 0.5 s) still waited, and its turn had come less than 10 s before (a car that lets its
  turn pass longer is stuck: rules 5.2, seed 000 Sec. 9.3).
- `stop_line_error_m`: the largest |line - front bumper| along the lane over our stops at stop lines
  (> 0 short of the line); `stop_line_stops` how many.
- `min_separation_m`: the smallest box-to-box distance from our car to any other car.
- `speed_limit_violations`: episodes (>= 0.5 s) above the MDF's limit of the lane we are on by more than
  `urban.speed_tolerance_mps`.
- `collisions`, `ego_collisions`: contacts of every pair of cars (separating axes), ours.
- `lateral_error_rms_m`, `lateral_error_max_m` (`lateral_error_max_at_s`: when): our *rear axle*'s
  offset from the nearest RNDF lane or exit (the paths the behaviour's stubs are cut from), sampled at
  10 Hz from 2 s after engaging, while the behaviour drives a lane or an intersection: not in a lane
  change, passing, K-turn, zone, recovery or replan, nor 5 s after one (those legs leave the lane on
  purpose).
- `road_departure_m` (`road_departure_at_s`: when, `road_departure_xy`: the corner): how far a corner of
  our car ever lay outside the road
  (every lane and exit a corridor of its RNDF lane width, every zone inside its perimeter:
  `host.roadnet.road_area`), 0 when never; the simulated curbs stand `CURB_GUTTER_M` (0.3 m) outside
  it (`hil.lidar.road_marks`). Judged in every state: a K-turn that swings over the curb is exactly what
  it is for.
- `lane_departure_m` (`lane_departure_at_s`): how far a corner of our car lay outside the lanes and exits
  running its way (into the oncoming lane or over the edge), while the behaviour drives a lane or an
  intersection (the states and times of the lateral error: a K-turn, a pass, a lane change or a zone
  leave the lane on purpose); 0: never.
- `direction_changes`: how often our car changed between forward and backward (a three-point turn: 2).
- `perception` (`perfect` | `lidar`), `perception_tracks`, `perception_false_objects`,
  `perception_missed_objects`, `lane_offset_error_m`: what the host perceived, against the truth
  (`hil.perception_eval`); `lidar_revolutions`, `lidar_dropped` what the simulated sensor sent.
- `time_s`: when the last checkpoint reached was reached (the mission's time when `mission_complete`).
- `hsm_state_at_fault`: the behaviour's state at `fault_ref_s` (the first fault's instant).
- `behaviour_faults`, `reverse_held`: internal errors the behaviour caught; control cycles a backward
  leg was held (0 since the reverse gear: kept for the JSON contract).

The document also carries `state_history` ([t_s, HSM state path] at every change) and `urban` (arrivals,
collisions, violations in detail).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from bywire.hil.perception_eval import perception_metrics
from bywire.hil.scenario import Scenario
from bywire.protocol.ecu_types import EcuState

STUCK_GRACE_S = 10.0  # hil.world.urban.STUCK_GRACE_S
TIE_S = 0.5
EXCLUDED_STATES = ("KTurn", "Zone", "Pass", "LaneChange", "Recovery", "Replan", "MissionComplete", "UTurn")
REJOIN_S = 5.0
MOVING_MPS = 0.2  # a direction is driven above this speed (slower is the stop at a cusp)
ENGAGE_SETTLE_S = 2.0


def precedence_violations(arrivals: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Our departures from stop lines that took another car's turn (see the module docstring)."""
    out = []
    for ours in arrivals:
        if ours["vehicle"] != "ego" or ours["departure_s"] is None:
            continue
        t_go = ours["departure_s"]
        inter = ours["intersection"]
        same = [a for a in arrivals if a["intersection"] == inter]
        for other in same:
            if other["vehicle"] == "ego":
                continue
            if not other["arrival_s"] < ours["arrival_s"] - TIE_S:
                continue
            if other["departure_s"] is not None and other["departure_s"] <= t_go:
                continue
            if other["arrival_s"] > t_go:
                continue
            before = [
                a["departure_s"]
                for a in same
                if a["departure_s"] is not None
                and a["departure_s"] <= t_go
                and a is not other
                and a is not ours
            ]
            turn_came = max([other["arrival_s"], *before])
            if t_go - turn_came < STUCK_GRACE_S:
                out.append({"t_s": t_go, "intersection": inter, "before": other["vehicle"]})
    return out


def _excluded_mask(t: np.ndarray, states: list[list[Any]], end_s: float) -> np.ndarray:
    """True where the state (or the REJOIN_S after it) is one the lateral error is not judged in."""
    mask = np.zeros(t.shape, dtype=bool)
    if not states:
        return mask
    for k, (t0, state) in enumerate(states):
        t1 = states[k + 1][0] if k + 1 < len(states) else end_s
        if not state or any(s in state for s in EXCLUDED_STATES):
            mask |= (t >= t0) & (t < t1 + REJOIN_S)
    return mask


def evaluate_urban(
    scenario: Scenario,
    plant: dict[str, np.ndarray],
    urban: dict[str, Any],
    host: dict[str, Any],
    t0_host_s: float = 0.0,
) -> tuple[dict[str, Any], dict[str, Any]]:
    """(metrics, details) of an urban run. `host` is the host's urban summary; `t0_host_s` maps the host's
    runtime clock to scenario time (0 in SIL)."""
    spec = scenario.urban
    assert spec is not None
    m: dict[str, Any] = {}
    reached = list(urban.get("checkpoints_reached", []))
    total = list(urban.get("checkpoints", []))
    m["checkpoints_reached"] = len(reached)
    m["checkpoints_reached_list"] = reached
    m["checkpoints_total"] = len(total)
    m["mission_complete"] = bool(total) and len(reached) == len(total)
    times = urban.get("checkpoint_times_s", [])
    m["time_s"] = float(times[-1]) if times else None
    arrivals = urban.get("arrivals", [])
    violations = precedence_violations(arrivals)
    m["precedence_violations"] = len(violations)
    ours = [a for a in arrivals if a["vehicle"] == "ego"]
    errors = [float(a["front_error_m"]) for a in ours]
    m["stop_line_stops"] = len(errors)
    m["stop_line_error_m"] = round(max(abs(e) for e in errors), 3) if errors else None
    m["min_separation_m"] = urban.get("min_separation_m")
    m["road_departure_m"] = urban.get("road_departure_m")
    m["road_departure_at_s"] = urban.get("road_departure_at_s")
    m["road_departure_xy"] = urban.get("road_departure_xy")
    m["direction_changes"] = direction_changes(plant)
    m["speed_limit_violations"] = len(urban.get("speed_violations", []))
    coll = urban.get("collisions", [])
    m["collisions"] = len(coll)
    m["ego_collisions"] = sum(1 for c in coll if "ego" in (c["a"], c["b"]))
    states = [[round(float(t) - t0_host_s, 3), s] for t, s in host.get("states", [])]
    lat = urban.get("lateral", [])
    m["lateral_error_rms_m"] = None
    m["lateral_error_max_m"] = None
    if lat:
        arr = np.array([[r[0], r[1]] for r in lat], dtype=float)
        t, d = arr[:, 0], arr[:, 1]
        engaged_t = _engaged_from(plant)
        keep = np.isfinite(d) & ~_excluded_mask(t, states, float(t[-1]) if t.size else 0.0)
        if engaged_t is not None:
            keep &= t >= engaged_t + ENGAGE_SETTLE_S
        else:
            keep[:] = False
        if keep.any():
            m["lateral_error_rms_m"] = round(float(np.sqrt(np.mean(d[keep] ** 2))), 4)
            m["lateral_error_max_m"] = round(float(np.max(np.abs(d[keep]))), 4)
            m["lateral_error_max_at_s"] = round(float(t[keep][np.argmax(np.abs(d[keep]))]), 2)
            m["lateral_error_samples"] = int(keep.sum())
    own = urban.get("own_side", [])
    m["lane_departure_m"] = None
    if own:
        arr = np.array(own, dtype=float).reshape(-1, 2)
        keep = ~_excluded_mask(arr[:, 0], states, float(arr[-1, 0]))
        engaged_t = _engaged_from(plant)
        keep &= arr[:, 0] >= (engaged_t if engaged_t is not None else np.inf)
        if keep.any():
            k = int(np.argmax(np.where(keep, arr[:, 1], -1.0)))
            m["lane_departure_m"] = round(float(arr[k, 1]), 3)
            m["lane_departure_at_s"] = round(float(arr[k, 0]), 2)
    if scenario.fault_ref_s is not None:
        before = [s for t, s in states if t <= scenario.fault_ref_s]
        m["hsm_state_at_fault"] = before[-1] if before else None
    m["behaviour_faults"] = len(host.get("faults", []))
    m["reverse_held"] = int(host.get("reverse_held", 0))
    m["behaviour_checkpoints"] = list(host.get("behaviour_checkpoints", []))
    m["perception"] = spec.perception
    m.update(perception_metrics(urban, host, spec.pose.map_offset_m, t0_host_s))
    lidar = urban.get("lidar")
    if lidar:
        m["lidar_revolutions"] = lidar["revolutions"]
        m["lidar_dropped"] = lidar["dropped"]
    details = {
        "state_history": states,
        "urban": {
            "precedence_violations": violations,
            "arrivals": arrivals,
            "collisions": coll,
            "speed_violations": urban.get("speed_violations", []),
            "min_separation_to": urban.get("min_separation_to", ""),
            "behaviour_faults": host.get("faults", [])[:20],
            "checkpoint_times_s": times,
        },
    }
    return m, details


def _engaged_from(plant: dict[str, np.ndarray]) -> float | None:
    if not plant or "ecu_state" not in plant or not plant["t_s"].size:
        return None
    idx = np.flatnonzero(plant["ecu_state"] == int(EcuState.ENGAGED))
    return float(plant["t_s"][idx[0]]) if idx.size else None


def direction_changes(plant: dict[str, np.ndarray]) -> int:
    """How often our car changed between driving forward and backward (each above `MOVING_MPS`)."""
    if not plant or "speed_mps" not in plant:
        return 0
    v = plant["speed_mps"]
    signs = np.sign(v[np.abs(v) > MOVING_MPS])
    return int(np.count_nonzero(np.diff(signs))) if signs.size else 0


def final_speed_hold(plant: dict[str, np.ndarray], after_s: float) -> bool:
    """Our car stood (< 0.1 m/s) at every sample from `after_s` on."""
    t = plant["t_s"]
    sel = t >= after_s
    return bool(sel.any() and np.all(np.abs(plant["speed_mps"][sel]) < 0.1))


__all__ = ["direction_changes", "evaluate_urban", "precedence_violations"]
