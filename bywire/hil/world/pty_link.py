"""A pseudo-terminal pair standing in for the GPS receiver's cable in HIL, so that the real serial path
(`host.world.serial_link`) runs end to end.

``os.openpty()``; the emulator writes to the master fd, the pose server opens `PtyLink.slave_path` with
pyserial like a real ``/dev/ttyUSB0``. Both ends are set raw (no echo, no CR/LF translation: NMEA's CR LF
must arrive as sent). The master is non-blocking: when nobody reads the slave, the kernel's buffer fills
and further bytes are dropped and counted (`overrun_bytes`), like a UART overrun, instead of stalling the
plant.
"""

from __future__ import annotations

import contextlib
import errno
import os
import termios
import tty
from types import TracebackType


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
