"""`bywire host run`: the host agent as its own process (wall clock), talking to the ECU over the link."""

from __future__ import annotations

import argparse
from pathlib import Path

from bywire.clock import WallClock
from bywire.hil.process_util import StopFlag, wait_for_t0
from bywire.hil.scenario import load_scenario
from bywire.hil.trace import HOST_COLUMNS, TraceWriter
from bywire.host.agent import HostAgent
from bywire.protocol.bus_url import open_bus
from bywire.protocol.canopen_node import HostMaster


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--scenario", default="demo", help="scenario whose host section drives the agent (default demo)"
    )
    p.add_argument(
        "--host-link",
        default="udp://127.0.0.1:47001?peer=127.0.0.1:47000",
        help="bus URL of the host<->ECU link (CANopen), CAN or Ethernet (udp://...)",
    )
    p.add_argument("--sensor-bus", help="bus URL where the radar frames arrive (optional)")
    p.add_argument("--trace", type=Path, help="CSV trace of the host's requests")
    p.add_argument("--t0", help="start instant on CLOCK_MONOTONIC, or '-' to read it from stdin")
    p.add_argument("--seconds", type=float, help="stop after this long (default: the scenario's duration)")
    p.add_argument(
        "--rt-priority",
        type=int,
        default=0,
        help="SCHED_FIFO priority (0: normal scheduling); the HIL runner uses 72, below the ECU (80)",
    )


def main(args: argparse.Namespace) -> int:
    scenario = load_scenario(args.scenario)
    clock = WallClock()
    stop = StopFlag()
    link_bus = open_bus(args.host_link)
    sensor_bus = open_bus(args.sensor_bus) if args.sensor_bus else None
    trace = TraceWriter(args.trace, HOST_COLUMNS, flush_every=25)
    if args.rt_priority:
        from bywire.ecu.realtime import apply_realtime

        print(f"host: real-time: {apply_realtime(priority=args.rt_priority).summary()}", flush=True)
    try:
        link = HostMaster(link_bus, clock)
        t0 = wait_for_t0(args.t0)
        agent = HostAgent(
            scenario, link, t0_s=t0, sensor_bus=sensor_bus, trace=trace, in_process_faults=False
        )
        end = t0 + (args.seconds if args.seconds is not None else scenario.duration_s + 2.0)
        clock.sleep_until(t0)
        while not stop() and clock.now() < end:
            agent.step(clock.now())
            clock.sleep_until(agent.next_due_s)  # frames wait in the socket until the next 20 ms step
    finally:
        trace.close()
        link_bus.shutdown()
        if sensor_bus is not None:
            sensor_bus.shutdown()
    return 0
