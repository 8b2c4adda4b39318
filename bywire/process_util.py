"""Small helpers shared by the processes of a run (plant, host): start handshake and clean shutdown."""

from __future__ import annotations

import signal
import sys
import time


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

    def _handler(self, signum: int, frame: object) -> None:
        self.stop = True

    def __call__(self) -> bool:
        return self.stop
