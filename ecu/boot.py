"""`bywire ecu run --store DIR`: boot the flashed firmware image, with A/B fallback.

No paper section; the U-Boot bootcount scheme in Python. `boot` is the supervisor process:

1. under the store lock, read boot.json and `plan_boot`: if the active slot's image does not verify
   (sha256), or a trial image has been started `MAX_TRIAL_BOOTS` times without coming up (power
   cut, supervisor killed), reject it and switch to the previous slot when that one verifies (an
   exhausted trial image with no fallback is still booted: it is all there is); a trial boot is
   counted before the image is started;
2. pick the calibration: current.json if it passes its CRC, else previous.json, else none (the app
   is then started with --no-calibration, stays OFF and never engages; without that flag it would
   use its packaged default);
3. start `python -I -S slots/X/image.pyz run --store DIR (--calibration PATH | --no-calibration)
   EXTRA...` as a child in its own process group (so a terminal's Ctrl-C reaches it once, through
   us), which dies with the supervisor (PR_SET_PDEATHSIG): a killed supervisor never leaves an ECU
   running unsupervised;
4. wait until the child's pid reports any EcuState in run/boot-status.json (READY, or OFF when it
   has no valid calibration; both mean the image works). A trial image is then confirmed.
   If a trial image exits or stays silent for `ready_timeout_s`, it is stopped and rejected, and
   the previous slot is booted instead, loudly. A confirmed image that fails is not swapped out (it
   has worked before; the fault is more likely outside it): its exit code is returned;
5. forward SIGINT / SIGTERM to the child and return its exit code (128 + n if signal n killed it).

The supervisor's waiting is polling on an injected `Clock`, no threads.
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import ctypes.util
import functools
import os
import signal
import subprocess
import sys
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from types import FrameType
from typing import Literal

from bywire.clock import Clock, WallClock
from bywire.ecu.firmware import ISOLATED_FLAGS
from bywire.ecu.store import (
    MAX_TRIAL_BOOTS,
    BootRecord,
    BootStatus,
    Slot,
    StoreError,
    StorePath,
    clear_boot_status,
    open_store,
    other_slot,
    read_boot_record,
    read_boot_status,
    slot_usable,
    store_lock,
    usable_calibration,
    verify_image,
    write_boot_record,
)

Log = Callable[[str], None]

EXIT_NO_IMAGE = 3  # no bootable image in the store
DEFAULT_READY_TIMEOUT_S = 30.0
STOP_GRACE_S = 5.0  # a child that ignores SIGTERM this long is killed
_PR_SET_PDEATHSIG = 1
_FORWARDED = (signal.SIGINT, signal.SIGTERM)


class BootError(Exception):
    """No image can be booted from the store; the message says why."""


def _stderr_log(msg: str) -> None:
    print(f"bywire-boot: {msg}", file=sys.stderr, flush=True)


def _pdeathsig_preexec() -> Callable[[], None] | None:
    if not sys.platform.startswith("linux"):
        return None
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        prctl = libc.prctl
    except (OSError, AttributeError):
        return None

    def preexec() -> None:
        prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM))

    return preexec


def _exit_code(returncode: int) -> int:
    return 128 - returncode if returncode < 0 else returncode


@dataclass(frozen=True)
class BootPlan:
    """What to boot, decided from the boot record and which slots verify (`plan_boot`)."""

    slot: Slot | None  # None: nothing can boot (see `problem`)
    record: BootRecord  # the boot record to write before starting `slot`
    rejected: tuple[tuple[Slot, str], ...]  # slots rejected on the way, with the reason
    problem: str | None
    warnings: tuple[str, ...] = ()


def plan_boot(
    record: BootRecord, slot_problem: Callable[[Slot], str | None], max_trial_boots: int = MAX_TRIAL_BOOTS
) -> BootPlan:
    """Pure: the slot to boot given the record and `slot_problem(slot)` (None when it verifies).

    A slot whose image does not verify is rejected for the previous one, and so is a trial image
    started `max_trial_boots` times without coming up; with no usable previous slot, such a trial
    image is still booted (it is the only image there is), a corrupt one is not. A trial boot is
    counted in the returned record."""
    rejected: list[tuple[Slot, str]] = []
    warnings: list[str] = []
    while True:
        problem = slot_problem(record.active)
        exhausted = problem is None and record.state == "trial" and record.trial_boots >= max_trial_boots
        if exhausted:
            problem = f"trial image started {record.trial_boots} times without coming up"
        if problem is None:
            break
        prev = record.previous
        prev_problem = slot_problem(prev) if prev is not None else "no previous slot"
        if prev is None or prev_problem is not None:
            if exhausted:
                warnings.append(
                    f"slot {record.active}: {problem}; no fallback ({prev_problem}), booting it anyway"
                )
                break
            reason = f"slot {record.active} cannot boot ({problem}) and there is no fallback ({prev_problem})"
            return BootPlan(None, record, tuple(rejected), reason, tuple(warnings))
        rejected.append((record.active, problem))
        record = BootRecord(
            active=prev,
            previous=None,
            state="confirmed",
            rejected={**record.rejected, record.active: problem},
        )
    if record.state == "trial":
        record = replace(record, trial_boots=record.trial_boots + 1)
    return BootPlan(record.active, record, tuple(rejected), None, tuple(warnings))


def _select_slot(store: StorePath, log: Log, max_trial_boots: int) -> tuple[Slot, BootRecord]:
    """Under the store lock: plan the boot, log it loudly, write the record; BootError if none."""
    with store_lock(store):
        record = read_boot_record(store)
        if record is None:
            raise BootError(
                f"{Path(store)}: no firmware flashed (run `bywire ecu flash --store DIR --firmware`)"
            )
        plan = plan_boot(record, functools.partial(slot_usable, store), max_trial_boots)
        for slot, reason in plan.rejected:
            log(f"!!! slot {slot} REJECTED: {reason}; FALLING BACK to slot {other_slot(slot)}")
        for warning in plan.warnings:
            log(f"!!! {warning}")
        if plan.slot is None:
            raise BootError(plan.problem or "no bootable slot")
        if plan.record != record:
            write_boot_record(store, plan.record)
        return plan.slot, plan.record


def _fall_back(store: StorePath, record: BootRecord, reason: str, log: Log) -> BootRecord:
    """Reject the active slot and make the previous one active; BootError when there is none."""
    prev = record.previous
    prev_problem = slot_usable(store, prev) if prev is not None else "no previous slot"
    if prev is None or prev_problem is not None:
        raise BootError(f"slot {record.active} failed ({reason}) and there is no fallback ({prev_problem})")
    log(f"!!! slot {record.active} REJECTED: {reason}; FALLING BACK to slot {prev}")
    rejected = {**record.rejected, record.active: reason}
    new = BootRecord(active=prev, previous=None, state="confirmed", trial_boots=0, rejected=rejected)
    write_boot_record(store, new)
    return new


def _confirm(store: StorePath, slot: Slot, log: Log) -> None:
    with store_lock(store):
        record = read_boot_record(store)
        # A flash may have activated another image meanwhile: confirm only what we booted.
        if record is not None and record.active == slot and record.state == "trial":
            write_boot_record(store, replace(record, state="confirmed", trial_boots=0))
            log(f"slot {slot} confirmed")


def _reject_running(store: StorePath, slot: Slot, reason: str, log: Log) -> bool:
    """After a failed trial boot: fall back if the record still points at `slot`; True if it did."""
    with store_lock(store):
        record = read_boot_record(store)
        if record is None or record.active != slot or record.state != "trial":
            return False
        try:
            _fall_back(store, record, reason, log)
        except BootError as e:
            log(f"!!! {e}")
            return False
        return True


class _Supervisor:
    """The child and the signals meant for it."""

    def __init__(self) -> None:
        self.child: subprocess.Popen[bytes] | None = None
        self.stop_signal: int | None = None
        self.forwarded = False  # the child got the stop signal from us

    def handle(self, signum: int, _frame: FrameType | None) -> None:
        self.stop_signal = signum
        if self.child is not None and self.child.poll() is None:
            self.child.send_signal(signum)
            self.forwarded = True

    def stop_child(self, log: Log, *, already_signalled: bool = False) -> int:
        """Stop the child (SIGTERM unless it already got a stop signal), SIGKILL after the grace time."""
        child = self.child
        assert child is not None
        if child.poll() is None:
            if not already_signalled:
                child.terminate()
            try:
                child.wait(STOP_GRACE_S)
            except subprocess.TimeoutExpired:
                log(f"child {child.pid} still running {STOP_GRACE_S:g} s after the stop signal: killing it")
                child.kill()
        return child.wait()


def _wait_until_up(
    sup: _Supervisor, store: StorePath, clock: Clock, timeout_s: float, poll_s: float
) -> tuple[Literal["up", "exited", "timeout", "stopped"], BootStatus | None]:
    child = sup.child
    assert child is not None
    deadline = clock.now() + timeout_s
    while True:
        # Poll the exit first: a status written just before the child exited still counts.
        exited = child.poll() is not None
        status = None
        with contextlib.suppress(StoreError):
            status = read_boot_status(store)
        if status is not None and status.pid == child.pid:
            return "up", status
        # A child that exits because we forwarded a stop signal has not failed its trial.
        if sup.stop_signal is not None:
            return "stopped", None
        if exited:
            return "exited", None
        if clock.now() >= deadline:
            return "timeout", None
        clock.sleep_until(min(clock.now() + poll_s, deadline))


def boot(
    store: StorePath,
    extra_argv: Sequence[str] = (),
    ready_timeout_s: float = DEFAULT_READY_TIMEOUT_S,
    *,
    python: str = sys.executable,
    clock: Clock | None = None,
    poll_s: float = 0.05,
    max_trial_boots: int = MAX_TRIAL_BOOTS,
    log: Log = _stderr_log,
) -> int:
    """Boot the store's active image (falling back on a failed trial) and supervise it until it exits.

    Returns the child's exit code (128 + n after signal n), or EXIT_NO_IMAGE when nothing can boot.
    """
    clock = clock if clock is not None else WallClock()
    lay = open_store(store)
    sup = _Supervisor()
    previous_handlers: dict[int, object] = {}
    if threading.current_thread() is threading.main_thread():
        for sig in _FORWARDED:
            previous_handlers[sig] = signal.signal(sig, sup.handle)
    try:
        while True:
            try:
                slot, record = _select_slot(store, log, max_trial_boots)
                image, manifest = verify_image(store, slot)
            except (BootError, StoreError) as e:
                log(f"!!! cannot boot: {e}")
                return EXIT_NO_IMAGE
            trial = record.state == "trial"
            choice = usable_calibration(store)
            for problem in choice.problems:
                log(f"calibration skipped: {problem}")
            cal_args: list[str] = []
            if choice.path is not None:
                cal_args = ["--calibration", os.fspath(choice.path)]
            else:
                # Without this flag the app would fall back to its packaged default calibration.
                cal_args = ["--no-calibration"]
                log("!!! no valid calibration: the ECU will stay OFF and never engage")
            clear_boot_status(store)
            argv = [python, *ISOLATED_FLAGS, os.fspath(image), "run", "--store", os.fspath(lay.root)]
            argv += [*cal_args, *extra_argv]
            log(
                f"booting slot {slot} image {manifest.version}"
                + (f" (trial boot {record.trial_boots}/{max_trial_boots})" if trial else "")
            )
            if sup.stop_signal is not None:
                return 128 + sup.stop_signal
            sup.child = subprocess.Popen(argv, process_group=0, preexec_fn=_pdeathsig_preexec())
            outcome, status = _wait_until_up(sup, store, clock, ready_timeout_s, poll_s)
            if outcome == "up":
                assert status is not None
                log(f"slot {slot} image {manifest.version} is up: {status.state.name}")
                if trial:
                    _confirm(store, slot, log)
                return _exit_code(sup.child.wait())
            if outcome == "stopped":
                return _exit_code(sup.stop_child(log, already_signalled=sup.forwarded))
            if outcome == "exited":
                code = _exit_code(sup.child.wait())
                reason = f"image {manifest.version} exited with code {code} before reporting its state"
            else:
                reason = f"image {manifest.version} reported no state within {ready_timeout_s:g} s"
                if trial:
                    code = _exit_code(sup.stop_child(log))
                else:
                    log(f"!!! {reason}; it is the confirmed image, so it keeps running")
                    return _exit_code(sup.child.wait())
            if not trial:
                log(f"!!! confirmed slot {slot}: {reason}")
                return code
            if not _reject_running(store, slot, reason, log):
                return code
    finally:
        if sup.child is not None and sup.child.poll() is None:
            sup.stop_child(log)
        for signum, handler in previous_handlers.items():
            signal.signal(signum, handler)  # type: ignore[arg-type]


# --- CLI glue -----------------------------------------------------------------------------------


def add_run_from_store_arguments(parser: argparse.ArgumentParser) -> None:
    """`--store DIR` and `--ready-timeout S` for `bywire ecu run` (the app's own options stay the lead's)."""
    parser.add_argument("--store", type=Path, default=None, help="boot the firmware flashed into this store")
    parser.add_argument(
        "--ready-timeout",
        dest="ready_timeout_s",
        type=float,
        default=DEFAULT_READY_TIMEOUT_S,
        help="seconds a newly flashed image has to come up before the ECU falls back (default 30)",
    )


def cmd_run_from_store(args: argparse.Namespace) -> int:
    """`bywire ecu run --store DIR [--vehicle-bus URL] [--host-link URL]`: boot and supervise.

    Forwards `vehicle_bus`, `host_link` (when set) and `app_args` (a list, when present) to the app."""
    extra: list[str] = []
    for attr, flag in (("vehicle_bus", "--vehicle-bus"), ("host_link", "--host-link")):
        value = getattr(args, attr, None)
        if value is not None:
            extra += [flag, str(value)]
    extra += [str(a) for a in (getattr(args, "app_args", None) or [])]
    try:
        return boot(args.store, extra, getattr(args, "ready_timeout_s", DEFAULT_READY_TIMEOUT_S))
    except StoreError as e:
        print(f"error: {e}", file=sys.stderr)
        return EXIT_NO_IMAGE


def main(argv: list[str] | None = None) -> int:
    """`python -m bywire.ecu.boot --store DIR [--vehicle-bus URL] [--host-link URL] [-- APP ARGS]`."""
    parser = argparse.ArgumentParser(prog="bywire ecu run", description="boot the ECU firmware from a store")
    add_run_from_store_arguments(parser)
    parser.add_argument("--vehicle-bus", default=None)
    parser.add_argument("--host-link", default=None)
    parser.add_argument("app_args", nargs=argparse.REMAINDER, help="passed to the app after --")
    args = parser.parse_args(argv)
    if args.store is None:
        parser.error("--store is required")
    if args.app_args and args.app_args[0] == "--":
        args.app_args = args.app_args[1:]
    return cmd_run_from_store(args)


if __name__ == "__main__":
    sys.exit(main())
