"""The uniform and the distance-graded grid layouts compared on the shared KITTI scans (seed 000
section 12's lesson: 15 cm cells far from the car see too few points to be classified).

`python -m bywire.host.perception.layout_study [DATA]` prints the tables of docs/perception.md
("Occupancy grid"), DATA being the shared `lidar_kitti` folder (default: beside the repository):

- coverage, per distance band from the car, over the six odometry scans (each integrated at the pose
  scan registration gives): cells hit, the share of them with enough points to be classified
  (n_i >= min_points), and the share of the band's ground that holds evidence after the scan;
- the update time of one revolution, median and p99 over repeated passes (an informal number on a
  shared machine; `bywire bench perception` is the measurement);
- the labelled objects of the object frames: obstacle cells inside each box (grown by a cell), and
  the segmentation's precision and recall (`kitti_objects`).
"""

from __future__ import annotations

import argparse
import itertools
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bywire.host.perception.ego_pose import EgoPose
from bywire.host.perception.grid import GridLayout, OccupancyGrid
from bywire.host.perception.kitti_objects import (
    evaluate_object_frames,
    precision_recall,
    read_calibration,
    read_labels,
)
from bywire.host.perception.registration import register
from bywire.host.perception.scan import Scan, read_kitti_bin
from bywire.host.perception.segmentation import segment

BANDS_M = (0.0, 20.0, 40.0, 60.0, 76.8)
LAYOUTS = {
    "uniform 0.15": GridLayout.uniform(0.15),
    "uniform 0.30": GridLayout.uniform(0.30),
    "graded 0.15-0.60": GridLayout.graded(0.15, levels=3),
    "graded 0.15-1.20": GridLayout.graded(0.15, levels=4),
}


def registered_poses(scans: Sequence[Scan]) -> list[EgoPose]:
    """Each scan's pose in the first one's frame, chaining consecutive registrations."""
    poses = [EgoPose()]
    for prev, scan in itertools.pairwise(scans):
        poses.append(poses[-1].compose(register(scan, prev).pose))
    return poses


def coverage(layout: GridLayout, scans: Sequence[Scan], poses: Sequence[EgoPose]) -> list[dict[str, Any]]:
    """Per band: mean cells hit per scan, share classifiable, share of the band's area with evidence."""
    grid = OccupancyGrid(layout)
    sums = np.zeros((len(BANDS_M) - 1, 3))
    active = layout.active_mask().reshape(-1)
    for scan, pose in zip(scans, poses, strict=True):
        me = grid.update(scan, pose)
        xy, _ = layout.cell_centres_m(me.cells)
        r = np.hypot(*(xy + np.asarray(grid.centre_m) - [pose.x_m, pose.y_m]).T)
        band = np.digitize(r, BANDS_M) - 1
        classified = me.points >= grid.model.min_points
        all_xy, all_size = layout.cell_centres_m(np.flatnonzero(active))
        all_r = np.hypot(*(all_xy + np.asarray(grid.centre_m) - [pose.x_m, pose.y_m]).T)
        known = grid.evidence.reshape(-1)[active] != 0.0
        for b in range(len(BANDS_M) - 1):
            inb, in_all = band == b, (all_r >= BANDS_M[b]) & (all_r < BANDS_M[b + 1])
            ring_m2 = np.pi * (BANDS_M[b + 1] ** 2 - BANDS_M[b] ** 2)
            sums[b] += (
                inb.sum(),
                classified[inb].sum() / max(inb.sum(), 1),
                (all_size[in_all & known] ** 2).sum() / ring_m2,
            )
    n = len(scans)
    return [
        {
            "band": f"{BANDS_M[b]:.0f}-{BANDS_M[b + 1]:.0f} m",
            "hit": s[0] / n,
            "classifiable": s[1] / n,
            "known": s[2] / n,
        }
        for b, s in enumerate(sums)
    ]


def update_times_ms(
    layout: GridLayout, scans: Sequence[Scan], poses: Sequence[EgoPose], passes: int = 30
) -> dict[str, float]:
    """Median and p99 of one update, wall clock and the thread's CPU time (which other processes on a
    busy machine inflate less), and the CPU median of a snapshot and its segmentation."""
    grid = OccupancyGrid(layout)
    wall, cpu, seg = [], [], []
    for k in range(passes):
        # each pass drives on from where the last ended, so every update also shifts the grid
        offset = EgoPose(k * (poses[-1].x_m + 0.7), k * poses[-1].y_m)
        for scan, pose in zip(scans, poses, strict=True):
            t0, c0 = time.perf_counter(), time.thread_time()
            grid.update(scan, offset.compose(pose))
            cpu.append(time.thread_time() - c0)
            wall.append(time.perf_counter() - t0)
            c0 = time.thread_time()
            segment(grid.snapshot())
            seg.append(time.thread_time() - c0)
    w, c = np.array(wall[len(scans) :]) * 1e3, np.array(cpu[len(scans) :]) * 1e3  # pass 1 warms up
    return {
        "wall_p50": float(np.median(w)),
        "wall_p99": float(np.percentile(w, 99)),
        "cpu_p50": float(np.median(c)),
        "cpu_p99": float(np.percentile(c, 99)),
        "segment_cpu_p50": float(np.median(seg[len(scans) :]) * 1e3),
    }


def labelled_box_hits(layout: GridLayout, folder: Path) -> list[dict[str, Any]]:
    """Obstacle cells inside each labelled box (grown by half a cell of the box's level) per frame."""
    out = []
    for scan_path in sorted((folder / "velodyne").glob("*.bin")):
        calib = read_calibration(folder / "calib" / f"{scan_path.stem}.txt")
        grid = OccupancyGrid(layout)
        grid.update(read_kitti_bin(scan_path))
        cells = grid.snapshot().obstacle_cells()
        for b in read_labels(folder / "label_2" / f"{scan_path.stem}.txt", calib):
            if b.kind == "Misc":
                continue
            c, s = np.cos(b.yaw_rad), np.sin(b.yaw_rad)
            dx, dy = cells.xy_m[:, 0] - b.x_m, cells.xy_m[:, 1] - b.y_m
            u, v = np.abs(c * dx + s * dy), np.abs(-s * dx + c * dy)
            inside = (u <= b.length_m / 2 + cells.size_m / 2) & (v <= b.width_m / 2 + cells.size_m / 2)
            out.append(
                {
                    "frame": scan_path.stem,
                    "kind": b.kind,
                    "range_m": float(np.hypot(b.x_m, b.y_m)),
                    "cells": int(inside.sum()),
                }
            )
    return out


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument(
        "data", nargs="?", type=Path, default=Path(__file__).resolve().parents[4] / "shared/data/lidar_kitti"
    )
    args = p.parse_args(argv)
    scans = [read_kitti_bin(f) for f in sorted((args.data / "odometry_seq00_frames0-5").glob("*.bin"))]
    poses = registered_poses(scans)
    print("poses:", ", ".join(f"({q.x_m:.2f}, {q.y_m:.2f})" for q in poses))
    print("\n| layout | cells | band | cells hit | classifiable | band area with evidence |")
    print("|---|---|---|---|---|---|")
    for name, layout in LAYOUTS.items():
        for row in coverage(layout, scans, poses):
            print(
                f"| {name} | {layout.n_cells} | {row['band']} | {row['hit']:.0f} | {row['classifiable']:.2f} "
                f"| {row['known']:.4f} |"
            )
    print("\n| layout | update wall p50 / p99 ms | CPU p50 / p99 ms | snapshot + segment CPU p50 ms |")
    print("|---|---|---|---|")
    for name, layout in LAYOUTS.items():
        t = update_times_ms(layout, scans, poses)
        wall, cpu = f"{t['wall_p50']:.1f} / {t['wall_p99']:.1f}", f"{t['cpu_p50']:.1f} / {t['cpu_p99']:.1f}"
        print(f"| {name} | {wall} | {cpu} | {t['segment_cpu_p50']:.1f} |")
    objects = args.data / "object_frames"
    print("\n| layout | obstacle cells in each labelled box | P / R centre 2 m | P / R box 1 m |")
    print("|---|---|---|---|")
    for name, layout in LAYOUTS.items():
        hits = ", ".join(
            f"{h['kind']} {h['range_m']:.0f} m: {h['cells']}" for h in labelled_box_hits(layout, objects)
        )
        pr = []
        for match, d in (("centre", 2.0), ("box", 1.0)):
            prec, rec, tp, fp, fn = precision_recall(
                evaluate_object_frames(objects, layout, match=match, match_distance_m=d)
            )
            pr.append(f"{prec:.2f} / {rec:.2f} ({tp} TP, {fp} FP, {fn} FN)")
        print(f"| {name} | {hits} | {pr[0]} | {pr[1]} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
