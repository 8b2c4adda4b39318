"""`bywire bench zone`: the zone planner (seed 000 Sec. 10) on Autoware's freespace-planner test lot and on
our maze, beside the planners users pick today, in the same run, for the same car and the same collision
check.

Per map: ``cspace_ms``, the configuration-space table (all headings) for a new grid of that size with the
kernels' spectra cached (what a replan pays), and ``cspace_cold_ms`` with them computed. Per goal, over
``--runs`` runs: our plan time p50 / max, found, path length, direction changes, expansions; and per peer
(OMPL's RRT* and BIT* on a Reeds-Shepp state space with our table as its validity checker, each asked to
stop as soon as it holds a path as short as ours, within ``--budget`` seconds): found (a path as short
as ours within the budget), plan time p50 (the budget where it never got there), and the length it
reached. ``speedup_vs_fastest_peer`` divides the fastest peer's p50 by ours where a peer got there.

Targets on these 2-core machines (the zone planning issue): every goal <= 200 ms; on the two hardest
goals at least 10 times faster than the fastest peer that reaches a path as short as ours; c-space
<= 100 ms for the 30 m lot. Nothing is asserted (DESIGN section 5). Without OMPL (the `bench` extra)
the peers are reported as not installed.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from bywire.host.navigation import cspace as cspace_mod
from bywire.host.navigation.cspace import CSpace, build_cspace
from bywire.host.navigation.hybrid_astar import PlannerParams, plan, warm_up
from bywire.host.navigation.reference_maps import ReferenceProblem, reference_problems

PEERS = ("RRTstar", "BITstar")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--runs", type=int, default=5, help="runs of our planner per goal (default 5)")
    p.add_argument("--peer-runs", type=int, default=3, help="runs of each peer per goal (default 3)")
    p.add_argument("--budget", type=float, default=5.0, help="a peer's time budget per run, s (default 5)")
    p.add_argument("--no-peers", action="store_true", help="our planner only")
    p.add_argument("--json", type=Path, help="write the result document here")


def _margin(problem: ReferenceProblem) -> float:
    return 0.0 if problem.name == "autoware_lot" else 0.3  # Autoware's test checks the bare outline


def _peer(cs: CSpace, problem: ReferenceProblem, goal: tuple[float, float, float], name: str,
          target_m: float, budget_s: float) -> tuple[bool, float, float | None]:  # fmt: skip
    """(reached a path as short as `target_m`, seconds, the length it reached)."""
    from ompl import base as ob
    from ompl import geometric as og

    space = ob.ReedsSheppStateSpace(problem.turn_radius_m)
    bounds = ob.RealVectorBounds(2)
    w, h = cs.grid.size_m
    ox, oy = cs.grid.origin_xy_m
    bounds.setLow(0, ox)
    bounds.setHigh(0, ox + w)
    bounds.setLow(1, oy)
    bounds.setHigh(1, oy + h)
    space.setBounds(bounds)
    ss = og.SimpleSetup(space)
    ss.setStateValidityChecker(
        lambda s: not bool(cs.collides(np.array([s.getX()]), np.array([s.getY()]), np.array([s.getYaw()]))[0])
    )
    si = ss.getSpaceInformation()
    si.setStateValidityCheckingResolution(0.5 * cs.grid.resolution_m / space.getMaximumExtent())
    start, end = space.allocState(), space.allocState()
    for st, pose in ((start, problem.start), (end, goal)):
        st.setX(pose[0])
        st.setY(pose[1])
        st.setYaw(math.remainder(pose[2], 2.0 * math.pi))  # OMPL's SO(2) bounds: [-pi, pi]
    ss.setStartAndGoalStates(start, end, 0.1)
    objective = ob.PathLengthOptimizationObjective(si)
    objective.setCostThreshold(ob.Cost(target_m))
    ss.setOptimizationObjective(objective)
    ss.setPlanner(getattr(og, name)(si))
    t0 = time.perf_counter()
    ss.solve(budget_s)
    dt = time.perf_counter() - t0
    if not ss.haveExactSolutionPath():
        return False, dt, None
    length = float(ss.getSolutionPath().length())
    return length <= target_m + 1e-6, dt, length


def main(args: argparse.Namespace) -> int:
    peers_ok = not args.no_peers
    if peers_ok:
        try:
            import ompl.base  # noqa: F401
        except ImportError:
            print(
                "bench zone: OMPL is not installed (pip install 'bywire[bench]'): peers skipped",
                file=sys.stderr,
            )
            peers_ok = False
        else:
            from ompl import util as ou

            ou.setLogLevel(ou.LogLevel.LOG_ERROR)
    doc: dict[str, Any] = {"maps": [], "goals": []}
    warm_up()  # numba's compile or cache load, which a planner's process pays at its start
    for problem in reference_problems():
        margin = _margin(problem)
        cspace_mod._kernel_spectra.cache_clear()
        t0 = time.perf_counter()
        cs = build_cspace(problem.grid, problem.footprint, margin_m=margin)
        cold = 1e3 * (time.perf_counter() - t0)
        warm = []
        for _ in range(5):
            t0 = time.perf_counter()
            cs = build_cspace(problem.grid, problem.footprint, margin_m=margin)
            warm.append(1e3 * (time.perf_counter() - t0))
        row_map = {
            "map": problem.name,
            "cspace_ms": round(statistics.median(warm), 2),
            "cspace_cold_ms": round(cold, 2),
        }
        doc["maps"].append(row_map)
        print(f"{problem.name}: c-space {row_map['cspace_ms']} ms (cold {row_map['cspace_cold_ms']} ms)")
        params = PlannerParams(turn_radius_m=problem.turn_radius_m)
        for name, goal in problem.goals:
            times, result = [], None
            for _ in range(args.runs):
                result = plan(cs, problem.start, goal, params)
                times.append(result.plan_ms)
            assert result is not None
            row: dict[str, Any] = {
                "map": problem.name, "name": name, "found": result.found,
                "plan_ms_p50": round(statistics.median(times), 2), "plan_ms_max": round(max(times), 2),
                "length_m": round(result.length_m, 3), "direction_changes": result.direction_changes,
                "expansions": result.expansions, "peers": {},
            }  # fmt: skip
            if peers_ok and result.found:
                for peer in PEERS:
                    runs = [
                        _peer(cs, problem, goal, peer, result.length_m, args.budget)
                        for _ in range(args.peer_runs)
                    ]
                    reached = [r for r in runs if r[0]]
                    lengths = [r[2] for r in runs if r[2] is not None]
                    row["peers"][peer] = {
                        "found": bool(reached),
                        "reached": f"{len(reached)}/{len(runs)}",
                        "plan_ms_p50": round(1e3 * statistics.median(r[1] for r in runs), 1),
                        "length_m": round(min(lengths), 3) if lengths else None,
                    }
                got_there = [v["plan_ms_p50"] for v in row["peers"].values() if v["found"]]
                row["speedup_vs_fastest_peer"] = (
                    round(min(got_there) / row["plan_ms_p50"], 1) if got_there else None
                )
            doc["goals"].append(row)
            peers = "; ".join(
                f"{k} {v['reached']} as short, p50 {v['plan_ms_p50']} ms, best {v['length_m']} m"
                for k, v in row["peers"].items()
            )
            print(f"  {name}: {'found' if row['found'] else 'NOT FOUND'} p50 {row['plan_ms_p50']} ms max "
                  f"{row['plan_ms_max']} ms, {row['length_m']} m, {row['direction_changes']} changes, "
                  f"{row['expansions']} expansions" + (f" | {peers}" if peers else ""))  # fmt: skip
    doc["cspace_ms"] = max(m["cspace_ms"] for m in doc["maps"])
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    return 0 if all(g["found"] for g in doc["goals"]) and math.isfinite(doc["cspace_ms"]) else 1
