"""Wheel speeds and the INS's yaw rate and acceleration off vehicle CAN (E2E-checked frames), for the
pose server's dead reckoning (seed 003 section II-h).
"""

from __future__ import annotations

import functools
import math

import can

from bywire.host.modules.gcdc_messages import (
    EGO_MOTION,
    EgoMotion,
)
from bywire.host.runtime.module import Module, ModuleContext
from bywire.protocol.timebase import rx_time_s
from bywire.protocol.vehicle_can import Motion, VehicleCodec, WheelSpeeds
from bywire.protocol.vehicle_rx import VehicleRx

MOTION_STALE_S = 0.1


@functools.lru_cache(maxsize=1)
def _codec() -> VehicleCodec:
    """The DBC, parsed once per process (~20 ms): a restarted adapter starts within its hang bound."""
    return VehicleCodec()


class VehicleSensorsIo(Module):
    """Wheel speeds and the INS's yaw rate and acceleration off vehicle CAN (E2E-checked frames)."""

    def __init__(self, bus: can.BusABC | None) -> None:
        self.bus = bus
        self.codec = _codec()
        self.rx = VehicleRx(self.codec, accept=("GW_WheelSpeeds", "GW_Motion"))
        self._speed: tuple[float, float] | None = None  # value, rx time
        self._motion: tuple[float, float, float] | None = None  # yaw rate, accel, rx time

    def step(self, ctx: ModuleContext) -> None:
        now = ctx.now_s
        samples = 0
        while self.bus is not None:
            msg = self.bus.recv(timeout=0)
            if msg is None:
                break
            t = rx_time_s(msg, now)
            frame = self.rx.feed(msg, now, t)
            if isinstance(frame, WheelSpeeds):
                self._speed = (frame.mean_mps, t)
                samples += 1
            elif isinstance(frame, Motion):
                self._motion = (frame.yaw_rate_radps, frame.long_accel_mps2, t)
        if self._speed is None or now - self._speed[1] > MOTION_STALE_S:
            ctx.publish(EGO_MOTION, EgoMotion(now, False, math.nan, math.nan, math.nan, math.nan, samples))
            return
        yaw, acc = (self._motion[0], self._motion[1]) if self._motion is not None else (0.0, 0.0)
        ctx.publish(EGO_MOTION, EgoMotion(now, True, self._speed[1], self._speed[0], yaw, acc, samples))
