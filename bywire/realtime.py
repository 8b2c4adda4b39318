"""Real-time set-up of a process (the ECU, the host, the bus servers): SCHED_FIFO priority, CPU affinity,
locked memory, frozen GC.

Paper: seed 000 Sec. 3 relays vehicle control commands at 1 kHz between the control process and
the ECU (KogMo-RTDB) but does not describe how that loop is made real-time; this module is our own
user-space discipline for a stock (non-PREEMPT_RT) Linux kernel. Like ros2_control's controller
manager (`userdoc.rst`: thread priority, CPU affinity, memory locking), each measure is a named,
configurable setting, and each one that the system refuses (no root, no CAP_SYS_NICE, container
limits) is recorded with its reason instead of aborting start-up: the ECU still runs, just with
worse jitter, and the one-line summary printed at start-up says exactly what is missing and how to
fix it.

What is applied, and why:

- SCHED_FIFO at `priority` (1..99): the executive's thread preempts every normal (CFS) task, so a
  busy host agent or plant on the same 2 cores cannot delay a 1 ms cycle. The executive sleeps
  between cycles (clock_nanosleep, absolute deadlines) and never spins: a SCHED_FIFO busy loop
  would starve the whole machine.
- CPU affinity to one core: no migrations (cache refills, cross-core wake-ups) in the loop.
- mlockall(MCL_CURRENT | MCL_FUTURE): no page faults in the loop, today's pages or tomorrow's.
- gc.collect(), gc.freeze(), gc.disable(): CPython's cyclic collector runs whenever allocations
  cross a threshold and can pause for milliseconds; inside a 1 kHz loop that is an overrun. After
  start-up everything alive is moved to the permanent generation (freeze) and the collector is
  off, so the loop must not create reference cycles (they would leak: reference counting alone
  frees everything else). Deviation from "never collect": callers may run `gc.collect()` at a
  safe point (e.g. not ENGAGED) if they ever need to.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno
import gc
import os
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

__all__ = [
    "MCL_CURRENT",
    "MCL_FUTURE",
    "LinuxRealtimeSystem",
    "RealtimeReport",
    "RealtimeStep",
    "RealtimeSystem",
    "apply_realtime",
]

# <sys/mman.h> on Linux (all architectures bywire targets).
MCL_CURRENT = 1
MCL_FUTURE = 2

_FIX_HINT: dict[str, dict[int, str]] = {
    "sched": {
        errno.EPERM: "EPERM: run as root or grant CAP_SYS_NICE / ulimit -r; in a container also "
        "check the cgroup's cpu.rt_runtime_us",
        errno.EINVAL: "EINVAL: priority not valid for SCHED_FIFO",
    },
    "affinity": {
        errno.EINVAL: "EINVAL: CPU not in this machine's or cgroup's allowed set",
        errno.EPERM: "EPERM: not allowed to change the affinity",
    },
    "mlock": {
        errno.EPERM: "EPERM: run as root or set CAP_IPC_LOCK/ulimit -l",
        errno.ENOMEM: "ENOMEM: locked-memory limit too small: raise ulimit -l (or CAP_IPC_LOCK)",
        errno.EAGAIN: "EAGAIN: some memory could not be locked",
    },
}


def _reason(kind: str, exc: OSError) -> str:
    hint = _FIX_HINT.get(kind, {}).get(exc.errno or 0)
    if hint is not None:
        return hint
    name = errno.errorcode.get(exc.errno or 0, "error")
    return f"{name}: {exc.strerror or exc}"


class RealtimeSystem(Protocol):
    """The OS calls `apply_realtime` makes; each raises OSError (with errno) when refused.

    Injected so that tests can exercise every failure path without changing the test process.
    """

    def set_fifo(self, priority: int) -> None: ...

    def set_affinity(self, cpu: int) -> None: ...

    def lock_memory(self) -> None: ...

    def freeze_gc(self) -> None: ...


class LinuxRealtimeSystem:
    """The real calls: os.sched_setscheduler, os.sched_setaffinity, libc mlockall, gc."""

    def set_fifo(self, priority: int) -> None:
        if not hasattr(os, "sched_setscheduler"):
            raise OSError(errno.ENOSYS, "os.sched_setscheduler not available on this platform")
        # pid 0: the calling thread, which is the one that runs the executive.
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))

    def set_affinity(self, cpu: int) -> None:
        if not hasattr(os, "sched_setaffinity"):
            raise OSError(errno.ENOSYS, "os.sched_setaffinity not available on this platform")
        os.sched_setaffinity(0, {cpu})

    def lock_memory(self) -> None:
        libc_name = ctypes.util.find_library("c") or "libc.so.6"
        try:
            libc = ctypes.CDLL(libc_name, use_errno=True)
            mlockall = libc.mlockall
        except (OSError, AttributeError) as exc:
            raise OSError(errno.ENOSYS, f"mlockall not found in {libc_name}") from exc
        mlockall.argtypes = [ctypes.c_int]
        mlockall.restype = ctypes.c_int
        if mlockall(MCL_CURRENT | MCL_FUTURE) != 0:
            err = ctypes.get_errno()
            raise OSError(err, os.strerror(err))

    def freeze_gc(self) -> None:
        gc.collect()
        gc.freeze()
        gc.disable()


@dataclass(frozen=True)
class RealtimeStep:
    """One measure: whether it was asked for, whether it took effect, and why not."""

    label: str  # as printed: "SCHED_FIFO 80", "CPU affinity 1", "mlockall", "gc frozen"
    requested: bool
    applied: bool
    reason: str = ""  # empty when applied

    def describe(self) -> str:
        if self.applied:
            return f"{self.label}: yes"
        return f"{self.label}: no ({self.reason if self.requested else 'not requested'})"


@dataclass(frozen=True)
class RealtimeReport:
    """What `apply_realtime` did, step by step."""

    sched_fifo: RealtimeStep
    affinity: RealtimeStep
    mlockall: RealtimeStep
    gc_frozen: RealtimeStep

    @property
    def steps(self) -> tuple[RealtimeStep, ...]:
        return (self.sched_fifo, self.affinity, self.mlockall, self.gc_frozen)

    @property
    def fully_applied(self) -> bool:
        """True when every requested measure took effect."""
        return all(s.applied for s in self.steps if s.requested)

    def summary(self) -> str:
        """The one start-up line: 'SCHED_FIFO 80: yes; ...; mlockall: no (EPERM: ...); gc frozen: yes'."""
        return "; ".join(s.describe() for s in self.steps)


def _attempt(label: str, kind: str, requested: bool, call: Callable[..., None], *args: int) -> RealtimeStep:
    if not requested:
        return RealtimeStep(label, requested=False, applied=False)
    try:
        call(*args)
    except OSError as exc:
        return RealtimeStep(label, requested=True, applied=False, reason=_reason(kind, exc))
    return RealtimeStep(label, requested=True, applied=True)


def apply_realtime(
    priority: int = 80,
    cpu: int | None = None,
    lock_memory: bool = True,
    freeze_gc: bool = True,
    *,
    system: RealtimeSystem | None = None,
) -> RealtimeReport:
    """Apply SCHED_FIFO `priority` (0 = leave the scheduler alone), pin to `cpu`, mlockall, freeze GC.

    Refusals by the OS are recorded in the report, never raised; only arguments that can never be
    valid (priority outside 0..99, negative cpu) raise ValueError.
    """
    if not 0 <= priority <= 99:
        raise ValueError(f"apply_realtime: priority {priority} outside 1..99 (0 = do not change policy)")
    if cpu is not None and cpu < 0:
        raise ValueError(f"apply_realtime: cpu {cpu} must be a CPU index >= 0")
    sys_ = system if system is not None else LinuxRealtimeSystem()
    fifo_label = f"SCHED_FIFO {priority}" if priority else "SCHED_FIFO"
    cpu_label = f"CPU affinity {cpu}" if cpu is not None else "CPU affinity"
    return RealtimeReport(
        sched_fifo=_attempt(fifo_label, "sched", priority > 0, sys_.set_fifo, priority),
        affinity=_attempt(cpu_label, "affinity", cpu is not None, sys_.set_affinity, cpu or 0),
        mlockall=_attempt("mlockall", "mlock", lock_memory, sys_.lock_memory),
        gc_frozen=_attempt("gc frozen", "gc", freeze_gc, sys_.freeze_gc),
    )
