"""`bywire zone plan MAP --start X,Y,YAW --goal X,Y,YAW [--plot OUT.png] --json OUT`: the zone planner
(seed 000 Sec. 10) on any occupancy grid, as a motion-planning engineer tries a planner: a map file in,
a path, its numbers and a picture out.

MAP is a `.npy` array (nonzero: occupied; row 0 at y = origin) or an image (dark: occupied; the top row
is the far edge, as image tools draw it); `--resolution` gives its cell size. The JSON holds `found`,
`length_m`, `direction_changes`, `plan_ms`, `expansions` (and `cost`, `cspace_ms`, `reason`, the path's
poses). The plot shows the map, the configuration-space obstacles at the start's heading, the search
tree, the obstacle-aware heuristic and the path with the car's outline along it.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

# The planner (numpy, scipy) loads when the command runs, not when `bywire` builds its parser.
if TYPE_CHECKING:
    from .cspace import CSpace, Footprint
    from .hybrid_astar import Plan

CAR_NAMES = ("lexus", "passat")  # lexus: Autoware's test car
DEFAULT_HEURISTIC_WEIGHT = 1.5  # PlannerParams.heuristic_weight (a test holds the two equal)


def cars() -> dict[str, tuple[Footprint, float]]:
    """Each car's footprint and turning radius (m)."""
    from .cspace import PASSAT_FOOTPRINT
    from .reference_maps import LEXUS_FOOTPRINT, LEXUS_TURN_RADIUS_M

    return {"passat": (PASSAT_FOOTPRINT, 5.5), "lexus": (LEXUS_FOOTPRINT, LEXUS_TURN_RADIUS_M)}


def _pose(text: str) -> tuple[float, float, float]:
    parts = text.split(",")
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: a pose is X,Y,YAW (metres, metres, radians)") from None
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"{text!r}: a pose is three finite numbers X,Y,YAW")
    return values[0], values[1], values[2]


def add_plan_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "map", type=Path, help="occupancy grid: .npy (nonzero occupied) or an image (dark occupied)"
    )
    p.add_argument("--start", type=_pose, required=True, help="X,Y,YAW of the rear axle's centre (m, m, rad)")
    p.add_argument("--goal", type=_pose, required=True, help="X,Y,YAW of the rear axle's centre (m, m, rad)")
    p.add_argument("--resolution", type=float, default=0.2, help="cell size in metres (default 0.2)")
    p.add_argument(
        "--origin", type=_pose, default=(0.0, 0.0, 0.0), help="X,Y,0: world position of cell (0, 0)"
    )
    p.add_argument("--car", choices=CAR_NAMES, default="passat", help="footprint and turning radius")
    p.add_argument(
        "--margin", type=float, default=0.3, help="safety distance around the car, m (default 0.3)"
    )
    p.add_argument("--weight", type=float, default=DEFAULT_HEURISTIC_WEIGHT,
                   help="heuristic weight (1: the search graph's optimum; default %(default)s)")  # fmt: skip
    p.add_argument("--headings", type=int, default=72, help="heading bins of the configuration space")
    p.add_argument("--plot", type=Path, help="write a PNG of the map, search tree, heuristic and path")
    p.add_argument("--json", type=Path, help="write the result document here")


def main_plan(args: argparse.Namespace) -> int:
    import numpy as np

    from .cspace import build_cspace
    from .grid_map import load
    from .hybrid_astar import PlannerParams, plan

    try:
        grid = load(args.map, args.resolution, (args.origin[0], args.origin[1]))
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    footprint, radius = cars()[args.car]
    t0 = time.perf_counter()
    try:
        cs = build_cspace(grid, footprint, margin_m=args.margin, n_headings=args.headings)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    cspace_ms = 1e3 * (time.perf_counter() - t0)
    params = PlannerParams(turn_radius_m=radius, heuristic_weight=args.weight)
    result = plan(cs, args.start, args.goal, params, keep_tree=args.plot is not None)
    doc: dict[str, Any] = {**result.summary(), "cspace_ms": round(cspace_ms, 2), "map": str(args.map),
                           "start": list(args.start), "goal": list(args.goal), "car": args.car,
                           "poses": np.round(result.poses, 4).tolist(),
                           "directions": result.directions.astype(int).tolist()}  # fmt: skip
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    if args.plot:
        plot_plan(cs, result, args.start, args.goal, args.plot, radius)
    verdict = "found" if result.found else f"not found ({result.reason})"
    print(
        f"zone plan: {verdict}: {result.length_m:.1f} m, {result.direction_changes} direction changes, "
        f"{result.plan_ms:.0f} ms, {result.expansions} expansions (c-space {cspace_ms:.0f} ms)"
    )
    return 0 if result.found else 1


def plot_plan(
    cs: CSpace, result: Plan, start: tuple[float, float, float], goal: tuple[float, float, float], out: Path,
    turn_radius_m: float,
) -> None:  # fmt: skip
    import matplotlib
    import numpy as np

    from .heuristics import HeuristicField

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    grid = cs.grid
    w, h = grid.size_m
    ext = (grid.origin_xy_m[0], grid.origin_xy_m[0] + w, grid.origin_xy_m[1], grid.origin_xy_m[1] + h)
    fig, (ax, axh) = plt.subplots(1, 2, figsize=(15, 7.5))
    k = int(cs.heading_bin(start[2]))
    ax.imshow(cs.blocked[k], origin="lower", extent=ext, cmap="Reds", alpha=0.25, interpolation="nearest")
    ax.imshow(np.ma.masked_where(~grid.occupied, grid.occupied), origin="lower", extent=ext, cmap="Greys",
              vmin=0, vmax=1, interpolation="nearest")  # fmt: skip
    if result.tree:
        t = np.asarray(result.tree)
        ax.plot(t[:, [0, 2]].T, t[:, [1, 3]].T, color="0.7", lw=0.4)
    if result.found:
        fwd = np.where(result.directions > 0, result.poses[:, 1], np.nan)
        rev = np.where(result.directions < 0, result.poses[:, 1], np.nan)
        ax.plot(result.poses[:, 0], fwd, color="tab:blue", lw=2, label="forward")
        ax.plot(result.poses[:, 0], rev, color="tab:orange", lw=2, label="reverse")
        step = max(1, len(result.poses) // 15)
        for x, y, th in result.poses[::step]:
            _outline(ax, cs.footprint, (x, y, th), "tab:blue")
    for pose, colour in ((start, "tab:green"), (goal, "tab:red")):
        _outline(ax, cs.footprint, pose, colour)
    ax.set_title(f"{'found' if result.found else 'not found'}: {result.length_m:.1f} m, "
                 f"{result.direction_changes} direction changes, {result.plan_ms:.0f} ms, "
                 f"{result.expansions} expansions")  # fmt: skip
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(loc="upper right", fontsize=8)
    hf = HeuristicField(cs, goal, turn_radius_m)
    field = np.where(np.isfinite(hf.obstacle_m), hf.obstacle_m, np.nan)
    im = axh.imshow(field, origin="lower", extent=ext, cmap="viridis", interpolation="nearest")
    fig.colorbar(im, ax=axh, label="obstacle-aware distance to the goal [m]")
    axh.set_title("heuristic: free-space distance through the orientation-free superset")
    axh.set_aspect("equal")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)


def _outline(ax: Any, fp: Footprint, pose: tuple[float, float, float], colour: str) -> None:
    import numpy as np

    c, s = math.cos(pose[2]), math.sin(pose[2])
    pts = fp.corners()
    xs = pose[0] + c * pts[:, 0] - s * pts[:, 1]
    ys = pose[1] + s * pts[:, 0] + c * pts[:, 1]
    ax.plot(np.append(xs, xs[0]), np.append(ys, ys[0]), color=colour, lw=0.8)
