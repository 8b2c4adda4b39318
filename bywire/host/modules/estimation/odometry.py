"""Odometry: the distance driven, integrated from the ECU's measured speed at its reception times.

The host's own notion of where it is along the path (seed 000 section 11: the vehicle "drives on
rails"); the stopping controller measures the distance to the stop line with it. The cooperative host's
GPS/INS pose server (`estimation/pose.py`) knows more; the spine keeps this one.
"""

from __future__ import annotations

from bywire.host.modules.messages import ECU_STATUS, ODOMETRY, EcuStatusReport, Odometry
from bywire.host.runtime.module import Module, ModuleContext


class OdometryModule(Module):
    def __init__(self) -> None:
        self.odometer_m = 0.0
        self.speed_mps = 0.0
        self._last_rx_s: float | None = None

    def step(self, ctx: ModuleContext) -> None:
        status: EcuStatusReport | None = ctx.latest(ECU_STATUS)
        if status is not None and status.valid:
            if self._last_rx_s is not None and status.rx_s > self._last_rx_s:
                self.odometer_m += status.speed_mps * (status.rx_s - self._last_rx_s)
            if self._last_rx_s is None or status.rx_s > self._last_rx_s:
                self._last_rx_s = status.rx_s
            self.speed_mps = status.speed_mps
        ctx.publish(
            ODOMETRY, Odometry(ctx.now_s, self.odometer_m, self.speed_mps, self._last_rx_s is not None)
        )
