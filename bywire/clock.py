"""One clock abstraction for wall time (HIL, real ECU) and simulated time (SIL, replay).

Every loop in bywire asks a `Clock` for the time and sleeps on it, never on `time` directly, so the
same ECU, plant and host code runs in real time and in lockstep simulation.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import time
from typing import Protocol

CLOCK_MONOTONIC = 1
TIMER_ABSTIME = 1


class Clock(Protocol):
    """Monotonic seconds, and sleeping until an absolute instant on the same time base."""

    def now(self) -> float: ...

    def sleep_until(self, t_s: float) -> None: ...


class _Timespec(ctypes.Structure):
    _fields_ = [("tv_sec", ctypes.c_long), ("tv_nsec", ctypes.c_long)]


def _load_clock_nanosleep():  # type: ignore[no-untyped-def]
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        fn = libc.clock_nanosleep
    except (OSError, AttributeError):
        return None
    fn.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.POINTER(_Timespec), ctypes.POINTER(_Timespec)]
    fn.restype = ctypes.c_int
    return fn


class WallClock:
    """CLOCK_MONOTONIC, with absolute-deadline sleeps (clock_nanosleep TIMER_ABSTIME) where available.

    Absolute deadlines keep a periodic loop from drifting: lateness in one cycle does not shift the
    next deadline. `time.monotonic()` reads CLOCK_MONOTONIC on Linux, so both share one time base.
    """

    def __init__(self) -> None:
        self._nanosleep = _load_clock_nanosleep() if os.name == "posix" else None
        self._ts = _Timespec()

    def now(self) -> float:
        return time.monotonic()

    def sleep_until(self, t_s: float) -> None:
        if self._nanosleep is not None:
            sec = int(t_s)
            self._ts.tv_sec = sec
            self._ts.tv_nsec = int((t_s - sec) * 1e9)
            # EINTR: a signal woke us early; the caller re-checks the time, so returning is fine.
            self._nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, ctypes.byref(self._ts), None)
            return
        remaining = t_s - time.monotonic()
        if remaining > 0:
            time.sleep(remaining)


class SimClock:
    """Simulated time that only moves when the lockstep driver advances it."""

    def __init__(self, start_s: float = 0.0) -> None:
        self._t = start_s

    def now(self) -> float:
        return self._t

    def advance_to(self, t_s: float) -> None:
        if t_s < self._t:
            raise ValueError(f"simulated time cannot go back: {t_s} < {self._t}")
        self._t = t_s

    def sleep_until(self, t_s: float) -> None:
        # In lockstep nothing else runs while a component "sleeps": time jumps to the deadline.
        if t_s > self._t:
            self._t = t_s
