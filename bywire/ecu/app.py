"""The ECU application: the 1 kHz cycle that ties the buses to the pure core (DESIGN section 1, ECU box).

One cycle (`EcuApp.step`), every millisecond on an absolute deadline:
1. drain vehicle CAN through the E2E monitor (CRC, alive counter, age) and the host link through the
   CANopen node (request RPDO, host heartbeat, SDO, NMT);
2. reduce what was received to the core's inputs: freshness from the DBC cycle times, corruption
   from error streaks, the host's heartbeat from our consumer (canopen has none: canopen-python/canopen#543);
3. `core_step`, the pure safety state machine + cascaded acceleration controller;
4. send `DBW_Command` every 10 ms, the CANopen heartbeat and the status TPDOs on their timers, and
   an EMCY when a new fault appears.

Seed 000 section 2.1 / seed 003 section II-d: the ECU runs the low-level controller and is the
safety authority; the host only asks. Imports: protocol, clock and the ECU's own modules only.

What the application adds to the pure core's rules (ecu.safety's docstring), DESIGN section 4:

- Loop stall. A gap between the starts of two cycles on the ECU's own clock longer than
  `LOOP_STALL_MAX_GAP_S` (two DBW_Command periods, 20 ms) is the stop fault LOOP_STALL by itself,
  whatever the inputs look like afterwards: for that long the gateway ran on a command nobody had
  re-judged, and at least one command period went by without a command. The gateway trusts a
  command for five periods (50 ms), so the ECU calls a stall before the gateway would give up on
  it. A longer stall is therefore never judged safer than a shorter one; the inputs that arrived
  before or during it are judged by their receive time (the buses' stamps), not by the poll.
- Internal error. An exception anywhere inside a cycle never kills the process: the cycle sends the
  transmit guard's replacement command and the next cycle's core sees INTERNAL_ERROR (a stop fault).
- Transmit guard (ecu.tx_guard). Every DBW_Command passes it right before `bus.send`; a refused one
  is replaced and the next cycle's core sees TX_GUARD (a stop fault).
- The three events count in `internal_fault_events`, which the boot supervisor reads as health.
- E-stop frames in an error streak (corrupt, repeated, out of order) make the radio stale, exactly
  as a silent radio: a stuck transmitter that repeats its last frame is caught within its timeout.
- The service unlatch (SDO 0x2300sub1) is refused with an abort and a reason unless the ECU is
  DISABLED and the radio is heard saying RUN or PAUSE; accepted, it is the second factor of the
  re-arm, which the safety driver's arm button completes.
- Watchdog times (0x1016, 0x1017, 0x1400sub5, TPDO event timers) and calibrations cannot be
  written while the ECU actuates (ENGAGED, PAUSED, SAFE_STOP, DISABLED).

Vehicle profiles (protocol.vehicle_can): the ECU hears the car in our gateway's reports (`bywire`) or
in the VW PQ car's own messages (`pq`, protocol.vehicle_pq). The vehicle reports are every message the
DBC sends to the ECU but the E-stop radio, and each core input is read from the report whose typed
frame carries it; freshness (10 cycles of each report's GenMsgCycleTime), age, corruption streaks and
the counter checks are the same code on both profiles, over more and slower messages on the PQ bus.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can

from bywire.clock import Clock
from bywire.ecu.calibration import (
    Calibration,
    CalibrationError,
    default_calibration,
    dumps_calibration,
    loads_calibration,
)
from bywire.ecu.core import ActuatorCommand, CoreState, core_step, initial_core_state
from bywire.ecu.executive import CycleStats
from bywire.ecu.safety import EcuInputs
from bywire.ecu.tx_guard import TxGuard
from bywire.protocol.canopen_link.dictionary import ABORT_DEVICE_STATE
from bywire.protocol.canopen_link.ecu_node import EcuNode, RefusedWrite
from bywire.protocol.ecu_types import EcuState, EstopMode, Fault, Gear, RequestFlags
from bywire.protocol.host_link import EcuStatus, next_counter
from bywire.protocol.timebase import rx_time_s
from bywire.protocol.vehicle_can import (
    VEHICLE_PROFILES,
    DbwCommand,
    EstopRadio,
    VehicleCodec,
    VehicleTx,
    WheelSpeeds,
)
from bywire.protocol.vehicle_rx import RxMonitor, VehicleRx

ESTOP_MESSAGE = "ESTOP_Radio"
VEHICLE_TIMEOUT_CYCLES = 10.0
VEHICLE_MAX_AGE_CYCLES = 5.0
# Two DBW_Command periods (GenMsgCycleTime 10 ms): see the module docstring.
LOOP_STALL_MAX_GAP_S = 0.020
# States in which the ECU actuates: calibrations and watchdog times are fixed then.
ACTUATING = frozenset({EcuState.ENGAGED, EcuState.PAUSED, EcuState.SAFE_STOP, EcuState.DISABLED})
log = logging.getLogger(__name__)


@dataclass(frozen=True)
class EcuConfig:
    """Timing of the ECU's I/O; the limits and gains live in the calibration."""

    command_period_s: float = 0.010  # DBW_Command, GenMsgCycleTime 10 ms
    status_period_s: float = 0.020  # status TPDO refresh (the EDS event timers send them)
    corrupt_streak: int = 3  # consecutive rejected frames of one report = corruption (30 ms at 100 Hz)


def command_frame(cmd: ActuatorCommand) -> DbwCommand:
    """The DBW_Command frame that carries a core command to the gateway."""
    return DbwCommand(
        throttle_pct=cmd.throttle_pct,
        brake_bar=cmd.brake_bar,
        steer_angle_rad=cmd.steer_angle_rad,
        engage=cmd.engage,
        park_brake=cmd.park_brake,
        ignition=cmd.ignition,
        steer_enable=cmd.steer_enable,
        ecu_state=cmd.state,
        gear_request=cmd.gear_request,
    )


class EcuApp:
    """The ECU's cyclic work on two buses; steppable in lockstep (SIL) and by the real-time executive."""

    def __init__(
        self,
        vehicle_bus: can.BusABC,
        host_bus: can.BusABC,
        clock: Clock,
        calibration: Calibration | None,
        calibration_error: str | None = None,
        config: EcuConfig | None = None,
        stats: CycleStats | None = None,
        on_calibration: Any = None,
        vehicle_profile: str = "bywire",
    ) -> None:
        self.vehicle_bus = vehicle_bus
        self.clock = clock
        self.config = config or EcuConfig()
        self.calibration = calibration
        self.calibration_error = calibration_error
        # With no valid calibration the core stays OFF and never actuates; it still needs limits to
        # compute its (passive) outputs, which the packaged default provides.
        self._core_cal = calibration if calibration is not None else default_calibration()
        self.stats = stats or CycleStats()
        self.codec = VehicleCodec(profile=vehicle_profile)
        # A report is timed out after 10 of its cycles (100 ms for the 10 ms GW_* frames): on a shared
        # 2-core machine the plant's frames jitter by tens of ms, and a 5-cycle timeout stopped the car
        # for that alone. A frame that waited more than 5 cycles (the ECU itself was late) is stale.
        self.rx = VehicleRx.for_node(
            self.codec, "ECU", timeout_cycles=VEHICLE_TIMEOUT_CYCLES, max_age_cycles=VEHICLE_MAX_AGE_CYCLES
        )
        self.tx = VehicleTx(self.codec)
        self.vehicle_reports = vehicle_reports(self.codec)
        self._reports = tuple(self.rx.monitor(name) for name in self.vehicle_reports)
        source = _report_sources(self.codec, self.vehicle_reports, self._reports)
        self._wheels = source["fl_mps"]
        self._accel, self._gear = source["long_accel_mps2"], source["gear_engaged"]
        self._steer = source["steer_angle_rad"]
        self._brake, self._throttle, self._arm = (
            source["brake_pedal_pressed"],
            source["throttle_pedal_pct"],
            source["safety_arm"],
        )
        self._estop = self.rx.monitor(ESTOP_MESSAGE)
        self._reported_faults = -1
        self._status_counter = 0
        self._on_calibration = on_calibration
        self.node = EcuNode(
            host_bus,
            clock,
            on_calibration_write=self._calibration_written,
            on_unlatch=self._unlatch_requested,
            actuating=self._actuating_state,
        )
        self.core: CoreState = initial_core_state(clock.now())
        self.guard = TxGuard(self._core_cal)
        self._unlatch_pending = False
        # Events of the last cycle that the core judges in the next one (ecu.safety's inputs).
        self._stall_pending = False
        self._internal_pending = False
        self._guard_pending = False
        self.internal_fault_events = 0  # loop stalls, exceptions in a cycle, guard trips, since boot
        self.loop_stalls = 0
        self.cycle_exceptions = 0
        self.last_exception: str | None = None
        self.max_cycle_gap_s = 0.0
        self._last_cycle_s: float | None = None  # clock time at the start of the last cycle
        self._last_inputs: EcuInputs | None = None
        self._inputs_valid_until_s = -math.inf
        self._next_command_s = -math.inf
        self._next_status_s = -math.inf
        self.last_command: ActuatorCommand | None = None
        if calibration is not None:
            self.node.set_calibration(dumps_calibration(calibration), calibration.version)

    # -- SDO hooks (run inside node.poll, i.e. inside the cycle) ----------------------------------

    def _actuating_state(self) -> str | None:
        state = self.core.safety.state
        return state.name if state in ACTUATING else None

    def _calibration_written(self, data: bytes) -> int:
        """A new calibration over SDO: validated before anything changes; refused while actuating."""
        if self.core.safety.state in ACTUATING:
            raise RefusedWrite(
                "calibration can only be written while the ECU is not actuating (OFF/READY/MANUAL)",
                ABORT_DEVICE_STATE,
            )
        cal = loads_calibration(data, "SDO 0x2200")  # CalibrationError names the field
        if self._on_calibration is not None:
            self._on_calibration(data, cal)  # persist first: a calibration that was not stored is not used
        self.calibration = cal
        self._core_cal = cal
        self.guard.cal = cal
        self.calibration_error = None
        return cal.version

    def _unlatch_requested(self) -> None:
        """The service tool's unlatch: refused (with a true reason) unless it can count."""
        state = self.core.safety.state
        if state != EcuState.DISABLED:
            raise RefusedWrite(
                f"nothing to unlatch: the ECU is {state.name}, not DISABLED", ABORT_DEVICE_STATE
            )
        estop = self._estop.state.last_frame
        now = self.clock.now()
        if not isinstance(estop, EstopRadio) or not self._estop_heard(now):
            raise RefusedWrite(
                "unlatch refused: the E-stop radio is not heard; the ECU stays DISABLED", ABORT_DEVICE_STATE
            )
        if estop.mode == EstopMode.DISABLE:
            raise RefusedWrite(
                "unlatch refused: the E-stop radio still says DISABLE; the ECU stays DISABLED",
                ABORT_DEVICE_STATE,
            )
        self._unlatch_pending = True

    def _estop_heard(self, now_s: float) -> bool:
        """The E-stop radio's last frame is within its timeout and not in an error streak."""
        estop = self._estop
        return not estop.timed_out(now_s) and estop.state.error_streak < self.config.corrupt_streak

    # -- one cycle --------------------------------------------------------------------------------

    def step(self, now_s: float) -> None:
        """One cycle. Never raises: an exception inside it is the stop fault INTERNAL_ERROR."""
        started = self.clock.now()
        last = self._last_cycle_s
        self._last_cycle_s = started
        if last is not None:
            gap = started - last
            if gap > self.max_cycle_gap_s:
                self.max_cycle_gap_s = gap
            if gap > LOOP_STALL_MAX_GAP_S:
                self._stall_pending = True
                self.loop_stalls += 1
                self.internal_fault_events += 1
        try:
            self._cycle(now_s)
        except Exception as exc:  # the car brakes and holds; the process lives on to say why
            self._cycle_failed(now_s, exc)

    def _cycle_failed(self, now_s: float, exc: Exception) -> None:
        self.cycle_exceptions += 1
        self.internal_fault_events += 1
        self._internal_pending = True
        self.last_exception = f"{type(exc).__name__}: {exc}"
        if self.cycle_exceptions <= 10 or self.cycle_exceptions % 1000 == 0:  # a log, not a flood
            log.error("ECU cycle at %.3f s raised (%d so far): %r", now_s, self.cycle_exceptions, exc)
        try:
            engaged = _read(self._gear, "gear_engaged", Gear.DRIVE)
            frame = self.guard.replacement(self.core.safety.state, engaged, now_s)
            self.vehicle_bus.send(self.tx.encode(frame, timestamp_s=now_s))
            self._next_command_s = now_s + self.config.command_period_s
        except Exception:  # the bus itself is gone: nothing more can be said on it this cycle
            log.exception("ECU could not send the replacement command")

    def _cycle(self, now_s: float) -> None:
        bus = self.vehicle_bus
        rx = self.rx
        received = 0
        while True:
            msg = bus.recv(timeout=0)
            if msg is None:
                break
            rx.feed(msg, now_s, rx_time_s(msg, now_s))
            received += 1
        received += self.node.poll(now_s)
        # The inputs change only when a frame arrives or something fresh expires: most cycles reuse
        # the last ones (the same values, a tenth of the cost).
        inputs = self._last_inputs
        if (
            received
            or inputs is None
            or now_s > self._inputs_valid_until_s
            or self.stats.overrun_streak != inputs.overrun_streak
            or self._unlatch_pending != inputs.unlatch
            or self._stall_pending != inputs.loop_stall
            or self._internal_pending != inputs.internal_error
            or self._guard_pending != inputs.tx_guard_trip
        ):
            inputs = self._last_inputs = self._inputs(now_s)
        self.core, cmd = core_step(self.core, inputs, now_s, self._core_cal)
        # The core has judged these events: each counts once.
        self._unlatch_pending = self._stall_pending = self._internal_pending = self._guard_pending = False
        self.last_command = cmd
        guard = self.guard
        guard.note_cycle(cmd.steer_enable)
        if now_s >= self._next_command_s:
            self._next_command_s = max(self._next_command_s + self.config.command_period_s, now_s)
            frame, refused = guard.guard(command_frame(cmd), cmd.state, inputs.gear_engaged, now_s)
            if refused is not None:
                self._guard_pending = True
                self.internal_fault_events += 1
                if guard.trips <= 10 or guard.trips % 1000 == 0:
                    log.error("transmit guard refused the command at %.3f s: %s", now_s, refused)
            bus.send(self.tx.encode(frame, timestamp_s=now_s))
        if now_s >= self._next_status_s:
            self._next_status_s = max(self._next_status_s + self.config.status_period_s, now_s)
            self._status_counter = next_counter(self._status_counter)
            self.node.publish_status(self._status(inputs, cmd), now_s)
        faults = int(cmd.faults_active) | int(cmd.faults_latched)  # ints: Fault.__or__ costs microseconds
        if faults != self._reported_faults:
            self.node.report_faults(Fault(faults))  # EMCY on new bits, error reset when all clear
            self._reported_faults = faults
        self.node.tick(now_s)

    def _inputs(self, now_s: float) -> EcuInputs:
        """The core's inputs at `now_s`; also sets `_inputs_valid_until_s`, the instant until which
        they stay the same if no frame arrives (the earliest expiry of something fresh now)."""
        vehicle_fresh = True
        vehicle_corrupt = False
        streak = self.config.corrupt_streak
        # A microsecond early: recomputing too soon is exact, too late is not.
        horizon = self.node.freshness_horizon_s(now_s)
        for monitor in (*self._reports, self._estop):
            state = monitor.state
            t = state.last_time_s
            if t is None or now_s - t > monitor.timeout_s:
                if monitor is not self._estop:
                    vehicle_fresh = False
            elif t + monitor.timeout_s - 1e-6 < horizon:
                horizon = t + monitor.timeout_s - 1e-6
            if state.error_streak >= streak and monitor is not self._estop:
                vehicle_corrupt = True

        self._inputs_valid_until_s = horizon
        wheels = self._wheels.state.last_frame
        estop = self._estop.state.last_frame
        node = self.node
        request = node.latest_request()
        req = request[0] if request is not None else None
        return EcuInputs(
            estop_mode=estop.mode if isinstance(estop, EstopRadio) else EstopMode.INVALID,
            estop_fresh=self._estop_heard(now_s),
            host_alive=node.host_alive(now_s),
            request_accel_mps2=req.accel_mps2 if req is not None else 0.0,
            request_steer_angle_rad=req.steer_angle_rad if req is not None else 0.0,
            request_flags=req.flags if req is not None else RequestFlags.NONE,
            request_fresh=node.request_fresh(now_s),
            vehicle_fresh=vehicle_fresh,
            vehicle_corrupt=vehicle_corrupt,
            calibration_valid=self.calibration is not None,
            overrun_streak=self.stats.overrun_streak,
            driver_brake_pressed=_read(self._brake, "brake_pedal_pressed", False),
            driver_throttle_pct=_read(self._throttle, "throttle_pedal_pct", 0.0),
            driver_steer_torque_nm=_read(self._steer, "steer_torque_nm", 0.0),
            speed_mps=wheels.mean_mps if isinstance(wheels, WheelSpeeds) else 0.0,
            accel_meas_mps2=_read(self._accel, "long_accel_mps2", 0.0),
            steer_angle_meas_rad=_read(self._steer, "steer_angle_rad", 0.0),
            unlatch=self._unlatch_pending,
            gear_engaged=_read(self._gear, "gear_engaged", Gear.DRIVE),
            wheel_speed_max_mps=wheels.max_mps if isinstance(wheels, WheelSpeeds) else math.inf,
            safety_arm=_read(self._arm, "safety_arm", False),
            loop_stall=self._stall_pending,
            internal_error=self._internal_pending,
            tx_guard_trip=self._guard_pending,
        )

    def _status(self, inputs: EcuInputs, cmd: Any) -> EcuStatus:
        stats = self.stats
        return EcuStatus(
            state=cmd.state,
            faults=cmd.faults_active | cmd.faults_latched,
            speed_mps=inputs.speed_mps,
            accel_mps2=inputs.accel_meas_mps2,
            throttle_pct=cmd.throttle_pct,
            brake_bar=cmd.brake_bar,
            steer_angle_rad=cmd.steer_angle_rad,
            lateness_p99_us=stats.window_p99_lateness_us(),
            compute_max_us=stats.max_compute_us_window(),
            overruns=stats.overruns,
            counter=self._status_counter,
            gear=inputs.gear_engaged,
        )

    def rx_stats(self) -> dict[str, Any]:
        return self.rx.stats()

    def health_summary(self) -> dict[str, Any]:
        """The ECU's own health since boot, for reports: stalls, exceptions, guard trips."""
        return {
            "internal_fault_events": self.internal_fault_events,
            "loop_stalls": self.loop_stalls,
            "max_cycle_gap_ms": round(self.max_cycle_gap_s * 1e3, 3),
            "cycle_exceptions": self.cycle_exceptions,
            "last_exception": self.last_exception,
            "tx_guard_trips": self.guard.trips,
            "tx_guard_last_reason": self.guard.last_reason,
        }


# -- the vehicle reports of a profile ------------------------------------------------------------------


def vehicle_reports(codec: VehicleCodec) -> tuple[str, ...]:
    """The messages the ECU judges the car by: every message the DBC sends to the ECU but the E-stop."""
    return tuple(name for name in codec.received_by("ECU") if name != ESTOP_MESSAGE)


# The core's vehicle inputs, each by a field of the typed frame that carries it (WheelSpeeds by fl_mps).
_REPORT_FIELDS = (
    "fl_mps",
    "long_accel_mps2",
    "gear_engaged",
    "steer_angle_rad",
    "brake_pedal_pressed",
    "throttle_pedal_pct",
    "safety_arm",
)


def _report_sources(
    codec: VehicleCodec, names: tuple[str, ...], monitors: tuple[RxMonitor, ...]
) -> dict[str, RxMonitor]:
    """For each of `_REPORT_FIELDS`, the monitor of the report whose typed frame has that field;
    ValueError naming the DBC if a profile leaves one out (the ECU would judge the car blind)."""
    found: dict[str, RxMonitor] = {}
    for name, monitor in zip(names, monitors, strict=True):
        fields = {f.name for f in dataclasses.fields(codec.info(name).frame_type)}
        for wanted in _REPORT_FIELDS:
            if wanted in fields and wanted not in found:
                found[wanted] = monitor
    missing = [f for f in _REPORT_FIELDS if f not in found]
    if missing:
        raise ValueError(f"{codec.dbc_path}: no vehicle report to the ECU carries {', '.join(missing)}")
    return found


def _read(monitor: RxMonitor, field: str, default: Any) -> Any:
    """The field of the report's last accepted frame, or `default` before the first one."""
    frame = monitor.state.last_frame
    return default if frame is None else getattr(frame, field)


def selftest() -> None:
    """The firmware image's deeper check (ecu.firmware's SELFTEST_HOOK): both vehicle profiles' codecs
    load from the image and give the ECU every input it judges the car by."""
    for profile in VEHICLE_PROFILES:
        codec = VehicleCodec(profile=profile)
        names = vehicle_reports(codec)
        rx = VehicleRx.for_node(codec, "ECU")
        _report_sources(codec, names, tuple(rx.monitor(name) for name in names))


# -- calibration for a run ---------------------------------------------------------------------------


def load_calibration_file(path: Path | None) -> tuple[Calibration | None, str | None]:
    """The calibration to run with, or None and the reason (the ECU then stays OFF)."""
    if path is None:
        return default_calibration(), None
    try:
        return loads_calibration(path.read_bytes(), str(path)), None
    except (OSError, CalibrationError) as exc:
        return None, str(exc)


# -- the ECU process -----------------------------------------------------------------------------------


def add_run_arguments(p: Any) -> None:
    p.add_argument(
        "--vehicle-bus",
        default="virtual:vehicle",
        help="vehicle CAN bus URL (socketcan:can0, remote:ws://127.0.0.1:PORT/, ...)",
    )
    p.add_argument(
        "--host-link",
        default="udp://127.0.0.1:47000?peer=127.0.0.1:47001",
        help="host link bus URL: CAN, or CAN frames over UDP (udp://BIND?peer=HOST:PORT)",
    )
    p.add_argument(
        "--vehicle-profile",
        choices=VEHICLE_PROFILES,
        default="bywire",
        help="what the vehicle CAN speaks: bywire (our gateway's reports) or pq (a VW PQ Passat's own "
        "messages, opendbc's vw_pq.dbc; command and E-stop stay ours)",
    )
    p.add_argument(
        "--calibration", type=Path, help="calibration file (default: the packaged Passat calibration)"
    )
    p.add_argument(
        "--no-calibration",
        action="store_true",
        help="run without a calibration (the ECU stays OFF): what a store without a valid one boots",
    )
    p.add_argument("--store", type=Path, help="the store this image was booted from (boot status goes there)")
    p.add_argument("--seconds", type=float, help="stop after this long (default: run until SIGINT/SIGTERM)")
    p.add_argument("--no-rt", action="store_true", help="do not ask for SCHED_FIFO / mlockall / gc.freeze")
    p.add_argument("--rt-priority", type=int, default=80, help="SCHED_FIFO priority (default 80)")
    p.add_argument("--cpu", type=int, help="pin the ECU to this CPU")
    p.add_argument(
        "--stats-json", type=Path, help="write the loop statistics (bench ecu format) here at exit"
    )
    p.add_argument(
        "--ready-line", action="store_true", help="print 'ready' once running (for the HIL runner)"
    )


def main(argv: list[str] | None = None) -> int:
    """`bywire ecu run` without --store (and the firmware image's `run`): the 1 kHz ECU process."""
    import argparse
    import json
    import signal

    from bywire.clock import WallClock
    from bywire.ecu.boot_reporter import BootStatusWriter
    from bywire.ecu.executive import CyclicExecutive
    from bywire.ecu.health import FIRST_REPORT_CYCLES, SAMPLE_CYCLES, BootHealth
    from bywire.ecu.store import os_error_text, report_boot
    from bywire.protocol.bus_url import open_bus
    from bywire.realtime import apply_realtime

    parser = argparse.ArgumentParser(prog="bywire ecu run", description="run the ECU firmware at 1 kHz")
    add_run_arguments(parser)
    # Passed by the boot supervisor only (not a `bywire ecu run` option): the store this image was
    # booted from accepts unsigned firmware, so what runs here may be anybody's build.
    parser.add_argument("--unsigned-store", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.unsigned_store:
        print(f"ecu: !!! booted from a store that accepts UNSIGNED firmware ({args.store})", flush=True)
    cal: Calibration | None
    cal_error: str | None
    if args.no_calibration:
        cal, cal_error = None, "no calibration"
    else:
        cal, cal_error = load_calibration_file(args.calibration)
    if cal_error:
        print(f"ecu: calibration refused, staying OFF: {cal_error}", flush=True)
    else:
        assert cal is not None
        print(f"ecu: calibration {cal.vehicle} version {cal.version}", flush=True)
    vehicle_bus = open_bus(args.vehicle_bus)
    host_bus = open_bus(args.host_link)
    clock = WallClock()
    stats = CycleStats()
    on_cal = None
    if args.store is not None:
        from bywire.ecu.flash import persist_calibration_bytes

        def on_cal(data: bytes, _cal: Calibration) -> None:
            persist_calibration_bytes(args.store, data)

    app = EcuApp(
        vehicle_bus,
        host_bus,
        clock,
        cal,
        cal_error,
        stats=stats,
        on_calibration=on_cal,
        vehicle_profile=args.vehicle_profile,
    )
    rt = None if args.no_rt else apply_realtime(priority=args.rt_priority, cpu=args.cpu)
    scheduler = rt.summary() if rt is not None else "not requested (--no-rt)"
    print(f"ecu: real-time: {scheduler}", flush=True)
    stopping = False

    def _stop(signum: int, frame: object) -> None:
        nonlocal stopping
        stopping = True

    signal.signal(signal.SIGINT, _stop)
    signal.signal(signal.SIGTERM, _stop)
    executive = CyclicExecutive(0.001, clock, app.step, stats)
    end = clock.now() + args.seconds if args.seconds is not None else math.inf
    booted = False
    report_failed = False
    health = BootHealth()

    def report_error(exc: OSError) -> None:
        # The ECU keeps running: without its reports a trial image is not confirmed (and the
        # supervisor rolls it back), but a confirmed one must not stop over a status file.
        nonlocal report_failed
        if not report_failed:
            report_failed = True
            print(f"ecu: !!! cannot write the boot status: {os_error_text(exc)}", flush=True)

    store = args.store
    reporter = (
        BootStatusWriter(lambda status: report_boot(store, **status), report_error)
        if store is not None
        else None
    )

    def progress(cycles: int) -> None:
        # Called after every 1 ms cycle: returns at once on all but one cycle in SAMPLE_CYCLES.
        nonlocal booted
        if cycles < FIRST_REPORT_CYCLES or (booted and cycles % SAMPLE_CYCLES):
            return
        now = clock.now()
        faults = app.internal_fault_events
        health.sample(now, app.node.host_alive(now), faults)
        state = app.core.safety.state
        if reporter is not None and health.report_due(now):
            reporter.submit(  # written beside the loop (ecu.boot_reporter)
                {
                    "state_name": state.name,
                    "healthy_s": health.healthy_s,
                    "host_link_up": health.host_link_up,
                    "internal_faults": health.internal_faults,
                    "unsigned_store": args.unsigned_store,
                }
            )
        if not booted:
            booted = True
            print(f"ecu: running, state {state.name}", flush=True)
            if args.ready_line:
                print("ready", flush=True)

    try:
        executive.run(stop=lambda: stopping or clock.now() >= end, progress=progress)
    finally:
        if reporter is not None:
            reporter.close()
        snapshot: dict[str, Any] = stats.snapshot()
        snapshot["scheduler"] = scheduler
        snapshot["final_state"] = app.core.safety.state.name
        snapshot["vehicle_rx"] = app.rx_stats()["total"]
        snapshot["health"] = app.health_summary()
        snapshot["host_link"] = app.node.host_rhythm()
        if args.stats_json is not None:
            args.stats_json.parent.mkdir(parents=True, exist_ok=True)
            args.stats_json.write_text(json.dumps(snapshot, indent=2) + "\n", encoding="utf-8")
        late = snapshot["lateness_us"]
        print(
            f"ecu: stopped in {snapshot['final_state']} after {snapshot['cycles']} cycles, "
            f"{snapshot['overruns']} overruns, lateness p50 {late['p50']:.0f} us p99 {late['p99']:.0f} us "
            f"max {late['max']:.0f} us",
            flush=True,
        )
        if app.internal_fault_events:
            h = snapshot["health"]
            print(
                f"ecu: !!! {app.internal_fault_events} internal faults: {h['loop_stalls']} loop stalls "
                f"(largest gap {h['max_cycle_gap_ms']:.1f} ms), {h['cycle_exceptions']} exceptions "
                f"({h['last_exception']}), {h['tx_guard_trips']} commands refused by the transmit guard "
                f"({h['tx_guard_last_reason']})",
                flush=True,
            )
        vehicle_bus.shutdown()
        host_bus.shutdown()
    return 0
