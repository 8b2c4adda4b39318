"""The ECU's safety state machine: engage latch, E-stop, driver override, faults, re-arm.

Paper: seed 003 Sec. II (the gateway's "disengagement of autonomous functions in case that the
driver needs to interfere"; actuator control and fail-safe functions on the real-time computer)
and DARPA Urban Challenge rules 3.4.2 (E-stop RUN / PAUSE / DISABLE); DESIGN section 4. The shape
follows opendbc's safety.h: one engage decision that every unhealthy input refuses, evaluated from
scratch every cycle.

The rules, each there because its absence was found exploitable:

- Only a human re-arms. Leaving DISABLED or MANUAL needs a rising edge of the safety driver's arm
  button (GW_Driver.SafetyArm), an input the drive-by-wire gateway reports on vehicle CAN, E2E
  protected, from the car's side: the host software cannot produce it. The service tool's SDO
  unlatch (0x2300sub1) of a DISABLE remains, as a second factor and never alone.
- Engagement is an edge, never a level: READY -> ENGAGED needs the host's ENGAGE flag to rise
  between two accepted requests while every precondition holds. After a latch, a reset or an NMT
  restart a held ENGAGE engages nothing. Edges of ENGAGE and REARM are taken only between fresh
  requests (a request that is stale or missing neither sets nor clears them), and edges of the arm
  button only between usable vehicle reports; at boot all three count as held.
- A longer stall is never judged safer than a shorter one: a gap between two ECU cycles longer than
  the firmware's bound is a stop fault by itself (LOOP_STALL, measured by the application).
- Every watchdog time is bounded by the firmware (protocol.canopen_link.dictionary MAX_*), and any exception
  inside a cycle (INTERNAL_ERROR) or a command the transmit guard had to replace (TX_GUARD,
  ecu.tx_guard) is a stop fault of its own.

States (bywire.protocol.ecu_types.EcuState) and transitions, in priority order each cycle:

1. E-stop DISABLE, from any state (fresh or not: a stale DISABLE is still a DISABLE) -> DISABLED,
   which forgets any unlatch given before. DISABLED is latched: while the radio is heard saying RUN
   or PAUSE (fresh, not DISABLE), a rising edge of the service unlatch is remembered; then a rising
   edge of the arm button, with usable vehicle data -> READY (OFF without a valid calibration).
2. MANUAL (latched driver override) -> READY on a rising edge of the arm button with no driver input
   present (seen in usable vehicle data, not assumed from stale data). The host's REARM does not
   leave MANUAL.
3. OFF -> READY as soon as the calibration is valid.
4. Driver intervention while the ECU actuates (ENGAGED, PAUSED, SAFE_STOP) -> MANUAL at once:
   brake pedal pressed, |steer torque| > driver_torque_threshold_nm, or throttle pedal >
   driver_throttle_threshold_pct (above the pedal sensor's offset and noise; opendbc takes any
   gas press). Driver inputs are only believed while vehicle data is usable; stale or corrupt
   vehicle data is a fault of its own. In READY/OFF a driver input only blocks engaging.
5. READY: calibration invalid -> OFF; E-stop PAUSE -> PAUSED (a pause that began in READY);
   a rising edge of ENGAGE with no fault at all -> ENGAGED.
6. ENGAGED: a stop fault -> SAFE_STOP; else PAUSE -> PAUSED (a pause that may resume); else the
   host dropping ENGAGE -> SAFE_STOP with HOST_STOP_REQUEST (a host that lets go asks for a
   controlled stop).
7. PAUSED: a stop fault -> SAFE_STOP; E-stop RUN (fresh) -> for a pause that began ENGAGED:
   ENGAGED if the host still asks for ENGAGE and no fault is active (DARPA's resume), else
   SAFE_STOP with HOST_STOP_REQUEST (the car stays held until the host re-arms it rather than being
   released by the radio alone); for a pause that began in READY: back to READY (it was never
   engaged, and a resume must not turn a level into an engagement).
8. SAFE_STOP -> on a rising edge of REARM with no active fault at all and at standstill: ENGAGED if
   ENGAGE is set in the same request (the REARM edge is the host's act; the held car goes straight
   back under control, never through a passive cycle with the brakes released), else READY.

Stop faults (`STOP_FAULTS`): host heartbeat lost, host request stale or not finite, vehicle data
stale, corrupt or not finite, E-stop radio stale, INVALID or in an error streak, an overrun streak
of at least `OVERRUN_STREAK_LIMIT` cycles, a loop stall, an internal error, a transmit-guard trip,
calibration invalid, the host's STOP flag, and a gear the gateway never confirmed (GEAR_TIMEOUT:
judged by the core from its shift state, `ecu.gear`, and added to this cycle's fault bits before
the transition).

`faults_active` are the conditions of this cycle; `latched` is the cause of the current state
(SAFE_STOP: the stop faults at entry; DISABLED: ESTOP_DISABLE; MANUAL: DRIVER_OVERRIDE; PAUSED:
ESTOP_PAUSE; OFF: CALIBRATION_INVALID when that is why), NONE in READY and ENGAGED.

Deviation: DARPA's PAUSE asks only for a prompt stop and a resume; a fault *during* a pause still
latches SAFE_STOP here, so resuming after a fault always needs the host's REARM.
Bits are handled as plain ints inside (IntFlag arithmetic costs microseconds per operation).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from bywire.ecu.calibration import Calibration, fast_frozen_init
from bywire.protocol.ecu_types import EcuState, EstopMode, Fault, Gear, RequestFlags

__all__ = [
    "ACTUATING_STATES",
    "OVERRUN_STREAK_LIMIT",
    "STOP_FAULTS",
    "STOP_STATES",
    "EcuInputs",
    "SafetyState",
    "active_fault_bits",
    "active_faults",
    "driver_intervention",
    "engage_allowed",
    "initial_safety_state",
    "safety_step",
    "safety_transition",
    "vehicle_usable",
]

# Consecutive cycle overruns that count as a fault: 10 ms late at 1 kHz is one whole period of
# the 100 Hz vehicle command frame (DBW_Command, GenMsgCycleTime 10), i.e. a missed command.
OVERRUN_STREAK_LIMIT = 10

_HOST_HEARTBEAT = int(Fault.HOST_HEARTBEAT)
_VEHICLE_TIMEOUT = int(Fault.VEHICLE_TIMEOUT)
_VEHICLE_CORRUPT = int(Fault.VEHICLE_CORRUPT)
_CALIBRATION_INVALID = int(Fault.CALIBRATION_INVALID)
_OVERRUN = int(Fault.OVERRUN)
_ESTOP_DISABLE = int(Fault.ESTOP_DISABLE)
_ESTOP_PAUSE = int(Fault.ESTOP_PAUSE)
_DRIVER_OVERRIDE = int(Fault.DRIVER_OVERRIDE)
_ESTOP_TIMEOUT = int(Fault.ESTOP_TIMEOUT)
_REQUEST_INVALID = int(Fault.REQUEST_INVALID)
_HOST_STOP_REQUEST = int(Fault.HOST_STOP_REQUEST)
_GEAR_TIMEOUT = int(Fault.GEAR_TIMEOUT)
_LOOP_STALL = int(Fault.LOOP_STALL)
_INTERNAL_ERROR = int(Fault.INTERNAL_ERROR)
_TX_GUARD = int(Fault.TX_GUARD)

STOP_FAULTS = Fault(
    _HOST_HEARTBEAT
    | _REQUEST_INVALID
    | _VEHICLE_TIMEOUT
    | _VEHICLE_CORRUPT
    | _ESTOP_TIMEOUT
    | _OVERRUN
    | _CALIBRATION_INVALID
    | _HOST_STOP_REQUEST
    | _GEAR_TIMEOUT
    | _LOOP_STALL
    | _INTERNAL_ERROR
    | _TX_GUARD
)
_STOP_FAULTS = int(STOP_FAULTS)

_RUN, _PAUSE, _DISABLE = EstopMode.RUN, EstopMode.PAUSE, EstopMode.DISABLE
_ENGAGE = int(RequestFlags.ENGAGE)
_REARM = int(RequestFlags.REARM)
_STOP = int(RequestFlags.STOP)

_OFF, _READY, _ENGAGED, _PAUSED, _SAFE_STOP, _DISABLED, _MANUAL = (
    EcuState.OFF,
    EcuState.READY,
    EcuState.ENGAGED,
    EcuState.PAUSED,
    EcuState.SAFE_STOP,
    EcuState.DISABLED,
    EcuState.MANUAL,
)
STOP_STATES = frozenset({EcuState.PAUSED, EcuState.SAFE_STOP, EcuState.DISABLED})
ACTUATING_STATES = frozenset({EcuState.ENGAGED, *STOP_STATES})

_isfinite = math.isfinite


@fast_frozen_init
@dataclass(frozen=True, slots=True, kw_only=True)
class EcuInputs:
    """Everything the core sees in one cycle, already reduced to numbers and booleans by the I/O
    layer (freshness decided by its timeouts, corruption by its counter/CRC streaks)."""

    estop_mode: EstopMode  # ESTOP_Radio.EstopMode, last received
    estop_fresh: bool  # that frame is within its timeout
    host_alive: bool  # CANopen heartbeat consumer: host heartbeat within its time
    request_accel_mps2: float  # host request PDO
    request_steer_angle_rad: float
    request_flags: RequestFlags
    request_fresh: bool  # request PDO within its timeout, counter and range checks passed
    vehicle_fresh: bool  # all GW_* report frames within their timeouts
    vehicle_corrupt: bool  # a streak of bad CRC / counter on the GW_* frames
    calibration_valid: bool  # the store's calibration passed validation and CRC
    overrun_streak: int  # consecutive cyclic-executive overruns, ending with the last cycle
    driver_brake_pressed: bool  # GW_Driver.BrakePedalPressed
    driver_throttle_pct: float  # GW_Driver.ThrottlePedalDriver
    driver_steer_torque_nm: float  # GW_Steer.SteerTorqueDriver
    speed_mps: float  # from GW_WheelSpeeds (mean of the four)
    accel_meas_mps2: float  # GW_Motion.LongAccel (dv/dt, gravity removed)
    steer_angle_meas_rad: float  # GW_Steer.SteerAngleActual (for a bumpless steering engage)
    unlatch: bool  # the service tool's DISABLE unlatch (SDO 0x2300sub1; the rising edge counts)
    gear_engaged: Gear = Gear.DRIVE  # GW_Motion.GearEngaged: the gear the gateway reports engaged
    # The fastest of the four GW_WheelSpeeds (a shift needs every wheel still); inf: not known, which
    # never counts as standstill.
    wheel_speed_max_mps: float = math.inf
    safety_arm: bool = False  # GW_Driver.SafetyArm: the safety driver's arm button (level)
    loop_stall: bool = False  # the gap to the previous cycle exceeded the firmware's bound
    internal_error: bool = False  # the previous cycle raised: its command came from the fallback
    tx_guard_trip: bool = False  # the transmit guard replaced the previous command


@dataclass(frozen=True, slots=True)
class SafetyState:
    state: EcuState
    latched: Fault  # cause of the current state
    rearm_prev: bool  # REARM flag of the last fresh request (edge detection)
    unlatch_prev: bool  # unlatch input last cycle
    engage_prev: bool = True  # ENGAGE flag of the last fresh request (edge detection)
    arm_prev: bool = True  # arm button in the last usable vehicle report (edge detection)
    # Read in one state only, and set on every entry into it (so stale elsewhere, by design):
    unlatched: bool = False  # DISABLED: the service unlatch was given since the DISABLE
    resume: bool = False  # PAUSED: the pause began ENGAGED, RUN may resume it


def initial_safety_state() -> SafetyState:
    # Every edge input counts as held at boot, so a switch held down (or an ENGAGE held by the host)
    # through a reset or restart is not an edge.
    # `unlatched` and `resume` keep their defaults: each is read in one state only (DISABLED,
    # PAUSED) and set on every entry into it.
    return SafetyState(
        EcuState.OFF, Fault.NONE, rearm_prev=True, unlatch_prev=True, engage_prev=True, arm_prev=True
    )


def vehicle_usable(inp: EcuInputs) -> bool:
    """Vehicle data fresh, not corrupt and finite: speed, acceleration and driver inputs usable."""
    return (
        inp.vehicle_fresh
        and not inp.vehicle_corrupt
        and _isfinite(inp.speed_mps)
        and _isfinite(inp.accel_meas_mps2)
        and _isfinite(inp.driver_throttle_pct)
        and _isfinite(inp.driver_steer_torque_nm)
        and _isfinite(inp.steer_angle_meas_rad)
    )


def driver_intervention(inp: EcuInputs, cal: Calibration) -> bool:
    """The driver is acting (only meaningful when `vehicle_usable`)."""
    return (
        inp.driver_brake_pressed
        or abs(inp.driver_steer_torque_nm) > cal.driver_torque_threshold_nm
        or inp.driver_throttle_pct > cal.driver_throttle_threshold_pct
    )


def active_fault_bits(inp: EcuInputs, cal: Calibration) -> int:
    """This cycle's fault conditions as plain int bits (`active_faults` as a Fault)."""
    f = 0
    if not inp.host_alive:
        f |= _HOST_HEARTBEAT
    if not (
        inp.request_fresh and _isfinite(inp.request_accel_mps2) and _isfinite(inp.request_steer_angle_rad)
    ):
        f |= _REQUEST_INVALID
    if not inp.vehicle_fresh:
        f |= _VEHICLE_TIMEOUT
    if inp.vehicle_corrupt or (inp.vehicle_fresh and not vehicle_usable(inp)):
        f |= _VEHICLE_CORRUPT
    elif inp.vehicle_fresh and driver_intervention(inp, cal):
        f |= _DRIVER_OVERRIDE
    if not inp.calibration_valid:
        f |= _CALIBRATION_INVALID
    if inp.overrun_streak >= OVERRUN_STREAK_LIMIT:
        f |= _OVERRUN
    mode = inp.estop_mode
    if mode == _DISABLE:
        f |= _ESTOP_DISABLE
    elif not inp.estop_fresh or (mode != _RUN and mode != _PAUSE):
        f |= _ESTOP_TIMEOUT
    elif mode == _PAUSE:
        f |= _ESTOP_PAUSE
    if int(inp.request_flags) & _STOP:
        f |= _HOST_STOP_REQUEST
    if inp.loop_stall:
        f |= _LOOP_STALL
    if inp.internal_error:
        f |= _INTERNAL_ERROR
    if inp.tx_guard_trip:
        f |= _TX_GUARD
    return f


_active = active_fault_bits


def active_faults(inp: EcuInputs, cal: Calibration) -> Fault:
    """This cycle's fault conditions (independent of the state)."""
    return Fault(_active(inp, cal))


def _engage_ok(active: int, flags: int) -> bool:
    # RUN and fresh, host alive, request fresh, vehicle fresh and sane, calibration valid, no
    # overrun streak, no stall, no internal fault, no driver, no stop request - and ENGAGE set.
    return active == 0 and bool(flags & _ENGAGE)


def engage_allowed(inp: EcuInputs, cal: Calibration) -> bool:
    """Every precondition of READY -> ENGAGED holds in this cycle's inputs and ENGAGE is set (the
    transition itself also needs ENGAGE to have risen since the last fresh request)."""
    return _engage_ok(_active(inp, cal), int(inp.request_flags))


def safety_step(st: SafetyState, inp: EcuInputs, cal: Calibration) -> tuple[SafetyState, int]:
    """One cycle of the state machine; returns the new state and the active fault bits (int)."""
    a = _active(inp, cal)
    return safety_transition(st, inp, a, cal), a


def safety_transition(st: SafetyState, inp: EcuInputs, a: int, cal: Calibration) -> SafetyState:
    """The state machine's transition for this cycle, given `a = active_fault_bits(inp, cal)`.

    Split from `safety_step` so that a caller that already judged these inputs (the core reuses
    the verdict while the executive passes it the same inputs object) does not judge them again;
    the transition itself still runs every cycle. Returns `st` itself when nothing changed."""
    flags = int(inp.request_flags)
    # Edges between fresh requests only: a stale or missing request is not the host letting go of
    # a flag (after an NMT restart the ECU has no request at all while the host still holds ENGAGE).
    if inp.request_fresh:
        rearm = bool(flags & _REARM)
        engage = bool(flags & _ENGAGE)
    else:
        rearm, engage = st.rearm_prev, st.engage_prev
    rearm_edge = rearm and not st.rearm_prev
    engage_edge = engage and not st.engage_prev
    usable = vehicle_usable(inp)
    arm = inp.safety_arm if usable else st.arm_prev  # a button is only seen in usable reports
    arm_edge = arm and not st.arm_prev
    unlatch_edge = inp.unlatch and not st.unlatch_prev
    s = st.state
    new = s
    latched = st.latched
    unlatched = st.unlatched
    resume = st.resume
    stopping = s in STOP_STATES

    if a & _ESTOP_DISABLE:
        if s != _DISABLED:
            new, latched = _DISABLED, Fault.ESTOP_DISABLE
        unlatched = False  # an unlatch given before this DISABLE does not count for it
    elif s == _DISABLED:
        # The radio must be heard saying RUN or PAUSE: not DISABLE (this branch) and not stale.
        heard = not a & _ESTOP_TIMEOUT
        if unlatch_edge and heard:
            unlatched = True
        if arm_edge and unlatched and heard:
            new, latched = _ready_or_off(a)
    elif s == _MANUAL:
        # "No driver input" must be seen, not assumed: an arm edge is only ever seen in usable
        # vehicle data, which is also where the driver's pedals and torque are believed.
        if arm_edge and not a & _DRIVER_OVERRIDE:
            new, latched = _ready_or_off(a)
    elif s == _OFF:
        if not a & _CALIBRATION_INVALID:
            new, latched = _READY, Fault.NONE
    elif a & _DRIVER_OVERRIDE and (s == _ENGAGED or stopping):
        new, latched = _MANUAL, Fault.DRIVER_OVERRIDE
    elif s == _READY:
        if a & _CALIBRATION_INVALID:
            new, latched = _OFF, Fault.CALIBRATION_INVALID
        elif a & _ESTOP_PAUSE:
            new, latched, resume = _PAUSED, Fault.ESTOP_PAUSE, False
        elif a == 0 and engage_edge:
            new, latched = _ENGAGED, Fault.NONE
    elif s == _ENGAGED:
        if a & _STOP_FAULTS:
            new, latched = _SAFE_STOP, Fault(a & _STOP_FAULTS)
        elif a & _ESTOP_PAUSE:
            new, latched, resume = _PAUSED, Fault.ESTOP_PAUSE, True
        elif not flags & _ENGAGE:
            new, latched = _SAFE_STOP, Fault.HOST_STOP_REQUEST
    elif s == _PAUSED:
        if a & _STOP_FAULTS:
            new, latched = _SAFE_STOP, Fault(a & _STOP_FAULTS)
        elif not a & _ESTOP_PAUSE:  # RUN and fresh: no ESTOP_TIMEOUT, which is a stop fault
            if not resume:
                new, latched = _READY, Fault.NONE  # never engaged: back to where the pause began
            # Releasing the brakes of a stopped, possibly unattended car must be an explicit act
            # (the host's ENGAGE, or its REARM from the hold), never a side effect of the radio.
            elif _engage_ok(a, flags):
                new, latched = _ENGAGED, Fault.NONE
            else:
                new, latched = _SAFE_STOP, Fault.HOST_STOP_REQUEST
    else:  # SAFE_STOP: every other state has its branch above
        standstill = usable and inp.speed_mps < cal.standstill_speed_mps
        if rearm_edge and a == 0 and standstill:
            new, latched = (_ENGAGED if flags & _ENGAGE else _READY), Fault.NONE

    if (
        new == s
        and latched == st.latched
        and rearm == st.rearm_prev
        and inp.unlatch == st.unlatch_prev
        and engage == st.engage_prev
        and arm == st.arm_prev
        and unlatched == st.unlatched
        and resume == st.resume
    ):
        return st  # the common case: nothing changed, no allocation
    return SafetyState(new, latched, rearm, inp.unlatch, engage, arm, unlatched, resume)


def _ready_or_off(active: int) -> tuple[EcuState, Fault]:
    if active & _CALIBRATION_INVALID:
        return _OFF, Fault.CALIBRATION_INVALID
    return _READY, Fault.NONE
