"""Booting from the store: confirmation of a trial image by a period of health, fallback to the
previous slot when a trial dies, rollback of a confirmed image in a crash loop, the development
store's warning, calibration choice, signal forwarding, and the real firmware image coming up from a
store (and being confirmed only once a host's heartbeat makes it healthy)."""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import can
import pytest
from ecu_test_images import fake_ecu_image, key_pair
from hypothesis import given, settings
from hypothesis import strategies as st

import bywire.ecu
from bywire.ecu import boot, cli, firmware, flash, store
from bywire.ecu.boot import EXIT_NO_IMAGE, crash_loop, plan_boot
from bywire.ecu.health import REPORT_PERIOD_S, BootHealth
from bywire.ecu.store import BootEntry, BootRecord, StoreError
from bywire.ecu.trust import DEVELOPMENT
from bywire.protocol.ecu_types import EcuState

PASSAT = Path(bywire.ecu.__path__[0]) / "calibrations" / "passat.json"

# A stand-in for bywire.ecu.app. It reports like the real app (health.py's fields) every 50 ms.
# MODE: good (healthy from the start), sick (host link never up), crash (exit 7 at once), hang
# (never report), late (exit 5 after 0.8 s without reporting), stall (report 3 times, then fall
# silent while still running). Options: --exit-now CODE (exit after the first report),
# --seconds S (exit 0 after S, as the real app), and until then SIGTERM ends it with 0.
FAKE_APP = """
import json, os, signal, sys, time
from bywire.ecu.store import report_boot

MODE = {mode!r}

def main(argv):
    store = argv[argv.index("--store") + 1]
    with open(os.path.join(store, "run", "app-argv.json"), "w") as f:
        json.dump(argv, f)
    if MODE == "crash":
        return 7
    if MODE == "hang":
        time.sleep(600)
    if MODE == "late":
        time.sleep(0.8)
        return 5
    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    seconds = float(argv[argv.index("--seconds") + 1]) if "--seconds" in argv else 1e9
    t0 = time.monotonic()
    reports = 0
    while not stop and time.monotonic() - t0 < seconds:
        if MODE != "stall" or reports < 3:
            up = MODE != "sick"
            report_boot(
                store,
                "READY" if "--calibration" in argv else "OFF",
                healthy_s=time.monotonic() - t0 if up else 0.0,
                host_link_up=up,
                unsigned_store="--unsigned-store" in argv,
            )
            reports += 1
        if "--exit-now" in argv:
            return int(argv[argv.index("--exit-now") + 1])
        time.sleep(0.05)
    return 0
"""

MODES = ("good", "good2", "sick", "crash", "hang", "late", "stall")


@pytest.fixture(scope="module")
def images(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("images")
    out = {}
    for mode in MODES:
        app = FAKE_APP.format(mode=mode.removesuffix("2"))
        if mode == "good2":
            app += "\n# another build\n"
        out[mode] = fake_ecu_image(d / f"{mode}.pyz", app)
    return out


class Log(list[str]):
    def __call__(self, msg: str) -> None:
        self.append(msg)

    def text(self) -> str:
        return "\n".join(self)


def app_argv(root: Path) -> list[str]:
    return json.loads((root / "run" / "app-argv.json").read_text())


def flashed(root: Path, *images: Path, confirm: bool = True) -> Path:
    """A development store with `images` flashed in order; each but the last confirmed (the last too
    if confirm)."""
    for i, image in enumerate(images):
        flash.flash_firmware(root, image, selftest=False, trust=DEVELOPMENT)
        if confirm or i < len(images) - 1:
            record = store.read_boot_record(root)
            assert record is not None
            store.write_boot_record(root, BootRecord(active=record.active, previous=record.previous))
    return root


def record_of(root: Path) -> BootRecord:
    record = store.read_boot_record(root)
    assert record is not None
    return record


def version(image: Path) -> str:
    return str(firmware.read_image_info(image)["version"])


class FakeWall:
    """Unix seconds for the boot history, advancing by `step_s` per boot."""

    def __init__(self, step_s: float, start: float = 1.8e9) -> None:
        self.t = start - step_s
        self.step_s = step_s

    def __call__(self) -> float:
        self.t += self.step_s
        return self.t


# --- plan_boot and crash_loop (pure) ------------------------------------------------------------


def entries(slot: store.Slot, ends: list[store.BootEnd], step_s: float = 60.0) -> tuple[BootEntry, ...]:
    return tuple(BootEntry(slot, "v", 1.8e9 + i * step_s, end, 1) for i, end in enumerate(ends))


@settings(max_examples=300, deadline=None)
@given(
    active=st.sampled_from(store.SLOTS),
    has_previous=st.booleans(),
    state=st.sampled_from(["confirmed", "trial"]),
    trial_boots=st.integers(0, 5),
    bad=st.sets(st.sampled_from(store.SLOTS)),
    ends=st.lists(st.sampled_from(store.BOOT_ENDS), max_size=5),
    step_s=st.sampled_from([-60.0, 60.0, 250.0]),
)
def test_plan_boot_never_picks_a_bad_slot_and_only_falls_back_to_previous(
    active: store.Slot,
    has_previous: bool,
    state: store.BootState,
    trial_boots: int,
    bad: set[str],
    ends: list[store.BootEnd],
    step_s: float,
) -> None:
    previous = store.other_slot(active) if has_previous else None
    history = entries(active, ends, step_s)
    record = BootRecord(
        active=active, previous=previous, state=state, trial_boots=trial_boots, history=history
    )
    plan = plan_boot(record, lambda s: "bad" if s in bad else None, max_trial_boots=3)
    if plan.slot is None:
        assert active in bad and (previous is None or previous in bad)
        return
    assert plan.slot not in bad
    assert plan.slot in (active, previous)
    assert plan.record.history == history
    if plan.slot != active:
        assert plan.record.state == "confirmed" and active in plan.record.rejected
    elif state == "trial":
        assert plan.record.trial_boots == trial_boots + 1
    exhausted = state == "trial" and trial_boots >= 3
    last3 = ends[-3:]
    looping = (
        state == "confirmed"
        and len(last3) == 3
        and all(e in ("failed", "hung") for e in last3)
        and 0 <= 2 * step_s <= boot.CRASH_LOOP_WINDOW_S
    )
    fallback_ok = previous is not None and previous not in bad
    if active in bad or ((exhausted or looping) and fallback_ok):
        assert plan.slot == previous
    else:  # a good active image is never abandoned, an exhausted or looping one only for a good fallback
        assert plan.slot == active


def test_crash_loop_needs_consecutive_deaths_of_that_slot_within_the_window() -> None:
    assert crash_loop(entries("b", ["failed", "hung", "failed"]), "b") is not None
    assert "3 boots died within 2.0 min (exit 1, hung, exit 1)" in (
        crash_loop(entries("b", ["failed", "hung", "failed"]), "b") or ""
    )
    # A clean stop, a clean exit or an unseen end (power off) in between: not a loop.
    for between in ("stopped", "exited", "running"):
        assert crash_loop(entries("b", ["failed", between, "failed"]), "b") is None, between
    assert crash_loop(entries("b", ["failed", "failed"]), "b") is None
    assert crash_loop(entries("a", ["failed"] * 3), "b") is None
    # Spread over more than 10 minutes, or across a clock set back: not a loop.
    assert crash_loop(entries("b", ["failed"] * 3, step_s=301.0), "b") is None
    assert crash_loop(entries("b", ["failed"] * 3, step_s=-1.0), "b") is None
    # Older deaths before a good boot do not count, the last three do.
    assert crash_loop(entries("b", ["failed", "stopped", "failed", "failed", "failed"]), "b") is not None


# --- health (what the app reports) --------------------------------------------------------------


def test_health_accumulates_with_the_link_up_pauses_on_a_drop_and_restarts_on_a_fault() -> None:
    h = BootHealth()
    h.sample(0.0, True, 0)
    h.sample(0.1, True, 0)
    h.sample(0.2, True, 0)
    assert h.healthy_s == pytest.approx(0.2)
    h.sample(0.3, False, 0)  # link dropped: the interval that ends down does not count
    h.sample(0.4, False, 0)
    h.sample(0.5, True, 0)  # back up: counting resumes from the next interval
    assert h.healthy_s == pytest.approx(0.2)
    h.sample(0.6, True, 0)
    assert h.healthy_s == pytest.approx(0.3) and h.host_link_up
    h.sample(0.7, True, 1)  # an internal fault: the period starts again
    assert h.healthy_s == 0.0 and h.internal_faults == 1
    h.sample(0.8, True, 1)
    assert h.healthy_s == pytest.approx(0.1)


def test_health_is_reported_at_most_once_per_period() -> None:
    h = BootHealth()
    assert h.report_due(10.0)
    assert not h.report_due(10.0 + REPORT_PERIOD_S / 2)
    assert h.report_due(10.0 + REPORT_PERIOD_S)


# --- boot: trial confirmation ---------------------------------------------------------------------


def test_trial_image_is_confirmed_after_its_period_of_health(tmp_path: Path, images: dict[str, Path]) -> None:
    root = flashed(tmp_path / "ecu", images["good"], images["good2"], confirm=False)
    log = Log()
    assert boot.boot(root, ["--seconds", "1.5"], confirm_after_s=0.5, log=log) == 0
    record = record_of(root)
    assert (record.active, record.previous, record.state, record.trial_boots) == ("b", "a", "confirmed", 0)
    assert [(e.slot, e.end, e.code) for e in record.history] == [("b", "exited", 0)]
    status = store.read_boot_status(root)
    assert status is not None and status.state is EcuState.OFF and status.host_link_up
    assert "--no-calibration" in app_argv(root), "no calibration: the app must not use a default one"
    assert "slot b confirmed: healthy for" in log.text()


def test_trial_that_reports_and_exits_is_not_confirmed_and_rolls_back(
    tmp_path: Path, images: dict[str, Path]
) -> None:
    """Alive is not healthy: an image that comes up and exits has not proven itself."""
    root = flashed(tmp_path / "ecu", images["good"], images["good2"], confirm=False)
    log = Log()
    # Slot a (confirmed) is booted at once instead, with the same arguments: it exits 3 as told.
    assert boot.boot(root, ["--exit-now", "3"], confirm_after_s=60, log=log) == 3
    record = record_of(root)
    assert (record.active, record.state, record.previous) == ("a", "confirmed", None)
    assert "exited with code 3 before it was confirmed" in record.rejected["b"]
    assert "FALLING BACK to slot a" in log.text()
    assert [(e.slot, e.end) for e in record.history] == [("b", "failed"), ("a", "failed")]


def test_trial_without_host_link_is_never_confirmed(tmp_path: Path, images: dict[str, Path]) -> None:
    root = flashed(tmp_path / "ecu", images["good"], images["sick"], confirm=False)
    log = Log()
    assert boot.boot(root, ["--seconds", "1.0"], confirm_after_s=0.2, log=log) == 0
    record = record_of(root)
    assert record.active == "a", log.text()
    assert "exited with code 0 before it was confirmed (healthy 0 of 0.2 s)" in record.rejected["b"]
    assert "slot b confirmed" not in log.text()


def test_trial_that_stops_reporting_is_stopped_and_rolled_back(
    tmp_path: Path, images: dict[str, Path]
) -> None:
    root = flashed(tmp_path / "ecu", images["good"], images["stall"], confirm=False)
    log = Log()
    assert boot.boot(root, ["--seconds", "2"], confirm_after_s=60, report_timeout_s=0.5, log=log) == 0
    record = record_of(root)
    assert record.active == "a"
    assert "stopped reporting for 0.5 s before it was confirmed" in record.rejected["b"]
    assert [(e.slot, e.end) for e in record.history] == [("b", "hung"), ("a", "exited")]


@pytest.mark.parametrize(("bad", "timeout_s"), [("crash", 30.0), ("hang", 0.5)])
def test_failed_trial_falls_back_to_previous_slot(
    tmp_path: Path, images: dict[str, Path], bad: str, timeout_s: float
) -> None:
    root = flashed(tmp_path / "ecu", images["good"], images[bad], confirm=False)
    log = Log()
    assert boot.boot(root, ["--exit-now", "0"], ready_timeout_s=timeout_s, log=log) == 0
    record = record_of(root)
    assert (record.active, record.state, record.previous) == ("a", "confirmed", None)
    assert version(images[bad]) in record.rejected["b"]
    assert "REJECTED" in log.text() and "FALLING BACK to slot a" in log.text()
    status = store.read_boot_status(root)
    assert status is not None and status.state is EcuState.OFF
    # The next flash goes into the rejected slot, keeping a, with a clean history for it.
    result = flash.flash_firmware(root, images["good2"], selftest=False)
    assert (result.slot, result.previous) == ("b", "a")
    record = record_of(root)
    assert "b" not in record.rejected and all(e.slot == "a" for e in record.history)


def test_failed_trial_without_fallback_returns_its_code(tmp_path: Path, images: dict[str, Path]) -> None:
    root = flashed(tmp_path / "ecu", images["crash"], confirm=False)
    log = Log()
    assert boot.boot(root, log=log) == 7
    record = record_of(root)
    assert record.state == "trial" and record.trial_boots == 1


def test_exhausted_trial_boots_fall_back(tmp_path: Path, images: dict[str, Path]) -> None:
    root = flashed(tmp_path / "ecu", images["good"], images["good2"], confirm=False)
    store.write_boot_record(root, BootRecord(active="b", previous="a", state="trial", trial_boots=3))
    log = Log()
    assert boot.boot(root, ["--exit-now", "0"], log=log) == 0
    record = record_of(root)
    assert record.active == "a"
    assert "started 3 times without being confirmed" in record.rejected["b"]


# --- boot: confirmed images -----------------------------------------------------------------------


def test_app_exit_code_is_returned(tmp_path: Path, images: dict[str, Path]) -> None:
    root = flashed(tmp_path / "ecu", images["good"])
    assert boot.boot(root, ["--exit-now", "4"], log=Log()) == 4


def test_confirmed_image_that_fails_once_is_not_swapped_out(tmp_path: Path, images: dict[str, Path]) -> None:
    root = flashed(tmp_path / "ecu", images["good"], images["late"])
    log = Log()
    assert boot.boot(root, ready_timeout_s=0.3, log=log) == 5
    record = record_of(root)
    assert (record.active, record.previous, record.state) == ("b", "a", "confirmed")
    assert "keeps running" in log.text()
    assert [(e.slot, e.end, e.code) for e in record.history] == [("b", "failed", 5)]


def test_confirmed_image_in_a_crash_loop_rolls_back_loudly(tmp_path: Path, images: dict[str, Path]) -> None:
    root = flashed(tmp_path / "ecu", images["good"], images["good2"])
    wall = FakeWall(step_s=120.0)  # a restart every 2 minutes: three within 10 minutes
    for _ in range(2):
        log = Log()
        assert boot.boot(root, ["--exit-now", "9"], wall_clock=wall, log=log) == 9
        assert record_of(root).active == "b", log.text()
    log = Log()
    # The third death makes the loop: slot a is booted at once (and exits 9 too, as told).
    assert boot.boot(root, ["--exit-now", "9"], wall_clock=wall, log=log) == 9
    record = record_of(root)
    assert (record.active, record.previous, record.state) == ("a", None, "confirmed")
    assert "crash loop: its last 3 boots died within 4.0 min (exit 9, exit 9, exit 9)" in record.rejected["b"]
    assert "!!! slot b REJECTED: crash loop" in log.text() and "FALLING BACK to slot a" in log.text()


def test_deaths_spread_out_clean_exits_or_no_fallback_do_not_roll_back(
    tmp_path: Path, images: dict[str, Path]
) -> None:
    root = flashed(tmp_path / "ecu", images["good"], images["good2"])
    slow = FakeWall(step_s=400.0)  # three deaths over 13 minutes
    for _ in range(3):
        assert boot.boot(root, ["--exit-now", "9"], wall_clock=slow, log=Log()) == 9
    assert record_of(root).active == "b"
    fast = FakeWall(step_s=10.0, start=slow.t + 1000)
    for _ in range(3):  # exit code 0: asked to stop, not dying
        assert boot.boot(root, ["--exit-now", "0"], wall_clock=fast, log=Log()) == 0
    assert record_of(root).active == "b"

    alone = flashed(tmp_path / "alone", images["good"])
    log = Log()
    for _ in range(4):
        assert boot.boot(alone, ["--exit-now", "9"], wall_clock=fast, log=log) == 9
    assert record_of(alone).active == "a"
    assert "crash loop" in log.text() and "no fallback" in log.text() and "booting it anyway" in log.text()


# --- boot: the store and the app ------------------------------------------------------------------


def test_development_store_is_announced_at_every_boot_and_to_the_app(
    tmp_path: Path, images: dict[str, Path]
) -> None:
    root = flashed(tmp_path / "ecu", images["good"])
    for _ in range(2):
        log = Log()
        assert boot.boot(root, ["--exit-now", "0"], log=log) == 0
        assert f"!!! store {root.absolute()} accepts UNSIGNED firmware (development store)" in log
        assert "--unsigned-store" in app_argv(root)
        status = store.read_boot_status(root)
        assert status is not None and status.unsigned_store


def test_signed_store_boots_without_the_warning(tmp_path: Path, images: dict[str, Path]) -> None:
    signing, public, *_ = key_pair(tmp_path / "keys")
    root = tmp_path / "ecu"
    flash.flash_firmware(
        root, images["good"], signing_key=signing, trust=flash.TrustChange(add=(public,)), selftest=False
    )
    log = Log()
    assert boot.boot(root, ["--exit-now", "0"], log=log) == 0
    assert "UNSIGNED" not in log.text() and "--unsigned-store" not in app_argv(root)


def test_calibration_passed_is_current_or_the_valid_previous(tmp_path: Path, images: dict[str, Path]) -> None:
    root = flashed(tmp_path / "ecu", images["good"])
    d = json.loads(PASSAT.read_bytes())
    d.pop("crc32")
    for v in (1, 2):
        src = tmp_path / f"c{v}.json"
        src.write_text(json.dumps({**d, "version": v}))
        flash.flash_calibration(root, src)
    assert boot.boot(root, ["--exit-now", "0"], log=Log()) == 0
    argv = app_argv(root)
    assert argv[argv.index("--calibration") + 1] == str(store.current_calibration_path(root))

    current = store.current_calibration_path(root)
    current.write_bytes(current.read_bytes()[:-5])  # torn by something outside our control
    log = Log()
    assert boot.boot(root, ["--exit-now", "0"], log=log) == 0
    argv = app_argv(root)
    assert argv[argv.index("--calibration") + 1] == str(store.previous_calibration_path(root))
    assert "current.json" in log.text()
    status = store.read_boot_status(root)
    assert status is not None and status.state is EcuState.READY


def test_corrupt_active_image_boots_previous_without_starting_it(
    tmp_path: Path, images: dict[str, Path]
) -> None:
    root = flashed(tmp_path / "ecu", images["good"], images["good2"])
    image_b = store.layout(root).image("b")
    data = bytearray(image_b.read_bytes())
    data[len(data) // 2] ^= 0xFF
    image_b.write_bytes(bytes(data))
    log = Log()
    assert boot.boot(root, ["--exit-now", "0"], log=log) == 0
    record = record_of(root)
    assert record.active == "a" and "sha256" in record.rejected["b"]
    assert [e.slot for e in record.history] == ["a"]


def test_nothing_to_boot(tmp_path: Path, images: dict[str, Path]) -> None:
    root = store.init_store(tmp_path / "ecu").root
    log = Log()
    assert boot.boot(root, log=log) == EXIT_NO_IMAGE
    assert "no firmware trust policy" in log.text()
    store.write_trust(root, store.TrustPolicy(allow_unsigned=True))
    assert boot.boot(root, log=log) == EXIT_NO_IMAGE
    assert "no firmware flashed" in log.text()
    flashed(root, images["good"])
    store.layout(root).image("a").write_bytes(b"rot")
    assert boot.boot(root, log=log) == EXIT_NO_IMAGE
    assert "no fallback" in log.text()
    with pytest.raises(StoreError, match="not an ECU store"):
        boot.boot(tmp_path)


def test_sigterm_is_forwarded_and_a_stopped_trial_boot_is_not_counted(
    tmp_path: Path, images: dict[str, Path]
) -> None:
    root = flashed(tmp_path / "ecu", images["good"], confirm=False)
    sup = subprocess.Popen(
        [sys.executable, "-m", "bywire.ecu.boot", "--store", str(root)],
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        deadline = time.monotonic() + 30
        status = None
        while time.monotonic() < deadline:
            status = store.read_boot_status(root)
            if status is not None:
                break
            assert sup.poll() is None, sup.stderr.read() if sup.stderr else ""
            time.sleep(0.05)
        assert status is not None, "the app never came up"
        app_pid = status.pid
        sup.send_signal(signal.SIGTERM)
        assert sup.wait(timeout=15) == 0  # the fake app exits 0 on SIGTERM
        with pytest.raises(ProcessLookupError):
            os.kill(app_pid, 0)
    finally:
        if sup.poll() is None:
            os.killpg(sup.pid, signal.SIGKILL)
            sup.wait()
    record = record_of(root)
    # Stopped on purpose within its 60 s: still on trial, and the boot does not use up a trial boot.
    assert (record.state, record.trial_boots) == ("trial", 0)
    assert [(e.end, e.code) for e in record.history] == [("stopped", 0)]


def test_cmd_run_from_store_forwards_the_bus_options(tmp_path: Path, images: dict[str, Path]) -> None:
    root = flashed(tmp_path / "ecu", images["good"])
    args = argparse.Namespace(
        store=root,
        vehicle_bus="virtual:v",
        host_link=None,
        app_args=["--exit-now", "0"],
        ready_timeout_s=30.0,
    )
    assert boot.cmd_run_from_store(args) == 0
    argv = app_argv(root)
    assert argv[argv.index("--vehicle-bus") + 1] == "virtual:v"
    assert "--host-link" not in argv
    args.store = tmp_path / "nowhere"
    assert boot.cmd_run_from_store(args) == EXIT_NO_IMAGE


def test_ecu_run_confirm_after_reaches_the_supervisor_not_the_app(
    tmp_path: Path, images: dict[str, Path]
) -> None:
    root = flashed(tmp_path / "ecu", images["good"], images["good2"], confirm=False)
    assert cli.main(["run", "--store", str(root), "--confirm-after", "0.4", "--seconds", "1.2"]) == 0
    assert record_of(root).state == "confirmed"
    argv = app_argv(root)
    assert "--confirm-after" not in argv and argv[argv.index("--seconds") + 1] == "1.2"
    with pytest.raises(SystemExit):
        cli.build_parser().parse_args(["run", "--store", str(root), "--confirm-after", "-1"])


# --- the real image -------------------------------------------------------------------------------


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture
def host_heartbeat() -> Iterator[str]:
    """A host on a UDP host link sending its CANopen heartbeat (OPERATIONAL) every 50 ms; yields the
    ECU's end of the link."""
    from bywire.protocol.bus_url import open_bus
    from bywire.protocol.canopen_link.dictionary import HOST_NODE_ID
    from bywire.protocol.canopen_link.nmt import HEARTBEAT_COB_BASE, NmtState

    ecu_port, host_port = _free_udp_port(), _free_udp_port()
    bus = open_bus(f"udp://127.0.0.1:{host_port}?peer=127.0.0.1:{ecu_port}")
    stop = threading.Event()
    frame = can.Message(
        arbitration_id=HEARTBEAT_COB_BASE + HOST_NODE_ID,
        data=[int(NmtState.OPERATIONAL)],
        is_extended_id=False,
    )

    def beat() -> None:
        while not stop.wait(0.05):
            bus.send(frame)

    thread = threading.Thread(target=beat, daemon=True)
    thread.start()
    try:
        yield f"udp://127.0.0.1:{ecu_port}?peer=127.0.0.1:{host_port}"
    finally:
        stop.set()
        thread.join(5)
        bus.shutdown()


def test_real_signed_image_is_confirmed_once_the_host_link_makes_it_healthy(
    tmp_path: Path, host_heartbeat: str
) -> None:
    """The real firmware, built, signed and flashed with its self-test, is confirmed from the store
    only by its health: without a host it runs but stays on trial; with one it is confirmed."""
    _, _, private, public = key_pair(tmp_path / "keys")
    root = tmp_path / "ecu"
    argv = ["--store", str(root), "--firmware", "--key", str(private), "--trust-key", str(public)]
    assert flash.main([*argv, "--calibration", str(PASSAT)]) == 0
    app = ["--vehicle-bus", "virtual:vehicle", "--no-rt"]

    log = Log()
    alone = [*app, "--host-link", "virtual:nohost", "--seconds", "2.5"]
    rc = boot.boot(root, alone, ready_timeout_s=60, confirm_after_s=1.0, log=log)
    assert rc == 0, log.text()
    record = record_of(root)
    assert (record.active, record.state) == ("a", "trial"), log.text()
    status = store.read_boot_status(root)
    assert status is not None and status.state in (EcuState.OFF, EcuState.READY)
    assert not status.host_link_up and status.healthy_s == 0.0 and status.seq >= 2

    log = Log()
    # 6 s for 1 s of health: a loop stall on this shared machine restarts the count.
    hosted = [*app, "--host-link", host_heartbeat, "--seconds", "6"]
    rc = boot.boot(root, hosted, ready_timeout_s=60, confirm_after_s=1.0, log=log)
    assert rc == 0, log.text()
    record = record_of(root)
    assert (record.active, record.state) == ("a", "confirmed"), log.text()
    status = store.read_boot_status(root)
    assert status is not None and status.host_link_up and status.healthy_s >= 1.0
    assert not status.unsigned_store
    assert store.slot_usable(root, "a") is None
