"""The boot status is written beside the 1 kHz loop: handing it over never waits for the file system,
the newest status wins, a failing write is reported and the writer goes on, and closing writes what
is pending."""

from __future__ import annotations

import os
import threading
from collections.abc import Mapping
from typing import Any

import pytest

from bywire.ecu.boot_reporter import BootStatusWriter


def test_the_loop_never_waits_for_the_write_and_the_newest_status_wins() -> None:
    gate = threading.Event()
    started = threading.Event()
    written: list[dict[str, Any]] = []

    def slow_write(status: Mapping[str, Any]) -> None:
        started.set()
        assert gate.wait(10.0)  # a file system that holds the writer
        written.append(dict(status))

    writer = BootStatusWriter(slow_write, lambda exc: None)
    writer.submit({"seq": 1})
    assert started.wait(10.0)
    for seq in range(2, 50):  # the loop goes on while the first write is held
        writer.submit({"seq": seq})
    assert written == []
    gate.set()
    writer.close(10.0)
    assert written == [{"seq": 1}, {"seq": 49}]  # the ones in between were never the newest when free


def test_a_failing_write_is_reported_and_the_next_status_still_written() -> None:
    errors: list[OSError] = []
    written: list[dict[str, Any]] = []
    done = threading.Event()

    def write(status: Mapping[str, Any]) -> None:
        if status["seq"] == 1:
            raise OSError(28, "No space left on device")
        written.append(dict(status))
        done.set()

    writer = BootStatusWriter(write, errors.append)
    writer.submit({"seq": 1})
    while not errors:
        threading.Event().wait(0.001)
    writer.submit({"seq": 2})
    assert done.wait(10.0)
    writer.close(10.0)
    assert [e.errno for e in errors] == [28] and written == [{"seq": 2}]


def test_the_writer_leaves_the_loops_real_time_priority() -> None:
    """Made by a SCHED_FIFO thread (the loop's), as the ECU makes it: threads inherit the policy."""
    policies: list[int] = []
    made: list[BootStatusWriter] = []
    refused: list[OSError] = []

    def realtime_creator() -> None:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))
        except OSError as exc:
            refused.append(exc)
            return
        made.append(
            BootStatusWriter(lambda status: policies.append(os.sched_getscheduler(0)), lambda e: None)
        )

    creator = threading.Thread(target=realtime_creator)
    creator.start()
    creator.join(10.0)
    if refused:
        pytest.skip(f"this machine refuses SCHED_FIFO: {refused[0]}")
    made[0].submit({})
    made[0].close(10.0)
    assert policies == [os.SCHED_OTHER]
