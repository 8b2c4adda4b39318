"""Enumerations shared by the ECU, the host and the plant: ECU state, fault bits, request flags, gear.

These values travel on the wire (vehicle CAN `DBW_Command.EcuState`, the CANopen status PDO and the
request PDO), so they are part of the protocol contract: append, never renumber.
"""

from __future__ import annotations

from enum import IntEnum, IntFlag


class EcuState(IntEnum):
    """The ECU safety state machine's states (DESIGN section 4)."""

    OFF = 0  # booting, or no valid calibration: never engages
    READY = 1  # armed and healthy, waiting for an engage request; actuators passive
    ENGAGED = 2  # closing the host's acceleration and steering requests
    PAUSED = 3  # E-stop PAUSE: prompt stop, brakes hold; resumes on RUN (DARPA rules 3.4.2)
    SAFE_STOP = 4  # a fault: controlled stop at the configured deceleration, then hold; latched
    DISABLED = 5  # E-stop DISABLE: stop, propulsion off, brakes held; latched until manual unlatch
    MANUAL = 6  # driver intervened: control handed back at once; latched until re-armed


class Fault(IntFlag):
    """Fault bits reported in the status PDO and in EMCY frames."""

    NONE = 0
    HOST_HEARTBEAT = 1 << 0  # host heartbeat missing for longer than the consumer time
    VEHICLE_TIMEOUT = 1 << 1  # a vehicle-CAN report frame is stale
    VEHICLE_CORRUPT = 1 << 2  # a streak of corrupt / repeated / out-of-order vehicle frames
    CALIBRATION_INVALID = 1 << 3  # no calibration, or it failed validation / CRC
    OVERRUN = 1 << 4  # a streak of cyclic-executive overruns
    ESTOP_DISABLE = 1 << 5
    ESTOP_PAUSE = 1 << 6
    DRIVER_OVERRIDE = 1 << 7
    ESTOP_TIMEOUT = 1 << 8  # E-stop radio frame stale: treated like a fault (stop and hold)
    REQUEST_INVALID = 1 << 9  # host request PDO stale, out of range or with a bad alive counter
    HOST_STOP_REQUEST = 1 << 10  # the host itself asked for a controlled stop (supervisor)
    GEAR_TIMEOUT = 1 << 11  # a requested gear was not reported engaged within the shift timeout
    # The ECU's own health (DESIGN section 4: a longer stall is never judged safer than a shorter one)
    LOOP_STALL = 1 << 12  # two ECU cycles further apart than the firmware's bound (ecu.app)
    INTERNAL_ERROR = 1 << 13  # an exception inside a cycle: the command came from the fallback
    TX_GUARD = 1 << 14  # the transmit guard replaced a command that broke a limit (ecu.tx_guard)


class RequestFlags(IntFlag):
    """Bits of the host's request PDO."""

    NONE = 0
    # The host wants the ECU to close its requests. READY -> ENGAGED needs this flag to RISE (an edge
    # between two accepted requests) while every precondition holds; ENGAGED and a PAUSE that began
    # ENGAGED need it held (dropping it asks for a controlled stop).
    ENGAGE = 1 << 0
    REARM = 1 << 1  # clear a latched SAFE_STOP at standstill once the cause is gone (rising edge)
    STOP = 1 << 2  # controlled stop and hold requested by the host
    STEER = 1 << 3  # the steering request is valid
    # Drive in reverse. The request's accel_mps2 stays along the direction of travel of the selected
    # gear (positive: the speed magnitude grows). The ECU brakes to standstill, shifts and drives on
    # only once the gateway reports the gear engaged.
    REVERSE = 1 << 4


class Gear(IntEnum):
    """Transmission gear, as on vehicle CAN `DBW_Command.GearRequest` / `GW_Motion.GearEngaged` and
    in the status PDO. The drive-by-wire gateway owns the selector: the ECU only asks for a gear."""

    DRIVE = 0
    REVERSE = 1


class EstopMode(IntEnum):
    """E-stop radio mode, as on vehicle CAN `ESTOP_Radio.EstopMode`."""

    INVALID = 0
    RUN = 1
    PAUSE = 2
    DISABLE = 3
