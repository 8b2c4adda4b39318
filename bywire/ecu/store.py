"""The ECU's non-volatile store: two firmware slots, the boot record, calibrations, boot status, trust.

No paper section: the 2007 and 2011 AnnieWAY ECUs were flashed by hand. This is the A/B layout of
automotive bootloaders (and U-Boot's bootcount): a new image goes into the inactive slot and is
booted on trial; the slot that last proved itself stays as the fallback until the new one has
(DESIGN section 4: firmware is signed; a trial image is confirmed by a period of health).

Layout of a store directory (a directory on the ECU computer)::

    DIR/store.json                  format marker, layout 2 (layout 1 stores still open; see below);
                                    a non-empty directory without it is refused
    DIR/trust.json                  TrustPolicy: the Ed25519 public keys firmware must be signed
                                    with, or "allow_unsigned" (a development store); absent: not
                                    configured yet, and then no firmware boots
    DIR/lock                        flock(2) held while slots, boot record or calibrations change
    DIR/boot.json                   BootRecord: active slot, previous slot, "confirmed" | "trial",
                                    trial boot count, slots rejected by a failed trial boot, and the
                                    history of the last boots (slot, start time, how each ended)
    DIR/slots/{a,b}/image.pyz       firmware image (see firmware.py), exactly the signed bytes
    DIR/slots/{a,b}/manifest.json   ImageManifest: version, sha256, size, built time, python, and
                                    the image's Ed25519 signature with the id of the key it verified with
    DIR/staging/                    images being flashed; never booted; removed on the next flash
    DIR/calibration/current.json    calibration in canonical JSON with "version" and "crc32"
    DIR/calibration/previous.json   the last good one, kept for fallback
    DIR/calibration/incoming.json   a calibration being flashed; never booted
    DIR/run/boot-status.json        BootStatus written by the running app via `report_boot` about
                                    once a second: state, healthy seconds, host link, internal faults

Every file write is atomic (`write_atomic`: temp file in the same directory, fsync, os.replace,
fsync of the directory), so a crash or power loss leaves each file either old or new, never torn.
A write whose rename happened but whose directory fsync failed raises `DirSyncError`: the new file
is the one every reader sees, but a power cut could still bring the old one back (callers report
exactly that). The boot status is volatile (replaced, not fsynced): it only matters to the running
supervisor, and an fsync a second would cost milliseconds of the disk the whole machine shares
(it is written beside the 1 kHz loop, never in it: `ecu.boot_reporter`).

A slot is usable only when image.pyz hashes to its manifest's sha256 and, unless the store allows
unsigned firmware, its signature verifies with a key in trust.json; that is checked on every boot,
which also catches a slot left half-written by a killed flash and a slot whose key was revoked.

Versions: layout 1 stores (before trust.json) open, with no trust configured (`write_trust` marks
the store layout 2 when it writes trust.json, so an older supervisor, which would not check
signatures, refuses the store). boot.json carries "version": 2; a version 1 record (no "version",
no "history") reads as one with an empty history. Manifests without "signature" read as unsigned.
"""

from __future__ import annotations

import base64
import contextlib
import errno
import fcntl
import hashlib
import itertools
import json
import math
import os
import shutil
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from bywire.protocol.ecu_types import EcuState

if TYPE_CHECKING:
    from bywire.ecu.calibration import Calibration

StorePath = str | os.PathLike[str]
Slot = Literal["a", "b"]
BootState = Literal["confirmed", "trial"]
# How a boot ended, as the supervisor saw it: "running" (written before the start; stays when the
# end was never seen: power cut, supervisor killed), "stopped" (a stop signal the supervisor
# forwarded), "exited" (exit code 0 on its own: its --seconds ran out, or it was signalled
# directly), "failed" (non-zero exit code, or killed by a signal), "hung" (stopped by the
# supervisor because it did not report, or stopped reporting).
BootEnd = Literal["running", "stopped", "exited", "failed", "hung"]
BOOT_ENDS: tuple[BootEnd, ...] = ("running", "stopped", "exited", "failed", "hung")
DEATHS: frozenset[str] = frozenset({"failed", "hung"})

SLOTS: tuple[Slot, Slot] = ("a", "b")
STORE_FORMAT = "bywire-ecu-store"
STORE_LAYOUT_VERSION = 2  # 2: trust.json (signed firmware); 1 still opens, with no trust configured
READABLE_LAYOUTS = (1, 2)
BOOT_RECORD_VERSION = 2  # 2: "history"; a record without "version" is 1
TRUST_FORMAT = "bywire-ecu-trust"
TRUST_VERSION = 1
IMAGE_NAME = "image.pyz"
MANIFEST_NAME = "manifest.json"
INCOMING_CALIBRATION_NAME = "incoming.json"
# A trial image that has been started this many times without being confirmed (and without the
# supervisor seeing it stopped on purpose) is rejected even if the supervisor never saw it fail:
# power cuts or a killed supervisor during the trial boots. U-Boot's customary bootlimit.
MAX_TRIAL_BOOTS = 3
# Boots kept in boot.json's history: enough for the crash-loop rule (boot.py) over both slots.
HISTORY_LEN = 12


class StoreError(Exception):
    """Something in the store is missing or wrong; names the file and the problem."""

    def __init__(self, path: StorePath, problem: str) -> None:
        super().__init__(f"{os.fspath(path)}: {problem}")
        self.path = Path(path)
        self.problem = problem


@dataclass(frozen=True)
class StoreLayout:
    """Paths of one store directory."""

    root: Path

    @property
    def marker(self) -> Path:
        return self.root / "store.json"

    @property
    def trust(self) -> Path:
        return self.root / "trust.json"

    @property
    def lock_path(self) -> Path:
        return self.root / "lock"

    @property
    def boot_record(self) -> Path:
        return self.root / "boot.json"

    @property
    def slots_dir(self) -> Path:
        return self.root / "slots"

    @property
    def staging_dir(self) -> Path:
        return self.root / "staging"

    @property
    def calibration_dir(self) -> Path:
        return self.root / "calibration"

    @property
    def current_calibration(self) -> Path:
        return self.calibration_dir / "current.json"

    @property
    def previous_calibration(self) -> Path:
        return self.calibration_dir / "previous.json"

    @property
    def incoming_calibration(self) -> Path:
        return self.calibration_dir / INCOMING_CALIBRATION_NAME

    @property
    def run_dir(self) -> Path:
        return self.root / "run"

    @property
    def boot_status(self) -> Path:
        return self.run_dir / "boot-status.json"

    def slot_dir(self, slot: Slot) -> Path:
        return self.slots_dir / _check_slot(slot, self.slots_dir)

    def image(self, slot: Slot) -> Path:
        return self.slot_dir(slot) / IMAGE_NAME

    def manifest(self, slot: Slot) -> Path:
        return self.slot_dir(slot) / MANIFEST_NAME


def layout(store: StorePath) -> StoreLayout:
    return StoreLayout(Path(store).absolute())


def other_slot(slot: Slot) -> Slot:
    return "b" if slot == "a" else "a"


# --- atomic file primitives -------------------------------------------------------------------


def fsync_dir(path: StorePath) -> None:
    """Make a rename or unlink inside `path` durable (POSIX needs the directory itself synced)."""
    fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


class DirSyncError(OSError):
    """`write_atomic` replaced the file, but the fsync of its directory failed: every reader sees
    the new file now, and a power cut before the kernel writes the directory back may restore the
    old one. Either is a whole file; the caller must not report the write as not done."""


def os_error_text(e: OSError) -> str:
    """ "EIO (Input/output error)": the errno name a technician can look up, and its meaning."""
    name = errno.errorcode.get(e.errno, "") if e.errno is not None else ""
    text = e.strerror or str(e)
    return f"{name} ({text})" if name else text


def write_atomic(path: StorePath, data: bytes, *, durable: bool = True) -> None:
    """Replace `path` by `data` so that a crash at any instant leaves either the old or new file.

    Any OSError before the rename leaves the old file and no temporary behind. `durable=False`
    skips both fsyncs (for volatile files such as the boot status): still never torn, but a power
    cut may lose the write."""
    target = Path(path)
    tmp = target.with_name(f".{target.name}.{os.getpid()}.tmp")
    try:
        # os.open/os.write rather than open(): the same calls as every other step, so a test can
        # inject the I/O error a failing flash chip gives at any one of them.
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view) :]
            if durable:
                os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise
    if durable:
        try:
            fsync_dir(target.parent)
        except OSError as e:
            raise DirSyncError(e.errno, e.strerror, os.fspath(target.parent)) from e


def write_json_atomic(path: StorePath, obj: Any, *, durable: bool = True) -> None:
    write_atomic(path, (json.dumps(obj, indent=2, sort_keys=True) + "\n").encode(), durable=durable)


def read_json(path: StorePath) -> dict[str, Any]:
    """Read a JSON object; StoreError naming the file if it is missing, torn or not an object."""
    try:
        raw = Path(path).read_bytes()
    except FileNotFoundError:
        raise StoreError(path, "missing") from None
    except OSError as e:
        raise StoreError(path, f"cannot read: {e.strerror}") from None
    try:
        obj = json.loads(raw)
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise StoreError(path, f"not valid JSON: {e}") from None
    if not isinstance(obj, dict):
        raise StoreError(path, f"expected a JSON object, got {type(obj).__name__}")
    return obj


def sha256_file(path: StorePath) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _field(obj: Mapping[str, Any], key: str, kind: type | tuple[type, ...], path: StorePath) -> Any:
    if key not in obj:
        raise StoreError(path, f"{key}: missing")
    value = obj[key]
    # bool is an int in Python; a count or size of `true` is a corrupt file, not 1.
    if not isinstance(value, kind) or (isinstance(value, bool) and bool not in _as_tuple(kind)):
        names = " or ".join(t.__name__ for t in _as_tuple(kind))
        raise StoreError(path, f"{key}: expected {names}, got {value!r}")
    return value


def _as_tuple(kind: type | tuple[type, ...]) -> tuple[type, ...]:
    return kind if isinstance(kind, tuple) else (kind,)


def _check_slot(value: object, path: StorePath, key: str = "slot") -> Slot:
    if value not in SLOTS:
        raise StoreError(path, f"{key}: expected one of {list(SLOTS)}, got {value!r}")
    return value


# --- store directory ----------------------------------------------------------------------------


def init_store(store: StorePath) -> StoreLayout:
    """Create the store (or open an existing one).

    Refuses a non-empty directory that is not a store, so a typo in --store cannot scatter the
    ECU's files into someone's home directory. A new store has no trust policy: `write_trust`.
    """
    lay = layout(store)
    if lay.root.exists() and not lay.root.is_dir():
        raise StoreError(lay.root, "not a directory")
    if lay.marker.exists():
        _check_marker(lay)
    else:
        if lay.root.is_dir() and any(lay.root.iterdir()):
            raise StoreError(lay.root, f"not empty and not an ECU store (no {lay.marker.name}); refusing")
        lay.root.mkdir(parents=True, exist_ok=True)
        write_json_atomic(lay.marker, {"format": STORE_FORMAT, "layout": STORE_LAYOUT_VERSION})
    for d in (lay.slots_dir, lay.calibration_dir, lay.run_dir):
        d.mkdir(exist_ok=True)
    return lay


def open_store(store: StorePath) -> StoreLayout:
    """An existing store, for reading and booting; StoreError if `store` is not one."""
    lay = layout(store)
    if not lay.root.is_dir():
        raise StoreError(lay.root, "no such store directory")
    if not lay.marker.exists():
        raise StoreError(lay.root, f"not an ECU store (no {lay.marker.name}); flash it first")
    _check_marker(lay)
    return lay


def _check_marker(lay: StoreLayout) -> int:
    """The store's layout version; StoreError if store.json is not ours or from a newer bywire."""
    marker = read_json(lay.marker)
    if marker.get("format") != STORE_FORMAT:
        raise StoreError(lay.marker, f"format: expected {STORE_FORMAT!r}, got {marker.get('format')!r}")
    layout_version = marker.get("layout")
    if layout_version not in READABLE_LAYOUTS or isinstance(layout_version, bool):
        raise StoreError(
            lay.marker, f"layout: expected one of {list(READABLE_LAYOUTS)}, got {layout_version!r}"
        )
    return int(layout_version)


def store_layout_version(store: StorePath) -> int:
    return _check_marker(layout(store))


@contextlib.contextmanager
def store_lock(store: StorePath, timeout_s: float | None = None) -> Iterator[StoreLayout]:
    """Exclusive lock over slot, boot-record and calibration changes (flash, boot, the app).

    flock is released by the kernel when its holder dies, so a killed flash never wedges the ECU.
    `timeout_s`: give up with StoreError after this long (None: wait as long as it takes).
    """
    lay = layout(store)
    fd = os.open(lay.lock_path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        if timeout_s is None:
            fcntl.flock(fd, fcntl.LOCK_EX)
        else:
            deadline = time.monotonic() + timeout_s
            while True:
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                    break
                except BlockingIOError:
                    if time.monotonic() >= deadline:
                        raise StoreError(
                            lay.lock_path, f"store busy (locked for more than {timeout_s:g} s)"
                        ) from None
                    time.sleep(0.01)
        yield lay
    finally:
        os.close(fd)


def clean_staging(store: StorePath) -> None:
    """Remove what an interrupted flash left behind (staging images, temp files)."""
    lay = layout(store)
    if lay.staging_dir.exists():
        shutil.rmtree(lay.staging_dir)
        fsync_dir(lay.root)
    # A calibration that was staged but never renamed into place: current/previous are intact.
    lay.incoming_calibration.unlink(missing_ok=True)
    for d in (lay.root, lay.calibration_dir, lay.run_dir, *(lay.slot_dir(s) for s in SLOTS)):
        if d.is_dir():
            for tmp in d.glob(".*.tmp"):
                tmp.unlink(missing_ok=True)


# --- trust: which firmware this store boots ------------------------------------------------------


@dataclass(frozen=True)
class TrustPolicy:
    """The keys a slot's image must be signed with, or `allow_unsigned` (a development store).

    Exactly one of the two: a store with keys never also takes unsigned images, and a development
    store has no keys (flash.py decides how a policy may change)."""

    keys: Mapping[str, bytes] = field(default_factory=dict)  # key id -> 32 raw Ed25519 bytes
    allow_unsigned: bool = False

    def to_dict(self) -> dict[str, Any]:
        return {
            "format": TRUST_FORMAT,
            "version": TRUST_VERSION,
            "allow_unsigned": self.allow_unsigned,
            "keys": {
                kid: {"ed25519": base64.b64encode(raw).decode()} for kid, raw in sorted(self.keys.items())
            },
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: StorePath) -> TrustPolicy:
        from bywire.ecu.signing import PUBLIC_KEY_BYTES, key_id

        if d.get("format") != TRUST_FORMAT:
            raise StoreError(source, f"format: expected {TRUST_FORMAT!r}, got {d.get('format')!r}")
        if d.get("version") != TRUST_VERSION:
            raise StoreError(source, f"version: expected {TRUST_VERSION}, got {d.get('version')!r}")
        allow_unsigned = _field(d, "allow_unsigned", bool, source)
        entries = _field(d, "keys", dict, source)
        keys: dict[str, bytes] = {}
        for kid, entry in entries.items():
            where = f"keys.{kid}"
            if not isinstance(entry, dict) or not isinstance(entry.get("ed25519"), str):
                raise StoreError(source, f'{where}: expected {{"ed25519": base64}}, got {entry!r}')
            try:
                raw = base64.b64decode(entry["ed25519"], validate=True)
            except ValueError:
                raise StoreError(source, f"{where}.ed25519: not base64") from None
            if len(raw) != PUBLIC_KEY_BYTES:
                raise StoreError(source, f"{where}.ed25519: {len(raw)} bytes, expected {PUBLIC_KEY_BYTES}")
            # The id is derived, never trusted: a hand-edited id would make logs name the wrong key.
            if key_id(raw) != kid:
                raise StoreError(source, f"{where}: the key's id is {key_id(raw)}")
            keys[kid] = raw
        if allow_unsigned and keys:
            raise StoreError(
                source, "allow_unsigned: a store with trusted keys never accepts unsigned firmware"
            )
        if not allow_unsigned and not keys:
            raise StoreError(source, "keys: no trusted key, and unsigned firmware is not allowed")
        return cls(keys, allow_unsigned)


def read_trust(store: StorePath) -> TrustPolicy | None:
    """The store's trust policy, or None when none was configured (then no firmware boots)."""
    path = layout(store).trust
    if not path.exists():
        return None
    return TrustPolicy.from_dict(read_json(path), path)


def write_trust(store: StorePath, policy: TrustPolicy) -> None:
    """Write trust.json, then mark the store layout 2 so that a supervisor that predates signed
    firmware refuses it instead of booting it unchecked. (In this order: a crash in between leaves a
    layout 1 store with a policy, which this code reads; the reverse would leave an unbootable one.)

    DirSyncError from the trust.json write propagates (the policy is in effect, maybe not durable)."""
    lay = layout(store)
    write_json_atomic(lay.trust, policy.to_dict())
    if _check_marker(lay) != STORE_LAYOUT_VERSION:
        write_json_atomic(lay.marker, {"format": STORE_FORMAT, "layout": STORE_LAYOUT_VERSION})


NO_TRUST = (
    "no firmware trust policy: give the store a key (bywire ecu flash --store DIR --trust-key"
    " PUBLIC.pem) or make it a development store (--allow-unsigned)"
)


def no_trust_problem(store: StorePath) -> str:
    return f"{layout(store).root}: {NO_TRUST}"


# --- image manifests ----------------------------------------------------------------------------


@dataclass(frozen=True)
class ImageManifest:
    """What a slot claims to hold; `sha256` is what makes the claim checkable."""

    version: str
    sha256: str
    size_bytes: int
    built_utc: str  # ISO 8601; informational only (the image bytes themselves are reproducible)
    python: str  # "3.11": the interpreter line the image was built and self-tested with
    entry: str  # "bywire.ecu.app:main"
    signature: bytes | None = None  # Ed25519 over the image's exact bytes (signing.py)
    key_id: str | None = None  # the trusted key it verified with when flashed (for logs only)

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {
            "version": self.version,
            "sha256": self.sha256,
            "size_bytes": self.size_bytes,
            "built_utc": self.built_utc,
            "python": self.python,
            "entry": self.entry,
        }
        if self.signature is not None:
            d["signature"] = base64.b64encode(self.signature).decode()
            d["key_id"] = self.key_id
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: StorePath) -> ImageManifest:
        sha = _field(d, "sha256", str, source)
        if len(sha) != 64 or any(c not in "0123456789abcdef" for c in sha):
            raise StoreError(source, f"sha256: expected 64 lowercase hex digits, got {sha!r}")
        size = _field(d, "size_bytes", int, source)
        if size <= 0:
            raise StoreError(source, f"size_bytes: expected > 0, got {size}")
        signature: bytes | None = None
        kid: str | None = None
        if d.get("signature") is not None:
            try:
                signature = base64.b64decode(_field(d, "signature", str, source), validate=True)
            except ValueError:
                raise StoreError(source, "signature: not base64") from None
            kid = d.get("key_id") if isinstance(d.get("key_id"), str) else None
        return cls(
            version=_field(d, "version", str, source),
            sha256=sha,
            size_bytes=size,
            built_utc=_field(d, "built_utc", str, source),
            python=_field(d, "python", str, source),
            entry=_field(d, "entry", str, source),
            signature=signature,
            key_id=kid,
        )


def read_manifest(store: StorePath, slot: Slot) -> ImageManifest:
    path = layout(store).manifest(slot)
    return ImageManifest.from_dict(read_json(path), path)


def signature_problem(policy: TrustPolicy, signature: bytes | None, data: bytes) -> str | None:
    """None when `data` may boot under `policy`, else why not (the words flash and boot both use)."""
    if policy.allow_unsigned:
        return None
    if signature is None:
        return "no signature given and the store requires signed firmware"
    from bywire.ecu.signing import verifying_key

    if verifying_key(policy.keys, signature, data) is None:
        return "signature does not verify with any trusted key"
    return None


def verify_image(
    store: StorePath, slot: Slot, policy: TrustPolicy | None = None
) -> tuple[Path, ImageManifest]:
    """The slot's image path and manifest, after checking the image's size, sha256 and signature.

    `policy`: the trust policy to check the signature against (default: the store's trust.json;
    StoreError when it has none)."""
    lay = layout(store)
    if policy is None:
        policy = read_trust(store)
        if policy is None:
            raise StoreError(lay.root, NO_TRUST)
    manifest = read_manifest(store, slot)
    image = lay.image(slot)
    try:
        data = image.read_bytes()
    except FileNotFoundError:
        raise StoreError(image, "missing") from None
    except OSError as e:
        raise StoreError(image, f"cannot read: {os_error_text(e)}") from None
    if len(data) != manifest.size_bytes:
        raise StoreError(image, f"size {len(data)} bytes, manifest says {manifest.size_bytes}")
    digest = hashlib.sha256(data).hexdigest()
    if digest != manifest.sha256:
        raise StoreError(image, f"sha256 {digest[:16]}... does not match manifest {manifest.sha256[:16]}...")
    problem = signature_problem(policy, manifest.signature, data)
    if problem is not None:
        raise StoreError(image, problem)
    return image, manifest


def slot_usable(store: StorePath, slot: Slot) -> str | None:
    """None when the slot's image verifies, else the reason it does not."""
    try:
        verify_image(store, slot)
    except StoreError as e:
        return str(e)
    return None


# --- boot record --------------------------------------------------------------------------------


@dataclass(frozen=True)
class BootEntry:
    """One boot in the history: which image, when it started (unix seconds), how it ended."""

    slot: Slot
    version: str
    started_unix: float
    end: BootEnd = "running"
    code: int | None = None  # exit code (128 + n after signal n) when it exited

    def to_dict(self) -> dict[str, Any]:
        return {
            "slot": self.slot,
            "version": self.version,
            "started_unix": self.started_unix,
            "end": self.end,
            "code": self.code,
        }

    @classmethod
    def from_dict(cls, d: Any, source: StorePath, where: str) -> BootEntry:
        if not isinstance(d, dict):
            raise StoreError(source, f"{where}: expected an object, got {d!r}")
        slot = _check_slot(d.get("slot"), source, f"{where}.slot")
        version = d.get("version")
        started = d.get("started_unix")
        end = d.get("end")
        code = d.get("code")
        if not isinstance(version, str):
            raise StoreError(source, f"{where}.version: expected str, got {version!r}")
        if not isinstance(started, int | float) or isinstance(started, bool) or not math.isfinite(started):
            raise StoreError(source, f"{where}.started_unix: expected a number, got {started!r}")
        if end not in BOOT_ENDS:
            raise StoreError(source, f"{where}.end: expected one of {list(BOOT_ENDS)}, got {end!r}")
        if code is not None and (not isinstance(code, int) or isinstance(code, bool)):
            raise StoreError(source, f"{where}.code: expected int or null, got {code!r}")
        return cls(slot, version, float(started), end, code)


@dataclass(frozen=True)
class BootRecord:
    """Which slot boots, and whether it has proven itself.

    `trial`: flashed but not yet confirmed; the boot supervisor confirms it after a period of health
    (boot.py) and falls back to `previous` if it dies first. `confirmed`: proved itself once; still
    rolled back to `previous` if it keeps dying (boot.py's crash-loop rule, over `history`).
    `rejected` maps a slot to the reason it was rejected (cleared when the slot is flashed again).
    `history`: the last HISTORY_LEN boots, oldest first.
    """

    active: Slot
    previous: Slot | None = None
    state: BootState = "confirmed"
    trial_boots: int = 0
    rejected: Mapping[str, str] = field(default_factory=dict)
    history: tuple[BootEntry, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        return {
            "version": BOOT_RECORD_VERSION,
            "active": self.active,
            "previous": self.previous,
            "state": self.state,
            "trial_boots": self.trial_boots,
            "rejected": dict(sorted(self.rejected.items())),
            "history": [entry.to_dict() for entry in self.history],
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: StorePath) -> BootRecord:
        version = d.get("version", 1)
        if version not in (1, BOOT_RECORD_VERSION) or isinstance(version, bool):
            raise StoreError(source, f"version: expected 1 or {BOOT_RECORD_VERSION}, got {version!r}")
        active = _check_slot(d.get("active"), source, "active")
        previous = d.get("previous")
        if previous is not None:
            previous = _check_slot(previous, source, "previous")
            if previous == active:
                raise StoreError(source, f"previous: must differ from active ({active!r})")
        state = d.get("state")
        if state not in ("confirmed", "trial"):
            raise StoreError(source, f"state: expected 'confirmed' or 'trial', got {state!r}")
        trial_boots = _field(d, "trial_boots", int, source)
        if trial_boots < 0:
            raise StoreError(source, f"trial_boots: expected >= 0, got {trial_boots}")
        rejected = d.get("rejected", {})
        if not isinstance(rejected, dict) or not all(
            k in SLOTS and isinstance(v, str) for k, v in rejected.items()
        ):
            raise StoreError(source, f"rejected: expected {{slot: reason}}, got {rejected!r}")
        history = d.get("history", [])
        if not isinstance(history, list):
            raise StoreError(source, f"history: expected a list, got {history!r}")
        entries = tuple(BootEntry.from_dict(e, source, f"history[{i}]") for i, e in enumerate(history))
        return cls(active, previous, state, trial_boots, dict(rejected), entries)

    def with_boot(self, entry: BootEntry) -> BootRecord:
        """This record with `entry` appended to the history (the oldest dropped past HISTORY_LEN)."""
        return replace(self, history=(*self.history, entry)[-HISTORY_LEN:])

    def without_slot_history(self, slot: Slot) -> BootRecord:
        """Forget `slot`'s boots: a newly flashed image starts with a clean history."""
        return replace(self, history=tuple(e for e in self.history if e.slot != slot))


def read_boot_record(store: StorePath) -> BootRecord | None:
    """The boot record, or None when no firmware was ever flashed into this store."""
    path = layout(store).boot_record
    if not path.exists():
        return None
    return BootRecord.from_dict(read_json(path), path)


def write_boot_record(store: StorePath, record: BootRecord) -> None:
    write_json_atomic(layout(store).boot_record, record.to_dict())


def active_image(store: StorePath) -> tuple[Slot, Path, ImageManifest]:
    """The active slot, its verified image path and manifest; StoreError if there is none."""
    record = read_boot_record(store)
    if record is None:
        raise StoreError(layout(store).boot_record, "missing: no firmware flashed into this store")
    image, manifest = verify_image(store, record.active)
    return record.active, image, manifest


# --- boot status (written by the running app) ---------------------------------------------------


@dataclass(frozen=True)
class BootStatus:
    """What the running ECU app last reported (health.py computes the health fields).

    `healthy_s`: seconds this boot with the host link up and no internal fault since the last one
    (a fault restarts the count, a link drop pauses it); the supervisor confirms a trial image on it.
    `seq` counts the reports of this pid: a report that stops changing is a hung app. Files written
    before these fields existed read as an unhealthy, link-down report."""

    pid: int
    state: EcuState
    t_unix: float
    seq: int = 0
    healthy_s: float = 0.0
    host_link_up: bool = False
    internal_faults: int = 0
    unsigned_store: bool = False


_report_seq = itertools.count(1)


def report_boot(
    store_dir: StorePath,
    state_name: str | EcuState,
    *,
    healthy_s: float = 0.0,
    host_link_up: bool = False,
    internal_faults: int = 0,
    unsigned_store: bool = False,
) -> None:
    """Called by the ECU app once its cyclic executive runs, then about once a second: its state
    ("READY", or "OFF" without calibration) and health.

    The boot supervisor matches the pid against its child, so a stale file from an earlier run
    can never confirm a new image. Not fsynced (see the module docstring): called about once a
    second by the writer thread beside the 1 kHz loop (`ecu.boot_reporter`); an OSError is the
    caller's to handle.
    """
    if isinstance(state_name, EcuState):
        state = state_name
    else:
        try:
            state = EcuState[state_name]
        except KeyError:
            raise ValueError(
                f"report_boot: state {state_name!r} is not an EcuState name"
                f" ({', '.join(EcuState.__members__)})"
            ) from None
    lay = layout(store_dir)
    lay.run_dir.mkdir(parents=True, exist_ok=True)
    status = {
        "pid": os.getpid(),
        "state": state.name,
        "t_unix": time.time(),
        "seq": next(_report_seq),
        "healthy_s": round(float(healthy_s), 3),
        "host_link_up": bool(host_link_up),
        "internal_faults": int(internal_faults),
        "unsigned_store": bool(unsigned_store),
    }
    write_json_atomic(lay.boot_status, status, durable=False)


def read_boot_status(store: StorePath) -> BootStatus | None:
    """The last reported boot status, or None when there is none (or it is unreadable)."""
    path = layout(store).boot_status
    if not path.exists():
        return None
    d = read_json(path)
    pid = _field(d, "pid", int, path)
    state_name = _field(d, "state", str, path)
    if state_name not in EcuState.__members__:
        raise StoreError(path, f"state: expected an EcuState name, got {state_name!r}")
    t_unix = _field(d, "t_unix", (int, float), path)
    optional: dict[str, Any] = {}
    for key, kind in (
        ("seq", int),
        ("healthy_s", (int, float)),
        ("host_link_up", bool),
        ("internal_faults", int),
        ("unsigned_store", bool),
    ):
        if key in d:
            optional[key] = _field(d, key, kind, path)
    healthy_s = float(optional.pop("healthy_s", 0.0))
    if not math.isfinite(healthy_s) or healthy_s < 0:
        raise StoreError(path, f"healthy_s: expected a finite number >= 0, got {healthy_s!r}")
    return BootStatus(
        pid=pid, state=EcuState[state_name], t_unix=float(t_unix), healthy_s=healthy_s, **optional
    )


def clear_boot_status(store: StorePath) -> None:
    path = layout(store).boot_status
    if path.exists():
        path.unlink()
        fsync_dir(path.parent)


# --- calibration --------------------------------------------------------------------------------


def current_calibration_path(store: StorePath) -> Path:
    return layout(store).current_calibration


def previous_calibration_path(store: StorePath) -> Path:
    return layout(store).previous_calibration


def read_calibration_file(path: StorePath) -> Calibration:
    """A stored calibration, CRC-checked; CalibrationError or StoreError naming the file."""
    # Imported here so that the boot-record and status functions (report_boot runs inside the
    # app) do not depend on the calibration schema module.
    from bywire.ecu.calibration import loads_calibration

    try:
        data = Path(path).read_bytes()
    except FileNotFoundError:
        raise StoreError(path, "missing") from None
    except OSError as e:
        raise StoreError(path, f"cannot read: {e.strerror}") from None
    return loads_calibration(data, os.fspath(path))


@dataclass(frozen=True)
class CalibrationChoice:
    """The calibration the ECU should run with (None: none usable) and why others were skipped."""

    path: Path | None
    calibration: Calibration | None
    problems: tuple[str, ...]


def usable_calibration(store: StorePath) -> CalibrationChoice:
    """current.json if it loads and passes its CRC, else previous.json, else none.

    `problems` lists the files that exist but were refused (a missing file is not a problem)."""
    from bywire.ecu.calibration import CalibrationError

    lay = layout(store)
    problems: list[str] = []
    for path in (lay.current_calibration, lay.previous_calibration):
        if not path.exists():
            continue
        try:
            return CalibrationChoice(path, read_calibration_file(path), tuple(problems))
        except (StoreError, CalibrationError) as e:
            problems.append(str(e))
    return CalibrationChoice(None, None, tuple(problems))


def store_status(store: StorePath) -> dict[str, Any]:
    """A JSON-able summary for operators: boot record, each slot's state, calibrations."""
    lay = open_store(store)
    record = read_boot_record(store)
    slots: dict[str, Any] = {}
    for slot in SLOTS:
        if not lay.manifest(slot).exists() and not lay.image(slot).exists():
            slots[slot] = {"empty": True}
            continue
        problem = slot_usable(store, slot)
        entry: dict[str, Any] = {"usable": problem is None}
        if problem is not None:
            entry["problem"] = problem
        with contextlib.suppress(StoreError):
            entry["version"] = read_manifest(store, slot).version
        slots[slot] = entry
    from bywire.ecu.calibration import CalibrationError

    calibrations: dict[str, Any] = {}
    for name, path in (("current", lay.current_calibration), ("previous", lay.previous_calibration)):
        if not path.exists():
            calibrations[name] = None
            continue
        try:
            calibrations[name] = {"version": read_calibration_file(path).version, "valid": True}
        except (StoreError, CalibrationError) as e:
            calibrations[name] = {"valid": False, "problem": str(e)}
    status = None
    with contextlib.suppress(StoreError):
        status = read_boot_status(store)
    trust: dict[str, Any] | None = None
    try:
        policy = read_trust(store)
        if policy is not None:
            trust = {"allow_unsigned": policy.allow_unsigned, "keys": sorted(policy.keys)}
    except StoreError as e:
        trust = {"problem": str(e)}
    return {
        "store": os.fspath(lay.root),
        "trust": trust,
        "boot": record.to_dict() if record is not None else None,
        "slots": slots,
        "calibration": calibrations,
        "last_boot_status": (
            {
                "pid": status.pid,
                "state": status.state.name,
                "t_unix": status.t_unix,
                "healthy_s": status.healthy_s,
                "host_link_up": status.host_link_up,
                "internal_faults": status.internal_faults,
            }
            if status
            else None
        ),
    }
