"""The plant: the FMU vehicle behind a simulated drive-by-wire gateway, E-stop radio and radar.

It stands in for everything on the car's side of the vehicle CAN bus (DESIGN section 1, PLANT box):
it turns the ECU's `DBW_Command` frames into FMU inputs the way the gateway would (only while the
frame is fresh, valid and engaged; the driver's brake always adds), steps the FMU every millisecond,
and turns FMU outputs into the gateway's report frames with sensor noise. Scenario faults are
injected here: E-stop modes, driver brake and steering, grade and wind, and lost, corrupt, repeated
or delayed frames. The same class runs in the HIL plant process (wall clock) and in SIL (lockstep).

The world around the car (`hil.world`, cooperative driving): roads, traffic, the radar that sees it, the
GPS receiver and the V2V radio, stepped at the plant's events. A scenario's `world:` section builds it;
the spine's `host.lead` becomes a scripted car on a one-lane road (`hil.world.sim.lead_world`), with the
spine's radar. `PlantLinks` carries where the world's V2V datagrams and GPS bytes go (SIL: in-process;
HIL: loopback UDP broadcast and a pty) and the traffic trace.

Urban driving: a scenario's `urban:` section adds `hil.world.urban.UrbanWorldSim` (an RNDF/MDF network with
rule-following traffic), stepped at the same events (~100 Hz); its object list and our pose go to the host
through `PlantLinks.objects_send` (`protocol.objects`).

The gear (for reversing out of parking spots): the gateway owns the selector. It takes
`DBW_Command.GearRequest` only from a fresh, engaged command, and shifts only at standstill (|v| below
`SHIFT_STANDSTILL_SPEED_MPS`) with at least `SHIFT_BRAKE_MIN_BAR` applied; the new gear is engaged
`SHIFT_DELAY_S` later (a shift that loses either condition on the way is abandoned), and refused
requests are counted (`shifts_refused`). `GW_Motion.GearEngaged` reports the gear engaged and the FMU's
`gear` input (the drive force's sign) follows it. Wheel speeds go out as magnitudes, LongAccel signed.

Vehicle profiles (the scenario's `vehicle_profile`, protocol.vehicle_can): on `bywire` the gateway
reports the car in its GW_* frames; on `pq` the plant is the VW PQ car itself and sends what the car
sends (protocol.vehicle_pq: Bremse_3, Bremse_5, Motor_2, Motor_3, Lenkhilfe_3, Getriebe_1, each at its
DBC cycle time, with its XOR checksum and counter where it has them), and the gateway only its INS
(GW_Inertial) and arm button (GW_Arm). A frame fault that names a gateway report hits the PQ messages
that carry it (`vehicle_pq.REPORT_MESSAGES`); `corrupt` spoils a message's checksum, and a car message
without one goes out unchanged (there is nothing a receiver could catch); `repeat` freezes a counter
only where there is one.
"""

from __future__ import annotations

import dataclasses
import random
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import can

from bywire.hil.scenario import FaultEvent, Scenario
from bywire.hil.trace import PLANT_COLUMNS
from bywire.hil.world.sim import WorldSim, lead_world
from bywire.hil.world.urban import UrbanWorldSim
from bywire.host.trace import TraceWriter
from bywire.profiles import ramp_value
from bywire.protocol.ecu_types import EcuState, EstopMode, Gear
from bywire.protocol.timebase import rx_time_s
from bywire.protocol.vehicle_can import (
    CHECKSUM_NONE,
    BrakePressure,
    BrakeSwitch,
    DbwCommand,
    DriverInputs,
    EstopRadio,
    GasPedal,
    GearReport,
    InertialReport,
    Motion,
    RadarTarget,
    SafetyArmButton,
    SteerReport,
    VehicleCodec,
    VehicleFrame,
    WheelSpeeds,
)
from bywire.protocol.vehicle_pq import report_messages
from bywire.protocol.vehicle_rx import VehicleRx
from bywire.vehicle_models.fmu_vehicle import FmuVehicle, VehicleInputs

GATEWAY_PERIOD_S = 0.010  # GW_* frames, GenMsgCycleTime 10 ms in vehicle.dbc
SLOW_PERIOD_S = 0.050  # ESTOP_Radio and RADAR_Target, 50 ms
TRACE_PERIOD_S = 0.010
MAX_HOLD_S = 0.010  # the model is advanced at least this often, even without an event
PARK_BRAKE_EQUIV_BAR = 60.0  # the electric park brake, expressed as service-brake pressure for the model
DRIVER_BRAKE_BAR_PER_PCT = 1.2  # 100 % pedal ~ 120 bar: a full driver stop
GATEWAY_FRAMES = ("GW_WheelSpeeds", "GW_Motion", "GW_Driver", "GW_Steer")
# The gateway's selector: a shift takes this long (an automatic gearbox's R <-> D at standstill), only
# at standstill and with the brake applied; otherwise the request is refused.
SHIFT_DELAY_S = 0.4
SHIFT_STANDSTILL_SPEED_MPS = 0.05
SHIFT_BRAKE_MIN_BAR = 5.0
# The world (traffic, radar geometry, V2V, GPS) is stepped at events at most this often: ~100 Hz, the
# gateway's rate; the command and delay events in between change nothing the traffic could see.
WORLD_MIN_STEP_S = 0.0095


@dataclass
class PlantLinks:
    """Where the world speaks to the host besides vehicle CAN (all optional: a world without them is mute)."""

    v2x_send: Callable[[bytes], Any] | None = None
    gps_write: Callable[[bytes], Any] | None = None
    traffic_trace: TraceWriter | None = None
    unix_time: Callable[[float], float] | None = None  # scenario time -> UNIX s (V2V generation stamps)
    replay_profile: Sequence[tuple[float, float]] = field(default_factory=tuple)
    objects_send: Callable[[bytes], Any] | None = None  # the urban world's object-list datagrams
    # The urban world's LIDAR revolutions (`perception: lidar`): cast in the plant's step and sent with
    # `scans_send` (SIL: deterministic), or by a sensor process started before the run, `lidar` (HIL: a
    # cast takes longer than a step; hil.lidar.sensor_link.LidarProcess).
    scans_send: Callable[[bytes], Any] | None = None
    lidar: Any = None


@dataclass
class _Actuation:
    throttle_pct: float = 0.0
    brake_bar: float = 0.0
    steer_rad: float = 0.0


class Plant:
    """Steps the vehicle model and speaks the gateway's side of vehicle CAN."""

    def __init__(
        self,
        scenario: Scenario,
        vehicle: FmuVehicle,
        bus: can.BusABC,
        t0_s: float,
        trace: TraceWriter | None = None,
        links: PlantLinks | None = None,
    ) -> None:
        self.scenario = scenario
        self.vehicle = vehicle
        self.bus = bus
        self.t0_s = t0_s
        self.trace = trace or TraceWriter(None, PLANT_COLUMNS)
        self.vehicle_profile = scenario.vehicle_profile
        self.codec = VehicleCodec(profile=self.vehicle_profile)
        self.rx = VehicleRx.for_node(self.codec, "GATEWAY", max_age_cycles=3.0)
        # Reports slower than the gateway's 10 ms (the PQ car's 20 ms ones) go out every n-th tick.
        self._every = {
            info.name: max(1, round(info.cycle_time_s / GATEWAY_PERIOD_S)) for info in self.codec.messages
        }
        self._gateway_tick = 0
        self.rng = random.Random(scenario.seed)
        self._pending: deque[tuple[float, DbwCommand]] = deque()
        self._cmd: DbwCommand | None = None
        self._park_brake_latched = False
        self._counters: dict[str, int] = {}
        self._delayed: deque[tuple[float, can.Message]] = deque()
        self._next_gateway_s = t0_s
        self._next_slow_s = t0_s
        self._next_trace_s = t0_s
        self._last_step_s: float | None = None
        self.outputs = vehicle.outputs()
        self.links = links or PlantLinks()
        self.world = self._make_world(scenario, self.links)
        self.urban: UrbanWorldSim | None = None
        if scenario.urban is not None:
            self.urban = UrbanWorldSim(scenario.urban, scenario.seed, self.links.objects_send)
            if scenario.urban.perception == "lidar" and self.links.lidar is not None:
                self.urban.lidar = self.links.lidar
            elif scenario.urban.perception == "lidar" and self.links.scans_send is not None:
                from bywire.hil.lidar.sensor_link import LidarSender

                self.urban.lidar = LidarSender(
                    self.urban.world, scenario.urban.lidar, self.links.scans_send, scenario.seed
                )
        self._world_t_s = -1.0
        self._applied = _Actuation()
        self.gear = Gear.DRIVE  # engaged
        self._shift_to: Gear | None = None  # a shift under way, engaged at _shift_done_s
        self._shift_done_s = float("inf")
        self._refused_request: Gear | None = None
        self.shifts = 0
        self.shifts_refused = 0
        self.collisions = 0
        self._in_collision = False
        self.min_gap_m = float("inf")
        self._faults: dict[str, tuple[FaultEvent, ...]] = {}
        for fault in scenario.faults:
            if fault.frames and self.vehicle_profile == "pq":
                fault = dataclasses.replace(fault, frames=report_messages(fault.frames))
            self._faults[fault.kind] = (*self._faults.get(fault.kind, ()), fault)
        self._cmd_monitor = self.rx.monitor("DBW_Command")
        self._frame_faults = any(k in self._faults for k in ("drop", "corrupt", "repeat", "delay", "stuck"))
        self._last_sent: dict[str, can.Message] = {}  # per frame: what a stuck sender repeats
        self._actuator_delay_s = scenario.actuator_delay_ms / 1000.0
        # Instants (scenario time) at which a fault starts or ends: the model is advanced there.
        starts = {f.at_s for f in scenario.faults}
        ends = {f.at_s + f.duration_s for f in scenario.faults if f.duration_s}
        self._fault_edges_s = sorted(starts | ends)
        self._edge_i = 0
        self._next_event_s = t0_s

    # -- scenario state at time t ------------------------------------------------------------------

    def _active(self, kind: str, t: float, frame: str | None = None) -> FaultEvent | None:
        for fault in self._faults.get(kind, ()):
            if fault.active(t) and (frame is None or frame in fault.frames):
                return fault
        return None

    def estop_mode(self, t: float) -> EstopMode:
        mode = EstopMode.RUN
        for fault in self.scenario.faults:
            if fault.kind == "estop" and fault.at_s <= t:
                mode = fault.mode
        return mode

    def driver_brake_pct(self, t: float) -> float:
        if "driver_brake" not in self._faults:
            return 0.0
        fault = self._active("driver_brake", t)
        return fault.pedal_pct if fault else 0.0

    def driver_torque_nm(self, t: float) -> float:
        fault = self._active("driver_steer", t)
        return fault.torque_nm if fault else 0.0

    def safety_arm(self, t: float) -> bool:
        """The safety driver's arm button on the car (GW_Driver.SafetyArm), pressed by the scenario."""
        return "arm_button" in self._faults and self._active("arm_button", t) is not None

    # -- stepping -----------------------------------------------------------------------------------

    def step(self, now_s: float) -> None:
        """Called every millisecond (the HIL process on the wall clock, SIL in lockstep).

        The vehicle model is advanced only at events: a command arriving or becoming due, a report
        frame or trace sample due, a delayed frame due, a command timing out, a fault starting or
        ending, and at least every `MAX_HOLD_S`. Between events its inputs are constant (the gateway
        holds the last command), so one longer FMU step is the same physics as many short ones (the
        FMU sub-steps internally at its own `step_s`), and most milliseconds cost only a bus poll.
        """
        self._receive(now_s)
        if now_s >= self._next_event_s:
            self._event(now_s)

    def _event(self, now_s: float) -> None:
        t = now_s - self.t0_s
        dt = now_s - self._last_step_s if self._last_step_s is not None else 0.0
        if dt > 0.0:
            # The last interval ran on the actuation decided at its start: a command takes effect
            # after it arrived (and after the actuator delay), never before.
            t_prev = self._last_step_s - self.t0_s if self._last_step_s is not None else t
            act = self._applied
            self.outputs = self.vehicle.step(
                dt,
                VehicleInputs(
                    throttle_pct=act.throttle_pct,
                    brake_bar=act.brake_bar,
                    steer_angle_rad=act.steer_rad,
                    grade_pct=ramp_value(self.scenario.grade_pct, t_prev),
                    wind_mps=ramp_value(self.scenario.wind_mps, t_prev),
                    gear=-1.0 if self.gear == Gear.REVERSE else 1.0,
                ),
            )
            self._advance_world(t)
        if self._last_step_s is None or now_s > self._last_step_s:
            self._last_step_s = now_s
        while self._pending and self._pending[0][0] <= now_s:
            self._cmd = self._pending.popleft()[1]
        cmd_fresh = self._cmd is not None and not self._cmd_monitor.timed_out(now_s)
        self._applied = self._actuation(t, cmd_fresh)
        self._shift(now_s, cmd_fresh)
        if now_s >= self._next_gateway_s:
            self._next_gateway_s += GATEWAY_PERIOD_S
            if self._next_gateway_s < now_s:  # a stalled HIL process re-phases instead of bursting
                self._next_gateway_s = now_s + GATEWAY_PERIOD_S
            self._send_gateway(now_s, t)
        if now_s >= self._next_slow_s:
            self._next_slow_s += SLOW_PERIOD_S
            if self._next_slow_s < now_s:
                self._next_slow_s = now_s + SLOW_PERIOD_S
            self._send_slow(now_s, t)
        self._flush_delayed(now_s)
        if now_s >= self._next_trace_s:
            self._next_trace_s += TRACE_PERIOD_S
            if self._next_trace_s < now_s:
                self._next_trace_s = now_s + TRACE_PERIOD_S
            self._record(t, cmd_fresh)
        self._next_event_s = self._plan_next_event(now_s, cmd_fresh)

    def _plan_next_event(self, now_s: float, cmd_fresh: bool) -> float:
        nxt = min(self._next_gateway_s, self._next_slow_s, self._next_trace_s, now_s + MAX_HOLD_S)
        if self._pending:
            nxt = min(nxt, self._pending[0][0])
        if self._delayed:
            nxt = min(nxt, self._delayed[0][0])
        if self._shift_to is not None:
            nxt = min(nxt, self._shift_done_s)
        if cmd_fresh:
            last = self._cmd_monitor.state.last_time_s
            if last is not None:  # the instant the gateway stops trusting the command
                nxt = min(nxt, last + self._cmd_monitor.timeout_s + 1e-6)
        edges = self._fault_edges_s
        while self._edge_i < len(edges) and edges[self._edge_i] <= now_s - self.t0_s:
            self._edge_i += 1
        if self._edge_i < len(edges):
            nxt = min(nxt, self.t0_s + edges[self._edge_i])
        return nxt

    def _actuation(self, t: float, cmd_fresh: bool) -> _Actuation:
        """What the gateway applies from now until the next event."""
        act = _Actuation()
        cmd = self._cmd
        if cmd is not None and cmd_fresh:
            if cmd.engage and cmd.ignition:
                act.throttle_pct = cmd.throttle_pct
            if cmd.engage:
                act.brake_bar = cmd.brake_bar
            if cmd.steer_enable:
                act.steer_rad = cmd.steer_angle_rad
            if cmd.park_brake:
                self._park_brake_latched = True
            elif cmd.ignition:
                self._park_brake_latched = False
        driver_pct = self.driver_brake_pct(t)
        act.brake_bar = max(act.brake_bar, driver_pct * DRIVER_BRAKE_BAR_PER_PCT)
        if self._park_brake_latched:
            act.brake_bar = max(act.brake_bar, PARK_BRAKE_EQUIV_BAR)
            act.throttle_pct = 0.0
        if driver_pct > 0.0:
            act.throttle_pct = 0.0  # brake override: a driver on the brake always wins over throttle
        return act

    def _shift(self, now_s: float, cmd_fresh: bool) -> None:
        """The selector: engage a shift that is due, start one that is asked for (see the docstring)."""
        cmd = self._cmd
        wanted = cmd.gear_request if cmd is not None and cmd_fresh and cmd.engage else self.gear
        held = (
            abs(self.outputs.speed_mps) < SHIFT_STANDSTILL_SPEED_MPS
            and self._applied.brake_bar >= SHIFT_BRAKE_MIN_BAR
        )
        if self._shift_to is not None:
            if self._shift_to != wanted or not held:
                self._shift_to, self._shift_done_s = None, float("inf")  # abandoned: the gear stays
            elif now_s >= self._shift_done_s:
                self.gear, self._shift_to, self._shift_done_s = wanted, None, float("inf")
                self.shifts += 1
                return
        if wanted != self.gear and self._shift_to is None:
            if held:
                self._shift_to, self._shift_done_s = wanted, now_s + SHIFT_DELAY_S
            elif self._refused_request != wanted:
                self.shifts_refused += 1  # once per request, not per event
            self._refused_request = wanted if not held else None
        elif wanted == self.gear:
            self._refused_request = None

    def _receive(self, now_s: float) -> None:
        bus = self.bus
        while True:
            msg = bus.recv(timeout=0)
            if msg is None:
                return
            frame = self.rx.feed(msg, now_s, rx_time_s(msg, now_s))
            if isinstance(frame, DbwCommand):
                due = now_s + self._actuator_delay_s
                self._pending.append((due, frame))
                if due < self._next_event_s:
                    self._next_event_s = due

    @staticmethod
    def _make_world(scenario: Scenario, links: PlantLinks) -> WorldSim | None:
        spec = scenario.world
        if spec is None and scenario.lead is not None:
            lead = scenario.lead
            spec = lead_world(lead.gap0_m, lead.speed_profile, lead.length_m, lead.leaves_at_s)
        if spec is None:
            return None
        epoch = spec.v2v.epoch_unix_s
        return WorldSim(
            spec,
            scenario.seed,
            links.unix_time or (lambda t: epoch + t),
            send=links.v2x_send,
            gps_write=links.gps_write,
            trace=links.traffic_trace,
            replay_profile=links.replay_profile,
        )

    def _advance_world(self, t: float) -> None:
        """The world at scenario time t, around the FMU's state at t (the traffic's own lag integrates
        over the interval; the gaps are booked at t, every event)."""
        world = self.world
        if (world is None and self.urban is None) or t < self._world_t_s + WORLD_MIN_STEP_S:
            return
        self._world_t_s = t
        out = self.outputs
        if self.urban is not None:
            self.urban.step(t, out.x_m, out.y_m, out.heading_rad, out.speed_mps, out.yaw_rate_radps)
        if world is None:
            return
        world.step(t, out.x_m, out.y_m, out.heading_rad, out.speed_mps, out.accel_mps2, out.yaw_rate_radps)
        gap = self.lead_gap_m(t)
        if gap is not None:
            self.min_gap_m = min(self.min_gap_m, gap)
            if gap <= 0.0 and not self._in_collision:
                self.collisions += 1
            self._in_collision = gap <= 0.0

    def lead_gap_m(self, t: float) -> float | None:
        """Gap from our front bumper to the car ahead on our lane (truth), None when there is none."""
        lead = self.world.lead() if self.world is not None else None
        return None if lead is None else lead[0]

    def lead_speed_mps(self) -> float:
        lead = self.world.lead() if self.world is not None else None
        return float("nan") if lead is None else lead[1]

    # -- frames ------------------------------------------------------------------------------------

    def _next_counter(self, name: str, t: float) -> int:
        counter = self._counters.get(name, 0)
        if not self._frame_faults or self._active("repeat", t, name) is None:
            self._counters[name] = (counter + 1) & 0x0F
        return counter

    def _emit(self, name: str, frame: VehicleFrame, now_s: float, t: float) -> None:
        if not self._frame_faults:
            msg = self.codec.encode(frame, self._next_counter(name, t), saturate=True, timestamp_s=now_s)
            self.bus.send(msg)
            return
        if self._active("drop", t, name) is not None:
            self._next_counter(name, t)  # the sender still counts: the receiver sees a gap
            return
        stuck = self._last_sent.get(name) if self._active("stuck", t, name) is not None else None
        if stuck is not None:
            # A frozen transmitter: the last frame again, byte for byte (counter, content and CRC).
            msg = can.Message(
                arbitration_id=stuck.arbitration_id, data=bytes(stuck.data), is_extended_id=False
            )
        else:
            msg = self.codec.encode(frame, self._next_counter(name, t), saturate=True)
            self._last_sent[name] = msg
        msg.timestamp = now_s
        if self._active("corrupt", t, name) is not None:
            info = self.codec.info(name)
            if info.checksum != CHECKSUM_NONE:
                data = bytearray(msg.data)
                data[info.checksum_byte] ^= 0x5A  # a checksum that cannot match
                msg.data = data
        delay = self._active("delay", t, name)
        if delay is not None:
            self._delayed.append((now_s + delay.delay_ms / 1000.0, msg))
            return
        self.bus.send(msg)

    def _flush_delayed(self, now_s: float) -> None:
        while self._delayed and self._delayed[0][0] <= now_s:
            self.bus.send(self._delayed.popleft()[1])

    def _noise(self, sigma: float) -> float:
        return self.rng.gauss(0.0, sigma) if sigma > 0.0 else 0.0

    def _wheel_speeds(self) -> WheelSpeeds:
        out = self.outputs
        wn = self.scenario.wheel_speed_noise_mps

        def wheel(v: float) -> float:
            return max(0.0, abs(v) + self._noise(wn)) if abs(v) > 0.01 else 0.0

        return WheelSpeeds(
            fl_mps=wheel(out.wheel_speed_fl_mps),
            fr_mps=wheel(out.wheel_speed_fr_mps),
            rl_mps=wheel(out.wheel_speed_rl_mps),
            rr_mps=wheel(out.wheel_speed_rr_mps),
        )

    def _inertial(self) -> InertialReport:
        """The INS: acceleration and yaw rate with their noise."""
        out = self.outputs
        return InertialReport(
            long_accel_mps2=out.accel_mps2 + self._noise(self.scenario.accel_noise_mps2),
            yaw_rate_radps=out.yaw_rate_radps + self._noise(0.002),
        )

    def _send_gateway(self, now_s: float, t: float) -> None:
        if self.vehicle_profile == "pq":
            self._send_pq(now_s, t)
            return
        out = self.outputs
        self._emit("GW_WheelSpeeds", self._wheel_speeds(), now_s, t)
        ins = self._inertial()
        self._emit(
            "GW_Motion",
            Motion(
                long_accel_mps2=ins.long_accel_mps2,
                yaw_rate_radps=ins.yaw_rate_radps,
                brake_bar_actual=out.brake_bar_actual,
                gear_engaged=self.gear,
            ),
            now_s,
            t,
        )
        pedal = self.driver_brake_pct(t)
        self._emit(
            "GW_Driver",
            DriverInputs(
                brake_pedal_pressed=pedal > 2.0,
                throttle_pedal_pct=0.0,
                brake_pedal_pct=pedal,
                safety_arm=self.safety_arm(t),
            ),
            now_s,
            t,
        )
        self._emit(
            "GW_Steer",
            SteerReport(steer_angle_rad=out.steer_angle_rad_actual, steer_torque_nm=self.driver_torque_nm(t)),
            now_s,
            t,
        )

    def _send_pq(self, now_s: float, t: float) -> None:
        """The VW PQ car's own reports and the gateway's INS and arm button (profile pq), each at its
        DBC cycle time; the same noise draws, in the same order, as the bywire gateway's."""
        out = self.outputs
        tick = self._gateway_tick
        self._gateway_tick = tick + 1
        every = self._every
        frames: tuple[tuple[str, VehicleFrame], ...] = (
            ("Bremse_3", self._wheel_speeds()),
            ("GW_Inertial", self._inertial()),
            ("Bremse_5", BrakePressure(brake_bar_actual=out.brake_bar_actual)),
            ("Getriebe_1", GearReport(gear_engaged=self.gear)),
            ("Motor_2", BrakeSwitch(brake_pedal_pressed=self.driver_brake_pct(t) > 2.0)),
            ("Motor_3", GasPedal(throttle_pedal_pct=0.0)),
            ("GW_Arm", SafetyArmButton(safety_arm=self.safety_arm(t))),
            (
                "Lenkhilfe_3",
                SteerReport(
                    steer_angle_rad=out.steer_angle_rad_actual, steer_torque_nm=self.driver_torque_nm(t)
                ),
            ),
        )
        for name, frame in frames:
            if tick % every[name] == 0:
                self._emit(name, frame, now_s, t)

    def _send_slow(self, now_s: float, t: float) -> None:
        self._emit("ESTOP_Radio", EstopRadio(mode=self.estop_mode(t)), now_s, t)
        ret = self.world.world.radar(self._noise, self.scenario.radar_range_noise_m) if self.world else None
        if ret is not None and ret.valid:
            target = RadarTarget(
                valid=True,
                range_m=ret.range_m,
                range_rate_mps=ret.range_rate_mps,
                azimuth_rad=ret.azimuth_rad,
            )
        else:
            target = RadarTarget(valid=False, range_m=0.0, range_rate_mps=0.0, azimuth_rad=0.0)
        self._emit("RADAR_Target", target, now_s, t)

    def _record(self, t: float, cmd_fresh: bool) -> None:
        out = self.outputs
        cmd = self._cmd
        gap = self.lead_gap_m(t)
        lead_speed = self.lead_speed_mps() if gap is not None else float("nan")
        self.trace.append(
            (
                t,
                out.speed_mps,
                out.accel_mps2,
                out.distance_m,
                out.x_m,
                out.y_m,
                out.heading_rad,
                out.yaw_rate_radps,
                cmd.throttle_pct if cmd else 0.0,
                cmd.brake_bar if cmd else 0.0,
                cmd.steer_angle_rad if cmd else 0.0,
                self._applied.throttle_pct,
                self._applied.brake_bar,
                out.brake_bar_actual,
                out.steer_angle_rad_actual,
                float(bool(cmd and cmd.engage)),
                float(int(cmd.ecu_state) if cmd else int(EcuState.OFF)),
                float(int(self.estop_mode(t))),
                self.driver_brake_pct(t),
                ramp_value(self.scenario.grade_pct, t),
                gap if gap is not None else float("nan"),
                lead_speed,
                float(cmd_fresh),
            )
        )


__all__ = ["Plant", "PlantLinks"]
