"""Recording every frame of a run with python-can's loggers (.log, .asc, .blf, .csv, .trc by suffix).

One file for all buses of a run: each frame carries its bus in `channel` ("vehicle", "host_link"),
so a replay or a viewer can tell the ECU's vehicle CAN from its host link.
"""

from __future__ import annotations

from pathlib import Path

import can

from bywire.hil.sil_bus import received_copy


class Recorder:
    """Drains listener buses into one python-can log file; call `pump()` regularly, `close()` at the end."""

    def __init__(self, path: Path, buses: dict[str, can.BusABC]) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        self.path = path
        self.buses = buses
        self.logger = can.Logger(str(path))
        self.frames = 0

    def pump(self) -> int:
        n = 0
        for name, bus in self.buses.items():
            while True:
                msg = bus.recv(timeout=0)
                if msg is None:
                    break
                # A copy: in SIL receivers share one frame object, which must stay untouched.
                self.logger(received_copy(msg, msg.timestamp, name))
                n += 1
        self.frames += n
        return n

    def close(self) -> None:
        self.pump()
        self.logger.stop()
