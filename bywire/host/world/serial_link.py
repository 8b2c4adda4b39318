"""Thin serial adapters of the pose server: the receiver's port (pyserial) and, for HIL, a pseudo-terminal
pair standing in for the cable so that the real serial path runs end to end.

- `SerialSource`: opens a port (a device path or any pyserial URL) non-blocking and hands what has
  arrived to a callback with the receive time from an injected clock. Nothing here parses.
- `PtyLink`: ``os.openpty()``; the emulator writes to the master fd, the pose server opens
  `PtyLink.slave_path` with pyserial like a real ``/dev/ttyUSB0``. Both ends are set raw (no echo, no
  CR/LF translation: NMEA's CR LF must arrive as sent). The master is non-blocking: when nobody reads the
  slave, the kernel's buffer fills and further bytes are dropped and counted (`overrun_bytes`), like a
  UART overrun, instead of stalling the plant.
"""

from __future__ import annotations

import contextlib
import errno
import os
import termios
import tty
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


class PtyLink:
    """A pseudo-terminal pair: write to the master, open `slave_path` with pyserial."""

    def __init__(self) -> None:
        self.master_fd, self._slave_fd = os.openpty()
        for fd in (self.master_fd, self._slave_fd):
            tty.setraw(fd, termios.TCSANOW)
        os.set_blocking(self.master_fd, False)
        self.slave_path = os.ttyname(self._slave_fd)
        self.bytes_written = 0
        self.overrun_bytes = 0

    def write(self, data: bytes) -> int:
        """Bytes accepted by the line; the rest is dropped (counted) if the reader is not keeping up."""
        if not data:
            return 0
        try:
            n = os.write(self.master_fd, data)
        except OSError as e:
            if e.errno in (errno.EAGAIN, errno.EWOULDBLOCK):
                n = 0
            else:
                raise
        self.bytes_written += n
        self.overrun_bytes += len(data) - n
        return n

    def close(self) -> None:
        # The slave fd is held open until here so that the pty does not hang up between pyserial reopenings.
        for fd in (self.master_fd, self._slave_fd):
            with contextlib.suppress(OSError):
                os.close(fd)

    def __enter__(self) -> PtyLink:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
