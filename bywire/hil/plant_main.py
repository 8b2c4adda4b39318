"""`bywire hil plant`: the plant as its own real-time process on the vehicle bus (1 kHz, wall clock).

With a world (cooperative driving): `--v2x URL` broadcasts the simulated vehicles' and road side's datagrams,
`--gps-fd N` writes the GPS receiver's NMEA to an inherited pty master, `--traffic-trace` and
`--world-summary` keep the per-vehicle trace and the bookkeeping, `--leader-profile CSV` replays a real
leader (see `hil.world.replay`). With an urban world: `--objects URL` sends our pose and the
object list (protocol/objects.py), `--urban-summary` keeps the world's bookkeeping. V2V generation times
are the wall clock's (UNIX) at scenario time t.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import gc
import json
import os
import time
from typing import Any

from bywire.clock import WallClock
from bywire.ecu.executive import CycleStats, CyclicExecutive
from bywire.hil.plant import Plant, PlantLinks
from bywire.hil.scenario import load_scenario, with_perception
from bywire.hil.scenario_vehicle import open_scenario_vehicle
from bywire.hil.trace import PLANT_COLUMNS
from bywire.hil.world.links import FdWriter
from bywire.hil.world.traffic import TRAFFIC_COLUMNS
from bywire.host.trace import TraceWriter
from bywire.process_util import StopFlag, wait_for_t0
from bywire.protocol.bus_url import open_bus
from bywire.realtime import apply_realtime
from bywire.stall_recorder import StallRecorder

PLANT_PERIOD_S = 0.001

STALL_STEP_S = 0.020  # twenty periods of the 1 kHz loop: two of the gateway's 10 ms reports


def main(args: argparse.Namespace) -> int:
    scenario = load_scenario(args.scenario)
    if args.perception is not None:
        scenario = with_perception(scenario, args.perception)
    if args.duration is not None:
        scenario = dataclasses.replace(scenario, duration_s=args.duration)
    if args.vehicle_profile is not None:
        scenario = dataclasses.replace(scenario, vehicle_profile=args.vehicle_profile)
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
    traffic = (
        TraceWriter(args.traffic_trace, TRAFFIC_COLUMNS, flush_every=200) if args.traffic_trace else None
    )
    v2x: Any = None
    objects: Any = None
    lidar: Any = None
    gps: FdWriter | None = None
    profile: tuple[tuple[float, float], ...] = ()
    if args.leader_profile is not None:
        from bywire.hil.world.replay import leader_profile_from_csv

        profile = leader_profile_from_csv(scenario, args.leader_profile)
    plant: Plant | None = None
    # A silence of the 1 kHz loop over STALL_STEP_S is a stall: recorded with what every thread was doing.
    stalls = StallRecorder(
        "plant", {"step": STALL_STEP_S}, rt_priority=args.rt_priority + 1 if args.rt_priority else 0
    )
    try:
        if args.v2x:
            from bywire.protocol.v2x.transport import open_v2x

            v2x = open_v2x(args.v2x, receive=False)
        if args.gps_fd is not None:
            gps = FdWriter(args.gps_fd)
        if args.objects:
            from bywire.protocol.objects import open_object_link

            objects = open_object_link(args.objects, receiver=False)
        if scenario.world is not None:
            # The V2V senders' ASN.1 compiles (~0.5 s of pyparsing) here, not in the first step:
            # seen in HIL, one held the plant's loop for 109 ms and the ECU stopped the car.
            from bywire.protocol.v2x.schemas import compile_all

            compile_all()
        # Collect the set-up's garbage now and keep what lives from the collector's passes: pyparsing's
        # finalizers, collected inside a step, held the loop for 85 ms in a loaded HIL run.
        if args.scans and scenario.urban is not None and scenario.urban.perception == "lidar":
            from bywire.hil.lidar.sensor_link import LidarProcess

            # the sensor's process and its scene (~1 s) before the run, not in its first steps
            lidar = LidarProcess(scenario.urban, scenario.seed, args.scans)
        gc.collect()
        gc.freeze()
        t0 = wait_for_t0(args.t0)
        t0_unix = t0 + (time.time() - time.monotonic())
        links = PlantLinks(
            v2x_send=v2x.send if v2x is not None else None,
            gps_write=gps.write if gps is not None else None,
            traffic_trace=traffic,
            unix_time=lambda t: t0_unix + t,
            replay_profile=profile,
            objects_send=objects.send if objects is not None else None,
            lidar=lidar,
        )
        plant = Plant(scenario, vehicle, bus, t0_s=t0, trace=trace, links=links)
        stats = CycleStats()
        end = t0 + scenario.duration_s
        step = plant.step

        def step_and_beat(deadline_s: float) -> None:
            step(deadline_s)
            stalls.beat("step")

        executive = CyclicExecutive(PLANT_PERIOD_S, clock, step_and_beat, stats)
        clock.sleep_until(t0)
        stalls.start()
        executive.run(stop=lambda: stop() or clock.now() >= end)
        snap: dict[str, Any] = stats.snapshot()
        print(
            f"plant: done, {snap['cycles']} cycles, {snap['overruns']} overruns, "
            f"lateness p99 {snap['lateness_us']['p99']:.0f} us",
            flush=True,
        )
    finally:
        stalls.close()
        if args.stalls is not None:
            args.stalls.write_text(json.dumps(stalls.summary(), indent=1), encoding="utf-8")
        trace.close()
        if traffic is not None:
            traffic.close()
        if plant is not None and plant.world is not None and args.world_summary is not None:
            args.world_summary.write_text(json.dumps(plant.world.summary(), indent=1), encoding="utf-8")
        if plant is not None and plant.urban is not None and args.urban_summary is not None:
            args.urban_summary.write_text(json.dumps(plant.urban.summary(), default=str), encoding="utf-8")
        if lidar is not None:
            lidar.close()
        if objects is not None:
            objects.close()
        if v2x is not None:
            v2x.close()
        if gps is not None:
            gps.close()
        vehicle.close()
        bus.shutdown()
    return 0
