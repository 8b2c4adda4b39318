"""The boot status written beside the 1 kHz loop, not in it (DESIGN section 4: the loop does no I/O
that can block it).

The boot supervisor (`ecu.boot`) learns the running image's state and health from a file that the
image replaces about once a second (`store.report_boot`). Written from the loop itself, its system
calls (a temporary file, a write, a rename) ran at the loop's real-time priority inside a cycle and
held it for as long as the file system took. Measured on the 2-core VM (2026-11-27), one report
takes 0.75 ms median and 1.5 ms at most on a quiet disk (most of a 1 ms cycle), and 4 ms median,
44 ms at most beside a process writing to the disk; a 25 ms stall of the loop, a LOOP_STALL that
stopped the car, was seen in a HIL run. The loop now
hands the newest status to a thread of normal priority and goes on at once. A status not yet
written when a newer one comes is replaced by it: the supervisor only ever wants the newest.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Mapping
from typing import Any


def _normal_priority() -> None:
    """Leave SCHED_FIFO for the calling thread (threads inherit their creator's policy): the writer
    must never take the CPU from the loop."""
    try:
        if os.sched_getscheduler(0) != os.SCHED_OTHER:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except (OSError, AttributeError):
        pass  # not Linux, or not allowed: it then runs as its creator does, still off the loop


class BootStatusWriter:
    """Writes statuses handed to it by `submit` with `write(status)` in a thread of its own; an
    OSError of a write goes to `on_error` and the thread goes on with the next status."""

    def __init__(
        self, write: Callable[[Mapping[str, Any]], None], on_error: Callable[[OSError], None]
    ) -> None:
        self._write = write
        self._on_error = on_error
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._pending: dict[str, Any] | None = None
        self._closing = False
        self.written = 0
        self._thread = threading.Thread(target=self._run, name="ecu-boot-status", daemon=True)
        self._thread.start()

    def submit(self, status: Mapping[str, Any]) -> None:
        """Called from the loop: no I/O and no wait beyond a lock the writer holds for an assignment."""
        with self._lock:
            self._pending = dict(status)
        self._wake.set()

    def close(self, timeout_s: float = 1.0) -> None:
        """Write what is pending, then end the thread (waited for at most `timeout_s`)."""
        self._closing = True
        self._wake.set()
        self._thread.join(timeout_s)

    def _run(self) -> None:
        _normal_priority()
        while True:
            self._wake.wait()
            self._wake.clear()
            with self._lock:
                status, self._pending = self._pending, None
            if status is not None:
                try:
                    self._write(status)
                    self.written += 1
                except OSError as exc:
                    self._on_error(exc)
            if self._closing and self._pending is None:
                return
