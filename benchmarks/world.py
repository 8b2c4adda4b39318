"""`bywire bench world`: the world model's per-cycle operations, timed, each beside a baseline in one run.

Seed 003 section IV: map matching on a kd-tree and vehicle prediction.

Rows (median / p99 / max over many calls; all in one process so that machine load hits both sides alike):

- lane-map match of one position on a recorded two-lane map of `MAP_KM` km (0.5 m vertices): the
  kd-tree `LaneMap.match` (all lanes near the point, with foot point and margin) against
  `LaneMap.match_brute_force` (nearest vertex by an O(n) numpy scan, then the same projection). Both are
  called on the same random points near the lanes, interleaved.
- vehicle-manager prediction of 10 vehicles on the platoon MPC's grid (10 s at 0.1 s, 101 points):
  `VehicleManager.predict_all` (closed-form CYRA, one vectorised evaluation per vehicle) against a
  baseline that integrates the same model numerically (explicit Euler at 10 ms, vectorised over vehicles).
- the pose filter: one odometry sample (propagation), one GNSS position update, and one `pose(t)` query.

Contract (``--json FILE``): ``{"match_us", "match_bruteforce_us", "predict10_us", "predict10_euler_us",
"pose_odometry_us", "pose_fix_us", "pose_query_us"}``, each ``{"p50", "p99", "max", "n"}``, plus
``"ratios"`` (baseline p50 / ours p50), ``"map_vertices"`` and ``"max_predict_diff_m"`` (largest position
difference between the closed form and the Euler baseline on the grid: the baseline's own error).
"""

from __future__ import annotations

import argparse
import functools
import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from benchmarks.timed import add_timed_arguments, run_timed
from bywire.host.geo import LocalFrame
from bywire.host.world.lanemap import LaneMap, record_lane
from bywire.host.world.nmea import FixQuality
from bywire.host.world.pose import PoseFilter
from bywire.host.world.vehicles import VehicleManager, VehicleMessage

DEFAULT_SECONDS = 6.0
MAP_KM = 10.0
VEHICLES = 10
GRID_S = np.arange(101, dtype=np.float64) * 0.1
EULER_DT_S = 0.01


def _stats(samples_s: list[float]) -> dict[str, float]:
    a = np.asarray(samples_s) * 1e6
    return {
        "p50": float(np.percentile(a, 50)),
        "p99": float(np.percentile(a, 99)),
        "max": float(np.max(a)),
        "n": int(a.size),
    }


def _timed(fn: Callable[[], object]) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def build_map(km: float = MAP_KM) -> LaneMap:
    """A gently winding two-lane road: a sine of 200 m amplitude and 2 km period, recorded with 3 cm noise."""
    rng = np.random.default_rng(1)
    x = np.arange(0.0, km * 1000.0, 0.7)
    y = 200.0 * np.sin(2.0 * math.pi * x / 2000.0)
    track = np.column_stack((x, y)) + rng.normal(0.0, 0.03, (x.size, 2))
    return record_lane(track, LocalFrame(51.47, 5.62)).with_offset_lane(0, 3.5, 1, "left")


def bench_match(lanemap: LaneMap, seconds: float, seed: int = 2) -> dict[str, Any]:
    rng = np.random.default_rng(seed)
    lane = lanemap.lane(0)
    kd: list[float] = []
    bf: list[float] = []
    disagree = 0
    deadline = time.perf_counter() + seconds
    while time.perf_counter() < deadline or len(kd) < 50:
        s = float(rng.uniform(0.0, lane.length_m))
        x, y, h = lane.point_at(s)
        off = float(rng.uniform(-1.5, 5.0))
        px, py = x - off * math.sin(h), y + off * math.cos(h)
        t0 = time.perf_counter()
        a = lanemap.match(px, py)
        t1 = time.perf_counter()
        b = lanemap.match_brute_force(px, py)
        t2 = time.perf_counter()
        kd.append(t1 - t0)
        bf.append(t2 - t1)
        if a is not None and b is not None and a.lane_id == b.lane_id and abs(a.s_m - b.s_m) > 1e-6:
            disagree += 1
    return {"match_us": _stats(kd), "match_bruteforce_us": _stats(bf), "match_disagreements": disagree}


def _manager(rng: np.random.Generator) -> VehicleManager:
    vm = VehicleManager()
    for sid in range(VEHICLES):
        for k in range(20):
            t = 0.1 * k
            v = 20.0 + sid * 0.3
            vm.receive(
                VehicleMessage(
                    sid,
                    t,
                    30.0 * sid + v * t + rng.normal(0.0, 0.3),
                    rng.normal(0.0, 0.3),
                    0.01 * sid,
                    v,
                    0.002 * (sid - 5),
                    -0.3 * (sid % 3),
                ),
                t + 0.05,
            )
    return vm


def euler_predict(vm: VehicleManager, t0: float, grid_s: np.ndarray) -> np.ndarray:
    """Baseline: the same clipped CYRA model integrated with explicit Euler steps, all vehicles at once."""
    tracks = list(vm.tracks.values())
    x = np.array([tr.x for tr in tracks])  # [x, y, psi, v, w, a] per vehicle
    v_max = vm.config.speed_max_mps
    # Each vehicle starts at its own filter time; bring all to t0 first, then walk the grid.
    out = np.empty((len(tracks), grid_s.size, 2))
    t = np.array([tr.t_s for tr in tracks])
    targets = t0 + grid_s
    px, py, psi, v, w, a = (x[:, i].copy() for i in range(6))
    for j, target in enumerate(targets):
        while np.any(t < target - 1e-12):
            dt = np.clip(target - t, 0.0, EULER_DT_S)
            moving = v > 0.0
            v_new = np.clip(v + a * dt, 0.0, v_max)
            v_mid = 0.5 * (v + v_new)
            psi_mid = psi + 0.5 * w * dt * moving
            px = px + v_mid * np.cos(psi_mid) * dt
            py = py + v_mid * np.sin(psi_mid) * dt
            psi = psi + w * dt * moving
            v = v_new
            t = t + dt
        out[:, j, 0], out[:, j, 1] = px, py
    return out


def bench_predict(seconds: float, seed: int = 3) -> dict[str, Any]:
    rng = np.random.default_rng(seed)
    vm = _manager(rng)
    t0 = 2.0
    ours: list[float] = []
    base: list[float] = []
    ref = vm.predict_all(t0 + GRID_S)
    eul = euler_predict(vm, t0, GRID_S)
    diff = max(
        float(np.max(np.hypot(tr.x_m - eul[k, :, 0], tr.y_m - eul[k, :, 1])))
        for k, tr in enumerate(ref.values())
    )
    deadline = time.perf_counter() + seconds
    while time.perf_counter() < deadline or len(base) < 5:
        for _ in range(10):  # the fast side is ~100x quicker: more samples for its p99
            ours.append(_timed(lambda: vm.predict_all(t0 + GRID_S)))
        base.append(_timed(lambda: euler_predict(vm, t0, GRID_S)))
    return {"predict10_us": _stats(ours), "predict10_euler_us": _stats(base), "max_predict_diff_m": diff}


def bench_pose(seconds: float) -> dict[str, Any]:
    f = PoseFilter()
    f.update_odometry(0.0, 15.0, 0.01)
    f.update_position(0.0, 0.0, 0.0, 0.03, 0.03, FixQuality.RTK_FIXED)
    f.update_heading(0.0, 0.0, math.radians(0.1))
    rng = np.random.default_rng(4)
    odo: list[float] = []
    fix: list[float] = []
    query: list[float] = []
    t = 0.0
    deadline = time.perf_counter() + seconds
    k = 0
    while time.perf_counter() < deadline or len(fix) < 50:
        k += 1
        t = 0.01 * k
        v = 15.0 + float(rng.normal(0.0, 0.05))
        odo.append(_timed(functools.partial(f.update_odometry, t, v, 0.01)))
        if k % 10 == 0:  # 10 Hz GNSS, 100 Hz odometry, as in the car
            p = f.state_at(t)
            assert p is not None
            x = float(p.mean[0] + rng.normal(0.0, 0.02))
            y = float(p.mean[1] + rng.normal(0.0, 0.02))
            fix.append(
                _timed(functools.partial(f.update_position, t, x, y, 0.03, 0.03, FixQuality.RTK_FIXED))
            )
            query.append(_timed(functools.partial(f.pose, t + 0.02)))
    return {"pose_odometry_us": _stats(odo), "pose_fix_us": _stats(fix), "pose_query_us": _stats(query)}


def run(seconds: float) -> dict[str, Any]:
    lanemap = build_map()
    doc: dict[str, Any] = {"map_vertices": lanemap.n_vertices, "map_km": MAP_KM, "vehicles": VEHICLES}
    doc.update(bench_match(lanemap, 0.4 * seconds))
    doc.update(bench_predict(0.4 * seconds))
    doc.update(bench_pose(0.2 * seconds))
    doc["ratios"] = {
        "match_bruteforce_over_kdtree": doc["match_bruteforce_us"]["p50"] / doc["match_us"]["p50"],
        "predict_euler_over_closed_form": doc["predict10_euler_us"]["p50"] / doc["predict10_us"]["p50"],
    }
    return doc


def _print_table(doc: dict[str, Any]) -> None:
    rows = [
        (f"lane match, kd-tree ({doc['map_vertices']} vertices)", "match_us"),
        ("lane match, brute force (baseline)", "match_bruteforce_us"),
        (f"predict {doc['vehicles']} vehicles x 101 points", "predict10_us"),
        ("predict, Euler 10 ms (baseline)", "predict10_euler_us"),
        ("pose filter: odometry sample", "pose_odometry_us"),
        ("pose filter: GNSS fix", "pose_fix_us"),
        ("pose filter: pose(t) query", "pose_query_us"),
    ]
    print(f"{'[us]':44} {'p50':>10} {'p99':>10} {'max':>10} {'n':>8}")
    for label, key in rows:
        r = doc[key]
        print(f"{label:44} {r['p50']:10.1f} {r['p99']:10.1f} {r['max']:10.1f} {r['n']:8d}")
    ratios = doc["ratios"]
    print(f"\nbrute force / kd-tree match (p50): {ratios['match_bruteforce_over_kdtree']:.1f}x")
    print(f"Euler / closed-form prediction (p50): {ratios['predict_euler_over_closed_form']:.1f}x")
    print(f"closed form vs Euler baseline, largest difference: {doc['max_predict_diff_m']:.2e} m")


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_timed_arguments(p, DEFAULT_SECONDS, "the timed part takes")


def main(args: argparse.Namespace) -> int:
    return run_timed(args, "world", DEFAULT_SECONDS, run, _print_table)
