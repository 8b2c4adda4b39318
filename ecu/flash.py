"""`bywire ecu flash`: write a firmware image and/or a calibration into an ECU's store, crash-safely.

No paper section (the AnnieWAY ECUs were flashed with vendor tools). The contract:
exit 0 on success; on failure a non-zero exit, one line naming the bad file and field, and the
store unchanged; a flash killed at any instant leaves the image and calibration the ECU booted
before still bootable.

Firmware (`flash_firmware`), under the store lock:
  1. stage the image in DIR/staging/new/ (built from the installed bywire unless one is given),
     re-read it and check its sha256, run its self-test there under `python -I -S`;
     a failure deletes the staging directory: the store is as before;
  2. pick the slot to keep: the active slot when confirmed, else the trial's previous slot, else any
     slot that verifies; the other one is the target. If the boot record points at the target
     (a trial being replaced, or a stale `previous`), rewrite it first to boot the kept slot only;
  3. swap the staged directory into slots/<target> (two renames; in between the target is absent,
     and nothing points at it), verify its sha256 in place;
  4. commit: one atomic write of boot.json: active = target on "trial", previous = kept slot.
  The boot supervisor confirms the trial when the image comes up, or falls back (boot.py).

Calibration (`flash_calibration`): the file is validated with bywire.ecu.calibration (ranges,
monotone maps, CRC when the file has one; a hand-written file without "crc32" gets one) before
anything is written. Then, under the store lock: write calibration/incoming.json atomically and
verify it (read back, CRC, same bytes); rename current.json -> previous.json (only when current is
valid: a corrupt current never displaces a good previous) and incoming.json -> current.json;
verify current.json. The old previous is dropped only once the new one is verified, and at every
instant current.json or previous.json holds a good calibration.
`persist_calibration_bytes` does the same for a calibration the running ECU received over SDO.
Deviation: a calibration whose `version` is lower than the flashed one, or equal with different
content, is refused unless `allow_downgrade` (`--allow-downgrade`): two calibrations with one
version number could not be told apart in logs.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import os
import shutil
import sys
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from bywire.ecu.calibration import (
    Calibration,
    CalibrationError,
    calibration_from_dict,
    dumps_calibration,
    loads_calibration,
)
from bywire.ecu.firmware import FirmwareError, build_image, read_image_info, run_selftest
from bywire.ecu.store import (
    BootRecord,
    ImageManifest,
    Slot,
    StoreError,
    StoreLayout,
    StorePath,
    clean_staging,
    fsync_dir,
    init_store,
    other_slot,
    read_boot_record,
    read_calibration_file,
    sha256_file,
    slot_usable,
    store_lock,
    usable_calibration,
    verify_image,
    write_atomic,
    write_boot_record,
    write_json_atomic,
)

Log = Callable[[str], None]


class FlashError(Exception):
    """A flash was refused or failed; the message names the file and what is wrong."""


@dataclass(frozen=True)
class FirmwareFlashResult:
    slot: Slot  # where the new image went (now active, on trial)
    previous: Slot | None  # the slot kept as fallback
    manifest: ImageManifest


@dataclass(frozen=True)
class CalibrationFlashResult:
    calibration: Calibration
    path: Path  # calibration/current.json
    replaced_version: int | None  # the version that became previous.json (None: none did)
    changed: bool  # False when the same calibration was already flashed


def _quiet(_: str) -> None:
    pass


# --- firmware -----------------------------------------------------------------------------------


def _stage_image(lay: StoreLayout, image_path: StorePath | None) -> tuple[Path, ImageManifest]:
    stage = lay.staging_dir / "new"
    stage.mkdir(parents=True)
    staged = stage / "image.pyz"
    if image_path is None:
        try:
            manifest = build_image(staged)
        except FirmwareError as e:
            raise FlashError(f"building the firmware image: {e}") from None
    else:
        source = Path(image_path)
        try:
            info = read_image_info(source)
        except FirmwareError as e:
            raise FlashError(str(e)) from None
        for key in ("version", "entry", "python"):
            if not isinstance(info.get(key), str):
                raise FlashError(f"{source}: _image.json: {key}: expected a string, got {info.get(key)!r}")
        running = f"{sys.version_info.major}.{sys.version_info.minor}"
        if info["python"] != running:
            raise FlashError(
                f"{source}: python: image built for Python {info['python']}, this ECU runs {running}"
            )
        data = source.read_bytes()
        write_atomic(staged, data)
        built = datetime.fromtimestamp(source.stat().st_mtime, UTC).isoformat(timespec="seconds")
        manifest = ImageManifest(
            version=info["version"],
            sha256=hashlib.sha256(data).hexdigest(),
            size_bytes=len(data),
            built_utc=built,
            python=info["python"],
            entry=info["entry"],
        )
    # Re-read what reached the disk: the hash in the manifest must describe the stored bytes.
    digest = sha256_file(staged)
    if digest != manifest.sha256:
        raise FlashError(f"{staged}: sha256 {digest} after writing, expected {manifest.sha256}")
    write_json_atomic(stage / "manifest.json", manifest.to_dict())
    return stage, manifest


def _slot_to_keep(store: StorePath, record: BootRecord | None) -> Slot | None:
    """The slot that must survive this flash: the one the ECU would boot (or fall back to) now."""
    if record is None:
        return None
    order: list[Slot] = [record.active] if record.state == "confirmed" else []
    if record.previous is not None:
        order.append(record.previous)
    order += [record.active, other_slot(record.active)]
    for slot in dict.fromkeys(order):
        if slot_usable(store, slot) is None:
            return slot
    return None


def flash_firmware(
    store: StorePath,
    image_path: StorePath | None = None,
    *,
    python: str = sys.executable,
    selftest: bool = True,
    selftest_timeout_s: float = 120.0,
    log: Log = _quiet,
) -> FirmwareFlashResult:
    """Build (or take) an image, stage and self-test it, write it to the inactive slot, activate it
    on trial. `selftest=False` only for images already self-tested with this interpreter."""
    existed = Path(store).exists()
    lay = init_store(store)
    with store_lock(store):
        clean_staging(store)
        try:
            stage, manifest = _stage_image(lay, image_path)
            if selftest:
                log(f"self-testing image {manifest.version} ...")
                report = run_selftest(stage / "image.pyz", python=python, timeout_s=selftest_timeout_s)
                if not report.ok:
                    for problem in report.problems[1:]:
                        log(f"selftest: {problem}")
                    first = report.problems[0] if report.problems else "failed"
                    more = f" (and {len(report.problems) - 1} more above)" if len(report.problems) > 1 else ""
                    name = image_path or f"built image {manifest.version}"
                    raise FlashError(f"{name}: selftest: {first}{more}")
        except BaseException:
            # Refused: leave no trace, not even the empty store this call created.
            if existed:
                clean_staging(store)
            else:
                shutil.rmtree(lay.root, ignore_errors=True)
            raise

        record = read_boot_record(store)
        keep = _slot_to_keep(store, record)
        target: Slot = (
            other_slot(keep) if keep is not None else ("a" if record is None else other_slot(record.active))
        )
        if record is not None and keep is not None and (record.active != keep or record.previous == target):
            # Nothing may point at the slot about to be rewritten, not even as a fallback.
            log(f"boot record: slot {keep} only (was active {record.active}, {record.state})")
            write_boot_record(
                store, BootRecord(active=keep, previous=None, state="confirmed", rejected=record.rejected)
            )

        slot_dir = lay.slot_dir(target)
        old = lay.staging_dir / "old"
        if slot_dir.exists():
            os.rename(slot_dir, old)
        os.rename(stage, slot_dir)
        fsync_dir(lay.slots_dir)
        fsync_dir(lay.staging_dir)
        try:
            verify_image(store, target)
        except StoreError as e:
            raise FlashError(f"after writing slot {target}: {e}") from None

        rejected = {k: v for k, v in (record.rejected if record else {}).items() if k != target}
        write_boot_record(
            store, BootRecord(active=target, previous=keep, state="trial", trial_boots=0, rejected=rejected)
        )
        clean_staging(store)
    log(f"firmware {manifest.version} written to slot {target}, active on trial (fallback: {keep or 'none'})")
    return FirmwareFlashResult(slot=target, previous=keep, manifest=manifest)


# --- calibration --------------------------------------------------------------------------------


def load_calibration_source(path: StorePath) -> Calibration:
    """Validate a calibration file to be flashed; CalibrationError naming the field, else FlashError.

    A file with "crc32" must match it; a hand-written file without one is accepted (the store
    writes it with its CRC)."""
    source = os.fspath(path)
    try:
        data = Path(path).read_bytes()
    except FileNotFoundError:
        raise FlashError(f"{source}: no such file") from None
    except OSError as e:
        raise FlashError(f"{source}: cannot read: {e.strerror}") from None
    try:
        return loads_calibration(data, source)
    except CalibrationError as e:
        if e.field != "crc32" or e.message != "missing":
            raise
    # loads_calibration already parsed and checked this document up to the CRC.
    return calibration_from_dict(json.loads(data), source)


def flash_calibration(
    store: StorePath,
    path: StorePath,
    *,
    allow_downgrade: bool = False,
    calibration: Calibration | None = None,
    log: Log = _quiet,
) -> CalibrationFlashResult:
    """Validate `path` and make it the store's current calibration, keeping the old one as previous.

    `calibration`: the already validated content of `path` (saves parsing it twice)."""
    cal = calibration if calibration is not None else load_calibration_source(path)
    return install_calibration(store, cal, os.fspath(path), allow_downgrade=allow_downgrade, log=log)


def persist_calibration_bytes(
    store: StorePath, data: bytes, *, source: str = "SDO 0x2200", lock_timeout_s: float = 1.0
) -> CalibrationFlashResult:
    """For the running ECU: store a calibration received over SDO (bytes with "crc32") as current.

    Same checks and crash-safety as `flash_calibration`, but a lower or equal version is accepted
    (an SDO write is an explicit operator action), and the store lock is waited for at most
    `lock_timeout_s` (StoreError: a flash is running), so that the caller's loop is never stalled for
    the length of a firmware self-test."""
    cal = loads_calibration(data, source)
    return install_calibration(store, cal, source, allow_downgrade=True, lock_timeout_s=lock_timeout_s)


def install_calibration(
    store: StorePath,
    cal: Calibration,
    source: str,
    *,
    allow_downgrade: bool = False,
    lock_timeout_s: float | None = None,
    log: Log = _quiet,
) -> CalibrationFlashResult:
    """Write a validated calibration as current.json, the old current kept as previous.json."""
    data = dumps_calibration(cal)
    lay = init_store(store)
    with store_lock(store, lock_timeout_s):
        current = lay.current_calibration
        choice = usable_calibration(store)
        flashed = choice.calibration
        if flashed is not None and choice.path is not None:
            if choice.path == current and current.read_bytes() == data:
                log(f"calibration version {cal.version} is already flashed")
                return CalibrationFlashResult(cal, current, None, changed=False)
            if not allow_downgrade and cal.version <= flashed.version:
                what = (
                    "lower than" if cal.version < flashed.version else "the same as, with other content than,"
                )
                raise CalibrationError(
                    "version",
                    source,
                    f"{cal.version} is {what} the flashed version {flashed.version} "
                    "(bump it, or flash with --allow-downgrade)",
                )
        incoming = lay.incoming_calibration
        write_atomic(incoming, data)
        _verify_calibration_file(incoming, data)
        replaced: int | None = None
        current_valid = False
        with contextlib.suppress(StoreError, CalibrationError):
            replaced = read_calibration_file(current).version
            current_valid = True
        if current_valid:
            os.replace(current, lay.previous_calibration)
        os.replace(incoming, current)
        fsync_dir(lay.calibration_dir)
        _verify_calibration_file(current, data)
    log(
        f"calibration version {cal.version} ({cal.vehicle}) flashed"
        + (f"; version {replaced} kept as previous" if replaced is not None else "")
    )
    return CalibrationFlashResult(cal, current, replaced, changed=True)


def _verify_calibration_file(path: Path, expected: bytes) -> None:
    data = path.read_bytes()
    if data != expected:
        raise FlashError(f"{path}: read back {len(data)} bytes that differ from the {len(expected)} written")
    try:
        loads_calibration(data, os.fspath(path))
    except CalibrationError as e:
        raise FlashError(f"read-back check failed: {e}") from None


# --- CLI glue -----------------------------------------------------------------------------------


def add_flash_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `bywire ecu flash`."""
    parser.add_argument("--store", required=True, type=Path, help="the ECU's non-volatile store directory")
    parser.add_argument(
        "--firmware", action="store_true", help="build a firmware image from this installation and flash it"
    )
    parser.add_argument(
        "--image", type=Path, default=None, help="flash this prebuilt firmware image (implies --firmware)"
    )
    parser.add_argument("--calibration", type=Path, default=None, help="flash this calibration file (JSON)")
    parser.add_argument(
        "--allow-downgrade",
        action="store_true",
        help="accept a calibration whose version is not higher than the flashed one",
    )
    parser.add_argument(
        "--no-selftest", action="store_true", help="skip the image self-test (only for pre-tested images)"
    )


def _print(msg: str) -> None:
    print(msg, file=sys.stderr)


def cmd_flash(args: argparse.Namespace) -> int:
    """Run `bywire ecu flash` from parsed arguments: 0 on success, 1 when refused or failed, 2 on usage."""
    image = getattr(args, "image", None)
    firmware = bool(getattr(args, "firmware", False)) or image is not None
    cal_path = getattr(args, "calibration", None)
    if not firmware and cal_path is None:
        print(
            "error: nothing to flash: give --firmware, --image IMAGE and/or --calibration FILE",
            file=sys.stderr,
        )
        return 2
    try:
        # Validate the calibration before touching anything, so a bad file changes nothing at all.
        cal = load_calibration_source(cal_path) if cal_path is not None else None
        if firmware:
            result = flash_firmware(
                args.store, image, selftest=not getattr(args, "no_selftest", False), log=_print
            )
            print(f"firmware {result.manifest.version} -> slot {result.slot} (trial)")
        if cal_path is not None:
            cal_result = flash_calibration(
                args.store,
                cal_path,
                allow_downgrade=bool(getattr(args, "allow_downgrade", False)),
                calibration=cal,
                log=_print,
            )
            print(f"calibration version {cal_result.calibration.version} -> {cal_result.path}")
    except (FlashError, StoreError, CalibrationError, FirmwareError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    return 0


def main(argv: list[str] | None = None) -> int:
    """`python -m bywire.ecu.flash ...`, the same as `bywire ecu flash ...`."""
    parser = argparse.ArgumentParser(prog="bywire ecu flash", description="flash an ECU's store")
    add_flash_arguments(parser)
    return cmd_flash(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
