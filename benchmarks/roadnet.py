"""`bywire bench roadnet`: read, parse, build the graph and plan full missions on the largest shared networks.

Seed 000 section 8: RNDF/MDF mission planning.

Networks: the DARPA NQE RNDF with the MDFs of test areas A, B1, B2 and C, and Stanford's VAIL RNDF (the
largest file, v1.1 extension) with its MDF.  For each, timed `--repeats` times in one run (so machine load
hits all rows alike), median / p99 / max in milliseconds:

- ``read``: reading the RNDF's bytes (the floor any parser sits on) - baseline of ``parse``;
- ``parse``: `load_rndf` + `load_mdf` + `resolve_mission` of every MDF;
- ``graph``: `build_graph` (splines, connectors, derived edges);
- ``route``: `MissionPlanner.plan` for every MDF on the fresh graph: A*, and on the way the geometry of the
  derived edges it looks at (made on first use) and every edge time;
- ``replan``: the same plans again with the same planners (geometry and edge times cached): the search
  alone, what a replanning after a blockade costs;
- ``dijkstra``: the same legs with plain `networkx.dijkstra_path` on precomputed edge times - the baseline
  of ``replan``;
- ``total``: parse + graph + route.

The data is read in place from ``$BYWIRE_SHARED_DATA/rndf`` (default ``/work/shared/data/rndf``, or the
``shared/data`` beside the checkout).  JSON (``--json``): ``{"repeats", "networks": {name: {row: {"median_ms",
"p99_ms", "max_ms"}, "parse_over_read", "replan_over_dijkstra", "route_length_m", "vertices", "edges"}}}``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

# The subsystem loads when the benchmark runs, not when `bywire` builds its parser (add_arguments).
if TYPE_CHECKING:
    from bywire.host.roadnet.graph import RoadGraph
    from bywire.host.roadnet.mdf import ResolvedMission
    from bywire.host.roadnet.route import MissionPlanner

DEFAULT_REPEATS = 5
ROWS = ("read", "parse", "graph", "route", "replan", "dijkstra", "total")
NETWORKS: dict[str, tuple[str, tuple[str, ...]]] = {
    "nqe": (
        "darpa_nqe/nqe_rndf.rdf",
        (
            "darpa_nqe/nqe_a_mdf.mdf",
            "darpa_nqe/nqe_b1_mdf.mdf",
            "darpa_nqe/nqe_b2_mdf.mdf",
            "darpa_nqe/nqe_c_mdf.mdf",
        ),
    ),
    "vail": ("stanford/VAIL_rndf_20091020.txt", ("stanford/VAIL_mdf.txt",)),
}


def data_dir() -> Path:
    env = os.environ.get("BYWIRE_SHARED_DATA")
    if env:
        return Path(env) / "rndf"
    beside = Path(__file__).resolve().parents[2] / "shared" / "data" / "rndf"
    return beside if beside.exists() else Path("/work/shared/data/rndf")


def _stats(samples_s: list[float]) -> dict[str, float]:
    ms = sorted(x * 1e3 for x in samples_s)
    # p99 by linear interpolation between order statistics (numpy's default method)
    pos = 0.99 * (len(ms) - 1)
    lo = int(pos)
    p99 = ms[lo] + (ms[min(lo + 1, len(ms) - 1)] - ms[lo]) * (pos - lo)
    return {"median_ms": statistics.median(ms), "p99_ms": p99, "max_ms": ms[-1]}


def _timed(fn: Callable[[], Any]) -> tuple[float, Any]:
    t0 = time.perf_counter()
    out = fn()
    return time.perf_counter() - t0, out


def _dijkstra(graph: RoadGraph, missions: list[ResolvedMission], planner: MissionPlanner) -> float:
    import networkx as nx

    for _, _, d in graph.digraph.edges(data=True):
        d["time_s"] = planner.edge_time_s(d["edge"])
    t0 = time.perf_counter()
    for m in missions:
        here = m.waypoints[0]
        for goal in m.waypoints:
            if goal != here:
                nx.dijkstra_path(graph.digraph, here, goal, weight="time_s")
            here = goal
    return time.perf_counter() - t0


def _plan_all(planners: list[MissionPlanner]) -> list[Any]:
    return [p.plan() for p in planners]


def bench_network(root: Path, rndf: str, mdfs: tuple[str, ...], repeats: int) -> dict[str, Any]:
    from bywire.host.roadnet.graph import build_graph
    from bywire.host.roadnet.mdf import load_mdf, resolve_mission
    from bywire.host.roadnet.rndf import load_rndf
    from bywire.host.roadnet.route import MissionPlanner

    rows: dict[str, list[float]] = {k: [] for k in ROWS}
    length = 0.0
    vertices = edges = 0
    for _ in range(repeats):
        t_read, _ = _timed(lambda: (root / rndf).read_bytes())

        def parse() -> tuple[Any, list[ResolvedMission]]:
            net = load_rndf(root / rndf)
            return net, [resolve_mission(net, load_mdf(root / m)) for m in mdfs]

        t_parse, (net, missions) = _timed(parse)
        t_graph, graph = _timed(partial(build_graph, net, missions[0]))
        planners = [MissionPlanner(graph, m) for m in missions]  # same speed limits: NQE's MDFs agree
        t_route, routes = _timed(partial(_plan_all, planners))
        t_replan, _ = _timed(partial(_plan_all, planners))
        t_dijkstra = _dijkstra(graph, missions, planners[0])
        for key, value in (
            ("read", t_read),
            ("parse", t_parse),
            ("graph", t_graph),
            ("route", t_route),
            ("replan", t_replan),
            ("dijkstra", t_dijkstra),
            ("total", t_parse + t_graph + t_route),
        ):
            rows[key].append(value)
        length = sum(r.length_m for r in routes)
        vertices, edges = graph.digraph.number_of_nodes(), graph.digraph.number_of_edges()
    doc: dict[str, Any] = {k: _stats(v) for k, v in rows.items()}
    doc["parse_over_read"] = doc["parse"]["median_ms"] / doc["read"]["median_ms"]
    doc["replan_over_dijkstra"] = doc["replan"]["median_ms"] / doc["dijkstra"]["median_ms"]
    doc["route_length_m"] = length
    doc["vertices"] = vertices
    doc["edges"] = edges
    doc["mdfs"] = list(mdfs)
    return doc


def run(repeats: int, root: Path | None = None) -> dict[str, Any]:
    root = root or data_dir()
    return {
        "repeats": repeats,
        "data": str(root),
        "networks": {name: bench_network(root, r, m, repeats) for name, (r, m) in NETWORKS.items()},
    }


def _print_table(doc: dict[str, Any]) -> None:
    print(f"{doc['repeats']} repeats, data {doc['data']}")
    for name, net in doc["networks"].items():
        print(
            f"\n{name}: {net['vertices']} vertices, {net['edges']} edges, {len(net['mdfs'])} missions, "
            f"{net['route_length_m'] / 1000:.1f} km of routes"
        )
        print(f"  {'row':10} {'median ms':>10} {'p99 ms':>10} {'max ms':>10}")
        for row in ROWS:
            r = net[row]
            print(f"  {row:10} {r['median_ms']:10.2f} {r['p99_ms']:10.2f} {r['max_ms']:10.2f}")
        print(
            f"  parse / read {net['parse_over_read']:.0f}x, replan (A*) / dijkstra (baseline) "
            f"{net['replan_over_dijkstra']:.2f}x"
        )


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", type=Path, help="write the results as JSON")
    p.add_argument(
        "--repeats", type=int, default=DEFAULT_REPEATS, help=f"runs per network (default {DEFAULT_REPEATS})"
    )


def main(args: argparse.Namespace) -> int:
    repeats = DEFAULT_REPEATS if getattr(args, "repeats", None) is None else int(args.repeats)
    if repeats < 1:
        print("--repeats must be >= 1")
        return 2
    root = data_dir()
    missing = [root / r for r, _ in NETWORKS.values() if not (root / r).exists()]
    if missing:
        print(f"road network data not found at {missing[0]} (set BYWIRE_SHARED_DATA)")
        return 2
    doc = run(repeats, root)
    _print_table(doc)
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
    return 0
