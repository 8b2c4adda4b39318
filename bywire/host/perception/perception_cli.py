"""`bywire perception grid` and `bywire perception track-eval` (seed 000 sections 4-5).

One pair per command, `add_<name>_arguments(p)` and `main_<name>(args) -> int`, as `bywire.cli`'s table
names them; each imports what it runs inside its main, so one command does not load another's.

``perception grid SCAN.bin [--png OUT] [--json OUT] [--layout graded|uniform]``: one Velodyne revolution
(KITTI .bin) through the occupancy grid (`grid`, section 4) and the segmentation (`segmentation`,
section 5), at the origin pose. Prints a summary line; the PNG shows the occupancy and the obstacle
cells with the objects outlined; the JSON holds the layout, the cell counts, the obstacle cells, the
objects (centre, size) and the update time. A file that is not a scan: one line naming it on stderr,
exit 2; an output that cannot be written: exit 1.

``perception track-eval LABELS_DIR DETS_DIR [--calib DIR] [--sequences 0001,0002] --json OUT``: our
tracker (`tracker.Tracker`) on KITTI tracking detections, scored with CLEAR-MOT against the labels
(`track_eval`, AB3DMOT's protocol: car, 3-D IoU 0.25). Prints a table per sequence beside AB3DMOT's
published score and writes ``{"mota", "motp", "id_switches", "fragmentations", "sequences": {...}}``
plus more keys (``val_overall``, ``ab3dmot``, ``params``, ...) to OUT. ``--calib`` defaults to the
``calib`` folder beside LABELS_DIR. Exit status 0, or 2 for unreadable or missing input (the error
line on stderr, naming the file and line).
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
        print(f"error: {exc.filename}: cannot write: {exc.strerror}", file=sys.stderr)
        return 2
    return 0


def add_track_eval_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("labels_dir", type=Path, metavar="LABELS_DIR", help="KITTI label_02 folder (NNNN.txt)")
    p.add_argument(
        "dets_dir",
        type=Path,
        metavar="DETS_DIR",
        help="detections in AB3DMOT's format (NNNN.txt, comma separated)",
    )
    p.add_argument(
        "--calib", type=Path, metavar="DIR", help="calibration folder (default: `calib` beside LABELS_DIR)"
    )
    p.add_argument(
        "--sequences",
        metavar="LIST",
        help="comma-separated sequence names, e.g. 0001,0006 (default: all with labels and detections)",
    )
    p.add_argument("--json", type=Path, required=True, metavar="OUT", help="write the scores here")


def _sequences(text: str | None) -> list[str] | None:
    if text is None:
        return None
    names = [s.strip() for s in text.split(",") if s.strip()]
    # "1" and "0001" name the same KITTI sequence file.
    return [f"{int(s):04d}" if s.isdigit() else s for s in names]


def _row(name: str, s: dict[str, Any]) -> str:
    def pct(v: float | None) -> str:
        return "   n/a" if v is None else f"{100 * v:6.2f}"

    return (
        f"{name:>9} {pct(s['mota'])} {pct(s['motp'])} {s['id_switches']:5d} {s['fragmentations']:5d} "
        f"{s['false_positives']:6d} {s['misses']:6d} {s['objects']:7d}"
    )


def main_track_eval(args: argparse.Namespace) -> int:
    from bywire.host.perception.kitti_tracking import KittiFormatError
    from bywire.host.perception.track_eval import TrackEvalError, evaluate

    calib = args.calib if args.calib is not None else Path(args.labels_dir).parent / "calib"
    try:
        result = evaluate(args.labels_dir, args.dets_dir, calib, _sequences(args.sequences))
    except (KittiFormatError, TrackEvalError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(
        f"{'sequence':>9} {'MOTA%':>6} {'MOTP%':>6} {'IDS':>5} {'FRAG':>5} {'FP':>6} {'FN':>6} {'objects':>7}"
    )
    for name, scores in result["sequences"].items():
        print(_row(name + ("*" if scores["ab3dmot_val"] else ""), scores))
    print(_row("overall", result))
    if result["val_overall"] is not None:
        print(_row("val*", result["val_overall"]))
    ab = result["ab3dmot"]
    print(
        f"AB3DMOT (published, PointRCNN, KITTI val, {len(ab['sequences'])} sequences): "
        f"MOTA {100 * ab['mota']:.2f}; * = one of its validation sequences; MOTP: mean 3-D IoU of matches"
    )
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(result, indent=1, default=float) + "\n")
    return 0
