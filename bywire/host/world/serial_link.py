"""Thin serial adapters of the pose server: the GPS/INS receiver's port (pyserial), read without blocking.

- `SerialSource`: opens a port (a device path or any pyserial URL) non-blocking and hands what has
  arrived to a callback with the receive time from an injected clock. Nothing here parses.
"""

from __future__ import annotations

from collections.abc import Callable
from types import TracebackType

import serial

Clock = Callable[[], float]


class SerialSource:
    """A receiver's serial port. `poll` reads what is there (never blocks) and passes it on."""

    def __init__(self, port: str, baudrate: int = 115200, read_size: int = 4096) -> None:
        try:
            self.port = serial.serial_for_url(port, baudrate=baudrate, timeout=0)
        except (serial.SerialException, ValueError) as e:
            raise OSError(f"cannot open GPS/INS serial port {port!r} at {baudrate} baud: {e}") from e
        self.read_size = read_size
        self.bytes_read = 0

    def poll(self, sink: Callable[[bytes, float], None], clock: Clock) -> int:
        """Reads everything waiting; `sink(data, t_rx_s)` per read. Returns the number of bytes."""
        total = 0
        while True:
            data = self.port.read(self.read_size)
            if not data:
                break
            t = clock()
            total += len(data)
            sink(data, t)
            if len(data) < self.read_size:
                break
        self.bytes_read += total
        return total

    def close(self) -> None:
        self.port.close()

    def __enter__(self) -> SerialSource:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


class SerialReader:
    """The host's end of the GPS line: a receiver's serial port (in HIL the pty slave), read as bytes."""

    def __init__(self, port: str, clock: Callable[[], float], baudrate: int = 115200) -> None:
        self.source = SerialSource(port, baudrate)
        self.clock = clock

    def read(self) -> bytes:
        out: list[bytes] = []

        def sink(data: bytes, _t: float) -> None:
            out.append(data)

        self.source.poll(sink, self.clock)
        return b"".join(out)

    def close(self) -> None:
        self.source.close()
