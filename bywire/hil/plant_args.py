"""The command line of `bywire hil plant` (the plant process of a HIL run): its arguments alone, so that
`--help` and tab completion do not import the plant and its world (`hil.plant_main` runs it)."""

from __future__ import annotations

import argparse
from pathlib import Path

from bywire.protocol.vehicle_can import VEHICLE_PROFILES

__all__ = ["add_arguments"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", help="scenario name or file (its vehicle, plant and faults sections)")
    p.add_argument("--vehicle-bus", required=True, help="bus URL, e.g. remote:ws://127.0.0.1:54701/")
    p.add_argument("--trace", type=Path, help="CSV trace of the vehicle's ground truth")
    p.add_argument("--t0", help="start instant on CLOCK_MONOTONIC, or '-' to read it from stdin")
    p.add_argument("--duration", type=float, help="override the scenario's duration (s)")
    p.add_argument(
        "--vehicle-profile",
        choices=VEHICLE_PROFILES,
        help="what the vehicle CAN speaks, overriding the scenario's vehicle_profile: bywire (our "
        "gateway's reports) or pq (a VW PQ Passat's own messages)",
    )
    p.add_argument("--v2x", help="V2X link for the world's broadcasts, e.g. v2x://127.255.255.255:47100")
    p.add_argument(
        "--gps-fd", type=int, help="inherited file descriptor (pty master) for the GPS receiver's NMEA"
    )
    p.add_argument("--traffic-trace", type=Path, help="CSV trace of every vehicle of the world")
    p.add_argument(
        "--world-summary", type=Path, help="write the world's bookkeeping (gaps, TTC, collisions) as JSON"
    )
    p.add_argument(
        "--stalls", type=Path, help="write the stall recorder's evidence (gaps of the 1 kHz loop) as JSON"
    )
    p.add_argument("--leader-profile", type=Path, help="OpenACC or CARMA CSV: the replay vehicle's speed")
    p.add_argument("--objects", help="object link of an urban world, e.g. udp://127.0.0.1:47200")
    p.add_argument("--urban-summary", type=Path, help="write the urban world's bookkeeping as JSON")
    p.add_argument("--scans", help="LIDAR scan link of an urban world, e.g. tcp://127.0.0.1:47300")
    p.add_argument(
        "--perception", choices=("perfect", "lidar"), help="how the urban host perceives the traffic"
    )
    p.add_argument(
        "--rt-priority",
        type=int,
        default=0,
        help="SCHED_FIFO priority (default 0: normal scheduling at nice -10; see hil/runner.py for why)",
    )
