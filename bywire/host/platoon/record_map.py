"""`bywire platoon record-map NMEA_LOG -o map.json`: a lane map from a drive along the lane (seed 003 IV-A).

Seed 003 IV-A recorded the map a priori by driving the right lane with the RTK GPS: here the receiver's
NMEA log (a file of sentences as the serial line gave them, e.g. `cat /dev/ttyUSB0 > drive.nmea`) is
decoded by the pose server's strict NMEA decoder; the GGA fixes (RTK fixed or float by default) become
the lane through `host.world.lanemap.record_lane` (0.5 m segments, light smoothing), the local plane's
origin at the first fix (or `--origin LAT,LON`, which a scenario's road origin must match); further lanes
at `--lane-width` to the left (`--lanes N`). The JSON is the mission `bywire host run gcdc --lane-map FILE`
drives on (or a `world_model` module's `map_file`).
Bad input gets a clear error: no usable fix, a track shorter than one segment, an unreadable file.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from bywire.host.geo import LocalFrame
from bywire.host.world.lanemap import LaneMapError, record_lane
from bywire.host.world.nmea import FixQuality, Gga, NmeaStream

RTK_QUALITIES = (FixQuality.RTK_FIXED, FixQuality.RTK_FLOAT)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("nmea_log", type=Path, help="NMEA 0183 log of a drive along the right lane")
    p.add_argument("-o", "--output", type=Path, required=True, help="lane map JSON to write")
    p.add_argument("--origin", help="LAT,LON of the local plane's origin (default: the first fix)")
    p.add_argument("--lanes", type=int, default=1, help="lanes: the recorded one plus N-1 to its left")
    p.add_argument("--lane-width", type=float, default=3.5, help="lane width in m (seed 003: 3.5)")
    p.add_argument("--any-fix", action="store_true", help="accept GPS and DGPS fixes too, not only RTK")


def track_from_nmea(data: bytes, any_fix: bool = False) -> np.ndarray:
    """(N, 2) lat/lon of the usable GGA fixes, in order; ValueError when there are none."""
    stream = NmeaStream()
    fixes = []
    for rec in stream.feed(data):
        if not isinstance(rec, Gga) or rec.lat_deg is None or rec.lon_deg is None:
            continue
        if rec.quality == FixQuality.INVALID or (not any_fix and rec.quality not in RTK_QUALITIES):
            continue
        fixes.append((rec.lat_deg, rec.lon_deg))
    if not fixes:
        dropped = dict(stream.drops)
        raise ValueError(f"no usable GGA fix (RTK only unless --any-fix); dropped sentences: {dropped}")
    return np.asarray(fixes, dtype=np.float64)


def main(args: argparse.Namespace) -> int:
    try:
        data = args.nmea_log.read_bytes()
    except OSError as exc:
        print(f"error: {args.nmea_log}: {exc}")
        return 2
    try:
        track = track_from_nmea(data, args.any_fix)
        frame = None
        if args.origin:
            lat, lon = (float(v) for v in args.origin.split(","))
            frame = LocalFrame(lat, lon)
        lanemap = record_lane(track, frame, geodetic=True)
        for k in range(1, max(1, args.lanes)):
            lanemap = lanemap.with_offset_lane(0, k * args.lane_width, k, name=f"lane{k}")
    except (ValueError, LaneMapError) as exc:
        print(f"error: {args.nmea_log}: {exc}")
        return 2
    lanemap.save(args.output)
    print(
        f"{args.output}: {len(lanemap.lanes)} lane(s), {lanemap.n_vertices} vertices from {len(track)} fixes"
    )
    return 0


__all__ = ["add_arguments", "main", "track_from_nmea"]
