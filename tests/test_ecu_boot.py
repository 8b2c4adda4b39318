"""Booting from the store: trial confirmation, fallback to the previous slot, calibration choice,
signal forwarding, and the real firmware image coming up from a store."""

from __future__ import annotations

import functools
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import bywire.ecu
from bywire.ecu import boot, firmware, flash, store
from bywire.ecu.boot import EXIT_NO_IMAGE, plan_boot
from bywire.ecu.firmware import ImageContents
from bywire.ecu.store import BootRecord, StoreError
from bywire.protocol.ecu_types import EcuState

PASSAT = Path(bywire.ecu.__path__[0]) / "calibrations" / "passat.json"

# Test images get the boot machinery only, so these tests do not depend on the rest of the firmware
# (the real image boots in the last test).
MECHANICS = {
    "bywire/__init__.py",
    "bywire/clock.py",
    "bywire/protocol/__init__.py",
    "bywire/protocol/ecu_types.py",
    "bywire/ecu/__init__.py",
    "bywire/ecu/store.py",
    "bywire/ecu/firmware.py",
    "bywire/ecu/calibration.py",
    "bywire/ecu/calibrations/passat.json",
}

# A stand-in for bywire.ecu.app. MODE: good (report, then run until SIGTERM or --exit-now CODE),
# crash (exit 7 at once), hang (never report), late (exit 5 after 0.8 s without reporting).
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
    report_boot(store, "READY" if "--calibration" in argv else "OFF")
    if "--exit-now" in argv:
        return int(argv[argv.index("--exit-now") + 1])
    while not stop:
        time.sleep(0.01)
    return 0
"""


@pytest.fixture(scope="module")
def images(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    full = firmware.collect_image_contents()
    files = {k: v for k, v in full.files.items() if not k.startswith("bywire/") or k in MECHANICS}
    contents = ImageContents(files, full.distributions, full.skipped_extensions, full.entry_points)
    d = tmp_path_factory.mktemp("images")
    out = {}
    for mode in ("good", "good2", "crash", "hang", "late"):
        app = FAKE_APP.format(mode=mode.removesuffix("2"))
        if mode == "good2":
            app += "\n# another build\n"
        firmware.write_image(
            d / f"{mode}.pyz", contents, entry="fakeapp:main", extra_files={"fakeapp.py": app.encode()}
        )
        out[mode] = d / f"{mode}.pyz"
    return out


class Log(list[str]):
    def __call__(self, msg: str) -> None:
        self.append(msg)

    def text(self) -> str:
        return "\n".join(self)


def app_argv(root: Path) -> list[str]:
    return json.loads((root / "run" / "app-argv.json").read_text())


def flashed(root: Path, *images: Path, confirm: bool = True) -> Path:
    """A store with `images` flashed in order; each but the last confirmed (the last too if confirm)."""
    for i, image in enumerate(images):
        flash.flash_firmware(root, image, selftest=False)
        if confirm or i < len(images) - 1:
            record = store.read_boot_record(root)
            assert record is not None
            store.write_boot_record(root, BootRecord(active=record.active, previous=record.previous))
    return root


def version(image: Path) -> str:
    return str(firmware.read_image_info(image)["version"])


# --- plan_boot (pure) ---------------------------------------------------------------------------


@settings(max_examples=200, deadline=None)
@given(
    active=st.sampled_from(store.SLOTS),
    has_previous=st.booleans(),
    state=st.sampled_from(["confirmed", "trial"]),
    trial_boots=st.integers(0, 5),
    bad=st.sets(st.sampled_from(store.SLOTS)),
)
def test_plan_boot_never_picks_a_bad_slot_and_only_falls_back_to_previous(
    active: store.Slot, has_previous: bool, state: store.BootState, trial_boots: int, bad: set[str]
) -> None:
    previous = store.other_slot(active) if has_previous else None
    record = BootRecord(active=active, previous=previous, state=state, trial_boots=trial_boots)
    plan = plan_boot(record, lambda s: "bad" if s in bad else None, max_trial_boots=3)
    if plan.slot is None:
        assert active in bad and (previous is None or previous in bad)
        return
    assert plan.slot not in bad
    assert plan.slot in (active, previous)
    if plan.slot != active:
        assert plan.record.state == "confirmed" and active in plan.record.rejected
    elif state == "trial":
        assert plan.record.trial_boots == trial_boots + 1
    exhausted = state == "trial" and trial_boots >= 3
    fallback_ok = previous is not None and previous not in bad
    if active in bad or (exhausted and fallback_ok):
        assert plan.slot == previous
    else:  # a good active image is never abandoned, an exhausted one only for a good fallback
        assert plan.slot == active


# --- boot ---------------------------------------------------------------------------------------


def test_trial_image_that_comes_up_is_confirmed(tmp_path: Path, images: dict[str, Path]) -> None:
    root = flashed(tmp_path / "ecu", images["good"], images["good2"], confirm=False)
    log = Log()
    assert boot.boot(root, ["--exit-now", "0"], ready_timeout_s=30, log=log) == 0
    assert store.read_boot_record(root) == BootRecord(active="b", previous="a", state="confirmed")
    status = store.read_boot_status(root)
    assert status is not None and status.state is EcuState.OFF
    assert "--no-calibration" in app_argv(root), "no calibration: the app must not use a default one"
    assert "slot b confirmed" in log.text()


def test_app_exit_code_is_returned(tmp_path: Path, images: dict[str, Path]) -> None:
    root = flashed(tmp_path / "ecu", images["good"])
    assert boot.boot(root, ["--exit-now", "4"], log=Log()) == 4


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


@pytest.mark.parametrize(("bad", "timeout_s"), [("crash", 30.0), ("hang", 0.5)])
def test_failed_trial_falls_back_to_previous_slot(
    tmp_path: Path, images: dict[str, Path], bad: str, timeout_s: float
) -> None:
    root = flashed(tmp_path / "ecu", images["good"], images[bad], confirm=False)
    log = Log()
    assert boot.boot(root, ["--exit-now", "0"], ready_timeout_s=timeout_s, log=log) == 0
    record = store.read_boot_record(root)
    assert record is not None
    assert (record.active, record.state, record.previous) == ("a", "confirmed", None)
    assert version(images[bad]) in record.rejected["b"]
    assert "REJECTED" in log.text() and "FALLING BACK to slot a" in log.text()
    status = store.read_boot_status(root)
    assert status is not None and status.state is EcuState.OFF
    # The next flash goes into the rejected slot, keeping a.
    result = flash.flash_firmware(root, images["good2"], selftest=False)
    assert (result.slot, result.previous) == ("b", "a")
    record = store.read_boot_record(root)
    assert record is not None and "b" not in record.rejected


def test_failed_trial_without_fallback_returns_its_code(tmp_path: Path, images: dict[str, Path]) -> None:
    root = flashed(tmp_path / "ecu", images["crash"], confirm=False)
    log = Log()
    assert boot.boot(root, log=log) == 7
    record = store.read_boot_record(root)
    assert record is not None and record.state == "trial" and record.trial_boots == 1


def test_confirmed_image_that_fails_is_not_swapped_out(tmp_path: Path, images: dict[str, Path]) -> None:
    root = flashed(tmp_path / "ecu", images["good"], images["late"])
    before = store.read_boot_record(root)
    log = Log()
    assert boot.boot(root, ready_timeout_s=0.3, log=log) == 5
    assert store.read_boot_record(root) == before
    assert "keeps running" in log.text()


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
    record = store.read_boot_record(root)
    assert record is not None and record.active == "a" and "sha256" in record.rejected["b"]


def test_exhausted_trial_boots_fall_back(tmp_path: Path, images: dict[str, Path]) -> None:
    root = flashed(tmp_path / "ecu", images["good"], images["good2"], confirm=False)
    store.write_boot_record(root, BootRecord(active="b", previous="a", state="trial", trial_boots=3))
    log = Log()
    assert boot.boot(root, ["--exit-now", "0"], log=log) == 0
    record = store.read_boot_record(root)
    assert record is not None and record.active == "a"
    assert "started 3 times" in record.rejected["b"]


def test_nothing_to_boot(tmp_path: Path, images: dict[str, Path]) -> None:
    root = store.init_store(tmp_path / "ecu").root
    log = Log()
    assert boot.boot(root, log=log) == EXIT_NO_IMAGE
    assert "no firmware flashed" in log.text()
    flashed(root, images["good"])
    store.layout(root).image("a").write_bytes(b"rot")
    assert boot.boot(root, log=log) == EXIT_NO_IMAGE
    assert "no fallback" in log.text()
    with pytest.raises(StoreError, match="not an ECU store"):
        boot.boot(tmp_path)


def test_sigterm_is_forwarded_to_the_app(tmp_path: Path, images: dict[str, Path]) -> None:
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
            record = store.read_boot_record(root)
            status = store.read_boot_status(root)
            if status is not None and record is not None and record.state == "confirmed":
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


def test_cmd_run_from_store_forwards_the_bus_options(tmp_path: Path, images: dict[str, Path]) -> None:
    import argparse

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


def test_real_image_boots_from_a_store_and_is_confirmed(tmp_path: Path) -> None:
    """The real firmware, built and flashed with its self-test, reaches READY from the store."""
    root = tmp_path / "ecu"
    assert flash.main(["--store", str(root), "--firmware", "--calibration", str(PASSAT)]) == 0
    log = Log()
    app = ["--vehicle-bus", "virtual:vehicle", "--host-link", "virtual:host", "--no-rt", "--seconds", "1.5"]
    rc = boot.boot(root, app, ready_timeout_s=60, log=log)
    assert rc == 0, log.text()
    record = store.read_boot_record(root)
    assert record == BootRecord(active="a", state="confirmed"), log.text()
    status = store.read_boot_status(root)
    assert status is not None and status.state in (EcuState.OFF, EcuState.READY)
    assert functools.partial(store.slot_usable, root)("a") is None
