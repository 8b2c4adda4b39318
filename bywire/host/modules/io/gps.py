"""The GPS/INS receiver's serial line as a module (seed 003 section II-h): the bytes that arrived, for
the pose server. It reads a `host.world.serial_link.SerialReader` (a receiver's port; a pipe in SIL).
"""

from __future__ import annotations

from typing import Any

from bywire.host.modules.gcdc_messages import (
    GPS_NMEA,
    NmeaChunk,
)
from bywire.host.runtime.module import Module, ModuleContext


class GpsSerialIo(Module):
    """Reads the GPS/INS serial line (a pty in HIL, a pipe in SIL, a receiver's port on a car)."""

    def __init__(self, source: Any) -> None:
        self.source = source  # anything with read() -> bytes

    def step(self, ctx: ModuleContext) -> None:
        data = self.source.read() if self.source is not None else b""
        ctx.publish(GPS_NMEA, NmeaChunk(ctx.now_s, ctx.now_s, bytes(data)))
