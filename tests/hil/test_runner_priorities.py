"""The HIL runner gives every real-time process its SCHED_FIFO priority.

A host left at normal priority is starved by the 1 kHz processes on a 2-core machine and trips the
ECU's watchdogs (seen: an 88 ms host stall and a spurious SAFE_STOP), so the command lines are pinned
here rather than left to chance.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from bywire.hil import runner
from bywire.hil.scenario import load_scenario


class _AllStarted(Exception):
    pass


def test_every_child_gets_its_priority(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    started: dict[str, list[str]] = {}

    class RecordingChild:
        def __init__(self, name: str, argv: list[str], log_path: Path, wants_t0: bool) -> None:
            self.name = name
            started[name] = argv
            if name == "host":  # the last one: stop before anything real is waited for
                raise _AllStarted

        def stop(self) -> int:
            return 0

        def close(self) -> None:
            pass

    monkeypatch.setattr(runner, "Child", RecordingChild)
    monkeypatch.setattr(runner, "wait_for_port", lambda *args, **kwargs: None)
    with pytest.raises(_AllStarted):
        runner.run_hil(load_scenario("accel_steps"), tmp_path)

    def priority(argv: list[str]) -> int | None:
        return int(argv[argv.index("--rt-priority") + 1]) if "--rt-priority" in argv else None

    assert priority(started["bus-vehicle"]) == priority(started["bus-link"]) == runner.BUS_RT_PRIORITY
    assert priority(started["host"]) == runner.HOST_RT_PRIORITY
    assert priority(started["plant"]) is None  # normal scheduling: it must not use up the RT budget
    assert "--no-rt" not in started["ecu"]  # the ECU asks for its own (80)
    assert runner.BUS_RT_PRIORITY < 80 and runner.HOST_RT_PRIORITY < 80
