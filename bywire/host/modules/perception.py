"""Perception of the spine: the radar's target frames, and the lead vehicle tracked from them.

`RadarIo` is the thin adapter that reads RADAR_Target frames off the sensor bus (E2E-checked like
every vehicle frame) and publishes the newest target each release. `LeadTracker` turns it into the
lead vehicle's gap and speed (v_lead = v_own + range rate); it touches no bus, so it can run in a
worker process of its own — the crash-isolated perception of issue 3.
"""

from __future__ import annotations

import math

import can

from bywire.host.modules.messages import LEAD, ODOMETRY, RADAR, LeadTrack, Odometry, RadarReport
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


class LeadTracker(Module):
    def step(self, ctx: ModuleContext) -> None:
        radar: RadarReport | None = ctx.latest(RADAR)
        odo: Odometry | None = ctx.latest(ODOMETRY)
        v_own = odo.speed_mps if odo is not None else 0.0
        if radar is None or not radar.valid:
            track = LeadTrack(ctx.now_s, False, math.nan, math.nan)
        else:
            track = LeadTrack(ctx.now_s, True, radar.range_m, v_own + radar.range_rate_mps)
        ctx.publish(LEAD, track)
