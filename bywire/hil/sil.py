"""SIL: plant, ECU and host in one process, in lockstep on a simulated clock (DESIGN section 1).

The same `Plant`, `EcuApp` and `HostAgent` classes as the three HIL processes, on python-can
`virtual` buses (tuned for lockstep, see `sil_bus`), stepped every simulated millisecond in a fixed
order: plant (sensors out), ECU (one 1 kHz cycle), host (every 20 ms). No threads, no wall clock:
two runs of one scenario give identical traces.

A scenario with a world (cooperative driving) also gets the links the world speaks to the host, in process and
deterministic: the V2X radio as an in-process broadcast domain (`mem://sil-v2x-TAG`, receptions stamped
with the scenario's epoch + simulated time), the GPS receiver's serial line as a `BytePipe`, and a
second host reader of vehicle CAN for the odometry frames (wheel speeds, yaw rate).

An urban scenario gets the object link in process (`protocol.objects.MemObjectLink`): the plant's
urban world sends our pose and the object list, the host's `urban_io` reads them, in order. With
`perception: lidar` the plant casts the simulated Velodyne's revolutions in its step and the host's
`lidar_io` reads them off an in-process scan link (`protocol.lidar.scan_link.MemScanLink`).
"""

from __future__ import annotations

import time
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
import numpy as np

from bywire.clock import SimClock
from bywire.ecu.app import EcuApp, EcuConfig
from bywire.hil.host_inputs import host_inputs
from bywire.hil.module_faults import ModuleFaultInjector
from bywire.hil.plant import Plant, PlantLinks
from bywire.hil.recording import Recorder
from bywire.hil.run_calibration import load_run_calibration
from bywire.hil.scenario import Scenario, scenario_host_config
from bywire.hil.scenario_vehicle import open_scenario_vehicle
from bywire.hil.service_tool import ServiceTool
from bywire.hil.sil_bus import SimVirtualBus
from bywire.hil.sil_ecu import QuietCycleStepper
from bywire.hil.trace import PLANT_COLUMNS
from bywire.hil.world.links import BytePipe
from bywire.hil.world.traffic import TRAFFIC_COLUMNS
from bywire.host.agent import HostAgent
from bywire.host.trace import HOST_COLUMNS, TraceWriter
from bywire.protocol.canopen_link.host_master import HostMaster
from bywire.protocol.vehicle_can import VehicleCodec

ECU_PERIOD_S = 0.001
RADAR_MESSAGES = ("RADAR_Target",)
ODOMETRY_MESSAGES = ("GW_WheelSpeeds", "GW_Motion")


def _filters(dbc: VehicleCodec, messages: tuple[str, ...]) -> list[dict[str, Any]]:
    """python-can receive filters passing exactly these DBC messages."""
    return [{"can_id": dbc.info(m).frame_id, "can_mask": 0x7FF, "extended": False} for m in messages]


@dataclass
class RunResult:
    plant: dict[str, np.ndarray]
    host: dict[str, np.ndarray] | None
    extra: dict[str, Any] = field(default_factory=dict)
    traffic: dict[str, np.ndarray] | None = None  # the world's per-vehicle trace (hil.world.traffic)


def run_sil(
    scenario: Scenario,
    run_dir: Path | None = None,
    record: Path | None = None,
    progress: Callable[[float], None] | None = None,
    leader_profile: Sequence[tuple[float, float]] = (),
    quiet_ecu: bool = True,
) -> RunResult:
    """Run `scenario` in lockstep and return the traces (also written to `run_dir` when given).
    `leader_profile` replaces the speed of the world's `replay` vehicle (`--leader-profile CSV`).
    `quiet_ecu=False` runs every ECU cycle in full (the reference `sil_ecu` is held equal to)."""
    clock = SimClock(0.0)
    tag = uuid.uuid4().hex[:8]
    vehicle_ch, link_ch = f"sil-vehicle-{tag}", f"sil-link-{tag}"
    buses: list[can.BusABC] = []

    def bus(channel: str, **kwargs: Any) -> SimVirtualBus:
        b = SimVirtualBus(channel, clock, **kwargs)
        buses.append(b)
        return b

    recorder = None
    if record is not None:
        recorder = Recorder(record, {"vehicle": bus(vehicle_ch), "host_link": bus(link_ch)})
    cal, cal_error = load_run_calibration(scenario, run_dir)
    plant_trace = TraceWriter(run_dir / "plant.csv" if run_dir else None, PLANT_COLUMNS, flush_every=1000)
    host_trace = TraceWriter(run_dir / "host.csv" if run_dir else None, HOST_COLUMNS, flush_every=1000)
    vehicle = open_scenario_vehicle(scenario)
    host: HostAgent | None = None
    world = scenario.world
    traffic_trace = TraceWriter(
        run_dir / "traffic.csv" if run_dir and (world or scenario.lead) else None,
        TRAFFIC_COLUMNS,
        flush_every=1000,
    )
    links = PlantLinks(traffic_trace=traffic_trace, replay_profile=tuple(leader_profile))
    v2x_host: Any = None
    v2x_plant: Any = None
    gps_pipe: BytePipe | None = None
    if world is not None:
        from bywire.protocol.v2x.codec import remember_own_encodings
        from bywire.protocol.v2x.transport import MemV2xTransport

        remember_own_encodings()  # the simulated senders and the host share this process
        epoch = world.v2v.epoch_unix_s
        v2x_plant = MemV2xTransport(f"mem://sil-v2x-{tag}", receive=False)
        v2x_host = MemV2xTransport(f"mem://sil-v2x-{tag}", clock=lambda: epoch + clock.now())
        gps_pipe = BytePipe()
        links.v2x_send = v2x_plant.send
        links.gps_write = gps_pipe.write
        links.unix_time = lambda t: epoch + t
    objects_link: Any = None
    if scenario.urban is not None:
        from bywire.protocol.objects import MemObjectLink

        objects_link = MemObjectLink(f"sil-objects-{tag}")
        links.objects_send = objects_link.send
    scans_link: Any = None
    if scenario.urban is not None and scenario.urban.perception == "lidar":
        from bywire.protocol.lidar.scan_link import MemScanLink

        scans_link = MemScanLink(f"sil-scans-{tag}")
        links.scans_send = scans_link.send
    try:
        plant = Plant(scenario, vehicle, bus(vehicle_ch), t0_s=0.0, trace=plant_trace, links=links)
        ecu = EcuApp(
            bus(vehicle_ch),
            bus(link_ch),
            clock,
            cal,
            cal_error,
            EcuConfig(),
            vehicle_profile=scenario.vehicle_profile,
        )
        ecu_stepper = QuietCycleStepper(ecu, enabled=quiet_ecu)
        link = HostMaster(bus(link_ch), clock)
        host = HostAgent(
            host_inputs(scenario),
            link,
            t0_s=0.0,
            config=scenario_host_config(scenario),
            faults=ModuleFaultInjector(scenario, 0.0),
            sensor_bus=bus(vehicle_ch, can_filters=_filters(plant.codec, RADAR_MESSAGES)),
            trace=host_trace,
            clock=clock,
            v2x=v2x_host,
            gps=gps_pipe,
            vehicle_bus=(
                bus(vehicle_ch, can_filters=_filters(plant.codec, ODOMETRY_MESSAGES))
                if world is not None
                else None
            ),
            unix_time=(lambda now: world.v2v.epoch_unix_s + now) if world is not None else None,
            objects=objects_link,
            scans=scans_link,
        )
        if recorder is not None and recorder.mcap is not None:
            host.store.add_tap(recorder.mcap.record)  # topics and frames in one file, one clock
        # The ECU's own faults: its loop not stepped (a stall), a service tool's unlatch on the link.
        stalls = [(f.at_s, f.at_s + f.duration_s) for f in scenario.faults_of("loop_stall")]
        unlatches = sorted(f.at_s for f in scenario.faults_of("unlatch"))
        service = ServiceTool(bus(link_ch)) if unlatches else None
        n = round(scenario.duration_s / ECU_PERIOD_S)
        wall0 = time.perf_counter()
        # progress every 0.1 s simulated: a terminal's line and an interrupted run's JSON say how far
        report_every = max(1, round(0.1 / ECU_PERIOD_S))
        for k in range(n + 1):
            t = k * ECU_PERIOD_S
            clock.advance_to(t)
            plant.step(t)
            if not stalls or not any(a <= t < b for a, b in stalls):
                ecu_stepper.step(t)
            if service is not None:
                if unlatches and t >= unlatches[0]:
                    service.send_unlatch(unlatches.pop(0))
                service.poll(t)
            host.step(t)
            if recorder is not None:
                recorder.pump()
            if progress is not None and k % report_every == 0:
                progress(t / scenario.duration_s)
        ecu_stepper.settle()
        wall = time.perf_counter() - wall0
        extra: dict[str, Any] = {
            "real_time_factor": round(scenario.duration_s / wall, 2) if wall > 0 else None,
            "ecu_vehicle_rx": ecu.rx_stats()["total"],
            "ecu_health": ecu.health_summary(),
            "plant_collisions": plant.collisions,
            "host_runtime": host.summary(),
        }
        if service is not None:
            extra["service_tool"] = service.summary()
        if plant.world is not None:
            extra["world"] = plant.world.summary()
        if world is not None:
            extra["gcdc"] = host.gcdc_summary()
        if plant.urban is not None:
            extra["urban"] = plant.urban.summary()
            extra["urban_host"] = host.urban_summary()
    finally:
        if host is not None:
            host.close()
        plant_trace.close()
        host_trace.close()
        traffic_trace.close()
        for lk in (objects_link, scans_link):
            if lk is not None:
                lk.close()
        for t in (v2x_host, v2x_plant):
            if t is not None:
                t.close()
        if recorder is not None:
            recorder.close()
        vehicle.close()
        for b in buses:
            b.shutdown()
    traffic = traffic_trace.array() if traffic_trace.rows else None
    return RunResult(plant=plant_trace.array(), host=host_trace.array(), extra=extra, traffic=traffic)
