"""The command line of `bywire host run`: its arguments alone, so that `--help` and tab completion do
not import the host agent (numpy, scipy, the modules) to show them (`host.main` runs it)."""

from __future__ import annotations

import argparse
from pathlib import Path

__all__ = ["add_arguments"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "config",
        nargs="?",
        help="host configuration: a shipped name (default, gcdc, urban, urban_lidar, isolated_perception) "
        "or a YAML/TOML file (default: `default`; with --scenario: the scenario's host.config)",
    )
    mission = p.add_argument_group("mission (what the driver gives the car)")
    mission.add_argument("--rndf", type=Path, help="urban driving: the road network (DARPA RNDF)")
    mission.add_argument("--mdf", type=Path, help="urban driving: the mission on it (DARPA MDF)")
    mission.add_argument(
        "--lane-map",
        type=Path,
        help="platooning: the lane map (`bywire platoon record-map`); its origin anchors the local frame",
    )
    cmd = mission.add_mutually_exclusive_group()
    cmd.add_argument("--commands", type=Path, help="the driver's command script (YAML; host.command_script)")
    cmd.add_argument("--cruise", type=float, metavar="V", help="ask to engage and cruise at V m/s")
    p.add_argument(
        "--scenario",
        help="simulator only: drive a HIL scenario's script and faults instead of a car's mission",
    )
    p.add_argument(
        "--host-link", help="bus URL of the host<->ECU link (CANopen), CAN or Ethernet (udp://...)"
    )
    p.add_argument("--sensor-bus", help="bus URL of vehicle CAN (radar frames, wheel speeds)")
    p.add_argument(
        "--v2x", help="V2X link (v2x://HOST:PORT[?bind=..&iface=..]); default: the configuration's"
    )
    p.add_argument(
        "--gps-serial", help="GPS/INS serial port (path or pyserial URL); default: the configuration's"
    )
    p.add_argument("--objects", help="object link (pose + object list), udp://127.0.0.1:PORT or mem://NAME")
    p.add_argument("--scans", help="LIDAR scan link (revolutions), tcp://127.0.0.1:PORT or mem://NAME")
    p.add_argument(
        "--perception",
        choices=("perfect", "lidar"),
        help="simulator only, with --scenario: perceive an urban scenario's traffic this way",
    )
    p.add_argument("--trace", type=Path, help="CSV trace of the host's requests")
    p.add_argument("--summary", type=Path, help="write module timing and supervisor events as JSON at exit")
    p.add_argument("--record", type=Path, help="record every topic to this MCAP file")
    p.add_argument(
        "--live-view",
        type=int,
        metavar="PORT",
        help="serve every topic live to Foxglove (ws://127.0.0.1:PORT; default: the configuration's, off)",
    )
    p.add_argument("--t0", help="start instant on CLOCK_MONOTONIC, or '-' to read it from stdin")
    p.add_argument("--seconds", type=float, help="stop after this long (default: until stopped)")
    p.add_argument(
        "--rt-priority",
        type=int,
        default=0,
        help="SCHED_FIFO priority (0: normal scheduling); the HIL runner uses 72, below the ECU (80)",
    )
