"""Lane markers and the map's offset per LIDAR revolution, timed on the shared KITTI scans.

Seed 000 section 6. The six scans of KITTI odometry 00 (frames 0-5, about 124 000 points each) are fed
round and round, the car moving 0.72 m per revolution along x (the scans' registration), so that the
marker image holds what a drive holds. Rows (min / median / p99 / max in ms, all in one process so
that machine load hits every row alike; the min is the cost when the process had a core to itself):

- ``extract``: `extract_features` (road plane, paint, curbs) of one revolution;
- ``accumulate``: `LaneMarkerMap.add`: the grid's shift, decay and deposit of those features;
- ``spectrum``: `RadonSpectrum` of the 256 x 256 marker image (one 512 x 512 real FFT);
- ``offset``: `measure_offset` on that spectrum: the direction within 4 deg of the map lane's, its
  lines, the votes;
- ``dominant``: `dominant_normal` over all directions (what `find_lines` does without a map), for
  comparison with ``offset``'s windowed search;
- ``total``: `LaneOffsetEstimator.update`: one revolution in, the filtered offset out (extract +
  accumulate + spectrum + offset + filter).

The budget (DESIGN.md section 4, perception at 10 Hz): the marker update with its Radon about 10 ms of
the 30 ms p99 a perception frame has on these 2 cores. Nothing here is asserted. Run with
``python -m benchmarks.lane_markers [--seconds S] [--json FILE]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.timed import add_timed_arguments, run_timed

DEFAULT_SECONDS = 10.0
FRAME_STEP_M = 0.72
ROWS = ("extract", "accumulate", "spectrum", "offset", "dominant", "total")


def kitti_dir() -> Path:
    env = os.environ.get("BYWIRE_SHARED_DATA")
    if env:
        return Path(env) / "lidar_kitti" / "odometry_seq00_frames0-5"
    beside = Path(__file__).resolve().parents[2] / "shared" / "data"
    base = beside if beside.exists() else Path("/work/shared/data")
    return base / "lidar_kitti" / "odometry_seq00_frames0-5"


def _stats(samples_s: list[float]) -> dict[str, float]:
    ms = np.asarray(samples_s) * 1e3
    return {
        "min_ms": float(ms.min()),
        "median_ms": float(np.median(ms)),
        "p99_ms": float(np.percentile(ms, 99)),
        "max_ms": float(ms.max()),
        "n": int(ms.size),
    }


def run(seconds: float) -> dict[str, Any]:
    from bywire.host.lateral import VehiclePose
    from bywire.host.perception.lane_markers import LaneMarkerMap, extract_features, warm_up
    from bywire.host.perception.lane_offset import LaneOffsetEstimator, measure_offset
    from bywire.host.perception.radon import RadonSpectrum, dominant_normal
    from bywire.host.perception.scan import read_kitti_bin

    files = sorted(kitti_dir().glob("*.bin"))
    if not files:
        raise SystemExit(f"no KITTI scans in {kitti_dir()} (set BYWIRE_SHARED_DATA)")
    scans = [read_kitti_bin(f) for f in files]
    warm_up()  # the compiled kernels, loaded before the clock runs (as the host's module does)
    centreline = np.array([[-1000.0, 0.0], [1000.0, 0.0]])  # a map lane along x
    markers = LaneMarkerMap()
    estimator = LaneOffsetEstimator()
    samples: dict[str, list[float]] = {row: [] for row in ROWS}
    t_end = time.perf_counter() + seconds
    k = 0
    while time.perf_counter() < t_end or k < 12:
        scan = scans[k % len(scans)]
        pose = VehiclePose(FRAME_STEP_M * k, 0.0, 0.0)
        stamp = 0.1 * k
        scan = dataclasses.replace(scan, stamp_s=stamp)

        t0 = time.perf_counter()
        feats = extract_features(scan)
        t1 = time.perf_counter()
        markers.add(feats, pose, stamp)
        t2 = time.perf_counter()
        spec = RadonSpectrum(markers.grid.image, markers.grid.cell_m, disc=True)
        t3 = time.perf_counter()
        measure_offset(markers.grid, centreline, 3.5, spectrum=spec)
        t4 = time.perf_counter()
        dominant_normal(spec)
        t5 = time.perf_counter()
        estimator.update(scan, pose, centreline, 3.5)
        t6 = time.perf_counter()

        samples["extract"].append(t1 - t0)
        samples["accumulate"].append(t2 - t1)
        samples["spectrum"].append(t3 - t2)
        samples["offset"].append(t4 - t3)
        samples["dominant"].append(t5 - t4)
        samples["total"].append(t6 - t5)
        k += 1
    return {
        "revolutions": k,
        "points_per_revolution": int(np.mean([len(s) for s in scans])),
        "rows": {row: _stats(v) for row, v in samples.items()},
        "load_average": os.getloadavg()[0] if hasattr(os, "getloadavg") else math.nan,
    }


def print_table(doc: dict[str, Any]) -> None:
    print(
        f"lane markers per KITTI revolution ({doc['points_per_revolution']} points, "
        f"{doc['revolutions']} revolutions, load average {doc['load_average']:.1f})"
    )
    print(f"{'row':<12}{'min ms':>8}{'median ms':>11}{'p99 ms':>9}{'max ms':>9}")
    for row, st in doc["rows"].items():
        print(
            f"{row:<12}{st['min_ms']:>8.2f}{st['median_ms']:>11.2f}{st['p99_ms']:>9.2f}{st['max_ms']:>9.2f}"
        )


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_timed_arguments(p, DEFAULT_SECONDS, "to time the revolutions")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.lane_markers", description=__doc__.splitlines()[0])
    add_arguments(p)
    return run_timed(p.parse_args(argv), "lane-markers", DEFAULT_SECONDS, run, print_table)


if __name__ == "__main__":
    raise SystemExit(main())
