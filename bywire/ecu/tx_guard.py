"""The transmit guard: every DBW_Command is checked right before it is sent, whatever computed it.

DESIGN section 4 ("one transmit guard checks every outgoing command against state and limits") and
opendbc's `tx_hook` (safety.h): the core is meant to guarantee every rule below; the guard checks
them again on the frame that leaves the ECU, with nothing from the controller but the frame, the
safety state and the calibration. A command that breaks a rule is not sent: the guard's safe stop
command goes instead, and the application reports Fault.TX_GUARD, a stop fault, to the core's next
cycle (ecu.app). Written to be read by an auditor: one rule per line, each with its reason.

Rules (`check_command`; the first broken rule is named):

1. every value is a finite number inside the DBC's wire range and the calibration's limits:
   0 <= throttle <= 100 %, 0 <= brake <= 200 bar, |steer| <= steer_max_rad;
2. the frame's EcuState field is the safety state;
3. passive states (OFF, READY, MANUAL) command nothing: no engage, no throttle, no brake, no
   steering (so steering is enabled only while ENGAGED or in a stop that keeps its angle);
4. stops (PAUSED, SAFE_STOP, DISABLED) keep the gateway engaged (our brakes hold the car);
5. throttle only while ENGAGED (propulsion never helps a stop), never together with the brake, and
   only with the ignition on;
6. while steering stays enabled from one sent command to the next, the angle moves by at most
   steer_rate_max_radps times the time between them (plus one DBC step of 0.0001 rad);
7. ignition off and park brake only in DISABLED (the hold after an E-stop DISABLE);
8. a gear other than the engaged one is asked for only while ENGAGED, braked and without throttle
   (the gateway shifts at standstill with the brake applied).

A refused command is replaced (`TxGuard.replacement`): in a passive state by the passive command
(engage off: whoever drives keeps the car), otherwise by the safe stop command: gateway engaged,
no throttle, the brake ramped from the last command sent to the calibration's hold pressure within
FALLBACK_BRAKE_RAMP_S, steering held at the last angle sent (enabled only if it was), the gear
engaged (a shift in progress is abandoned). It decelerates at about what
the hold pressure gives (4.7 m/s^2 for the Passat's 50 bar: inside the -4.5 m/s^2 design clamp's
class of stop) and holds the car: what a broken controller must be replaced with.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from bywire.ecu.calibration import BRAKE_BAR_MAX, THROTTLE_PCT_MAX, Calibration
from bywire.protocol.ecu_types import EcuState, Gear
from bywire.protocol.vehicle_can import DbwCommand

__all__ = [
    "FALLBACK_BRAKE_RAMP_S",
    "STEER_LSB_RAD",
    "SafeStopCommand",
    "TxGuard",
    "check_command",
]

# An internal fault is an emergency: the hold pressure is reached this fast from any brake
# pressure (50 bar in 0.5 s, about 9 m/s^3 on the Passat: twice the comfort jerk limit).
FALLBACK_BRAKE_RAMP_S = 0.5
STEER_LSB_RAD = 0.0001  # DBW_Command.SteerAngle's scale: rounding on the wire may add one step

_PASSIVE = frozenset({EcuState.OFF, EcuState.READY, EcuState.MANUAL})
_STOPS = frozenset({EcuState.PAUSED, EcuState.SAFE_STOP, EcuState.DISABLED})
_isfinite = math.isfinite


def check_command(
    cmd: DbwCommand,
    state: EcuState,
    gear_engaged: Gear,
    cal: Calibration,
    prev: DbwCommand | None,
    dt_s: float,
    steer_continuous: bool,
) -> str | None:
    """None if `cmd` may be sent in `state`, else the rule it breaks (a sentence for the log).

    `prev` is the command sent before (None: none yet), `dt_s` the time since it was sent, and
    `steer_continuous` whether steering stayed enabled in every cycle in between (rule 6 only
    compares two angles that one continuous rate-limited motion joins)."""
    thr, brk, steer = cmd.throttle_pct, cmd.brake_bar, cmd.steer_angle_rad
    if not (_isfinite(thr) and _isfinite(brk) and _isfinite(steer)):
        return f"not a finite command: throttle {thr} %, brake {brk} bar, steer {steer} rad"
    if not 0.0 <= thr <= THROTTLE_PCT_MAX:
        return f"throttle {thr} % outside 0 .. {THROTTLE_PCT_MAX:g} %"
    if not 0.0 <= brk <= BRAKE_BAR_MAX:
        return f"brake {brk} bar outside 0 .. {BRAKE_BAR_MAX:g} bar"
    if abs(steer) > cal.steer_max_rad:
        return f"steer {steer} rad beyond the calibrated +-{cal.steer_max_rad} rad"
    if cmd.ecu_state != state:
        return f"frame says {EcuState(cmd.ecu_state).name}, the safety state is {state.name}"
    if state in _PASSIVE:
        if cmd.engage or brk > 0.0 or cmd.steer_enable:  # (a throttle is refused by rule 5)
            return f"{state.name} is passive: engage, throttle, brake and steering must be off"
    elif state in _STOPS and not cmd.engage:
        return f"{state.name} releases the gateway: a stop must hold the car with our brakes"
    if thr > 0.0:
        if state != EcuState.ENGAGED:
            return f"throttle {thr} % in {state.name}: propulsion only while ENGAGED"
        if brk > 0.0:
            return f"throttle {thr} % together with brake {brk} bar"
        if not cmd.ignition:
            return f"throttle {thr} % with the ignition off"
    if cmd.steer_enable and prev is not None and prev.steer_enable and steer_continuous:
        step = abs(steer - prev.steer_angle_rad)
        limit = cal.steer_rate_max_radps * max(dt_s, 0.0) + STEER_LSB_RAD
        if step > limit:
            return f"steering moved {step:.5f} rad in {dt_s * 1e3:.1f} ms, the rate limit allows {limit:.5f}"
    if (cmd.park_brake or not cmd.ignition) and state != EcuState.DISABLED:
        return f"ignition off or park brake in {state.name}: only the hold after a DISABLE"
    if cmd.gear_request != gear_engaged and not (state == EcuState.ENGAGED and brk > 0.0 and thr == 0.0):
        return (
            f"gear {Gear(cmd.gear_request).name} asked for with {Gear(gear_engaged).name} engaged "
            f"in {state.name}, brake {brk} bar, throttle {thr} %: shifts only held, braked, engaged"
        )
    return None


@dataclass(frozen=True, slots=True)
class SafeStopCommand:
    """What the guard sends instead of a command it refused (see the module docstring)."""

    brake_start_bar: float  # the brake of the last command sent when the fallback began
    start_s: float


class TxGuard:
    """The guard's memory between sends: the last command that left the ECU and the fallback in
    progress. `guard(cmd, ...)` returns the frame to send and the broken rule (None: `cmd` itself)."""

    def __init__(self, cal: Calibration) -> None:
        self.cal = cal
        self.last_sent: DbwCommand | None = None
        self.last_sent_s = -math.inf
        self.trips = 0  # commands refused since boot
        self.last_reason: str | None = None
        self._steer_continuous = True
        self._fallback: SafeStopCommand | None = None

    def note_cycle(self, steer_enable: bool) -> None:
        """Every core cycle, sent or not: whether steering stayed enabled since the last send."""
        if not steer_enable:
            self._steer_continuous = False

    def guard(
        self, cmd: DbwCommand, state: EcuState, gear_engaged: Gear, now_s: float
    ) -> tuple[DbwCommand, str | None]:
        reason = check_command(
            cmd,
            state,
            gear_engaged,
            self.cal,
            self.last_sent,
            now_s - self.last_sent_s,
            self._steer_continuous,
        )
        if reason is None:
            self._fallback = None
            self._sent(cmd, now_s)
            return cmd, None
        self.trips += 1
        self.last_reason = reason
        return self.replacement(state, gear_engaged, now_s), reason

    def replacement(self, state: EcuState, gear_engaged: Gear, now_s: float) -> DbwCommand:
        """What goes out instead of a refused command (or of none, when a cycle raised): in a passive
        state the passive command (whoever drives the car keeps it: braking a car a human drives
        would be the hazard), else the safe stop command."""
        if state in _PASSIVE:
            self._fallback = None
            frame = DbwCommand(
                throttle_pct=0.0,
                brake_bar=0.0,
                steer_angle_rad=0.0,
                engage=False,
                park_brake=False,
                ignition=True,
                steer_enable=False,
                ecu_state=state,
                gear_request=gear_engaged,
            )
            self._sent(frame, now_s)
            return frame
        return self.safe_stop(gear_engaged, now_s)

    def safe_stop(self, gear_engaged: Gear, now_s: float) -> DbwCommand:
        """The safe stop command at `now_s` (and remember it as sent)."""
        prev = self.last_sent
        if self._fallback is None:
            start = prev.brake_bar if prev is not None and _isfinite(prev.brake_bar) else 0.0
            self._fallback = SafeStopCommand(min(max(start, 0.0), BRAKE_BAR_MAX), now_s)
        fb = self._fallback
        hold = self.cal.hold_brake_bar
        ramp = (now_s - fb.start_s) / FALLBACK_BRAKE_RAMP_S
        brake = fb.brake_start_bar + (hold - fb.brake_start_bar) * min(max(ramp, 0.0), 1.0)
        if fb.brake_start_bar > hold:
            brake = fb.brake_start_bar  # already braking harder than the hold: keep it
        steer, steer_en = 0.0, False
        if prev is not None and prev.steer_enable and _isfinite(prev.steer_angle_rad):
            lim = self.cal.steer_max_rad
            steer, steer_en = min(max(prev.steer_angle_rad, -lim), lim), True
        frame = DbwCommand(
            throttle_pct=0.0,
            brake_bar=brake,
            steer_angle_rad=steer,
            engage=True,
            park_brake=False,
            ignition=True,
            steer_enable=steer_en,
            ecu_state=EcuState.SAFE_STOP,
            gear_request=gear_engaged,
        )
        self._sent(frame, now_s)
        return frame

    def _sent(self, frame: DbwCommand, now_s: float) -> None:
        self.last_sent = frame
        self.last_sent_s = now_s
        self._steer_continuous = True
