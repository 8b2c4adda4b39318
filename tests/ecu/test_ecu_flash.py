"""Firmware images and flashing: reproducible self-contained images, the check that an image holds
an ECU, A/B slot writes, calibrations, refusals that leave the store byte-for-byte unchanged, kills
at any instant of a flash, and I/O errors at every call site reported as what the store boots."""

from __future__ import annotations

import contextlib
import errno
import functools
import io
import json
import os
import random
import re
import signal
import subprocess
import sys
import time
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from ecu_test_images import fake_ecu_image, mechanics_contents

import bywire.ecu
from bywire.ecu import firmware, flash, store
from bywire.ecu.boot import plan_boot
from bywire.ecu.calibration import CalibrationError, calibration_from_dict, dumps_calibration
from bywire.ecu.firmware import ImageContents
from bywire.ecu.flash import FlashError
from bywire.ecu.store import BootRecord
from bywire.ecu.trust import DEVELOPMENT

PASSAT = Path(bywire.ecu.__path__[0]) / "calibrations" / "passat.json"

# A stand-in for bywire.ecu.app inside test images: reports its state like the real app.
FAKE_APP = """
import sys
from bywire.ecu.store import report_boot

def main(argv):
    store = argv[argv.index("--store") + 1]
    report_boot(store, "READY" if "--calibration" in argv else "OFF")
    return 0
"""


@pytest.fixture(scope="module")
def contents() -> ImageContents:
    return mechanics_contents()


@pytest.fixture(scope="module")
def images(tmp_path_factory: pytest.TempPathFactory, contents: ImageContents) -> dict[str, Path]:
    """Test images: two good ones (different versions), one whose app cannot even be imported, and
    zips that are not ECU images though their self-test would pass."""
    d = tmp_path_factory.mktemp("images")
    out = {}
    for name, app in (
        ("good1", FAKE_APP),
        ("good2", FAKE_APP + "\n# second build\n"),
        ("broken", "raise RuntimeError('flash me not')\n"),
    ):
        out[name] = fake_ecu_image(d / f"{name}.pyz", app)
    # Some application, no ECU in it at all: its own entry, and a self-test that says "ok".
    ecu_core = {"bywire/ecu/app.py", "bywire/ecu/core.py", "bywire/ecu/safety.py", "bywire/ecu/executive.py"}
    no_ecu = {k: v for k, v in contents.files.items() if k not in ecu_core}
    firmware.write_image(
        d / "other_app.pyz",
        ImageContents(no_ecu, contents.distributions, contents.skipped_extensions, contents.entry_points),
        entry="fakeapp:main",
        extra_files={"fakeapp.py": FAKE_APP.encode()},
    )
    out["other_app"] = d / "other_app.pyz"
    without_safety = {k: v for k, v in contents.files.items() if k != "bywire/ecu/safety.py"}
    firmware.write_image(
        d / "no_safety.pyz",
        ImageContents(
            without_safety, contents.distributions, contents.skipped_extensions, contents.entry_points
        ),
        extra_files={"bywire/ecu/app.py": FAKE_APP.encode()},
    )
    out["no_safety"] = d / "no_safety.pyz"
    # The ECU's files, but a __main__.py that runs something else when the ECU boots it.
    buf = io.BytesIO()
    with zipfile.ZipFile(out["good1"]) as src, zipfile.ZipFile(buf, "w") as dst:
        for info in src.infolist():
            data = src.read(info)
            dst.writestr(info, b"print('not the ECU')\n" if info.filename == "__main__.py" else data)
    (d / "other_main.pyz").write_bytes(buf.getvalue())
    out["other_main"] = d / "other_main.pyz"
    return out


def dev_flash(root: Path, image: Path, **kwargs: Any) -> flash.FirmwareFlashResult:
    """Flash into a development store (these tests are about slots and files, not signatures)."""
    return flash.flash_firmware(root, image, selftest=False, trust=DEVELOPMENT, **kwargs)


def snapshot(root: Path) -> dict[str, bytes | None]:
    """Every file and directory under root, with file contents: 'byte-for-byte unchanged'."""
    snap: dict[str, bytes | None] = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for name in dirnames:
            snap[os.path.relpath(os.path.join(dirpath, name), root) + "/"] = None
        for name in filenames:
            path = os.path.join(dirpath, name)
            if name == "lock":  # flock's file: content-free by design
                continue
            snap[os.path.relpath(path, root)] = Path(path).read_bytes()
    return snap


def calibration_doc(version: int, **changes: Any) -> dict[str, Any]:
    d = json.loads(PASSAT.read_bytes())
    d.pop("crc32")
    d["version"] = version
    d.update(changes)
    return d


def write_calibration(path: Path, version: int, **changes: Any) -> Path:
    path.write_bytes(dumps_calibration(calibration_from_dict(calibration_doc(version, **changes))))
    return path


def boot_choice(root: Path) -> tuple[str, str, str]:
    """(slot, "on trial" | "confirmed", image version) the ECU would boot now, like boot does."""
    record = store.read_boot_record(root)
    assert record is not None
    plan = plan_boot(record, functools.partial(store.slot_usable, root))
    assert plan.slot is not None, plan.problem
    _, manifest = store.verify_image(root, plan.slot)
    return plan.slot, "on trial" if plan.record.state == "trial" else "confirmed", manifest.version


def bootable(root: Path) -> tuple[str, int | None]:
    """(image version, calibration version) the ECU would boot now, resolving fallbacks like boot."""
    cal = store.usable_calibration(root).calibration
    return boot_choice(root)[2], cal.version if cal is not None else None


# --- images -------------------------------------------------------------------------------------


def test_real_image_is_self_contained_and_passes_its_selftest(tmp_path: Path) -> None:
    manifest = firmware.build_image(tmp_path / "ecu.pyz")
    assert manifest.entry == firmware.DEFAULT_ENTRY
    with zipfile.ZipFile(tmp_path / "ecu.pyz") as zf:
        names = zf.namelist()
    assert not [n for n in names if n.endswith((".so", ".pyc"))]
    for needed in (
        "bywire/ecu/store.py",
        "bywire/ecu/signing.py",
        "bywire/protocol/vehicle.dbc",
        "bywire/ecu/calibrations/passat.json",
        *firmware.ECU_IMAGE_FILES,
    ):
        assert needed in names
    assert any(n.startswith("python_can_remote-") and n.endswith("/entry_points.txt") for n in names)
    assert "bywire/cli.py" not in names, "the image holds only what the ECU runs"
    # The ECU's end of the CANopen link ships, the host's master never does: the self-test below then
    # proves that nothing the ECU imports needs it.
    assert "bywire/protocol/canopen_link/ecu_node.py" in names
    assert "bywire/protocol/canopen_link/host_master.py" not in names, "the host's master is the host's"
    assert not [n for n in names if n.startswith("cryptography/")], "the ECU itself never verifies"
    # -I -S: only the zip and the standard library are importable, so this proves self-containment
    # (bywire.ecu.signing among the modules it imports, without the compiled cryptography package).
    report = firmware.run_selftest(tmp_path / "ecu.pyz")
    assert report.ok, report.output
    assert report.version == manifest.version
    firmware.check_ecu_image((tmp_path / "ecu.pyz").read_bytes(), "ecu.pyz")


BUILD = """
import sys
from bywire.ecu.firmware import build_image
print(build_image(sys.argv[1], entry="bywire.ecu.store:report_boot").sha256)
"""


def test_image_is_reproducible(tmp_path: Path) -> None:
    """Builds in processes with different hash seeds give the same bytes (and version)."""

    def source_state() -> dict[str, bytes]:
        return dict(firmware.collect_image_contents().files)

    for _attempt in range(3):
        before = source_state()
        # This process runs with a random hash seed, the child with none (seed 0).
        here = firmware.build_image(tmp_path / "1.pyz", entry="bywire.ecu.store:report_boot").sha256
        out = subprocess.run(
            [sys.executable, "-c", BUILD, str(tmp_path / "2.pyz")],
            env={**os.environ, "PYTHONHASHSEED": "0"},
            capture_output=True,
            text=True,
            check=True,
        )
        shas = [here, out.stdout.strip()]
        # Other engineers edit this tree while the suite runs; only an unchanged source counts.
        if source_state() == before:
            break
    else:
        pytest.fail("the source tree kept changing during the build")
    assert shas[0] == shas[1]
    assert (tmp_path / "1.pyz").read_bytes() == (tmp_path / "2.pyz").read_bytes()
    info = firmware.read_image_info(tmp_path / "1.pyz")
    assert info["version"].startswith(bywire.__version__ + "+")
    other = firmware.write_image(
        tmp_path / "3.pyz",
        firmware.collect_image_contents(),
        entry="bywire.ecu.store:report_boot",
        extra_files={"note.txt": b"x"},
    )
    assert other.sha256 != shas[0] and other.version != info["version"]


def test_selftest_fails_when_a_dependency_is_missing_from_the_image(
    tmp_path: Path, contents: ImageContents
) -> None:
    # wrapt is installed in the venv; an image without it must not silently borrow it.
    files = {k: v for k, v in contents.files.items() if not k.startswith("wrapt/")}
    stripped = ImageContents(
        files, contents.distributions, contents.skipped_extensions, contents.entry_points
    )
    firmware.write_image(tmp_path / "x.pyz", stripped, entry="bywire.ecu.store:report_boot")
    report = firmware.run_selftest(tmp_path / "x.pyz")
    assert not report.ok
    assert any("wrapt" in p for p in report.problems), report.problems


def test_write_image_refuses_a_missing_entry(tmp_path: Path, contents: ImageContents) -> None:
    with pytest.raises(firmware.FirmwareError, match="not in the image"):
        firmware.write_image(tmp_path / "x.pyz", contents, entry="nowhere.app:main")
    assert not (tmp_path / "x.pyz").exists()


# --- what an ECU image is ------------------------------------------------------------------------


def test_an_application_whose_selftest_passes_is_still_not_an_ecu_image(
    tmp_path: Path, images: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    assert firmware.run_selftest(images["other_app"]).ok, "the zip's own self-test says ok"
    root = tmp_path / "ecu"
    rc = flash.main(["--store", str(root), "--image", str(images["other_app"]), "--allow-unsigned"])
    err = capsys.readouterr().err.strip()
    assert rc == 1
    assert err == (
        f"error: {images['other_app']}: not an ECU image: its entry is 'fakeapp:main',"
        " not bywire's ECU app bywire.ecu.app:main"
    )
    assert not root.exists()


@pytest.mark.parametrize(
    ("name", "problem"),
    [
        ("no_safety", "not an ECU image: bywire/ecu/safety.py missing"),
        ("other_main", "not an ECU image: its __main__.py is not the one the firmware builder writes"),
    ],
)
def test_an_image_without_the_ecu_is_refused_and_the_store_unchanged(
    tmp_path: Path, images: dict[str, Path], name: str, problem: str
) -> None:
    root = tmp_path / "ecu"
    dev_flash(root, images["good1"])
    before = snapshot(root)
    with pytest.raises(FlashError) as e:
        dev_flash(root, images[name])
    assert str(e.value) == f"{images[name]}: {problem}"
    assert snapshot(root) == before


# --- firmware flashing --------------------------------------------------------------------------


def test_flash_firmware_alternates_slots_and_keeps_the_good_one(
    tmp_path: Path, images: dict[str, Path]
) -> None:
    root = tmp_path / "ecu"
    first = dev_flash(root, images["good1"])
    assert (first.slot, first.previous) == ("a", None)
    assert store.read_boot_record(root) == BootRecord(active="a", previous=None, state="trial")
    assert store.active_image(root)[2].version == first.manifest.version
    # The boot supervisor confirms a slot once its image proved itself.
    store.write_boot_record(root, BootRecord(active="a", state="confirmed"))

    second = dev_flash(root, images["good2"])
    assert (second.slot, second.previous) == ("b", "a")
    assert store.read_boot_record(root) == BootRecord(active="b", previous="a", state="trial")
    # Flashing again before b proved itself replaces b and still keeps a, the known-good image.
    third = dev_flash(root, images["good1"])
    assert (third.slot, third.previous) == ("b", "a")
    assert store.read_manifest(root, "a").version == first.manifest.version
    assert not (root / "staging").exists()


def test_flash_clears_the_target_slots_boot_history(tmp_path: Path, images: dict[str, Path]) -> None:
    root = tmp_path / "ecu"
    dev_flash(root, images["good1"])
    dev_flash(root, images["good2"])
    died = [store.BootEntry("b", "v", 1.8e9 + i, "failed", 1) for i in range(3)]
    store.write_boot_record(
        root, BootRecord(active="b", previous="a", history=(*died, store.BootEntry("a", "v", 1.7e9)))
    )
    dev_flash(root, images["good1"])  # a is replaced: its old image's boots are not the new one's
    record = store.read_boot_record(root)
    assert record is not None and (record.active, record.previous) == ("a", "b")
    assert record.history == tuple(died)


def test_flash_refused_by_selftest_leaves_store_unchanged(tmp_path: Path, images: dict[str, Path]) -> None:
    root = tmp_path / "ecu"
    dev_flash(root, images["good1"])
    before = snapshot(root)
    with pytest.raises(FlashError, match="selftest") as e:
        flash.flash_firmware(root, images["broken"])
    assert "bywire.ecu.app: RuntimeError: flash me not" in str(e.value)
    assert snapshot(root) == before


def test_refused_first_flash_leaves_no_store_behind(tmp_path: Path) -> None:
    junk = tmp_path / "junk.pyz"
    junk.write_bytes(b"PK not really")
    with pytest.raises(FlashError, match="not a firmware image"):
        flash.flash_firmware(tmp_path / "new", junk, trust=DEVELOPMENT)
    assert not (tmp_path / "new").exists()


def test_flash_refuses_a_file_that_is_not_an_image(tmp_path: Path, images: dict[str, Path]) -> None:
    root = tmp_path / "ecu"
    dev_flash(root, images["good1"])
    before = snapshot(root)
    junk = tmp_path / "junk.pyz"
    junk.write_bytes(b"PK not really")
    with pytest.raises(FlashError, match=r"junk\.pyz: not a firmware image"):
        flash.flash_firmware(root, junk)
    assert snapshot(root) == before


def test_flash_overwrites_a_slot_whose_image_rotted(tmp_path: Path, images: dict[str, Path]) -> None:
    root = tmp_path / "ecu"
    dev_flash(root, images["good1"])
    store.write_boot_record(root, BootRecord(active="a"))
    dev_flash(root, images["good2"])
    store.write_boot_record(root, BootRecord(active="b", previous="a"))
    image_b = store.layout(root).image("b")
    image_b.write_bytes(image_b.read_bytes()[:-10])  # active b rotted: a is what still boots
    result = dev_flash(root, images["good2"])
    assert (result.slot, result.previous) == ("b", "a")


# --- calibration flashing -----------------------------------------------------------------------


def test_flash_calibration_keeps_previous_and_checks_versions(tmp_path: Path) -> None:
    root = tmp_path / "ecu"
    lay = store.init_store(root)
    r1 = flash.flash_calibration(root, write_calibration(tmp_path / "c1.json", 1))
    assert r1.changed and r1.replaced_version is None
    assert not lay.previous_calibration.exists()
    r2 = flash.flash_calibration(root, write_calibration(tmp_path / "c2.json", 2, ki_per_s=1.2))
    assert r2.replaced_version == 1
    assert store.read_calibration_file(lay.current_calibration).version == 2
    assert store.read_calibration_file(lay.previous_calibration).version == 1
    # The same file again is a no-op, not a rotation that would lose version 1.
    assert not flash.flash_calibration(root, tmp_path / "c2.json").changed
    assert store.read_calibration_file(lay.previous_calibration).version == 1

    before = snapshot(root)
    with pytest.raises(CalibrationError) as e:
        flash.flash_calibration(root, tmp_path / "c1.json")
    assert e.value.field == "version" and "lower than" in str(e.value)
    with pytest.raises(CalibrationError, match="same as"):
        flash.flash_calibration(root, write_calibration(tmp_path / "c2b.json", 2, ki_per_s=1.3))
    assert snapshot(root) == before
    assert flash.flash_calibration(root, tmp_path / "c1.json", allow_downgrade=True).replaced_version == 2


def test_corrupt_current_never_displaces_a_good_previous(tmp_path: Path) -> None:
    root = tmp_path / "ecu"
    lay = store.init_store(root)
    flash.flash_calibration(root, write_calibration(tmp_path / "c1.json", 1))
    flash.flash_calibration(root, write_calibration(tmp_path / "c2.json", 2))
    lay.current_calibration.write_bytes(lay.current_calibration.read_bytes().replace(b"50.0", b"51.0"))
    flash.flash_calibration(root, write_calibration(tmp_path / "c3.json", 3))
    assert store.read_calibration_file(lay.current_calibration).version == 3
    assert store.read_calibration_file(lay.previous_calibration).version == 1


def test_hand_written_calibration_without_crc_is_accepted_and_stored_with_one(tmp_path: Path) -> None:
    root = tmp_path / "ecu"
    src = tmp_path / "mine.json"
    src.write_text(json.dumps(calibration_doc(7), indent=4))
    flash.flash_calibration(root, src)
    assert store.read_calibration_file(store.current_calibration_path(root)).version == 7
    assert b'"crc32"' in store.current_calibration_path(root).read_bytes()


def test_persist_calibration_bytes_from_sdo(tmp_path: Path) -> None:
    root = tmp_path / "ecu"
    lay = store.init_store(root)
    flash.flash_calibration(root, write_calibration(tmp_path / "c3.json", 3))
    # An SDO write is an explicit operator action: an older version is accepted.
    result = flash.persist_calibration_bytes(root, write_calibration(tmp_path / "c2.json", 2).read_bytes())
    assert result.changed and result.replaced_version == 3
    assert store.read_calibration_file(lay.current_calibration).version == 2
    assert store.read_calibration_file(lay.previous_calibration).version == 3

    before = snapshot(root)
    corrupt = (tmp_path / "c2.json").read_bytes().replace(b"50.0", b"55.0")
    with pytest.raises(CalibrationError) as e:
        flash.persist_calibration_bytes(root, corrupt)
    assert e.value.field == "crc32" and e.value.source == "SDO 0x2200"
    # A flash holding the store must not stall the ECU loop for the length of a self-test.
    with store.store_lock(root), pytest.raises(store.StoreError, match="store busy"):
        flash.persist_calibration_bytes(root, (tmp_path / "c3.json").read_bytes(), lock_timeout_s=0.05)
    assert snapshot(root) == before


@pytest.mark.parametrize(
    ("mutate", "field"),
    [
        (lambda d: d["brake_map"]["bar"].__setitem__(3, 1.0), "brake_map.bar[3]"),
        (lambda d: d.__setitem__("accel_min_mps2", -40.0), "accel_min_mps2"),
        (lambda d: d.__setitem__("crc32", 12345), "crc32"),
        (lambda d: d.__setitem__("version", 0), "version"),
    ],
)
def test_bad_calibration_is_refused_naming_the_field_and_store_unchanged(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    mutate: Callable[[dict[str, Any]], None],
    field: str,
) -> None:
    root = tmp_path / "ecu"
    flash.flash_calibration(root, write_calibration(tmp_path / "good.json", 1))
    before = snapshot(root)
    d = calibration_doc(2)
    mutate(d)
    bad = tmp_path / "calibration.json"
    bad.write_text(json.dumps(d))
    rc = flash.main(["--store", str(root), "--calibration", str(bad)])
    err = capsys.readouterr().err.strip()
    assert rc == 1
    assert err.startswith(f"error: {bad}: {field}:"), err
    assert len(err.splitlines()) == 1
    assert snapshot(root) == before


def test_bad_calibration_refuses_the_firmware_flashed_with_it(
    tmp_path: Path, images: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    root = tmp_path / "ecu"
    dev_flash(root, images["good1"])
    before = snapshot(root)
    d = calibration_doc(2)
    d["coast_map"]["accel_mps2"][0] = 0.5
    bad = tmp_path / "calibration.json"
    bad.write_text(json.dumps(d))
    rc = flash.main(["--store", str(root), "--image", str(images["good2"]), "--calibration", str(bad)])
    assert rc == 1
    assert "coast_map.accel_mps2[0]" in capsys.readouterr().err
    assert snapshot(root) == before


def test_cli_needs_something_to_flash(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert flash.main(["--store", str(tmp_path / "s")]) == 2
    assert "nothing to flash" in capsys.readouterr().err
    assert not (tmp_path / "s").exists()


# --- crashes and I/O errors ---------------------------------------------------------------------


class PowerCut(Exception):
    pass


@pytest.fixture
def power_cut_after(monkeypatch: pytest.MonkeyPatch) -> Iterator[Callable[[int], None]]:
    """Arm a crash at the n-th rename (os.replace or os.rename): the flash dies right there."""
    real_replace, real_rename = os.replace, os.rename
    budget = {"n": -1}

    def guarded(real: Callable[..., None]) -> Callable[..., None]:
        def op(*args: Any, **kwargs: Any) -> None:
            if budget["n"] == 0:
                raise PowerCut
            budget["n"] -= 1
            real(*args, **kwargs)

        return op

    monkeypatch.setattr(os, "replace", guarded(real_replace))
    monkeypatch.setattr(os, "rename", guarded(real_rename))

    def arm(n: int) -> None:
        budget["n"] = n

    yield arm
    budget["n"] = -1


def test_calibration_flash_cut_at_every_rename_leaves_a_good_calibration(
    tmp_path: Path, power_cut_after: Callable[[int], None]
) -> None:
    for cut in range(10):
        root = tmp_path / f"ecu{cut}"
        flash.flash_calibration(root, write_calibration(tmp_path / "c1.json", 1))
        flash.flash_calibration(root, write_calibration(tmp_path / "c2.json", 2))
        power_cut_after(cut)
        try:
            flash.flash_calibration(root, write_calibration(tmp_path / "c3.json", 3))
            completed = True
        except PowerCut:
            completed = False
        power_cut_after(-1)
        choice = store.usable_calibration(root)
        assert choice.calibration is not None, f"cut {cut}: no usable calibration"
        assert choice.calibration.version in (2, 3), f"cut {cut}: fell back to {choice.calibration.version}"
        if completed:
            assert choice.calibration.version == 3
            assert store.read_calibration_file(store.previous_calibration_path(root)).version == 2
            break
        # The next flash after the crash completes normally.
        store.clean_staging(root)
        flash.flash_calibration(root, tmp_path / "c3.json")
        assert store.usable_calibration(root).calibration.version == 3  # type: ignore[union-attr]
    else:
        pytest.fail("the flash never completed: the crash loop did not reach the end")


def test_firmware_flash_cut_at_every_rename_leaves_a_bootable_image(
    tmp_path: Path, images: dict[str, Path], power_cut_after: Callable[[int], None]
) -> None:
    versions = {k: firmware.read_image_info(v)["version"] for k, v in images.items()}
    for trial in (False, True):
        for cut in range(20):
            root = tmp_path / f"ecu{cut}{trial}"
            dev_flash(root, images["good1"])
            store.write_boot_record(root, BootRecord(active="a"))
            if trial:  # a second image on trial, not yet confirmed: a must survive the next flash
                flash.flash_firmware(root, images["good1"], selftest=False)
            power_cut_after(cut)
            try:
                flash.flash_firmware(root, images["good2"], selftest=False)
                completed = True
            except PowerCut:
                completed = False
            power_cut_after(-1)
            version, _ = bootable(root)
            assert version in (versions["good1"], versions["good2"]), f"cut {cut}"
            assert store.slot_usable(root, "a") is None, f"cut {cut}: the known-good slot was touched"
            if completed:
                assert version == versions["good2"]
                break
        else:
            pytest.fail("the flash never completed")


def test_flash_killed_at_random_instants_leaves_a_bootable_store(
    tmp_path: Path, images: dict[str, Path]
) -> None:
    """Real SIGKILLs of `bywire ecu flash` (image + calibration) at random instants of its work."""
    root = tmp_path / "ecu"
    dev_flash(root, images["good1"])
    flash.flash_calibration(root, write_calibration(tmp_path / "c1.json", 1))
    cal2 = write_calibration(tmp_path / "c2.json", 2)
    # Without the self-test (a kill in it is a kill while staging, like any other before the swap)
    # the instants land among the writes and renames that matter.
    cmd = [sys.executable, "-m", "bywire.ecu.flash", "--store", str(root), "--image", str(images["good2"])]
    cmd += ["--calibration", str(cal2), "--no-selftest"]

    def reset() -> None:
        # The state before each flash: good1 confirmed in slot a, calibration 1, no leftovers.
        store.clean_staging(root)
        store.write_boot_record(root, BootRecord(active="a"))
        store.write_atomic(store.current_calibration_path(root), (tmp_path / "c1.json").read_bytes())
        store.previous_calibration_path(root).unlink(missing_ok=True)

    def start() -> tuple[subprocess.Popen[bytes], float]:
        """The flash process, and the instant its work began (the staging directory appeared)."""
        proc = subprocess.Popen(
            cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=tmp_path, start_new_session=True
        )
        while not (root / "staging").exists() and proc.poll() is None:
            time.sleep(0.0002)
        return proc, time.monotonic()

    reset()
    old = bootable(root)
    proc, t_work = start()
    assert proc.wait(timeout=60) == 0
    work_s = time.monotonic() - t_work
    new = bootable(root)
    assert new[0] != old[0] and new[1] == 2

    rng = random.Random(2011)
    for _ in range(8):
        reset()
        proc, t_work = start()
        time.sleep(rng.uniform(0.0, work_s))
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
        state = bootable(root)
        assert state[0] in (old[0], new[0]) and state[1] in (1, 2), state
    # Whatever a kill left behind, the next flash goes through.
    store.write_boot_record(root, BootRecord(active="a"))
    flash.flash_firmware(root, images["good2"], selftest=False)
    assert bootable(root)[0] == new[0]


@pytest.fixture
def eio_at(monkeypatch: pytest.MonkeyPatch) -> Iterator[Callable[[int], None]]:
    """Arm an EIO at the n-th call of os.write, os.fsync, os.replace or os.rename, counted together:
    every call site where a failing disk reports an error, in turn. arm(-1) disarms."""
    budget = {"n": -1}

    def guarded(real: Callable[..., Any]) -> Callable[..., Any]:
        def op(*args: Any, **kwargs: Any) -> Any:
            if budget["n"] == 0:
                budget["n"] = -1
                raise OSError(errno.EIO, os.strerror(errno.EIO))
            if budget["n"] > 0:
                budget["n"] -= 1
            return real(*args, **kwargs)

        return op

    for name in ("write", "fsync", "replace", "rename"):
        monkeypatch.setattr(os, name, guarded(getattr(os, name)))

    def arm(n: int) -> None:
        budget["n"] = n

    yield arm
    budget["n"] = -1


BOOTS = re.compile(
    r"(?:boots|will boot) slot (?P<slot>[ab]) (?P<state>on trial|confirmed) \(image (?P<version>\S+)\)"
)


@pytest.mark.parametrize("trial", [False, True])
def test_firmware_flash_io_error_at_every_call_site_says_what_the_store_boots(
    tmp_path: Path,
    images: dict[str, Path],
    eio_at: Callable[[int], None],
    capsys: pytest.CaptureFixture[str],
    trial: bool,
) -> None:
    versions = {k: firmware.read_image_info(v)["version"] for k, v in images.items() if k.startswith("good")}
    seen = set()
    for cut in range(200):
        root = tmp_path / f"ecu{cut}"
        dev_flash(root, images["good1"])
        store.write_boot_record(root, BootRecord(active="a"))
        if trial:  # a second image on trial, not yet confirmed: a must survive the next flash
            dev_flash(root, images["good1"])
        capsys.readouterr()
        eio_at(cut)
        rc = flash.main(["--store", str(root), "--image", str(images["good2"]), "--no-selftest"])
        eio_at(-1)
        err = capsys.readouterr().err
        if rc == 0:
            assert boot_choice(root) == ("b", "on trial", versions["good2"])
            break
        # Progress lines may come first (stderr is the flash's log); the failure is one line, the last.
        assert rc == 1 and "Traceback" not in err, (cut, err)
        assert [line for line in err.splitlines() if line.startswith("error: ")] == err.splitlines()[-1:], err
        err = err.splitlines()[-1]
        assert "EIO (Input/output error)" in err, (cut, err)
        said = BOOTS.search(err)
        assert said is not None, (cut, err)
        # The message is the truth: the store boots exactly what it says.
        assert boot_choice(root) == (said["slot"], said["state"], said["version"]), (cut, err)
        assert store.slot_usable(root, "a") is None, f"cut {cut}: the known-good slot was touched"
        if "committed to slot b (trial)" in err:
            assert said["version"] == versions["good2"], err
            if "directory fsync failed" in err:
                seen.add("committed, not synced")
                assert "the store is consistent and will boot slot b on trial" in err, err
                assert "may bring back slot a" in err, err
            else:
                seen.add("committed, not cleaned up")
                assert "removing the staging directory failed" in err, err
        else:
            seen.add("not committed")
            assert (
                "nothing committed: the store still boots" in err or "new image was not committed" in err
            ), err
            assert said["version"] == versions["good1"], err
            if trial:
                expected = "confirmed" if "trial image in slot b was dropped" in err else "on trial"
                assert said["state"] == expected, err
        # Whatever the error left, the next flash goes through.
        flash.flash_firmware(root, images["good2"], selftest=False)
        assert boot_choice(root)[2] == versions["good2"]
    else:
        pytest.fail("the flash never completed")
    assert seen == {"committed, not synced", "committed, not cleaned up", "not committed"}, seen


def test_calibration_flash_io_error_at_every_call_site_says_what_the_store_uses(
    tmp_path: Path, eio_at: Callable[[int], None], capsys: pytest.CaptureFixture[str]
) -> None:
    uses = re.compile(r"uses calibration version (\d+) \((\w+\.json)\)")
    seen = set()
    for cut in range(50):
        root = tmp_path / f"ecu{cut}"
        flash.flash_calibration(root, write_calibration(tmp_path / "c1.json", 1))
        flash.flash_calibration(root, write_calibration(tmp_path / "c2.json", 2))
        c3 = write_calibration(tmp_path / "c3.json", 3)
        capsys.readouterr()
        eio_at(cut)
        rc = flash.main(["--store", str(root), "--calibration", str(c3)])
        eio_at(-1)
        err = capsys.readouterr().err
        choice = store.usable_calibration(root)
        assert choice.calibration is not None and choice.path is not None, f"cut {cut}: no usable calibration"
        if rc == 0:
            assert choice.calibration.version == 3
            break
        assert rc == 1 and len(err.splitlines()) == 1 and "EIO" in err, (cut, err)
        said = uses.search(err)
        assert said is not None, (cut, err)
        assert (choice.calibration.version, choice.path.name) == (int(said[1]), said[2]), (cut, err)
        if "version 3 committed" in err:
            seen.add("committed")
            assert choice.calibration.version == 3
        else:
            seen.add("not committed")
            assert "calibration version 3 was not committed" in err and choice.calibration.version == 2
        flash.flash_calibration(root, c3)
        assert store.usable_calibration(root).calibration.version == 3  # type: ignore[union-attr]
    else:
        pytest.fail("the flash never completed")
    assert seen == {"committed", "not committed"}


def test_trust_change_io_error_is_one_line(
    tmp_path: Path, eio_at: Callable[[int], None], capsys: pytest.CaptureFixture[str]
) -> None:
    root = store.init_store(tmp_path / "ecu").root
    eio_at(0)
    assert flash.main(["--store", str(root), "--allow-unsigned"]) == 1
    eio_at(-1)
    err = capsys.readouterr().err
    assert err.startswith(f"error: {root / 'trust.json'}: writing failed: EIO") and "nothing committed" in err
    assert store.read_trust(root) is None
