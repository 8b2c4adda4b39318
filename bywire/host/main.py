"""`bywire host run [CONFIG]`: the host agent as its own process on the wall clock, talking to the ECU.

CONFIG is a host configuration (a shipped name such as `default`, or a file; schema in
docs/host_config.md); without it the scenario's `host.config` is used. Command-line bus URLs
override the file's.

Cooperative driving (issue 4, the `gcdc` configuration): `--v2x URL` is the V2X link (v2x://HOST:PORT UDP
broadcast), `--gps-serial PORT` the GPS/INS receiver's serial port (a device, a pty, a pyserial URL);
the odometry frames are read off the sensor bus by a second connection. V2V time stamps are UNIX time.
"""

from __future__ import annotations

import argparse
import json
import logging
import time
from pathlib import Path
from typing import Any

from bywire.clock import WallClock
from bywire.hil.process_util import StopFlag, wait_for_t0
from bywire.hil.scenario import load_scenario
from bywire.hil.trace import HOST_COLUMNS, TraceWriter
from bywire.host.agent import HostAgent
from bywire.host.config import load_host_config
from bywire.protocol.bus_url import open_bus
from bywire.protocol.canopen_link.host_master import HostMaster


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "config",
        nargs="?",
        help="host configuration: a shipped name (default, isolated_perception) or a YAML/TOML file "
        "(default: the scenario's host.config)",
    )
    p.add_argument(
        "--scenario", help="scenario whose mission drives the agent (default: the configuration's)"
    )
    p.add_argument(
        "--host-link", help="bus URL of the host<->ECU link (CANopen), CAN or Ethernet (udp://...)"
    )
    p.add_argument("--sensor-bus", help="bus URL where the radar frames arrive")
    p.add_argument(
        "--v2x", help="V2X link (v2x://HOST:PORT[?bind=..&iface=..]); default: the configuration's"
    )
    p.add_argument(
        "--gps-serial", help="GPS/INS serial port (path or pyserial URL); default: the configuration's"
    )
    p.add_argument(
        "--objects", help="object link (issue 5: pose + object list), udp://127.0.0.1:PORT or mem://NAME"
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
    p.add_argument("--seconds", type=float, help="stop after this long (default: the scenario's duration)")
    p.add_argument(
        "--rt-priority",
        type=int,
        default=0,
        help="SCHED_FIFO priority (0: normal scheduling); the HIL runner uses 72, below the ECU (80)",
    )


def main(args: argparse.Namespace) -> int:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    if args.config is not None:
        config = load_host_config(args.config)
        scenario = load_scenario(args.scenario or config.scenario)
    else:
        scenario = load_scenario(args.scenario or "demo")
        config = load_host_config(scenario.host_config)
    clock = WallClock()
    stop = StopFlag()
    link_bus = open_bus(args.host_link or config.ecu_link)
    sensor_url = args.sensor_bus or config.sensor_bus
    sensor_bus = open_bus(sensor_url) if sensor_url else None
    shared_sensor_bus: Any = sensor_bus
    trace = TraceWriter(args.trace, HOST_COLUMNS, flush_every=25)
    v2x_url = args.v2x or config.v2x
    gps_port = args.gps_serial or config.gps_serial
    v2x: Any = None
    gps: Any = None
    vehicle_bus = None
    objects: Any = None
    if args.objects:
        from bywire.protocol.objects import open_object_link

        objects = open_object_link(args.objects, receiver=True)
    if v2x_url:
        from bywire.protocol.v2x.transport import open_v2x

        v2x = open_v2x(v2x_url)
    if gps_port:
        from bywire.hil.world.links import SerialReader

        gps = SerialReader(gps_port, clock.now)
    if sensor_bus is not None and config.uses("vehicle_sensors"):
        # One connection to vehicle CAN, two readers: the radar adapter and the odometry adapter.
        from bywire.host.modules.fanout_bus import FanoutBus

        fanout = FanoutBus(sensor_bus)
        sensor_bus = fanout.view({0x300})  # type: ignore[assignment]  # RADAR_Target
        vehicle_bus = fanout.view({0x120, 0x121})  # GW_WheelSpeeds, GW_Motion
        shared_sensor_bus = fanout
    unix_offset = time.time() - time.monotonic()
    recorder: Any = None  # McapRecorder when asked for
    live: Any = None  # LiveView when asked for
    if args.rt_priority:
        from bywire.ecu.realtime import apply_realtime

        print(f"host: real-time: {apply_realtime(priority=args.rt_priority).summary()}", flush=True)
    agent: HostAgent | None = None
    try:
        link = HostMaster(link_bus, clock)
        agent = HostAgent(
            scenario,
            link,
            t0_s=0.0,  # set below, once the runner has said when the run starts
            sensor_bus=sensor_bus,
            trace=trace,
            config=config,
            clock=clock,
            lockstep=False,
            in_process_faults=False,
            v2x=v2x,
            gps=gps,
            vehicle_bus=vehicle_bus,  # type: ignore[arg-type]
            unix_time=lambda now: now + unix_offset,
            objects=objects,
        )
        if not agent.prestart():
            print("host: a worker process did not start; the supervisor will keep trying", flush=True)
        t0 = wait_for_t0(args.t0)
        agent.set_t0(t0)
        port = args.live_view if args.live_view is not None else config.live_view_port
        if port is not None:
            try:
                from bywire.host.runtime.live_view import LiveView
            except ImportError as exc:
                hint = "pip install 'bywire[live]'"
                raise SystemExit(f"the live view needs foxglove-sdk: {hint} ({exc})") from None

            live = LiveView(port)
            agent.store.add_tap(live.publish)
            print(f"host: live view for Foxglove on {live.url}", flush=True)
        if args.record is not None:
            from bywire.host.runtime.mcap_log import McapRecorder

            recorder = McapRecorder(args.record)
            agent.store.add_tap(recorder.record)
        end = t0 + (args.seconds if args.seconds is not None else scenario.duration_s + 2.0)
        clock.sleep_until(t0)
        agent.run_wall(end, stop)
    finally:
        if agent is not None:
            agent.close()
            if args.summary is not None:
                summary = agent.summary()
                gcdc = agent.gcdc_summary()
                if gcdc:
                    summary["gcdc"] = gcdc
                urban = agent.urban_summary()
                if urban:
                    summary["urban"] = urban
                args.summary.write_text(json.dumps(summary, indent=1, default=str), encoding="utf-8")
        if recorder is not None:
            recorder.close()
        if live is not None:
            live.close()
        trace.close()
        link_bus.shutdown()
        if shared_sensor_bus is not None:
            shared_sensor_bus.shutdown()
        if v2x is not None:
            v2x.close()
        if gps is not None:
            gps.close()
        if objects is not None:
            objects.close()
    return 0
