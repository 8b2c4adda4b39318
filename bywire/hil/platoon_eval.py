"""Evaluation of a platoon run (seed 003): the contract metrics and the per-vehicle table, from ground truth.

Inputs: the world's per-vehicle trace (`traffic.csv`, `hil.world.traffic.TRAFFIC_COLUMNS`), the plant
trace (our car's FMU state), the host trace (which controller was in charge), the world's bookkeeping
(gaps and TTC at every plant event) and the host's V2V counters. Everything from ground truth.

Contract metrics: `string_stability`, `min_gap_m`, `min_ttc_s`, `headway_error_rms_m`,
`collisions`, `limit_violations`, `v2v_rejected` (by reason), `platoon_length_m`; and `vehicles`: per
vehicle headway error (desired minus actual distance, as seed 003 Fig. 7), time-gap and distance-gap mean
and std, minimum gap, minimum TTC, control effort (RMS acceleration, m/s^2), collisions.

Definitions:

- Desired distance: ours ``reserve_m + headway_s * v`` with the host configuration's platoon parameters;
  a simulated car's ``standstill_m + headway_s * v`` of its driver (a scripted car has none). Judged from
  `SETTLE_S` after the host engaged, while the car has a predecessor within `FOLLOW_RANGE_M`.
- `collisions`: every pair on every lane, counted once per contact (the world's bookkeeping); our own in
  `ego_collisions`. `min_gap_m` / `min_ttc_s`: ours (TTC while closing).
- `limit_violations`: episodes in which our car left the GCDC envelope: acceleration (FMU, 0.25 s moving
  mean) outside -4.5 .. 2.0 m/s^2 by more than `ACCEL_TOL_MPS2` while the host was not braking for an
  emergency (controller "emergency", see host.modules.control.platoon), or speed outside 0 .. 100 km/h by more
  than `SPEED_TOL_MPS`.
- `string_stability`: the same estimator as `bywire platoon string-stability` (host.platoon.
  string_stability: peak H1 gain of successive vehicles' accelerations over the leader's excited band),
  on the string of vehicles that share our lane, leader first, from `SETTLE_S` after engaging. Ours is
  the pair (our predecessor -> us); every pair is listed. Needs `MIN_WINDOW_S` of data.
- `platoon_length_m`: mean distance from the front of the first to the rear of the last car of our
  lane's string (cars within `FOLLOW_RANGE_M` of each other), over the judged window.
"""

from __future__ import annotations

import functools
import math
from pathlib import Path
from typing import Any

import numpy as np

from bywire.hil.scenario import Scenario
from bywire.hil.world.spec import WorldSpec
from bywire.hil.world.traffic import EGO
from bywire.host.platoon.string_stability import Platoon, Vehicle, load_platoon_csv, string_stability
from bywire.host.trace import CONTROLLERS

SETTLE_S = 5.0
MIN_WINDOW_S = 20.0
FOLLOW_RANGE_M = 100.0
ACCEL_TOL_MPS2 = 0.25
SPEED_TOL_MPS = 0.5
ACCEL_WINDOW_S = 0.25
LIMIT_GRACE_S = 1.0  # the ECU's acceleration loop settles on the limit within a second of the zone
GCDC_ACCEL_MPS2 = (-4.5, 2.0)
GCDC_SPEED_MPS = (0.0, 100.0 / 3.6)
REAL_STRINGS = (
    "openacc_astazero/OpenACC_trajectory_1.csv",
    "openacc_zalazone/medium_setting__dynamic_part8.csv",
    "openacc_zalazone/short_setting__dynamic_part10.csv",
    "openacc_zalazone/no_ACC__handling_part40.csv",
    "carma_fhwa_2018/data5.csv",
)


def _round(x: float | None, nd: int = 3) -> float | None:
    return None if x is None or not math.isfinite(x) else round(float(x), nd)


def platoon_params(scenario: Scenario) -> tuple[float, float]:
    """(reserve_m, headway_s) of the host's platoon controller, from its host configuration."""
    from bywire.hil.scenario import scenario_host_config

    try:
        cfg = scenario_host_config(scenario)
    except ValueError:
        return 8.0, 0.6
    for m in cfg.modules:
        if m.kind == "platoon_control":
            return float(m.params.get("reserve_m", 20.0)), float(m.params.get("headway_s", 0.6))
    return 8.0, 0.6


def by_vehicle(traffic: dict[str, np.ndarray]) -> dict[int, dict[str, np.ndarray]]:
    """Split the long trace into one table per vehicle id."""
    out: dict[int, dict[str, np.ndarray]] = {}
    vid = traffic["vid"].astype(int)
    for v in np.unique(vid):
        sel = vid == v
        out[int(v)] = {k: a[sel] for k, a in traffic.items()}
    return out


def desired_distance(
    spec: WorldSpec, vid: int, speed: np.ndarray, ego: tuple[float, float]
) -> np.ndarray | None:
    if vid == EGO:
        reserve, headway = ego
        return reserve + headway * speed
    d = spec.vehicles[vid - 1].driver
    if d.kind == "scripted":
        return None
    return d.standstill_m + d.headway_s * speed


def lane_string(spec: WorldSpec, tables: dict[int, dict[str, np.ndarray]], t_from: float) -> list[int]:
    """Vehicle ids on our lane at t_from, front first."""
    ego_lane = spec.ego.lane
    start: list[tuple[float, int]] = []
    for vid, tab in tables.items():
        sel = np.flatnonzero(tab["t_s"] >= t_from)
        if sel.size and int(tab["lane"][sel[0]]) == ego_lane:
            start.append((float(tab["s_m"][sel[0]]), vid))
    return [vid for _, vid in sorted(start, reverse=True)]


def _common_grid(
    tables: dict[int, dict[str, np.ndarray]], ids: list[int], t0: float, t1: float, dt: float
) -> np.ndarray:
    return np.arange(t0, t1 - 1e-9, dt)


def estimate_string(
    tables: dict[int, dict[str, np.ndarray]],
    ids: list[int],
    names: list[str],
    t0: float,
    t1: float,
    dt: float,
) -> dict[str, Any] | None:
    """The string-stability estimator on the listed vehicles (leader first), resampled on one grid."""
    if len(ids) < 2 or t1 - t0 < MIN_WINDOW_S:
        return None
    grid = _common_grid(tables, ids, t0, t1, dt)
    vehicles = []
    for vid in ids:
        tab = tables[vid]
        if tab["t_s"].size < 2 or tab["t_s"][-1] < t1 - 2 * dt:
            return None  # left the road before the end: not part of a string over the window
        vehicles.append(
            Vehicle(
                names[vid],
                np.interp(grid, tab["t_s"], tab["speed_mps"]),
                np.interp(grid, tab["t_s"], tab["accel_mps2"]),
                True,
            )
        )
    try:
        res = string_stability(Platoon("simulated", "simulated", grid, tuple(vehicles)))
    except ValueError as exc:
        return {"error": str(exc)}
    return {
        "string_stability": _round(res.string_stability),
        "band_hz": [_round(res.band_hz[0], 4), _round(res.band_hz[1], 4)],
        "pairs": [
            {
                "leader": p.leader,
                "follower": p.follower,
                "ratio": _round(p.ratio),
                "peak_hz": _round(p.peak_hz, 4),
                "coherence": _round(p.coherence_at_peak),
            }
            for p in res.pairs
        ],
    }


@functools.lru_cache(maxsize=8)
def real_strings(data_dir: str) -> dict[str, Any]:
    """The same estimator on the shared OpenACC and CARMA strings (absent files are said, not skipped
    silently)."""
    out: dict[str, Any] = {}
    for rel in REAL_STRINGS:
        path = Path(data_dir) / rel
        if not path.exists():
            out[rel] = {"error": f"not found at {path}"}
            continue
        try:
            res = string_stability(load_platoon_csv(path))
        except ValueError as exc:
            out[rel] = {"error": str(exc)}
            continue
        out[rel] = {
            "string_stability": _round(res.string_stability),
            "band_hz": [_round(res.band_hz[0], 4), _round(res.band_hz[1], 4)],
            "pairs": [
                {"leader": p.leader, "follower": p.follower, "ratio": _round(p.ratio)} for p in res.pairs
            ],
        }
    return out


def shared_platoon_dir() -> Path:
    """../shared/data/platoon beside the checkout (as the tests' `shared_data_dir`), or
    $BYWIRE_SHARED_DATA/platoon."""
    import os

    env = os.environ.get("BYWIRE_SHARED_DATA")
    if env:
        return Path(env) / "platoon"
    beside = Path(__file__).resolve().parents[2] / "shared" / "data"
    return (beside if beside.exists() else Path("/work/shared/data")) / "platoon"


def limit_violations(
    plant: dict[str, np.ndarray], host: dict[str, np.ndarray] | None, engage_s: float
) -> dict[str, Any]:
    t = plant["t_s"]
    out: dict[str, Any] = {"accel": 0, "speed": 0, "episodes": []}
    if t.size < 2:
        return out
    dt = float(np.median(np.diff(t)))
    n = max(1, round(ACCEL_WINDOW_S / dt))
    acc = np.convolve(plant["accel_mps2"], np.ones(n) / n, mode="same")
    emergency = np.zeros_like(t, dtype=bool)
    if host is not None and host["t_s"].size:
        idx = np.clip(np.searchsorted(host["t_s"], t, side="right") - 1, 0, host["t_s"].size - 1)
        emergency = host["controller"][idx].astype(int) == CONTROLLERS.index("emergency")
    judged = t >= engage_s
    bad_a = (
        judged
        & ~emergency
        & ((acc < GCDC_ACCEL_MPS2[0] - ACCEL_TOL_MPS2) | (acc > GCDC_ACCEL_MPS2[1] + ACCEL_TOL_MPS2))
    )
    v = plant["speed_mps"]
    bad_v = judged & ((v < GCDC_SPEED_MPS[0] - SPEED_TOL_MPS) | (v > GCDC_SPEED_MPS[1] + SPEED_TOL_MPS))
    for name, mask in (("accel", bad_a), ("speed", bad_v)):
        edges = np.flatnonzero(np.diff(np.concatenate(([0], mask.astype(int)))) == 1)
        out[name] = int(edges.size)
        for i in edges[:10]:
            out["episodes"].append({"kind": name, "t_s": round(float(t[i]), 2)})
    out["emergency_s"] = round(float(np.sum(emergency & judged) * dt), 2)
    return out


def evaluate_platoon(
    scenario: Scenario,
    plant: dict[str, np.ndarray],
    host: dict[str, np.ndarray] | None,
    traffic: dict[str, np.ndarray] | None,
    extra: dict[str, Any],
    include_real: bool = True,
) -> dict[str, Any]:
    """The platoon metrics of a run (see the module docstring); {} for a scenario without a world."""
    spec = scenario.world
    if spec is None or traffic is None or traffic["t_s"].size == 0:
        return {}
    world = extra.get("world", {})
    gcdc = extra.get("gcdc", {})
    names = ["ego"] + [v.name for v in spec.vehicles]
    tables = by_vehicle(traffic)
    ego_params = platoon_params(scenario)
    t_end = float(traffic["t_s"][-1])
    t_from = scenario.engage_at_s + SETTLE_S
    m: dict[str, Any] = {}
    stats = world.get("vehicles", {})
    m["collisions"] = int(world.get("collisions", 0))
    m["ego_collisions"] = int(stats.get("ego", {}).get("collisions", 0))
    m["min_gap_m"] = stats.get("ego", {}).get("min_gap_m")
    m["min_ttc_s"] = stats.get("ego", {}).get("min_ttc_s")
    m["min_gap_all_m"] = world.get("min_gap_all_m")
    m["min_ttc_all_s"] = world.get("min_ttc_all_s")
    lv = limit_violations(plant, host, scenario.engage_at_s + 1.0)
    m["limit_violations"] = lv["accel"] + lv["speed"]
    m["limit_violation_detail"] = lv
    m["v2v_rejected"] = dict(gcdc.get("v2v_rejected", {}))
    if "fuzz_sent" in world:
        m["fuzz_sent"] = world["fuzz_sent"]
    m["v2v_lost"] = int(world.get("v2v_lost", 0))
    m["headway_s"] = ego_params[1]
    for k in ("v2v_received", "v2v_accepted", "cam_sent", "iclcm_sent", "nmea_dropped", "frozen_fixes"):
        if k in gcdc:
            m[k] = gcdc[k]
    per: dict[str, Any] = {}
    for vid, tab in tables.items():
        t = tab["t_s"]
        win = (t >= t_from) & np.isfinite(tab["gap_m"]) & (tab["gap_m"] < FOLLOW_RANGE_M)
        row: dict[str, Any] = {
            "lane": int(tab["lane"][0]),
            "control_effort_rms_mps2": _round(float(np.sqrt(np.mean(tab["accel_mps2"][t >= t_from] ** 2)))
                                              if np.any(t >= t_from) else None),
        }  # fmt: skip
        row.update(stats.get(names[vid], {}))
        if np.any(win):
            gap = tab["gap_m"][win]
            v = tab["speed_mps"][win]
            row["distance_gap_mean_m"] = _round(float(np.mean(gap)))
            row["distance_gap_std_m"] = _round(float(np.std(gap)))
            moving = v > 1.0
            if np.any(moving):
                tg = gap[moving] / v[moving]
                row["time_gap_mean_s"] = _round(float(np.mean(tg)))
                row["time_gap_std_s"] = _round(float(np.std(tg)))
            desired = desired_distance(spec, vid, v, ego_params)
            if desired is not None:
                err = desired - gap
                row["headway_error_rms_m"] = _round(float(np.sqrt(np.mean(err**2))))
                row["headway_error_max_m"] = _round(float(np.max(np.abs(err))))
        per[names[vid]] = row
    m["vehicles"] = per
    m["headway_error_rms_m"] = per.get("ego", {}).get("headway_error_rms_m")
    # The string on our lane, and the platoon's length over the window.
    ids = lane_string(spec, tables, t_from)
    dt = 1.0 / spec.trace_hz
    est = estimate_string(tables, ids, names, t_from, t_end, dt)
    if est is not None and "pairs" in est:
        m["string"] = est
        ours = [p for p in est["pairs"] if p["follower"] == "ego"]
        m["string_stability"] = ours[0]["ratio"] if ours else None
        m["string_stability_all"] = est["string_stability"]
    elif est is not None:
        m["string"] = est
    lengths = []
    ego_tab = tables.get(EGO)
    if ego_tab is not None:
        for t in ego_tab["t_s"]:
            if t < t_from:
                continue
            members = [
                (float(np.interp(t, tables[v]["t_s"], tables[v]["s_m"])), v) for v in ids if v in tables
            ]
            members.sort(reverse=True)
            front = members[0][0] + 0.5 * _length(spec, members[0][1]) if members else math.nan
            last = members[0]
            for s, v in members[1:]:
                if last[0] - s > FOLLOW_RANGE_M:
                    break
                last = (s, v)
            if members:
                lengths.append(front - (last[0] - 0.5 * _length(spec, last[1])))
    m["platoon_length_m"] = _round(float(np.mean(lengths))) if lengths else None
    m["string_order"] = [names[v] for v in ids]
    if ego_tab is not None:
        after = ego_tab["t_s"] >= scenario.engage_at_s + 1.0
        if np.any(after):
            m["min_speed_after_engage_mps"] = _round(float(np.min(ego_tab["speed_mps"][after])))
        excess = speed_limit_excess(spec, ego_tab)
        if excess is not None:
            m["speed_limit_excess_mps"] = excess
    if include_real:
        data = shared_platoon_dir()
        m["real_strings"] = real_strings(str(data)) if data.is_dir() else {"error": f"not found at {data}"}
    return m


def speed_limit_excess(spec: WorldSpec, ego: dict[str, np.ndarray]) -> float | None:
    """Largest speed above the limit in force (m/s), from `LIMIT_GRACE_S` after our front bumper entered a
    speed-limit zone on our lane (None: no zone entered)."""
    zones = sorted(
        (rs.s_m, rs.limit_mps)
        for rs in spec.roadside
        if rs.kind == "speed_limit" and (rs.lane is None or rs.lane == spec.ego.lane)
    )
    front = ego["s_m"] + 0.5 * spec.ego.length_m
    worst: float | None = None
    for k, (s_zone, limit) in enumerate(zones):
        end = zones[k + 1][0] if k + 1 < len(zones) else math.inf
        inside = np.flatnonzero((front >= s_zone) & (front < end))
        if inside.size == 0:
            continue
        t_in = ego["t_s"][inside[0]] + LIMIT_GRACE_S
        judged = inside[ego["t_s"][inside] >= t_in]
        if judged.size == 0:
            continue
        excess = float(np.max(ego["speed_mps"][judged]) - limit)
        worst = excess if worst is None else max(worst, excess)
    return _round(worst)


def _length(spec: WorldSpec, vid: int) -> float:
    return spec.ego.length_m if vid == EGO else spec.vehicles[vid - 1].length_m


__all__ = ["REAL_STRINGS", "estimate_string", "evaluate_platoon", "limit_violations", "real_strings"]
