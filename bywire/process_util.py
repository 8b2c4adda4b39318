"""Small helpers shared by the processes of a run (plant, host): start handshake, clean shutdown, and what
Linux says of a thread (/proc: its CPU time and scheduler state)."""

from __future__ import annotations

import os
import signal
import sys
import time
from collections.abc import Collection, Iterator
from contextlib import contextmanager
from pathlib import Path


def wait_for_t0(arg: str | None) -> float:
    """The common start instant: `-` reads it from stdin after printing `ready`; a number is used as is.

    Without --t0 the process starts right away (interactive use).
    """
    print("ready", flush=True)
    if arg is None:
        return time.monotonic()
    if arg == "-":
        line = sys.stdin.readline()
        if not line:
            raise SystemExit("no start time on stdin (runner gone?)")
        return float(line)
    return float(arg)


class StopFlag:
    """Set by SIGINT/SIGTERM so that loops finish their cycle and write their files."""

    def __init__(self) -> None:
        self.stop = False
        signal.signal(signal.SIGINT, self._handler)
        signal.signal(signal.SIGTERM, self._handler)
        # a blocked signal is inherited too, and a handler never runs for it
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})

    def _handler(self, signum: int, frame: object) -> None:
        self.stop = True

    def __call__(self) -> bool:
        return self.stop


class SignalInterrupt(KeyboardInterrupt):
    """A signal handled like Ctrl-C (raised in the main thread, so `finally` blocks run and a run
    writes its files); `signum` says which one asked (a shell's exit status is then 128 + signum)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


@contextmanager
def signals_interrupt(*signums: int) -> Iterator[None]:
    """Within the block each of `signums` raises `SignalInterrupt` in the main thread (SIGTERM, the
    polite stop of a supervisor or `timeout`, then ends a run as Ctrl-C does); the handlers before
    are restored after it."""
    before = {s: signal.getsignal(s) for s in signums}

    def interrupt(signum: int, frame: object) -> None:
        raise SignalInterrupt(signum)

    try:
        for s in signums:
            signal.signal(s, interrupt)
        yield
    finally:
        for s, handler in before.items():
            signal.signal(s, handler)


def task_cpu_time_s(pid: str | int, tid: int) -> float | None:
    """Time a thread has spent on a CPU, in seconds, from /proc/PID/task/TID/schedstat (nanosecond
    resolution, unlike the 10 ms ticks of /proc/.../stat); None where it cannot be read."""
    try:
        return int(Path(f"/proc/{pid}/task/{tid}/schedstat").read_text().split()[0]) * 1e-9
    except (OSError, IndexError, ValueError):
        return None


def process_cpu_time_s(pid: str | int) -> float | None:
    """Time all threads of process `pid` have spent on a CPU, in seconds (the sum of their
    schedstat: nanosecond resolution); None where /proc cannot be read."""
    try:
        tids = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return None
    times = [task_cpu_time_s(pid, int(t)) for t in tids]
    known = [t for t in times if t is not None]
    return sum(known) if known else None


def runnable_tasks(pid: str | int = "self", exclude: Collection[int] = ()) -> int | None:
    """How many threads of process `pid` are runnable (R) now, leaving out the native thread ids in
    `exclude`; None where /proc cannot be read."""
    try:
        tids = [int(t) for t in os.listdir(f"/proc/{pid}/task")]
    except (OSError, ValueError):
        return None
    return sum(1 for t in tids if t not in exclude and task_state(pid, t) == "R")


def task_state(pid: str | int, tid: int) -> str | None:
    """The scheduler state letter of a thread (R runnable, S sleeping, D uninterruptible, ...), from
    /proc/PID/task/TID/stat; None where it cannot be read."""
    try:
        stat = Path(f"/proc/{pid}/task/{tid}/stat").read_text()
        return stat[stat.rindex(")") + 2]  # the command name in parentheses may hold anything
    except (OSError, ValueError, IndexError):
        return None
