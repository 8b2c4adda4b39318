"""`bywire hil plant`: the plant as its own real-time process on the vehicle bus (1 kHz, wall clock)."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import os
from pathlib import Path
from typing import Any

from bywire.clock import WallClock
from bywire.ecu.executive import CycleStats, CyclicExecutive
from bywire.ecu.realtime import apply_realtime
from bywire.hil.plant import Plant
from bywire.hil.process_util import StopFlag, wait_for_t0
from bywire.hil.scenario import load_scenario
from bywire.hil.sil import open_scenario_vehicle
from bywire.hil.trace import PLANT_COLUMNS, TraceWriter
from bywire.protocol.bus_url import open_bus

PLANT_PERIOD_S = 0.001


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", help="scenario name or file (its vehicle, plant and faults sections)")
    p.add_argument("--vehicle-bus", required=True, help="bus URL, e.g. remote:ws://127.0.0.1:54701/")
    p.add_argument("--trace", type=Path, help="CSV trace of the vehicle's ground truth")
    p.add_argument("--t0", help="start instant on CLOCK_MONOTONIC, or '-' to read it from stdin")
    p.add_argument("--duration", type=float, help="override the scenario's duration (s)")
    p.add_argument(
        "--rt-priority",
        type=int,
        default=0,
        help="SCHED_FIFO priority (default 0: normal scheduling at nice -10; see hil/runner.py for why)",
    )


def main(args: argparse.Namespace) -> int:
    scenario = load_scenario(args.scenario)
    if args.duration is not None:
        scenario = dataclasses.replace(scenario, duration_s=args.duration)
    clock = WallClock()
    stop = StopFlag()
    bus = open_bus(args.vehicle_bus)
    trace = TraceWriter(args.trace, PLANT_COLUMNS, flush_every=100)
    vehicle = open_scenario_vehicle(scenario)
    if args.rt_priority:
        print(f"plant: real-time: {apply_realtime(priority=args.rt_priority).summary()}", flush=True)
    else:
        with contextlib.suppress(OSError):
            os.nice(-10)  # first among normal tasks, without counting against the RT budget
    try:
        t0 = wait_for_t0(args.t0)
        plant = Plant(scenario, vehicle, bus, t0_s=t0, trace=trace)
        stats = CycleStats()
        end = t0 + scenario.duration_s
        executive = CyclicExecutive(PLANT_PERIOD_S, clock, plant.step, stats)
        clock.sleep_until(t0)
        executive.run(stop=lambda: stop() or clock.now() >= end)
        snap: dict[str, Any] = stats.snapshot()
        print(
            f"plant: done, {snap['cycles']} cycles, {snap['overruns']} overruns, "
            f"lateness p99 {snap['lateness_us']['p99']:.0f} us",
            flush=True,
        )
    finally:
        trace.close()
        vehicle.close()
        bus.shutdown()
    return 0
