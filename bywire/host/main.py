"""`bywire host run CONFIG`: the host agent as its own process on the wall clock, talking to the ECU.

CONFIG is a host configuration (a shipped name such as `default`, `gcdc`, `urban`, or a file; schema in
docs/host_config.md). The mission is what a car's driver gives it: `--rndf F --mdf F` (urban driving,
seed 000 section 7), `--lane-map F` (platooning on a lane recorded with `bywire platoon record-map`,
seed 003 section IV-A; its origin is the local frame's), and the driver's commands (`--commands F`, a
`host.command_script` file, or `--cruise V`). Without commands the host asks to engage only to
drive a route (--rndf/--mdf).
Command-line bus URLs override the configuration's: `--host-link` (the ECU, CANopen over CAN or
UDP), `--sensor-bus` (vehicle CAN: radar, wheel speeds), `--v2x` (v2x://HOST:PORT UDP broadcast),
`--gps-serial` (the GPS/INS receiver's port: a device, a pty, a pyserial URL). V2V time stamps are
UNIX time.

Nothing here knows the simulator: `bywire host run --scenario NAME` (the HIL runner's) is the same entry
with the inputs and fault hooks the simulator builds from a scenario (`hil.host_process`).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import time
from typing import Any

from bywire.clock import WallClock
from bywire.host.agent import HostAgent
from bywire.host.command_script import CommandScript, cruise, load_command_script
from bywire.host.config import HostConfig, load_host_config
from bywire.host.inputs import HostFaultHooks, HostInputs, lane_map_file
from bywire.host.main_args import add_arguments as add_arguments  # the command line's, re-exported
from bywire.host.trace import HOST_COLUMNS, TraceWriter
from bywire.process_util import StopFlag, wait_for_t0
from bywire.protocol.bus_url import open_bus
from bywire.protocol.canopen_link.host_master import HostMaster
from bywire.protocol.vehicle_can import VehicleCodec
from bywire.stall_recorder import StallRecorder

STALL_SCHEDULER_S = 0.020  # the scheduler ticks every millisecond: a whole module period without it
STALL_ECU_LINK_S = 0.050  # the ECU link sends every 20 ms; half the ECU's 100 ms watchdog without it


def scene_tap(live: Any) -> Any:
    """A store tap that shows the urban host's world in the live view's 3D panel (`modules.scene_view`):
    one converter, called under a lock (taps run in the publishers' threads). It costs the publishing
    module the conversion (a few ms per revolution and grid); the live view is off unless asked for."""
    import threading

    from bywire.host.modules.scene_view import SOURCE_TOPICS, SceneConverter
    from bywire.host.runtime.log_schema import object_time_ns

    converter = SceneConverter()
    lock = threading.Lock()

    def tap(topic: str, obj: Any) -> None:
        if topic not in SOURCE_TOPICS:
            return
        with lock:
            out = converter.convert(topic, obj)
        for scene_topic, msg in out:
            live.publish_message(scene_topic, msg, object_time_ns(obj, live.url, topic))

    return tap


def car_inputs(args: argparse.Namespace) -> HostInputs:
    """The mission a car's command line gives (see the module docstring)."""
    if (args.rndf is None) != (args.mdf is None):
        raise SystemExit("host run: --rndf and --mdf go together (the road network and the mission on it)")
    for flag, path in (("--rndf", args.rndf), ("--mdf", args.mdf), ("--lane-map", args.lane_map)):
        if path is not None and not path.is_file():
            raise SystemExit(f"host run: {flag}: no such file {path}")
    # A route to drive is the driver's wish to drive it: the host asks to engage from the start (the
    # ECU engages only once its driver has armed it). With nothing to drive it asks for nothing.
    commands = CommandScript(engage_at_s=0.0 if args.rndf is not None else math.inf)
    if args.commands is not None:
        commands = load_command_script(args.commands)
    elif args.cruise is not None:
        commands = cruise(args.cruise)
    parts = [
        f"{k}={v}" for k, v in (("rndf", args.rndf), ("mdf", args.mdf), ("lane_map", args.lane_map)) if v
    ]
    parts.append(f"commands={commands.source}")
    return HostInputs(
        commands=commands,
        rndf=str(args.rndf) if args.rndf is not None else None,
        mdf=str(args.mdf) if args.mdf is not None else None,
        lane_map=lane_map_file(args.lane_map) if args.lane_map is not None else None,
        source="bywire host run " + " ".join(parts),
        source_text=json.dumps({k: str(v) for k, v in vars(args).items() if v is not None}, sort_keys=True),
    )


def main(args: argparse.Namespace) -> int:
    if args.scenario is not None:
        raise SystemExit("host run: --scenario needs the simulator (run it as `bywire host run`)")
    if args.perception is not None:
        raise SystemExit("host run: --perception belongs to a simulated scenario (--scenario)")
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    config = load_host_config(args.config or "default")
    return run_host(args, config, car_inputs(args))


def run_host(
    args: argparse.Namespace, config: HostConfig, inputs: HostInputs, faults: HostFaultHooks | None = None
) -> int:
    """Run the host on the wall clock until `--seconds`, the mission's end, or SIGINT/SIGTERM."""
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
    scans: Any = None
    if args.scans:
        from bywire.protocol.lidar.scan_link import open_scan_link

        scans = open_scan_link(args.scans, receiver=True)
    if v2x_url:
        from bywire.protocol.v2x.transport import open_v2x

        v2x = open_v2x(v2x_url)
    if gps_port:
        from bywire.host.world.serial_link import SerialReader

        gps = SerialReader(gps_port, clock.now)
    if sensor_bus is not None and config.uses("vehicle_sensors"):
        # One connection to vehicle CAN, two readers: the radar adapter and the odometry adapter.
        from bywire.host.modules.io.fanout_bus import FanoutBus

        fanout = FanoutBus(sensor_bus)
        dbc = VehicleCodec()
        sensor_bus = fanout.view({dbc.info("RADAR_Target").frame_id})  # type: ignore[assignment]
        vehicle_bus = fanout.view({dbc.info("GW_WheelSpeeds").frame_id, dbc.info("GW_Motion").frame_id})
        shared_sensor_bus = fanout
    unix_offset = time.time() - time.monotonic()
    recorder: Any = None  # McapRecorder when asked for
    live: Any = None  # LiveView when asked for
    if args.rt_priority:
        from bywire.realtime import apply_realtime

        print(f"host: real-time: {apply_realtime(priority=args.rt_priority).summary()}", flush=True)
    # Silences of the scheduler and the ECU link are stalls, recorded with what every thread was doing
    # (the ECU stops the car after 100 ms without the link).
    stalls = StallRecorder(
        "host",
        {"scheduler": STALL_SCHEDULER_S, "ecu_link": STALL_ECU_LINK_S},
        rt_priority=args.rt_priority + 1 if args.rt_priority else 0,
    )
    agent: HostAgent | None = None
    try:
        link = HostMaster(link_bus, clock)
        agent = HostAgent(
            inputs,
            link,
            t0_s=0.0,  # set below, once the runner has said when the run starts
            config=config,
            sensor_bus=sensor_bus,
            trace=trace,
            clock=clock,
            lockstep=False,
            faults=faults,
            v2x=v2x,
            gps=gps,
            vehicle_bus=vehicle_bus,  # type: ignore[arg-type]
            unix_time=lambda now: now + unix_offset,
            objects=objects,
            scans=scans,
            heartbeat_sent=lambda now: stalls.beat("ecu_link", now),
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
            agent.store.add_tap(scene_tap(live))  # the urban host's topics as a 3D scene
            print(f"host: live view for Foxglove on {live.url}", flush=True)
        if args.record is not None:
            from bywire.host.runtime.mcap_recorder import McapRecorder

            recorder = McapRecorder(args.record)
            agent.store.add_tap(recorder.record)
        seconds = args.seconds if args.seconds is not None else inputs.duration_s
        end = t0 + seconds if seconds is not None else float("inf")
        stalls.start()  # it records nothing until the first beat
        clock.sleep_until(t0)
        agent.run_wall(end, stop, beat=lambda now: stalls.beat("scheduler", now))
    finally:
        stalls.close()
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
                summary["stalls"] = stalls.summary()
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
        for lk in (objects, scans):
            if lk is not None:
                lk.close()
    return 0
