"""`bywire ecu run --store DIR`: boot the flashed firmware image, with A/B fallback and rollback.

No paper section; U-Boot's bootcount scheme in Python, with DESIGN section 4's two rules: firmware
is signed, and a trial image is confirmed by a period of health, not by being alive. `boot` is the
supervisor process:

1. under the store lock, read boot.json and `plan_boot`: reject the active slot, for the previous
   one when that one verifies, if
   a. its image does not verify: sha256, and the Ed25519 signature against trust.json's keys
      (unless the store allows unsigned firmware); checked on every boot, so a revoked key or a
      changed byte is caught like a torn write;
   b. it is on trial and has been started `MAX_TRIAL_BOOTS` times without being confirmed (power
      cuts or a killed supervisor during the trial; boots the supervisor saw stopped on purpose
      are not counted);
   c. it is confirmed but in a crash loop: its last `CRASH_LOOP_BOOTS` boots all died (non-zero
      exit, killed by a signal, or hung) within `CRASH_LOOP_WINDOW_S` of each other;
   a rejected image with no usable fallback is still booted in cases b and c (it is all there is),
   never in case a. A trial boot is counted and the boot added to the history before the start;
2. pick the calibration: current.json if it passes its CRC, else previous.json, else none (the app
   is then started with --no-calibration, stays OFF and never engages; without that flag it would
   use its packaged default);
3. start `python -I -S slots/X/image.pyz run --store DIR (--calibration PATH | --no-calibration)
   [--unsigned-store] EXTRA...` as a child in its own process group (so a terminal's Ctrl-C reaches
   it once, through us), which dies with the supervisor (PR_SET_PDEATHSIG): a killed supervisor
   never leaves an ECU running unsupervised. A development store (allow_unsigned) is announced at
   every boot, by us and (through --unsigned-store) by the app;
4. watch the child's reports in run/boot-status.json (about one a second, health.py):
   - a trial image is confirmed once it reports the host link up and `healthy_s >= confirm_after_s`
     (host heartbeat fresh and OPERATIONAL, no internal fault since the last one), and the
     supervisor's own clock agrees that long has passed since the start;
   - a trial image that exits (with any code) before that, reports nothing within
     `ready_timeout_s`, or stops reporting for `report_timeout_s` is stopped and rejected, and the
     previous slot is booted instead, loudly;
   - a confirmed image is not judged by its reports: it runs until it exits;
5. forward SIGINT / SIGTERM to the child; record how the boot ended in the history; if a confirmed
   image died and that makes a crash loop (1c) with a usable fallback, boot the fallback at once;
   else return the child's exit code (128 + n if signal n killed it).

Choices:
- `DEFAULT_CONFIRM_AFTER_S` = 60 s of health: long enough to cover start-up transients (imports,
  real-time set-up, the first host heartbeats, the loop statistics' window) and 60 000 cycles,
  1 500+ host heartbeats and 6 000 DBW_Commands without an internal fault; short enough to be
  confirmed in the first minute of commissioning after a flash. `--confirm-after` for bring-up.
- Crash loop: 3 deaths within 10 minutes. One death can be outside the image (a power dip, a
  bus-off storm); three in a row within 10 minutes is a pattern: a restart service (systemd
  RestartSec of seconds) gets there within a minute for a crash at start-up, and still within the
  window for one that strikes a few minutes into each run, while three unrelated crashes over days
  never add up. Exit code 0 is not a death (the app exits 0 only when asked to: its --seconds ran
  out or it got SIGINT/SIGTERM), and neither is a boot whose end was never seen: that is how an
  ECU's power goes off when the car is switched off.
- The history's times are wall-clock (unix) seconds, the only clock that spans reboots; only the
  span between a slot's own boots is compared, and a span that is negative (the clock was set
  back) is not a crash loop: a wrong clock never rolls back a confirmed image.

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
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from types import FrameType
from typing import Literal

from bywire.clock import Clock, WallClock
from bywire.ecu.firmware import ISOLATED_FLAGS
from bywire.ecu.store import (
    DEATHS,
    MAX_TRIAL_BOOTS,
    BootEnd,
    BootEntry,
    BootRecord,
    BootStatus,
    DirSyncError,
    Slot,
    StoreError,
    StorePath,
    clear_boot_status,
    no_trust_problem,
    open_store,
    os_error_text,
    other_slot,
    read_boot_record,
    read_boot_status,
    read_manifest,
    read_trust,
    slot_usable,
    store_lock,
    usable_calibration,
    verify_image,
    write_boot_record,
)

Log = Callable[[str], None]

EXIT_NO_IMAGE = 3  # no bootable image in the store
DEFAULT_READY_TIMEOUT_S = 30.0
DEFAULT_CONFIRM_AFTER_S = 60.0  # see the module docstring
REPORT_TIMEOUT_S = 5.0  # the app reports about once a second: five missed reports is a hung trial
CRASH_LOOP_BOOTS = 3
CRASH_LOOP_WINDOW_S = 600.0
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


def _end_text(entry: BootEntry) -> str:
    if entry.end == "failed":
        return f"exit {entry.code}" if entry.code is not None else "failed"
    return entry.end


def crash_loop(
    history: Sequence[BootEntry],
    slot: Slot,
    boots: int = CRASH_LOOP_BOOTS,
    window_s: float = CRASH_LOOP_WINDOW_S,
) -> str | None:
    """Pure: why `slot` is in a crash loop (its last `boots` boots all died within `window_s` of
    each other), or None when it is not."""
    mine = [e for e in history if e.slot == slot][-boots:]
    if boots <= 0 or len(mine) < boots or any(e.end not in DEATHS for e in mine):
        return None
    span_s = mine[-1].started_unix - mine[0].started_unix
    if not 0.0 <= span_s <= window_s:
        return None
    ends = ", ".join(_end_text(e) for e in mine)
    return f"crash loop: its last {boots} boots died within {span_s / 60:.1f} min ({ends})"


@dataclass(frozen=True)
class BootPlan:
    """What to boot, decided from the boot record and which slots verify (`plan_boot`)."""

    slot: Slot | None  # None: nothing can boot (see `problem`)
    record: BootRecord  # the boot record to write before starting `slot`
    rejected: tuple[tuple[Slot, str], ...]  # slots rejected on the way, with the reason
    problem: str | None
    warnings: tuple[str, ...] = ()


def plan_boot(
    record: BootRecord,
    slot_problem: Callable[[Slot], str | None],
    max_trial_boots: int = MAX_TRIAL_BOOTS,
    crash_loop_boots: int = CRASH_LOOP_BOOTS,
    crash_loop_window_s: float = CRASH_LOOP_WINDOW_S,
) -> BootPlan:
    """Pure: the slot to boot given the record and `slot_problem(slot)` (None when it verifies).

    A slot whose image does not verify is rejected for the previous one, and so are a trial image
    started `max_trial_boots` times without being confirmed and a confirmed image in a crash loop;
    with no usable previous slot, those two are still booted (it is the only image there is), a
    slot that does not verify is not. A trial boot is counted in the returned record."""
    rejected: list[tuple[Slot, str]] = []
    warnings: list[str] = []
    while True:
        problem = slot_problem(record.active)
        bootable_anyway = False
        if problem is None and record.state == "trial" and record.trial_boots >= max_trial_boots:
            problem = f"trial image started {record.trial_boots} times without being confirmed"
            bootable_anyway = True
        if problem is None and record.state == "confirmed":
            problem = crash_loop(record.history, record.active, crash_loop_boots, crash_loop_window_s)
            bootable_anyway = problem is not None
        if problem is None:
            break
        prev = record.previous
        prev_problem = slot_problem(prev) if prev is not None else "no previous slot"
        if prev is None or prev_problem is not None:
            if bootable_anyway:
                warnings.append(
                    f"slot {record.active}: {problem}; no fallback ({prev_problem}), booting it anyway"
                )
                break
            reason = f"slot {record.active} cannot boot ({problem}) and there is no fallback ({prev_problem})"
            return BootPlan(None, record, tuple(rejected), reason, tuple(warnings))
        rejected.append((record.active, problem))
        record = replace(
            record,
            active=prev,
            previous=None,
            state="confirmed",
            trial_boots=0,
            rejected={**record.rejected, record.active: problem},
        )
    if record.state == "trial":
        record = replace(record, trial_boots=record.trial_boots + 1)
    return BootPlan(record.active, record, tuple(rejected), None, tuple(warnings))


@dataclass(frozen=True)
class _Rules:
    """The supervisor's limits (see the module docstring for the defaults' reasons)."""

    ready_timeout_s: float = DEFAULT_READY_TIMEOUT_S
    confirm_after_s: float = DEFAULT_CONFIRM_AFTER_S
    report_timeout_s: float = REPORT_TIMEOUT_S
    max_trial_boots: int = MAX_TRIAL_BOOTS
    crash_loop_boots: int = CRASH_LOOP_BOOTS
    crash_loop_window_s: float = CRASH_LOOP_WINDOW_S

    def plan(self, store: StorePath, record: BootRecord) -> BootPlan:
        return plan_boot(
            record,
            functools.partial(slot_usable, store),
            self.max_trial_boots,
            self.crash_loop_boots,
            self.crash_loop_window_s,
        )


def _write_record(store: StorePath, record: BootRecord, log: Log) -> None:
    try:
        write_boot_record(store, record)
    except DirSyncError as e:
        # The record is in place for everyone who reads it; only its survival of a power cut now
        # is in doubt, and then the old record (also whole) is what the next boot reads.
        log(f"!!! boot record written but its directory fsync failed: {os_error_text(e)}")


def _select_slot(
    store: StorePath, log: Log, rules: _Rules, now_unix: float
) -> tuple[Slot, BootRecord, BootEntry]:
    """Under the store lock: plan the boot, log it loudly, add the boot to the history and write
    the record; BootError if nothing can boot."""
    with store_lock(store):
        record = read_boot_record(store)
        if record is None:
            raise BootError(
                f"{Path(store)}: no firmware flashed (run `bywire ecu flash --store DIR --firmware`)"
            )
        plan = rules.plan(store, record)
        for slot, reason in plan.rejected:
            log(f"!!! slot {slot} REJECTED: {reason}; FALLING BACK to slot {other_slot(slot)}")
        for warning in plan.warnings:
            log(f"!!! {warning}")
        if plan.slot is None:
            raise BootError(plan.problem or "no bootable slot")
        entry = BootEntry(plan.slot, read_manifest(store, plan.slot).version, now_unix)
        new = plan.record.with_boot(entry)
        _write_record(store, new, log)
        return plan.slot, new, entry


def _record_end(
    store: StorePath, entry: BootEntry, end: BootEnd, code: int | None, log: Log
) -> BootRecord | None:
    """Note how the boot `entry` ended; a trial boot stopped on purpose is uncounted (it did not
    fail, and must not use up the trial's boots). The record written, or None if it could not be."""
    try:
        with store_lock(store):
            record = read_boot_record(store)
            if record is None:
                return None
            history = list(record.history)
            for i in range(len(history) - 1, -1, -1):
                if history[i] == entry:
                    history[i] = replace(entry, end=end, code=code)
                    break
            new = replace(record, history=tuple(history))
            if end == "stopped" and new.state == "trial" and new.active == entry.slot and new.trial_boots > 0:
                new = replace(new, trial_boots=new.trial_boots - 1)
            if new != record:
                _write_record(store, new, log)
            return new
    except (StoreError, OSError) as e:
        log(f"!!! cannot record how the boot of slot {entry.slot} ended ({end}): {e}")
        return None


def _fall_back(store: StorePath, record: BootRecord, reason: str, log: Log) -> BootRecord:
    """Reject the active slot and make the previous one active; BootError when there is none."""
    prev = record.previous
    prev_problem = slot_usable(store, prev) if prev is not None else "no previous slot"
    if prev is None or prev_problem is not None:
        raise BootError(f"slot {record.active} failed ({reason}) and there is no fallback ({prev_problem})")
    log(f"!!! slot {record.active} REJECTED: {reason}; FALLING BACK to slot {prev}")
    rejected = {**record.rejected, record.active: reason}
    new = replace(record, active=prev, previous=None, state="confirmed", trial_boots=0, rejected=rejected)
    _write_record(store, new, log)
    return new


def _confirm(store: StorePath, slot: Slot, why: str, log: Log) -> None:
    try:
        with store_lock(store):
            record = read_boot_record(store)
            # A flash may have activated another image meanwhile: confirm only what we booted.
            if record is not None and record.active == slot and record.state == "trial":
                _write_record(store, replace(record, state="confirmed", trial_boots=0), log)
                log(f"slot {slot} confirmed: {why}")
    except (StoreError, OSError) as e:
        log(f"!!! slot {slot} earned its confirmation ({why}) but it could not be recorded: {e}")


def _reject_running(store: StorePath, slot: Slot, reason: str, log: Log) -> bool:
    """After a failed trial boot: fall back if the record still points at `slot`; True if it did."""
    try:
        with store_lock(store):
            record = read_boot_record(store)
            if record is None or record.active != slot or record.state != "trial":
                return False
            _fall_back(store, record, reason, log)
            return True
    except BootError as e:
        log(f"!!! {e}")
    except (StoreError, OSError) as e:
        log(f"!!! slot {slot} failed its trial ({reason}) but the fallback could not be recorded: {e}")
    return False


def _roll_back_crash_loop(store: StorePath, slot: Slot, rules: _Rules, log: Log) -> bool:
    """After a confirmed image died: True when that makes a crash loop with a usable fallback
    (the next `_select_slot` rejects it, loudly); a crash loop without one is only warned about."""
    try:
        with store_lock(store):
            record = read_boot_record(store)
            if record is None or record.active != slot or record.state != "confirmed":
                return False
            plan = rules.plan(store, record)
    except (StoreError, OSError) as e:
        log(f"!!! cannot read the boot record after slot {slot} died: {e}")
        return False
    if plan.slot is not None and plan.slot != slot:
        return True
    for warning in plan.warnings:
        log(f"!!! {warning}")
    return False


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

    def end_of(self, code: int) -> BootEnd:
        """How a child that exited with `code` (128 + n for signal n) ended."""
        if self.stop_signal is not None:
            return "stopped"
        return "exited" if code == 0 else "failed"


Outcome = Literal["confirmed", "up", "exited", "no_report", "hung", "stopped"]


def _healthy_enough(status: BootStatus, confirm_after_s: float) -> bool:
    return status.host_link_up and status.healthy_s >= confirm_after_s


def _watch(
    sup: _Supervisor,
    store: StorePath,
    clock: Clock,
    rules: _Rules,
    *,
    trial: bool,
    poll_s: float,
    on_up: Callable[[BootStatus], None],
) -> tuple[Outcome, BootStatus | None]:
    """Poll the child and its reports until something is decided (see the module docstring, 4).

    A confirmed image is watched only until its first report ("up"); a trial one until it is
    healthy long enough ("confirmed") or it fails ("exited", "no_report", "hung")."""
    child = sup.child
    assert child is not None
    start = clock.now()
    ready_deadline = start + rules.ready_timeout_s
    last: BootStatus | None = None
    last_new_s = start
    while True:
        # Poll the exit first: a report written just before the child exited still counts.
        exited = child.poll() is not None
        status = None
        with contextlib.suppress(StoreError):
            status = read_boot_status(store)
        now = clock.now()
        if status is not None and status.pid == child.pid:
            if last is None or (status.seq, status.t_unix) != (last.seq, last.t_unix):
                if last is None:
                    on_up(status)
                    if not trial:
                        return "up", status
                last, last_new_s = status, now
            if (
                trial
                and _healthy_enough(status, rules.confirm_after_s)
                and now - start >= rules.confirm_after_s
            ):
                return "confirmed", status
        # A child that exits because we forwarded a stop signal has not failed.
        if sup.stop_signal is not None:
            return "stopped", last
        if exited:
            return "exited", last
        if last is None and now >= ready_deadline:
            return "no_report", None
        if last is not None and now - last_new_s > rules.report_timeout_s:
            return "hung", last
        clock.sleep_until(now + poll_s)


def _trial_failure(
    outcome: Outcome, code: int, status: BootStatus | None, version: str, rules: _Rules
) -> str:
    healthy = f"healthy {status.healthy_s:.0f} of {rules.confirm_after_s:g} s" if status else "never reported"
    if outcome == "no_report":
        return f"image {version} reported no state within {rules.ready_timeout_s:g} s"
    if outcome == "hung":
        return (
            f"image {version} stopped reporting for {rules.report_timeout_s:g} s"
            f" before it was confirmed ({healthy})"
        )
    return f"image {version} exited with code {code} before it was confirmed ({healthy})"


def boot(
    store: StorePath,
    extra_argv: Sequence[str] = (),
    ready_timeout_s: float = DEFAULT_READY_TIMEOUT_S,
    *,
    confirm_after_s: float = DEFAULT_CONFIRM_AFTER_S,
    report_timeout_s: float = REPORT_TIMEOUT_S,
    python: str = sys.executable,
    clock: Clock | None = None,
    wall_clock: Callable[[], float] = time.time,
    poll_s: float = 0.05,
    max_trial_boots: int = MAX_TRIAL_BOOTS,
    crash_loop_boots: int = CRASH_LOOP_BOOTS,
    crash_loop_window_s: float = CRASH_LOOP_WINDOW_S,
    log: Log = _stderr_log,
) -> int:
    """Boot the store's active image (falling back on a failed trial or a crash loop) and supervise
    it until it exits.

    Returns the child's exit code (128 + n after signal n), or EXIT_NO_IMAGE when nothing can boot.
    `wall_clock`: unix seconds for the boot history (the crash-loop rule); `clock`: the waiting.
    """
    clock = clock if clock is not None else WallClock()
    rules = _Rules(
        ready_timeout_s,
        confirm_after_s,
        report_timeout_s,
        max_trial_boots,
        crash_loop_boots,
        crash_loop_window_s,
    )
    lay = open_store(store)
    sup = _Supervisor()
    previous_handlers: dict[int, object] = {}
    if threading.current_thread() is threading.main_thread():
        for sig in _FORWARDED:
            previous_handlers[sig] = signal.signal(sig, sup.handle)
    try:
        while True:
            try:
                policy = read_trust(store)
                if policy is None:
                    raise BootError(no_trust_problem(store))
                slot, record, entry = _select_slot(store, log, rules, wall_clock())
                image, manifest = verify_image(store, slot, policy)
            except (BootError, StoreError, OSError) as e:
                log(f"!!! cannot boot: {e}")
                return EXIT_NO_IMAGE
            trial = record.state == "trial"
            unsigned_args: list[str] = []
            if policy.allow_unsigned:
                log(f"!!! store {lay.root} accepts UNSIGNED firmware (development store)")
                unsigned_args = ["--unsigned-store"]
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
            with contextlib.suppress(OSError):
                clear_boot_status(store)
            argv = [python, *ISOLATED_FLAGS, os.fspath(image), "run", "--store", os.fspath(lay.root)]
            argv += [*unsigned_args, *cal_args, *extra_argv]
            log(
                f"booting slot {slot} image {manifest.version}"
                + (
                    f" (trial boot {record.trial_boots}/{max_trial_boots}, confirmed after"
                    f" {confirm_after_s:g} s of health)"
                    if trial
                    else ""
                )
            )
            if sup.stop_signal is not None:
                _record_end(store, entry, "stopped", None, log)
                return 128 + sup.stop_signal
            sup.child = subprocess.Popen(argv, process_group=0, preexec_fn=_pdeathsig_preexec())
            version = manifest.version

            def on_up(status: BootStatus, slot: Slot = slot, version: str = version) -> None:
                log(f"slot {slot} image {version} is up: {status.state.name}")

            outcome, status = _watch(sup, store, clock, rules, trial=trial, poll_s=poll_s, on_up=on_up)
            if outcome == "confirmed":
                assert status is not None
                since = (
                    f"since the last of {status.internal_faults} internal faults"
                    if status.internal_faults
                    else "no internal fault"
                )
                why = f"healthy for {status.healthy_s:.0f} s (host link up, {since})"
                _confirm(store, slot, why, log)
                trial = False
            if outcome in ("confirmed", "up") or (outcome == "no_report" and not trial):
                if outcome == "no_report":
                    log(
                        f"!!! image {version} reported no state within {ready_timeout_s:g} s;"
                        " it is the confirmed image, so it keeps running"
                    )
                code = _exit_code(sup.child.wait())
                end = sup.end_of(code)
            elif outcome == "stopped":
                code = _exit_code(sup.stop_child(log, already_signalled=sup.forwarded))
                end = "stopped"
            elif outcome == "exited":
                code = _exit_code(sup.child.wait())
                end = sup.end_of(code)
            else:  # a trial that did not report, or stopped reporting
                code = _exit_code(sup.stop_child(log))
                end = "hung"
            _record_end(store, entry, end, code, log)
            if end == "stopped":
                return code
            if trial:
                if not _reject_running(
                    store, slot, _trial_failure(outcome, code, status, version, rules), log
                ):
                    return code
                continue
            if end in DEATHS:
                what = f"exited with code {code}" if end == "failed" else "hung"
                log(f"!!! confirmed slot {slot}: image {version} {what}")
                if _roll_back_crash_loop(store, slot, rules, log):
                    continue
            return code
    finally:
        if sup.child is not None and sup.child.poll() is None:
            sup.stop_child(log)
        for signum, handler in previous_handlers.items():
            signal.signal(signum, handler)  # type: ignore[arg-type]


# --- CLI glue -----------------------------------------------------------------------------------


def _seconds(text: str) -> float:
    value = float(text)
    if not value >= 0.0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"expected a finite number of seconds >= 0, got {text!r}")
    return value


def add_supervisor_arguments(parser: argparse.ArgumentParser) -> None:
    """`--ready-timeout S` and `--confirm-after S`: the boot supervisor's options of `bywire ecu run`."""
    parser.add_argument(
        "--ready-timeout",
        dest="ready_timeout_s",
        type=_seconds,
        default=DEFAULT_READY_TIMEOUT_S,
        help="with --store: seconds a newly flashed image has to report before the ECU falls back (30)",
    )
    parser.add_argument(
        "--confirm-after",
        dest="confirm_after_s",
        type=_seconds,
        default=DEFAULT_CONFIRM_AFTER_S,
        help=(
            "with --store: seconds of health (host link up, no internal fault) that confirm a newly"
            f" flashed image (default {DEFAULT_CONFIRM_AFTER_S:g}; shorter only for tests and bring-up)"
        ),
    )


# The supervisor's options (and whether each takes a value), which `bywire ecu run --store` keeps
# from the app's command line.
SUPERVISOR_OPTIONS = {"--store": True, "--ready-timeout": True, "--confirm-after": True}


def add_run_from_store_arguments(parser: argparse.ArgumentParser) -> None:
    """`--store DIR` and the supervisor's options for `bywire ecu run` (the app's own stay the lead's)."""
    parser.add_argument("--store", type=Path, default=None, help="boot the firmware flashed into this store")
    add_supervisor_arguments(parser)


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
        return boot(
            args.store,
            extra,
            getattr(args, "ready_timeout_s", DEFAULT_READY_TIMEOUT_S),
            confirm_after_s=getattr(args, "confirm_after_s", DEFAULT_CONFIRM_AFTER_S),
        )
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
