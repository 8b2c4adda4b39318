"""The radar's target frames off the sensor bus (E2E-checked like every vehicle frame): the newest target
each release, for the lead tracker (seed 000 section 11.2's lead vehicle).
"""

from __future__ import annotations

import math

import can

from bywire.host.modules.messages import RADAR, RadarReport
from bywire.host.runtime.module import Module, ModuleContext
from bywire.protocol.timebase import rx_time_s
from bywire.protocol.vehicle_can import RadarTarget, VehicleCodec
from bywire.protocol.vehicle_rx import VehicleRx

RADAR_STALE_S = 0.25  # 5 radar cycles without a target: treat the lane as free


class RadarIo(Module):
    def __init__(self, bus: can.BusABC | None) -> None:
        self.bus = bus
        self.codec = VehicleCodec()
        self.rx = VehicleRx.for_node(self.codec, "HOST")
        self._newest: tuple[RadarTarget, float] | None = None

    def step(self, ctx: ModuleContext) -> None:
        now = ctx.now_s
        while self.bus is not None:
            msg = self.bus.recv(timeout=0)
            if msg is None:
                break
            frame = self.rx.feed(msg, now, rx_time_s(msg, now))
            if isinstance(frame, RadarTarget):
                self._newest = (frame, now)
        if self._newest is None or now - self._newest[1] > RADAR_STALE_S:
            report = RadarReport(now, False, math.nan, math.nan, math.nan)
        else:
            target, rx_s = self._newest
            report = RadarReport(now, bool(target.valid), rx_s, target.range_m, target.range_rate_mps)
        ctx.publish(RADAR, report)
