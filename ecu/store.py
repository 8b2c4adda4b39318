"""The ECU's non-volatile store: two firmware slots, the boot record, calibrations, boot status.

No paper section: the 2007 and 2011 AnnieWAY ECUs were flashed by hand. This is the A/B layout of
automotive bootloaders (and U-Boot's bootcount): a new image goes into the inactive slot and is
booted on trial; the slot that last came up stays as the fallback until the new one has.

Layout of a store directory (a directory on the ECU computer)::

    DIR/store.json                  format marker; a non-empty directory without it is refused
    DIR/lock                        flock(2) held while slots, boot record or calibrations change
    DIR/boot.json                   BootRecord: active slot, previous slot, "confirmed" | "trial",
                                    trial boot count, slots rejected by a failed trial boot
    DIR/slots/{a,b}/image.pyz       firmware image (see firmware.py)
    DIR/slots/{a,b}/manifest.json   ImageManifest: version, sha256, size, built time, python
    DIR/staging/                    images being flashed; never booted; removed on the next flash
    DIR/calibration/current.json    calibration in canonical JSON with "version" and "crc32"
    DIR/calibration/previous.json   the last good one, kept for fallback
    DIR/calibration/incoming.json   a calibration being flashed; never booted
    DIR/run/boot-status.json        BootStatus written by the running app via `report_boot`

Every file write is atomic (`write_atomic`: temp file in the same directory, fsync, os.replace,
fsync of the directory), so a crash or power loss leaves each file either old or new, never torn.
A slot is usable only when image.pyz hashes to its manifest's sha256; that is checked on every
boot, which also catches a slot left half-written by a killed flash.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import os
import shutil
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from bywire.protocol.ecu_types import EcuState

if TYPE_CHECKING:
    from bywire.ecu.calibration import Calibration

StorePath = str | os.PathLike[str]
Slot = Literal["a", "b"]
BootState = Literal["confirmed", "trial"]

SLOTS: tuple[Slot, Slot] = ("a", "b")
STORE_FORMAT = "bywire-ecu-store"
STORE_LAYOUT_VERSION = 1
IMAGE_NAME = "image.pyz"
MANIFEST_NAME = "manifest.json"
INCOMING_CALIBRATION_NAME = "incoming.json"
# A trial image that has been started this many times without coming up is rejected even if the
# supervisor never saw it fail (power cut or supervisor killed during the trial boots).
MAX_TRIAL_BOOTS = 3


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


def write_atomic(path: StorePath, data: bytes) -> None:
    """Replace `path` by `data` so that a crash at any instant leaves either the old or new file."""
    target = Path(path)
    tmp = target.with_name(f".{target.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise
    fsync_dir(target.parent)


def write_json_atomic(path: StorePath, obj: Any) -> None:
    write_atomic(path, (json.dumps(obj, indent=2, sort_keys=True) + "\n").encode())


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
    return value  # type: ignore[return-value]


# --- store directory ----------------------------------------------------------------------------


def init_store(store: StorePath) -> StoreLayout:
    """Create the store (or open an existing one) and sweep leftovers of an interrupted flash.

    Refuses a non-empty directory that is not a store, so a typo in --store cannot scatter the
    ECU's files into someone's home directory.
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


def _check_marker(lay: StoreLayout) -> None:
    marker = read_json(lay.marker)
    if marker.get("format") != STORE_FORMAT:
        raise StoreError(lay.marker, f"format: expected {STORE_FORMAT!r}, got {marker.get('format')!r}")
    if marker.get("layout") != STORE_LAYOUT_VERSION:
        raise StoreError(lay.marker, f"layout: expected {STORE_LAYOUT_VERSION}, got {marker.get('layout')!r}")


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

    def to_dict(self) -> dict[str, Any]:
        return {
            "version": self.version,
            "sha256": self.sha256,
            "size_bytes": self.size_bytes,
            "built_utc": self.built_utc,
            "python": self.python,
            "entry": self.entry,
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: StorePath) -> ImageManifest:
        sha = _field(d, "sha256", str, source)
        if len(sha) != 64 or any(c not in "0123456789abcdef" for c in sha):
            raise StoreError(source, f"sha256: expected 64 lowercase hex digits, got {sha!r}")
        size = _field(d, "size_bytes", int, source)
        if size <= 0:
            raise StoreError(source, f"size_bytes: expected > 0, got {size}")
        return cls(
            version=_field(d, "version", str, source),
            sha256=sha,
            size_bytes=size,
            built_utc=_field(d, "built_utc", str, source),
            python=_field(d, "python", str, source),
            entry=_field(d, "entry", str, source),
        )


def read_manifest(store: StorePath, slot: Slot) -> ImageManifest:
    path = layout(store).manifest(slot)
    return ImageManifest.from_dict(read_json(path), path)


def verify_image(store: StorePath, slot: Slot) -> tuple[Path, ImageManifest]:
    """The slot's image path and manifest, after checking the image's size and sha256."""
    lay = layout(store)
    manifest = read_manifest(store, slot)
    image = lay.image(slot)
    try:
        size = image.stat().st_size
    except FileNotFoundError:
        raise StoreError(image, "missing") from None
    if size != manifest.size_bytes:
        raise StoreError(image, f"size {size} bytes, manifest says {manifest.size_bytes}")
    digest = sha256_file(image)
    if digest != manifest.sha256:
        raise StoreError(image, f"sha256 {digest[:16]}... does not match manifest {manifest.sha256[:16]}...")
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
class BootRecord:
    """Which slot boots, and whether it has proven itself.

    `trial`: flashed but not yet seen to come up; the boot supervisor falls back to `previous`
    if it does not. `confirmed`: came up at least once. `rejected` maps a slot to the reason its
    trial failed (cleared when the slot is flashed again).
    """

    active: Slot
    previous: Slot | None = None
    state: BootState = "confirmed"
    trial_boots: int = 0
    rejected: Mapping[str, str] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {
            "active": self.active,
            "previous": self.previous,
            "state": self.state,
            "trial_boots": self.trial_boots,
            "rejected": dict(sorted(self.rejected.items())),
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: StorePath) -> BootRecord:
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
        return cls(active, previous, state, trial_boots, dict(rejected))


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
    """What the ECU app reported once its cyclic executive ran."""

    pid: int
    state: EcuState
    t_unix: float


def report_boot(store_dir: StorePath, state_name: str | EcuState) -> None:
    """Called by the ECU app once its cyclic executive runs: "READY", or "OFF" without calibration.

    The boot supervisor matches the pid against its child, so a stale file from an earlier run
    can never confirm a new image.
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
    write_json_atomic(lay.boot_status, {"pid": os.getpid(), "state": state.name, "t_unix": time.time()})


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
    return BootStatus(pid=pid, state=EcuState[state_name], t_unix=float(t_unix))


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
    return {
        "store": os.fspath(lay.root),
        "boot": record.to_dict() if record is not None else None,
        "slots": slots,
        "calibration": calibrations,
        "last_boot_status": (
            {"pid": status.pid, "state": status.state.name, "t_unix": status.t_unix} if status else None
        ),
    }
