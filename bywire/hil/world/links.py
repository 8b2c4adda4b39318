"""Byte links between the plant's world and the host that are not CAN: the GPS receiver's serial line.

In HIL the runner creates a pseudo-terminal pair (`hil.world.pty_link.PtyLink`): the plant writes the
receiver's NMEA bytes to the master (`FdWriter`, non-blocking: a full buffer drops bytes and counts them,
like a UART overrun, instead of stalling the plant), the host opens the slave with pyserial like a real
``/dev/ttyUSB0`` (`host.world.serial_link.SerialReader`). In SIL one process holds both ends of a
`BytePipe`, deterministic.
V2V datagrams go through `protocol.v2x.transport` (`v2x://` UDP broadcast on loopback, or `mem://`).
"""

from __future__ import annotations

import errno
import os
from collections import deque
from collections.abc import Callable

MAX_PIPE_BYTES = 1 << 20  # a SIL host that stops reading cannot make the plant's pipe grow forever


class BytePipe:
    """In-process byte stream (SIL): the plant writes, the host reads everything written so far."""

    def __init__(self, max_bytes: int = MAX_PIPE_BYTES) -> None:
        self._chunks: deque[bytes] = deque()
        self._size = 0
        self.max_bytes = max_bytes
        self.written = 0
        self.dropped = 0

    def write(self, data: bytes) -> int:
        if not data:
            return 0
        room = self.max_bytes - self._size
        if len(data) > room:
            self.dropped += len(data) - max(room, 0)
            data = data[: max(room, 0)]
        if data:
            self._chunks.append(bytes(data))
            self._size += len(data)
            self.written += len(data)
        return len(data)

    def read(self) -> bytes:
        out = b"".join(self._chunks)
        self._chunks.clear()
        self._size = 0
        return out


class FdWriter:
    """Non-blocking writes to a file descriptor (the pty master handed to the plant process)."""

    def __init__(self, fd: int) -> None:
        self.fd = fd
        os.set_blocking(fd, False)
        self.written = 0
        self.overrun_bytes = 0

    def write(self, data: bytes) -> int:
        if not data:
            return 0
        try:
            n = os.write(self.fd, data)
        except OSError as e:
            if e.errno not in (errno.EAGAIN, errno.EWOULDBLOCK, errno.EIO):
                raise
            n = 0  # EIO: nobody has the slave open (yet); EAGAIN: the reader is behind
        self.written += n
        self.overrun_bytes += len(data) - n
        return n

    def close(self) -> None:
        os.close(self.fd)


ByteSink = Callable[[bytes], int]

__all__ = ["BytePipe", "ByteSink", "FdWriter"]
