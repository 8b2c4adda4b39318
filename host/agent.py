"""The host agent of the spine: ECU link, odometry, radar lead target and longitudinal control.

Only what the spine's demo needs (issue 2, part 6); the runtime with modules and a supervisor comes
later. Every 20 ms (50 Hz, DESIGN section 4: host -> ECU requests 25-100 Hz) it reads the ECU status
and the radar, computes an acceleration request — scripted for ECU tests, or from the longitudinal
override controller of seed 000 section 11.2 to cruise a speed profile, follow a lead car and stop at
a line — and sends it with its heartbeat over the CANopen link.
"""

from __future__ import annotations

from dataclasses import dataclass

import can

from bywire.hil.scenario import Scenario, ramp_value, step_value
from bywire.hil.trace import CONTROLLERS, HOST_COLUMNS, TraceWriter
from bywire.host.longitudinal import (
    LeadObservation,
    LongitudinalInputs,
    LongitudinalParams,
    LongitudinalState,
    longitudinal_step,
)
from bywire.protocol.canopen_node import HostMaster, NmtState
from bywire.protocol.ecu_types import EcuState, Fault, RequestFlags
from bywire.protocol.host_link import HostRequest
from bywire.protocol.timebase import rx_time_s
from bywire.protocol.vehicle_can import RadarTarget, VehicleCodec, VehicleRx

HOST_PERIOD_S = 0.020
REARM_PULSE_S = 0.1  # long enough for the ECU to see a rising edge through a lost frame or two
RADAR_STALE_S = 0.25
NMT_START_RETRY_S = 0.2  # 5 radar cycles without a target: treat the lane as free


@dataclass
class HostState:
    counter: int = 0
    odometer_m: float = 0.0
    last_status_s: float | None = None
    last_speed_mps: float = 0.0
    stopped: bool = False  # host frozen / killed in SIL: nothing more is sent


class HostAgent:
    """Steppable host: call `step(now_s)` at least every millisecond or on its own 20 ms period."""

    def __init__(
        self,
        scenario: Scenario,
        link: HostMaster,
        t0_s: float,
        sensor_bus: can.BusABC | None = None,
        trace: TraceWriter | None = None,
        params: LongitudinalParams | None = None,
        in_process_faults: bool = True,
    ) -> None:
        self.scenario = scenario
        self.link = link
        self.t0_s = t0_s
        self.sensor_bus = sensor_bus
        self.trace = trace or TraceWriter(None, HOST_COLUMNS)
        self.params = params or LongitudinalParams()
        self.lon_state = LongitudinalState()
        self.state = HostState()
        self.codec = VehicleCodec()
        self.radar_rx = VehicleRx.for_node(self.codec, "HOST")
        self._radar: tuple[RadarTarget, float] | None = None
        self._next_s = t0_s
        # In HIL the runner freezes or kills the real process; in SIL the agent stops itself.
        self.in_process_faults = in_process_faults
        self._next_nmt_start_s = -1.0
        link.set_nmt_state(NmtState.OPERATIONAL)  # this host is in control: the ECU may engage

    @property
    def next_due_s(self) -> float:
        """When the next control step is due (a process can sleep until then)."""
        return self._next_s

    def _fault_active(self, kind: str, t: float) -> bool:
        return any(f.kind == kind and f.active(t) for f in self.scenario.faults)

    def _pulse(self, kind: str, t: float) -> bool:
        return any(f.kind == kind and f.at_s <= t < f.at_s + REARM_PULSE_S for f in self.scenario.faults)

    def step(self, now_s: float) -> None:
        if self.state.stopped or now_s < self._next_s:
            return
        t = now_s - self.t0_s
        if self.in_process_faults and (
            self._fault_active("host_freeze", t) or self._fault_active("host_kill", t)
        ):
            self.state.stopped = True
            return
        self._poll_inputs(now_s)  # frames wait in the bus queues until the next control step
        self._next_s += HOST_PERIOD_S
        if self._next_s < now_s:
            self._next_s = now_s + HOST_PERIOD_S
        self._control(now_s, t)

    def _poll_inputs(self, now_s: float) -> None:
        self.link.poll(now_s)
        if self.sensor_bus is None:
            return
        while True:
            msg = self.sensor_bus.recv(timeout=0)
            if msg is None:
                break
            frame = self.radar_rx.feed(msg, now_s, rx_time_s(msg, now_s))
            if isinstance(frame, RadarTarget):
                self._radar = (frame, now_s)

    def _lead(self, now_s: float) -> LeadObservation | None:
        if self._radar is None:
            return None
        target, rx_s = self._radar
        if not target.valid or now_s - rx_s > RADAR_STALE_S:
            return None
        return LeadObservation(
            gap_m=target.range_m, v_lead_mps=self.state.last_speed_mps + target.range_rate_mps
        )

    def _control(self, now_s: float, t: float) -> None:
        sc = self.scenario
        latest = self.link.latest_status()
        ecu_state, faults, speed = EcuState.OFF, Fault.NONE, 0.0
        if latest is not None:
            status, rx_s = latest
            ecu_state, faults, speed = status.state, status.faults, status.speed_mps
            if self.state.last_status_s is not None:
                # Odometry from the ECU's measured speed: the host's own notion of where the stop line is.
                self.state.odometer_m += (
                    speed * (rx_s - self.state.last_status_s) if rx_s > self.state.last_status_s else 0.0
                )
            self.state.last_status_s = rx_s
            self.state.last_speed_mps = speed
        lead = self._lead(now_s)
        v_des = ramp_value(sc.speed_profile, t) if sc.speed_profile else 0.0
        controller = "none"
        accel = 0.0
        if sc.host_mode == "script":
            accel = step_value(sc.accel_profile, t)
            controller = "script"
        else:
            stop_distance = None
            if sc.stop_line_m is not None:
                stop_distance = sc.stop_line_m - self.state.odometer_m
            inputs = LongitudinalInputs(
                v_mps=speed, v_des_mps=v_des, lead=lead, stop_distance_m=stop_distance
            )
            self.lon_state, accel, controller = longitudinal_step(self.lon_state, inputs, self.params)
        if self.link.ecu_nmt_state(now_s) is not NmtState.OPERATIONAL and now_s >= self._next_nmt_start_s:
            # CANopen start-up: the master puts the ECU node into OPERATIONAL (and again after a reset).
            self.link.start_ecu()
            self._next_nmt_start_s = now_s + NMT_START_RETRY_S
        flags = RequestFlags.NONE
        if t >= sc.engage_at_s:
            flags |= RequestFlags.ENGAGE
        if sc.steer_profile:
            flags |= RequestFlags.STEER
        if self._pulse("rearm", t):
            flags |= RequestFlags.REARM
        if self._fault_active("host_stop", t):
            flags |= RequestFlags.STOP
        steer = step_value(sc.steer_profile, t) if sc.steer_profile else 0.0
        self.state.counter = (self.state.counter + 1) & 0xFF
        self.link.send_request(
            HostRequest(accel_mps2=accel, steer_angle_rad=steer, flags=flags, counter=self.state.counter)
        )
        if not self._fault_active("heartbeat_mute", t):
            self.link.tick(now_s)  # the heartbeat producer: muting it is the heartbeat_loss fault
        gap = lead.gap_m if lead is not None else float("nan")
        self.trace.append(
            (
                t,
                accel,
                steer,
                float(int(flags)),
                float(int(ecu_state)),
                float(int(faults)),
                speed,
                v_des,
                self.state.odometer_m,
                float(CONTROLLERS.index(controller)),
                gap,
            )
        )
