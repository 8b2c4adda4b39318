"""`bywire perception grid` (seed 000 sections 4-5).

One pair per command, `add_<name>_arguments(p)` and `main_<name>(args) -> int`, as `bywire.cli`'s table
names them; each imports what it runs inside its main, so one command does not load another's.

``perception grid SCAN.bin [--png OUT] [--json OUT] [--layout graded|uniform]``: one Velodyne revolution
(KITTI .bin) through the occupancy grid (`grid`, section 4) and the segmentation (`segmentation`,
section 5), at the origin pose. Prints a summary line; the PNG shows the occupancy and the obstacle
cells with the objects outlined; the JSON holds the layout, the cell counts, the obstacle cells, the
objects (centre, size) and the update time. A file that is not a scan: one line naming it on stderr,
exit 2; an output that cannot be written: exit 1.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

GRID_LAYOUTS = ("graded", "uniform")


def add_grid_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scan", type=Path, metavar="SCAN.bin", help="Velodyne scan, KITTI .bin (float32 x y z r)")
    p.add_argument("--png", type=Path, metavar="OUT", help="write the occupancy and objects picture")
    p.add_argument("--json", type=Path, metavar="OUT", help="write cells, objects and timing as JSON")
    p.add_argument(
        "--layout",
        choices=GRID_LAYOUTS,
        default="graded",
        help="graded: 0.15 m cells near the car, coarser with distance (default); uniform: 0.15 m everywhere",
    )


def main_grid(args: argparse.Namespace) -> int:
    from bywire.host.perception.grid import GridLayout, OccupancyGrid
    from bywire.host.perception.scan import ScanFormatError, read_kitti_bin
    from bywire.host.perception.segmentation import segment

    try:
        scan = read_kitti_bin(args.scan)
    except ScanFormatError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    layout = GridLayout.graded() if args.layout == "graded" else GridLayout.uniform()
    grid = OccupancyGrid(layout)
    t0 = time.perf_counter()
    measures = grid.update(scan)
    update_ms = (time.perf_counter() - t0) * 1e3
    snapshot = grid.snapshot()
    seg = segment(snapshot)
    with_evidence = int((layout.active_mask() & (grid.evidence != 0.0)).sum())
    summary: dict[str, Any] = {
        "scan": str(args.scan),
        "points": len(scan),
        "layout": {
            "name": layout.name,
            "cell_sizes_m": list(layout.cell_sizes_m),
            "cells_per_side": layout.cells_per_side,
            "half_extent_m": layout.half_extent_m,
        },
        "cells": {"total": layout.n_cells, "hit": len(measures), "with_evidence": with_evidence},
        "obstacle_cells": len(seg.cells),
        "objects": [
            {
                "x_m": round(o.x_m, 3),
                "y_m": round(o.y_m, 3),
                "length_m": round(o.length_m, 3),
                "width_m": round(o.width_m, 3),
                "yaw_rad": round(o.yaw_rad, 4),
                "height_m": round(o.height_m, 3),
                "cells": o.cells,
            }
            for o in seg.objects
        ],
        # One cold update (first call of a fresh grid): `bywire bench perception` has the distribution.
        "update_ms": round(update_ms, 3),
    }
    print(
        f"{args.scan}: {len(scan)} points, {layout.name}: {len(measures)} cells hit, "
        f"{len(seg.cells)} obstacle cells, {len(seg.objects)} objects, update {update_ms:.1f} ms"
    )
    try:
        if args.json is not None:
            args.json.write_text(json.dumps(summary, indent=1) + "\n")
        if args.png is not None:
            from bywire.host.perception.grid_plot import plot_grid

            plot_grid(args.png, snapshot, seg, f"{args.scan.name}: {layout.name}", scan=scan)
    except OSError as exc:
        print(f"error: cannot write {exc.filename}: {exc.strerror}", file=sys.stderr)
        return 1
    return 0
