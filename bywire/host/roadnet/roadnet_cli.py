"""`bywire rndf check FILE...` and `bywire mission plan RNDF MDF` (seed 000 sec. 8).

``rndf check``: every FILE is read as an RNDF or an MDF, told apart by its first keyword (``RNDF_name`` /
``MDF_name``); with ``--rndf`` the MDFs' checkpoints are also resolved in that RNDF.  Exit status 0 when
all are good, 1 otherwise; one line ``file:line: what was expected`` on stderr per bad file, and the
warnings (tolerated quirks) on stdout unless ``--quiet``.  ``--strict`` makes the quirks errors.

``mission plan``: the fastest route through the MDF's checkpoints (`route.MissionPlanner`), printed as a
per-leg table; ``--json FILE`` writes ``{"checkpoints": [...], "reached_all", "route_length_m",
"route_time_s"}`` plus ``legs``, ``start``, ``rndf``, ``mdf``, ``blockades_forgotten``; ``--plot PNG``
draws the route over the network.  Exit status 0 when every checkpoint is reached, 1 when one is not, 2
for unreadable input (the error line on stderr).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path as FilePath
from typing import TYPE_CHECKING, Any

from .errors import MdfError, ParseWarning, RndfError, RoadnetError
from .ids import WaypointId
from .mdf import Mission, load_mdf, resolve_mission
from .rndf import RoadNetwork, load_rndf
from .tokens import decode, tokenize

if TYPE_CHECKING:
    from .graph import RoadGraph
    from .route import Route


def _kind(path: FilePath) -> str:
    """ "rndf" or "mdf" from the first keyword; RndfError if the file is neither."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise RndfError(str(path), 0, f"expected a readable file ({exc.strerror or exc})") from None
    lines = tokenize(decode(data), str(path), RndfError)
    first = lines[0] if lines else None
    if first is not None and first.keyword == "RNDF_name":
        return "rndf"
    if first is not None and first.keyword == "MDF_name":
        return "mdf"
    found = "an empty file" if first is None else repr(first.keyword)
    raise RndfError(str(path), first.number if first else 1, f"expected RNDF_name or MDF_name, found {found}")


def add_rndf_check_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("files", nargs="+", type=FilePath, metavar="FILE", help="RNDF or MDF files")
    p.add_argument("--rndf", type=FilePath, metavar="FILE", help="resolve the MDFs' checkpoints in this RNDF")
    p.add_argument("--strict", action="store_true", help="treat tolerated format quirks as errors")
    p.add_argument("-q", "--quiet", action="store_true", help="do not print warnings")


def main_rndf_check(args: argparse.Namespace) -> int:
    strict = bool(args.strict)
    network: RoadNetwork | None = None
    bad = 0
    if args.rndf is not None:
        try:
            network = load_rndf(args.rndf, strict=strict)
        except RoadnetError as exc:
            print(exc, file=sys.stderr)
            return 1
    for path in args.files:
        warnings: tuple[ParseWarning, ...] = ()
        try:
            if _kind(path) == "rndf":
                net = load_rndf(path, strict=strict)
                warnings = net.warnings
                summary = (
                    f"RNDF {net.name!r}: {len(net.segments)} segments, {len(net.zones)} zones, "
                    f"{sum(1 for _ in net.waypoints())} points, {len(net.checkpoints)} checkpoints"
                )
            else:
                mission = load_mdf(path, strict=strict)
                warnings = mission.warnings
                summary = f"MDF {mission.name!r}: {len(mission.checkpoints)} checkpoints"
                if network is not None:
                    resolved = resolve_mission(network, mission)
                    warnings += resolved.warnings
                    summary += f", all in RNDF {network.name!r}"
        except RoadnetError as exc:
            print(exc, file=sys.stderr)
            bad += 1
            continue
        if not args.quiet:
            print(f"{path}: ok, {summary}")
            for w in warnings:
                print(w)
    return 1 if bad else 0


# ---------------------------------------------------------------------------------------------- plan


def add_mission_plan_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("rndf", type=FilePath, metavar="RNDF", help="route network definition file")
    p.add_argument("mdf", type=FilePath, metavar="MDF", help="mission data file")
    p.add_argument("--json", type=FilePath, metavar="FILE", help="write the route summary as JSON")
    p.add_argument("--plot", type=FilePath, metavar="PNG", help="draw the route over the network")
    p.add_argument(
        "--start", metavar="WAYPOINT_ID", help="start vertex, e.g. 1.1.1 (default: the first checkpoint)"
    )


def route_json(route: Route, network: RoadNetwork, mission: Mission) -> dict[str, Any]:
    return {
        "checkpoints": [leg.checkpoint for leg in route.legs],
        "reached_all": route.reached_all,
        "route_length_m": route.length_m,
        "route_time_s": route.time_s,
        "start": str(route.start),
        "rndf": network.path,
        "mdf": mission.path,
        "blockades_forgotten": route.blockades_forgotten,
        "legs": [
            {
                "checkpoint": leg.checkpoint,
                "waypoint": str(leg.target),
                "reached": leg.reached,
                "length_m": leg.length_m,
                "time_s": leg.time_s,
                "edges": len(leg.edges),
                "kinds": sorted({e.kind.value for e in leg.edges}),
            }
            for leg in route.legs
        ],
    }


def _print_route(route: Route) -> None:
    print(f"start {route.start}")
    print(f"{'#':>4} {'checkpoint':>10} {'waypoint':>12} {'length m':>10} {'time s':>8}  via")
    for leg in route.legs:
        if not leg.reached:
            print(f"{leg.index + 1:>4} {leg.checkpoint:>10} {leg.target!s:>12} {'UNREACHABLE':>10}")
            continue
        counts: dict[str, int] = {}
        for e in leg.edges:
            counts[e.kind.value] = counts.get(e.kind.value, 0) + 1
        via = ", ".join(f"{n} {k}" for k, n in counts.items()) or "-"
        print(
            f"{leg.index + 1:>4} {leg.checkpoint:>10} {leg.target!s:>12} {leg.length_m:>10.1f} "
            f"{leg.time_s:>8.1f}  {via}"
        )
    print(f"total {route.length_m:.1f} m, {route.time_s:.1f} s ({route.time_s / 60.0:.1f} min)")
    if route.blockades_forgotten:
        print(f"blockades forgotten: {route.forgotten_blockades}")
    if not route.reached_all:
        print(f"checkpoints not reached: {[leg.checkpoint for leg in route.legs if not leg.reached]}")


def plot_route(graph: RoadGraph, route: Route, title: str, path: FilePath) -> None:
    """PNG of the network's lanes, exits and zones in grey, the route in colour, checkpoints numbered."""
    import matplotlib

    matplotlib.use("Agg")  # headless: write a file, never open a window
    import matplotlib.pyplot as plt

    from .graph import EdgeKind

    fig, ax = plt.subplots(figsize=(10, 10))
    for e in graph.edges((EdgeKind.LANE, EdgeKind.EXIT)):
        ax.plot(e.path.x_m, e.path.y_m, color="0.75", lw=0.8 if e.kind == EdgeKind.LANE else 0.5)
    for zone in graph.network.zones:
        pts = [graph.vertex_xy(p.id) for p in zone.perimeter.points]
        xs, ys = zip(*(pts + pts[:1]), strict=True)
        ax.fill(xs, ys, color="0.92", zorder=0)
        ax.plot(xs, ys, color="0.6", lw=0.6)
    colours = {
        EdgeKind.LANE_CHANGE: "tab:orange",
        EdgeKind.UTURN: "tab:red",
        EdgeKind.ZONE: "tab:green",
        EdgeKind.PARK: "tab:purple",
        EdgeKind.UNPARK: "tab:purple",
    }
    for e in route.edges:
        ax.plot(e.path.x_m, e.path.y_m, color=colours.get(e.kind, "tab:blue"), lw=2.0)
    for leg in route.legs:
        x, y = graph.vertex_xy(leg.target)
        ax.plot(x, y, "o", color="k" if leg.reached else "tab:red", ms=4)
        ax.annotate(str(leg.checkpoint), (x, y), fontsize=7, xytext=(3, 3), textcoords="offset points")
    sx, sy = graph.vertex_xy(route.start)
    ax.plot(sx, sy, "*", color="tab:green", ms=12)
    ax.set_aspect("equal")
    ax.set_xlabel("x east [m]")
    ax.set_ylabel("y north [m]")
    ax.set_title(title, fontsize=9)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main_mission_plan(args: argparse.Namespace) -> int:
    from .graph import build_graph
    from .route import MissionPlanner

    try:
        network = load_rndf(args.rndf)
        mission = load_mdf(args.mdf)
        resolved = resolve_mission(network, mission)
        start: WaypointId | None = None
        if args.start is not None:
            try:
                start = WaypointId.parse(args.start)
            except ValueError:
                raise MdfError("--start", 0, f"expected a waypoint id M.N.P, found {args.start!r}") from None
            if not network.has_waypoint(start):
                raise MdfError("--start", 0, f"expected a waypoint of {args.rndf}, {start} is not defined")
    except RoadnetError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for w in (*network.warnings, *mission.warnings, *resolved.warnings):
        print(w, file=sys.stderr)
    graph = build_graph(network, resolved)
    route = MissionPlanner(graph, resolved).plan(start)
    print(f"RNDF {network.name!r} ({args.rndf}), MDF {mission.name!r} ({args.mdf})")
    _print_route(route)
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(
            json.dumps(route_json(route, network, mission), indent=2) + "\n", encoding="utf-8"
        )
    if args.plot is not None:
        title = f"{args.mdf.name} on {args.rndf.name}: {route.length_m:.0f} m, {route.time_s:.0f} s"
        plot_route(graph, route, title, args.plot)
    return 0 if route.reached_all else 1
