"""The ECU's gear rules: when it may ask the gateway for another gear, and how it drives in reverse.

Not in the papers (AnnieWAY's gateway shifted on the computer's request; seed 003 Sec. II only says
the real-time computer handles actuator control and the fail-safe functions). DARPA rules 5.2 need
backing out of a parking spot, so bywire's ECU owns the shift sequence and the gateway owns the
selector (`DBW_Command.GearRequest` -> `GW_Motion.GearEngaged`):

1. The host asks for a gear with `RequestFlags.REVERSE` (set: REVERSE, clear: DRIVE).
2. While the wanted, the requested and the engaged gear are not all the same, the ECU does not drive:
   it brakes at `SHIFT_DECEL_MPS2` (throttle off) to standstill, i.e. every wheel speed below
   `SHIFT_STANDSTILL_SPEED_MPS`, and holds with the calibrated hold pressure.
3. Once the hold has been commanded for `SHIFT_BRAKE_SETTLE_S` (the pressure has built up), it asks
   the gateway for the wanted gear, and keeps holding until the gateway reports it engaged.
4. A requested gear that is not reported engaged within `GEAR_CONFIRM_TIMEOUT_S` is the stop fault
   `Fault.GEAR_TIMEOUT` (SAFE_STOP: the car is already held).
5. Only ENGAGED shifts. Every other state asks for the gear that is engaged (READY/OFF keep the last
   engaged gear, a stop or DISABLE never shifts).

Driving in reverse: the wheel speeds are magnitudes and the host's request is along the direction
of travel of the selected gear, so the cascaded controller runs unchanged on the speed magnitude and
on the acceleration along the direction of travel, `accel_along = sign(gear) * LongAccel` with the
INS's LongAccel signed in the vehicle frame (+ forward). `reverse_accel_limit_mps2` caps the request
so that the speed stays below `REVERSE_SPEED_MAX_MPS`.
"""

from __future__ import annotations

from bywire.protocol.ecu_types import Gear

__all__ = [
    "GEAR_CONFIRM_TIMEOUT_S",
    "REVERSE_SPEED_GAIN_PER_S",
    "REVERSE_SPEED_MAX_MPS",
    "SHIFT_BRAKE_SETTLE_S",
    "SHIFT_DECEL_MPS2",
    "SHIFT_STANDSTILL_SPEED_MPS",
    "accel_along_travel_mps2",
    "reverse_accel_limit_mps2",
]

# Reversing is for manoeuvres (parking, K-turns): walking pace plus a little, and the ECU enforces it
# whatever the host asks.
REVERSE_SPEED_MAX_MPS = 2.5
# The request is capped at gain * (limit - speed): 0 at the limit, braking above it. 1/s keeps the
# cap well below the controller's bandwidth, so it does not oscillate.
REVERSE_SPEED_GAIN_PER_S = 1.0
# Every wheel below this is standstill for a shift: a wheel-speed sensor's resolution is 0.01 m/s
# and the plant reports exactly 0 below 0.01 m/s; 0.05 m/s is 5 cm per second of creep at most.
SHIFT_STANDSTILL_SPEED_MPS = 0.05
# A shift the host asks for while rolling: a firm but comfortable stop (the host normally stops first).
SHIFT_DECEL_MPS2 = 2.0
# Three time constants of the brake-pressure lag (0.1 s in the Passat): 95 % of the hold pressure.
SHIFT_BRAKE_SETTLE_S = 0.3
# The gateway's shift takes 0.3 .. 0.5 s (hil/plant.py); three times that is a broken selector.
GEAR_CONFIRM_TIMEOUT_S = 1.5


def accel_along_travel_mps2(long_accel_mps2: float, gear: Gear) -> float:
    """The INS's longitudinal acceleration (vehicle frame, + forward) along the direction of travel of
    the engaged gear: positive when the speed magnitude grows."""
    return -long_accel_mps2 if gear == Gear.REVERSE else long_accel_mps2


def reverse_accel_limit_mps2(speed_mps: float) -> float:
    """The largest acceleration request along the direction of travel allowed in reverse at this speed
    magnitude."""
    return REVERSE_SPEED_GAIN_PER_S * (REVERSE_SPEED_MAX_MPS - speed_mps)
