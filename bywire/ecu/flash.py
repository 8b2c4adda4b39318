"""`bywire ecu flash`: write signed firmware, a calibration and/or trusted keys into an ECU's store.

No paper section (the AnnieWAY ECUs were flashed with vendor tools); DESIGN section 4: firmware is
signed. The contract: exit 0 on success; a refusal is one line naming the bad file and why, and
leaves the store unchanged; an I/O error (EIO, ENOSPC, ...) is one line saying exactly what was
committed and what the store boots now, never a traceback; a flash killed at any instant leaves the
image and calibration the ECU booted before still bootable.

Trust: `--trust-key`, `--trust-key-signature`, `--revoke-key`, `--allow-unsigned` change the store's
trust.json by the rules of trust.py (`change_trust` alone, or with a firmware flash in one locked
operation, the image then checked against the new policy).

Firmware (`flash_firmware`), under the store lock:
  1. check the image before anything is written: it is a bywire ECU image (firmware.py's
     `check_ecu_image`), built for this Python, and its signature (`--signature`, embedded in its zip
     comment, or made here with `--key`) verifies with a key of the store's (new) policy, unless the
     store is a development store. Then stage it in DIR/staging/new/, re-read it and check its
     sha256, run its self-test there under `python -I -S`; a failure deletes the staging
     directory: the store is as before;
  2. write trust.json if the policy changes;
  3. pick the slot to keep: the active slot when confirmed, else the trial's previous slot, else any
     slot that verifies; the other one is the target. If the boot record points at the target
     (a trial being replaced, or a stale `previous`), rewrite it first to boot the kept slot only;
  4. swap the staged directory into slots/<target> (two renames; in between the target is absent,
     and nothing points at it), verify its sha256 and signature in place;
  5. commit: one atomic write of boot.json: active = target on "trial", previous = kept slot, the
     target's boot history cleared. The boot supervisor confirms the trial after its period of
     health, or falls back (boot.py).

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

I/O errors: every OSError during a flash becomes a FlashError whose message ends with what the
store boots (or uses) now, read back from the store the way the boot supervisor reads it. A rename
that happened but whose directory fsync failed is reported as committed (every reader sees the new
file; a power cut could still bring back the old one, also whole), with `FlashError.committed`.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import hashlib
import json
import os
import shutil
import sys
from collections.abc import Callable
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from pathlib import Path

from bywire.ecu.boot import plan_boot
from bywire.ecu.calibration import (
    Calibration,
    CalibrationError,
    calibration_from_dict,
    dumps_calibration,
    loads_calibration,
)
from bywire.ecu.firmware import FirmwareError, build_image, check_ecu_image, run_selftest
from bywire.ecu.signing import (
    SigningError,
    SigningKey,
    load_public_key,
    load_signing_key,
    read_signature_file,
    split_embedded_signature,
    verifying_key,
)
from bywire.ecu.store import (
    IMAGE_NAME,
    MANIFEST_NAME,
    BootRecord,
    DirSyncError,
    ImageManifest,
    Slot,
    StoreError,
    StoreLayout,
    StorePath,
    TrustPolicy,
    clean_staging,
    fsync_dir,
    init_store,
    layout,
    no_trust_problem,
    os_error_text,
    other_slot,
    read_boot_record,
    read_calibration_file,
    read_manifest,
    read_trust,
    sha256_file,
    signature_problem,
    slot_usable,
    store_lock,
    usable_calibration,
    verify_image,
    write_atomic,
    write_boot_record,
    write_json_atomic,
    write_trust,
)
from bywire.ecu.trust import TrustChange, TrustError, describe_policy, plan_trust

Log = Callable[[str], None]
NO_TRUST_CHANGE = TrustChange()


class FlashError(Exception):
    """A flash was refused or failed; the message names the file and what is wrong.

    `committed`: the new image, calibration or trust policy is in place (what the store boots or
    uses now) although the flash reports a failure: its directory fsync or a clean-up failed."""

    def __init__(self, message: str, *, committed: bool = False) -> None:
        super().__init__(message)
        self.committed = committed


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


def change_trust(store: StorePath, change: TrustChange, *, log: Log = _quiet) -> TrustPolicy | None:
    """Apply `change` to the store's trust policy (creating the store if needed); the new policy."""
    lay = _init_store(store)
    with store_lock(store):
        current = read_trust(store)
        policy = plan_trust(current, change, store)
        if policy is None or policy == current:
            return current
        try:
            write_trust(store, policy)
        except DirSyncError as e:
            raise FlashError(
                f"{lay.trust}: trust policy updated but its directory fsync failed: {os_error_text(e)};"
                " it is in effect (after a power cut before the disk catches up, the old one may be)",
                committed=True,
            ) from None
        except OSError as e:
            raise FlashError(f"{lay.trust}: writing failed: {os_error_text(e)}; nothing committed") from None
    log(f"trust policy: {describe_policy(policy)}")
    return policy


def _init_store(store: StorePath) -> StoreLayout:
    try:
        return init_store(store)
    except OSError as e:
        raise FlashError(f"{os.fspath(store)}: cannot create the store: {os_error_text(e)}") from None


# --- what the store boots now (for the I/O-error messages) ---------------------------------------


def boots_now(store: StorePath) -> str:
    """'slot a (image V, confirmed)': what the boot supervisor would boot now, read from the store."""
    try:
        record = read_boot_record(store)
        if record is None:
            return "no firmware (none was ever committed)"
        plan = plan_boot(record, functools.partial(slot_usable, store))
        if plan.slot is None:
            return f"nothing: {plan.problem}"
        version = read_manifest(store, plan.slot).version
    except (StoreError, OSError) as e:
        return f"an unknown slot (reading the store back failed too: {e})"
    state = "on trial" if plan.record.state == "trial" else "confirmed"
    return f"slot {plan.slot} {state} (image {version})"


def calibration_now(store: StorePath) -> str:
    """'calibration version 3 (current.json)': what the ECU would boot with now."""
    try:
        choice = usable_calibration(store)
    except (StoreError, OSError) as e:
        return f"an unknown calibration (reading the store back failed too: {e})"
    if choice.calibration is None or choice.path is None:
        return "no usable calibration (the ECU stays OFF)"
    return f"calibration version {choice.calibration.version} ({choice.path.name})"


# --- firmware -----------------------------------------------------------------------------------


def _read_image(image_path: StorePath) -> bytes:
    try:
        return Path(image_path).read_bytes()
    except FileNotFoundError:
        raise FlashError(f"{os.fspath(image_path)}: no such file") from None
    except OSError as e:
        raise FlashError(f"{os.fspath(image_path)}: cannot read: {os_error_text(e)}") from None


def _check_image(data: bytes, name: str) -> dict[str, object]:
    try:
        info = check_ecu_image(data, name)
    except FirmwareError as e:
        raise FlashError(str(e)) from None
    for key in ("version", "entry", "python"):
        if not isinstance(info.get(key), str):
            raise FlashError(f"{name}: _image.json: {key}: expected a string, got {info.get(key)!r}")
    running = f"{sys.version_info.major}.{sys.version_info.minor}"
    if info["python"] != running:
        raise FlashError(f"{name}: python: image built for Python {info['python']}, this ECU runs {running}")
    return info


def _signature_for(
    data: bytes,
    name: str,
    policy: TrustPolicy,
    signature: bytes | None,
    embedded: bytes | None,
    signing_key: SigningKey | None,
) -> tuple[bytes | None, str | None]:
    """(signature, id of the trusted key it verifies with) for image `data`; FlashError if the
    store's policy refuses it."""
    if signature is not None and embedded is not None:
        raise FlashError(f"{name}: carries an embedded signature and --signature was given too; give one")
    sig = signature if signature is not None else embedded
    if signing_key is not None:
        if sig is not None:
            raise FlashError(f"{name}: already signed; do not give --key too")
        sig = signing_key.sign(data)
    problem = signature_problem(policy, sig, data)
    if problem is not None:
        if signing_key is not None:
            problem += f" (signed here with key {signing_key.public.key_id} from {signing_key.source})"
        raise FlashError(f"{name}: {problem}")
    kid = verifying_key(policy.keys, sig, data) if sig is not None and policy.keys else None
    return sig, kid


def _stage_image(
    lay: StoreLayout,
    image_path: StorePath | None,
    policy: TrustPolicy,
    signature: bytes | None,
    signing_key: SigningKey | None,
) -> tuple[Path, ImageManifest, str]:
    """Check and stage the image: (staging directory, manifest, the image's name for messages)."""
    embedded: bytes | None = None
    if image_path is None:
        # Built first (into staging): the signature can only be made over the bytes.
        stage = lay.staging_dir / "new"
        stage.mkdir(parents=True)
        try:
            manifest = build_image(stage / IMAGE_NAME)
        except FirmwareError as e:
            raise FlashError(f"building the firmware image: {e}") from None
        name = f"firmware {manifest.version} built from this installation"
        data = (stage / IMAGE_NAME).read_bytes()
        _check_image(data, name)
    else:
        name = os.fspath(image_path)
        raw = _read_image(image_path)
        try:
            data, embedded = split_embedded_signature(raw)
        except SigningError as e:
            raise FlashError(f"{name}: {e}") from None
        info = _check_image(data, name)
        built = datetime.fromtimestamp(Path(image_path).stat().st_mtime, UTC).isoformat(timespec="seconds")
        manifest = ImageManifest(
            version=str(info["version"]),
            sha256=hashlib.sha256(data).hexdigest(),
            size_bytes=len(data),
            built_utc=built,
            python=str(info["python"]),
            entry=str(info["entry"]),
        )
    # Refused before anything is written when given, after the build otherwise.
    sig, kid = _signature_for(data, name, policy, signature, embedded, signing_key)
    manifest = replace(manifest, signature=sig, key_id=kid)
    stage = lay.staging_dir / "new"
    staged = stage / IMAGE_NAME
    if image_path is not None:
        stage.mkdir(parents=True)
        write_atomic(staged, data)
    # Re-read what reached the disk: the hash in the manifest must describe the stored bytes.
    digest = sha256_file(staged)
    if digest != manifest.sha256:
        raise FlashError(f"{staged}: sha256 {digest} after writing, expected {manifest.sha256}")
    write_json_atomic(stage / MANIFEST_NAME, manifest.to_dict())
    return stage, manifest, name


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


@dataclass
class _Progress:
    """How far a firmware flash got, for the one line an I/O error is reported in."""

    doing: str = "opening the store"
    trust_written: bool = False
    dropped_trial: Slot | None = None  # the boot record was rewritten to stop booting this trial
    target: Slot | None = None  # set once only the commit is left
    keep: Slot | None = None

    def not_committed(self, store: StorePath, e: OSError) -> FlashError:
        failed = ": written, but its directory fsync failed" if isinstance(e, DirSyncError) else " failed"
        done = []
        if self.trust_written:
            done.append("the trust policy was updated")
        if self.dropped_trial is not None:
            done.append(f"the unconfirmed trial image in slot {self.dropped_trial} was dropped")
        state = (
            f"{'; '.join(done)}; the new image was not committed: the store boots"
            if done
            else "nothing committed: the store still boots"
        )
        return FlashError(
            f"{layout(store).root}: {self.doing}{failed}: {os_error_text(e)}; {state} {boots_now(store)}"
        )


def flash_firmware(
    store: StorePath,
    image_path: StorePath | None = None,
    *,
    signature: bytes | None = None,
    signing_key: SigningKey | None = None,
    trust: TrustChange = NO_TRUST_CHANGE,
    python: str = sys.executable,
    selftest: bool = True,
    selftest_timeout_s: float = 120.0,
    log: Log = _quiet,
) -> FirmwareFlashResult:
    """Check (and sign, with `signing_key`) an image, built from the installation unless
    `image_path` is given; stage and self-test it, write it to the inactive slot, activate it on
    trial. `signature`: a detached signature of `image_path`'s bytes. `trust`: a change of the
    store's trust policy made in the same locked operation (the image is checked against the new
    policy). `selftest=False` only for images already self-tested with this interpreter."""
    existed = Path(store).exists()
    lay = _init_store(store)
    progress = _Progress()
    with store_lock(store):
        try:
            progress.doing = "removing an earlier flash's leftovers"
            clean_staging(store)
            current = read_trust(store)
            policy = plan_trust(current, trust, store) or current
            if policy is None:
                raise FlashError(no_trust_problem(store))
            progress.doing = "staging the image"
            stage, manifest, name = _stage_image(lay, image_path, policy, signature, signing_key)
            if selftest:
                log(f"self-testing image {manifest.version} ...")
                report = run_selftest(stage / IMAGE_NAME, python=python, timeout_s=selftest_timeout_s)
                if not report.ok:
                    for problem in report.problems[1:]:
                        log(f"selftest: {problem}")
                    first = report.problems[0] if report.problems else "failed"
                    more = f" (and {len(report.problems) - 1} more above)" if len(report.problems) > 1 else ""
                    raise FlashError(f"{name}: selftest: {first}{more}")
        except BaseException as exc:
            # Refused: leave no trace, not even the empty store this call created.
            if existed:
                with contextlib.suppress(OSError):
                    clean_staging(store)
            else:
                shutil.rmtree(lay.root, ignore_errors=True)
            if isinstance(exc, OSError):
                raise progress.not_committed(store, exc) from None
            raise
        try:
            return _commit_firmware(store, lay, policy, current, stage, manifest, progress, log)
        except OSError as e:
            if isinstance(e, DirSyncError) and progress.doing == "committing boot.json":
                raise _committed_unsynced(store, manifest, progress, e) from None
            if progress.doing == "removing the staging directory":
                raise FlashError(
                    f"{lay.root}: new image {manifest.version} committed to slot {progress.target} (trial);"
                    f" removing the staging directory failed: {os_error_text(e)} (the next flash removes it);"
                    f" the store boots {boots_now(store)}",
                    committed=True,
                ) from None
            with contextlib.suppress(OSError):
                clean_staging(store)
            raise progress.not_committed(store, e) from None


def _committed_unsynced(
    store: StorePath, manifest: ImageManifest, progress: _Progress, e: OSError
) -> FlashError:
    target, keep = progress.target, progress.keep
    before = f"slot {keep}" if keep is not None else "no firmware"
    return FlashError(
        f"{layout(store).root}: new image {manifest.version} committed to slot {target} (trial) but its"
        f" directory fsync failed: {os_error_text(e)}; the store is consistent and will boot"
        f" {boots_now(store)} (a power cut before the disk catches up may bring back {before})",
        committed=True,
    )


def _commit_firmware(
    store: StorePath,
    lay: StoreLayout,
    policy: TrustPolicy,
    current: TrustPolicy | None,
    stage: Path,
    manifest: ImageManifest,
    progress: _Progress,
    log: Log,
) -> FirmwareFlashResult:
    """Steps 2-5 of the module docstring; an OSError leaves `progress` saying how far it got."""
    if policy != current:
        progress.doing = "writing trust.json"
        try:
            write_trust(store, policy)
        except DirSyncError:
            progress.trust_written = True  # renamed into place: in effect, if maybe not durable
            raise
        progress.trust_written = True
        log(f"trust policy: {describe_policy(policy)}")
    progress.doing = "reading the boot record"
    record = read_boot_record(store)
    keep = _slot_to_keep(store, record)
    target: Slot = (
        other_slot(keep) if keep is not None else ("a" if record is None else other_slot(record.active))
    )
    if record is not None and keep is not None and (record.active != keep or record.previous == target):
        # Nothing may point at the slot about to be rewritten, not even as a fallback.
        log(f"boot record: slot {keep} only (was active {record.active}, {record.state})")
        progress.doing = "rewriting boot.json to boot the kept slot only"
        dropping = target if record.active == target else None
        try:
            write_boot_record(
                store, replace(record, active=keep, previous=None, state="confirmed", trial_boots=0)
            )
        except DirSyncError:
            progress.dropped_trial = dropping  # renamed into place: in effect, if maybe not durable
            raise
        progress.dropped_trial = dropping
    slot_dir = lay.slot_dir(target)
    old = lay.staging_dir / "old"
    progress.doing = f"moving the image into slot {target}"
    if slot_dir.exists():
        os.rename(slot_dir, old)
    os.rename(stage, slot_dir)
    fsync_dir(lay.slots_dir)
    fsync_dir(lay.staging_dir)
    try:
        verify_image(store, target, policy)
    except StoreError as e:
        raise FlashError(
            f"after writing slot {target}: {e}; the new image was not committed:"
            f" the store boots {boots_now(store)}"
        ) from None
    base = record if record is not None else BootRecord(active=target)
    rejected = {k: v for k, v in base.rejected.items() if k != target}
    new = replace(
        base.without_slot_history(target),
        active=target,
        previous=keep,
        state="trial",
        trial_boots=0,
        rejected=rejected,
    )
    progress.target, progress.keep = target, keep
    progress.doing = "committing boot.json"
    write_boot_record(store, new)
    progress.doing = "removing the staging directory"
    clean_staging(store)
    signed = (
        f", signed by key {manifest.key_id}"
        if manifest.key_id
        else ", UNSIGNED"
        if policy.allow_unsigned
        else ""
    )
    log(
        f"firmware {manifest.version} written to slot {target}{signed}, active on trial"
        f" (fallback: {keep or 'none'})"
    )
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
    the length of a firmware self-test. A calibration that was committed but whose directory fsync
    failed counts as stored: it is what the store uses now, so the ECU must use it too."""
    cal = loads_calibration(data, source)
    try:
        return install_calibration(store, cal, source, allow_downgrade=True, lock_timeout_s=lock_timeout_s)
    except FlashError as e:
        if not e.committed:
            raise
        return CalibrationFlashResult(cal, layout(store).current_calibration, None, changed=True)


def install_calibration(
    store: StorePath,
    cal: Calibration,
    source: str,
    *,
    allow_downgrade: bool = False,
    lock_timeout_s: float | None = None,
    log: Log = _quiet,
) -> CalibrationFlashResult:
    """Write a validated calibration as current.json, the old current kept as previous.json.

    An OSError becomes a FlashError saying whether version `cal.version` was committed and which
    calibration the store uses now."""
    data = dumps_calibration(cal)
    lay = _init_store(store)
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
        doing = "writing incoming.json"
        committed = False
        try:
            incoming = lay.incoming_calibration
            write_atomic(incoming, data)
            _verify_calibration_file(incoming, data)
            replaced: int | None = None
            current_valid = False
            with contextlib.suppress(StoreError, CalibrationError):
                replaced = read_calibration_file(current).version
                current_valid = True
            if current_valid:
                doing = "moving current.json to previous.json"
                os.replace(current, lay.previous_calibration)
            doing = "moving incoming.json to current.json"
            os.replace(incoming, current)
            committed = True
            doing = "syncing the calibration directory"
            fsync_dir(lay.calibration_dir)
            doing = "reading current.json back"
            _verify_calibration_file(current, data)
        except OSError as e:
            if committed:
                raise FlashError(
                    f"{current}: calibration version {cal.version} committed, but {doing} failed:"
                    f" {os_error_text(e)}; the store is consistent and uses {calibration_now(store)}",
                    committed=True,
                ) from None
            with contextlib.suppress(OSError):
                lay.incoming_calibration.unlink(missing_ok=True)
            raise FlashError(
                f"{lay.calibration_dir}: {doing} failed: {os_error_text(e)}; calibration version"
                f" {cal.version} was not committed: the store uses {calibration_now(store)}"
            ) from None
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
    parser.add_argument(
        "--signature",
        type=Path,
        default=None,
        help="detached signature of --image: the 64 raw bytes of an Ed25519 signature (bywire ecu sign)",
    )
    parser.add_argument(
        "--key",
        type=Path,
        default=None,
        help="sign the image with this Ed25519 private key (PEM) as it is flashed",
    )
    parser.add_argument(
        "--trust-key",
        type=Path,
        action="append",
        default=[],
        metavar="PUBLIC.pem",
        help="trust firmware signed by this Ed25519 public key (repeatable for a store that trusts none yet)",
    )
    parser.add_argument(
        "--trust-key-signature",
        type=Path,
        default=None,
        metavar="FILE",
        help="signature of the --trust-key file by a key the store already trusts (needed to add a key)",
    )
    parser.add_argument(
        "--revoke-key",
        action="append",
        default=[],
        metavar="KEY_ID",
        help="stop trusting this key (never the last)",
    )
    parser.add_argument(
        "--allow-unsigned",
        action="store_true",
        help="make a store without a trust policy a development store (unsigned firmware, loud every boot)",
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


def _usage_problem(args: argparse.Namespace) -> str | None:
    image = getattr(args, "image", None)
    firmware = bool(getattr(args, "firmware", False)) or image is not None
    trust_keys = getattr(args, "trust_key", None) or []
    trust_ops = trust_keys or getattr(args, "revoke_key", None) or getattr(args, "allow_unsigned", False)
    if getattr(args, "signature", None) is not None and image is None:
        return "--signature goes with --image (a built --firmware image is signed with --key)"
    if getattr(args, "signature", None) is not None and getattr(args, "key", None) is not None:
        return "give --signature or --key, not both"
    if getattr(args, "key", None) is not None and not firmware:
        return "--key signs firmware: give --firmware or --image too"
    if getattr(args, "trust_key_signature", None) is not None and len(trust_keys) != 1:
        return "--trust-key-signature goes with exactly one --trust-key"
    if getattr(args, "allow_unsigned", False) and trust_keys:
        return "give --trust-key or --allow-unsigned, not both"
    if not firmware and getattr(args, "calibration", None) is None and not trust_ops:
        return (
            "nothing to flash: give --firmware, --image IMAGE, --calibration FILE"
            " and/or --trust-key PUBLIC.pem"
        )
    return None


def cmd_flash(args: argparse.Namespace) -> int:
    """Run `bywire ecu flash` from parsed arguments: 0 on success, 1 when refused or failed, 2 on usage."""
    problem = _usage_problem(args)
    if problem is not None:
        print(f"error: {problem}", file=sys.stderr)
        return 2
    image = getattr(args, "image", None)
    firmware = bool(getattr(args, "firmware", False)) or image is not None
    cal_path = getattr(args, "calibration", None)
    try:
        # Read and check every input before touching anything, so a bad file changes nothing at all.
        cal = load_calibration_source(cal_path) if cal_path is not None else None
        endorsement_path = getattr(args, "trust_key_signature", None)
        change = TrustChange(
            add=tuple(load_public_key(p) for p in getattr(args, "trust_key", None) or []),
            endorsement=read_signature_file(endorsement_path) if endorsement_path is not None else None,
            endorsement_source=os.fspath(endorsement_path) if endorsement_path is not None else "",
            revoke=tuple(getattr(args, "revoke_key", None) or []),
            allow_unsigned=bool(getattr(args, "allow_unsigned", False)),
        )
        signature_path = getattr(args, "signature", None)
        signature = read_signature_file(signature_path) if signature_path is not None else None
        key_path = getattr(args, "key", None)
        signing_key = load_signing_key(key_path) if key_path is not None else None
        if firmware:
            result = flash_firmware(
                args.store,
                image,
                signature=signature,
                signing_key=signing_key,
                trust=change,
                selftest=not getattr(args, "no_selftest", False),
                log=_print,
            )
            signed = f"signed by key {result.manifest.key_id}" if result.manifest.key_id else "unsigned"
            print(f"firmware {result.manifest.version} ({signed}) -> slot {result.slot} (trial)")
        elif not change.empty:
            policy = change_trust(args.store, change, log=_print)
            print(f"trust: {describe_policy(policy) if policy is not None else 'none'}")
        if cal_path is not None:
            cal_result = flash_calibration(
                args.store,
                cal_path,
                allow_downgrade=bool(getattr(args, "allow_downgrade", False)),
                calibration=cal,
                log=_print,
            )
            print(f"calibration version {cal_result.calibration.version} -> {cal_result.path}")
    except (FlashError, StoreError, CalibrationError, FirmwareError, SigningError, TrustError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    except OSError as e:
        # Every step that writes the store reports its own I/O errors with the store's state; this
        # is the last resort for one that does not (reading an input, the lock file).
        print(f"error: {os.fspath(args.store)}: {os_error_text(e)}: {e}", file=sys.stderr)
        return 1
    return 0


def main(argv: list[str] | None = None) -> int:
    """`python -m bywire.ecu.flash ...`, the same as `bywire ecu flash ...`."""
    parser = argparse.ArgumentParser(prog="bywire ecu flash", description="flash an ECU's store")
    add_flash_arguments(parser)
    return cmd_flash(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
