"""The ECU store: atomic writes (and what an I/O error after the rename means), layout and its
versions, boot record and its history, manifests, boot status with health, calibration choice."""

from __future__ import annotations

import errno
import json
import os
import re
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import bywire.ecu
from bywire.ecu import store
from bywire.ecu.calibration import calibration_from_dict, calibration_to_dict, dumps_calibration
from bywire.ecu.store import BootEntry, BootRecord, DirSyncError, ImageManifest, StoreError
from bywire.protocol.ecu_types import EcuState

PASSAT = Path(bywire.ecu.__path__[0]) / "calibrations" / "passat.json"


def calibration_bytes(version: int) -> bytes:
    d = json.loads(PASSAT.read_bytes())
    d.pop("crc32")
    d["version"] = version
    return dumps_calibration(calibration_from_dict(d))


def fake_slot(root: Path, slot: store.Slot, content: bytes, version: str = "0.1.0+test") -> ImageManifest:
    import hashlib

    lay = store.layout(root)
    lay.slot_dir(slot).mkdir(parents=True, exist_ok=True)
    lay.image(slot).write_bytes(content)
    manifest = ImageManifest(
        version=version,
        sha256=hashlib.sha256(content).hexdigest(),
        size_bytes=len(content),
        built_utc="2025-01-01T00:00:00+00:00",
        python="3.11",
        entry="x:main",
    )
    store.write_json_atomic(lay.manifest(slot), manifest.to_dict())
    return manifest


# --- atomic writes ------------------------------------------------------------------------------


def test_write_atomic_replaces_content(tmp_path: Path) -> None:
    target = tmp_path / "f.json"
    store.write_atomic(target, b"one")
    store.write_atomic(target, b"two")
    assert target.read_bytes() == b"two"
    assert [p.name for p in tmp_path.iterdir()] == ["f.json"]


def test_write_atomic_crash_before_rename_keeps_old_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    target = tmp_path / "f.json"
    store.write_atomic(target, b"old")

    def power_cut(src: object, dst: object) -> None:
        raise OSError("power cut")

    monkeypatch.setattr(os, "replace", power_cut)
    with pytest.raises(OSError, match="power cut") as e:
        store.write_atomic(target, b"new")
    assert not isinstance(e.value, DirSyncError), "before the rename: not done at all"
    assert target.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["f.json"], "the temp file must not be left behind"


def test_write_atomic_io_error_while_writing_leaves_the_old_file_and_no_temp(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    target = tmp_path / "f.json"
    store.write_atomic(target, b"old")

    def full(fd: int, data: object) -> int:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "write", full)
    with pytest.raises(OSError) as e:
        store.write_atomic(target, b"new")
    assert store.os_error_text(e.value) == "ENOSPC (No space left on device)"
    assert target.read_bytes() == b"old" and [p.name for p in tmp_path.iterdir()] == ["f.json"]


def test_write_atomic_dir_fsync_error_after_the_rename_is_a_dir_sync_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    target = tmp_path / "f.json"
    store.write_atomic(target, b"old")
    calls: list[int] = []
    real_fsync = os.fsync

    def fsync(fd: int) -> None:
        calls.append(fd)
        if len(calls) == 2:  # the first is the file's, the second the directory's
            raise OSError(errno.EIO, os.strerror(errno.EIO))
        real_fsync(fd)

    monkeypatch.setattr(os, "fsync", fsync)
    with pytest.raises(DirSyncError) as e:
        store.write_atomic(target, b"new")
    assert e.value.errno == errno.EIO
    assert target.read_bytes() == b"new", "renamed: every reader sees the new file"
    calls.clear()
    store.write_atomic(target, b"volatile", durable=False)
    assert calls == [] and target.read_bytes() == b"volatile"


# --- layout -------------------------------------------------------------------------------------


def test_init_store_creates_layout_and_is_idempotent(tmp_path: Path) -> None:
    root = tmp_path / "ecu"
    lay = store.init_store(root)
    assert lay.marker.is_file() and lay.slots_dir.is_dir() and lay.calibration_dir.is_dir()
    before = lay.marker.read_bytes()
    store.init_store(root)
    assert lay.marker.read_bytes() == before
    assert store.open_store(root).root == lay.root


def test_init_store_refuses_a_non_empty_foreign_directory(tmp_path: Path) -> None:
    (tmp_path / "thesis.tex").write_text("precious")
    with pytest.raises(StoreError, match="not an ECU store"):
        store.init_store(tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["thesis.tex"]


def test_layout_1_stores_open_without_trust_and_unknown_layouts_are_refused(tmp_path: Path) -> None:
    lay = store.init_store(tmp_path / "s")
    assert store.store_layout_version(lay.root) == store.STORE_LAYOUT_VERSION == 2
    lay.marker.write_text(json.dumps({"format": store.STORE_FORMAT, "layout": 1}))
    assert store.open_store(lay.root).root == lay.root and store.read_trust(lay.root) is None
    store.write_trust(lay.root, store.TrustPolicy(allow_unsigned=True))
    assert store.store_layout_version(lay.root) == 2
    lay.marker.write_text(json.dumps({"format": store.STORE_FORMAT, "layout": 3}))
    with pytest.raises(StoreError, match=r"store\.json: layout: expected one of \[1, 2\], got 3"):
        store.open_store(lay.root)


def test_open_store_names_the_bad_marker(tmp_path: Path) -> None:
    lay = store.init_store(tmp_path / "s")
    lay.marker.write_text(json.dumps({"format": "something-else", "layout": 1}))
    with pytest.raises(StoreError) as e:
        store.open_store(lay.root)
    assert "store.json" in str(e.value) and "format" in str(e.value)
    with pytest.raises(StoreError, match="no such store"):
        store.open_store(tmp_path / "missing")


def test_clean_staging_removes_leftovers_of_a_killed_flash(tmp_path: Path) -> None:
    lay = store.init_store(tmp_path / "s")
    (lay.staging_dir / "new").mkdir(parents=True)
    (lay.staging_dir / "new" / "image.pyz").write_bytes(b"half")
    (lay.calibration_dir / ".current.json.123.tmp").write_bytes(b"half")
    (lay.calibration_dir / "incoming.json").write_bytes(b"half")
    store.clean_staging(lay.root)
    assert not lay.staging_dir.exists()
    assert list(lay.calibration_dir.iterdir()) == []


# --- boot record and manifests ------------------------------------------------------------------

slots = st.sampled_from(store.SLOTS)


boot_entries = st.builds(
    BootEntry,
    slot=slots,
    version=st.text(max_size=20),
    started_unix=st.floats(0, 4e9, allow_nan=False),
    end=st.sampled_from(store.BOOT_ENDS),
    code=st.none() | st.integers(-255, 255),
)


@st.composite
def boot_records(draw: st.DrawFn) -> BootRecord:
    active = draw(slots)
    previous = draw(st.none() | st.just(store.other_slot(active)))
    rejected = draw(st.dictionaries(slots, st.text(max_size=20), max_size=2))
    return BootRecord(
        active=active,
        previous=previous,
        state=draw(st.sampled_from(["confirmed", "trial"])),
        trial_boots=draw(st.integers(0, 10)),
        rejected=rejected,
        history=tuple(draw(st.lists(boot_entries, max_size=store.HISTORY_LEN))),
    )


@settings(max_examples=50, deadline=None)
@given(boot_records())
def test_boot_record_round_trips(record: BootRecord) -> None:
    assert BootRecord.from_dict(json.loads(json.dumps(record.to_dict())), "boot.json") == record


def test_a_boot_json_from_before_the_history_still_loads() -> None:
    old = {"active": "b", "previous": "a", "state": "trial", "trial_boots": 1, "rejected": {}}
    record = BootRecord.from_dict(old, "boot.json")
    assert record == BootRecord(active="b", previous="a", state="trial", trial_boots=1)
    assert record.history == () and record.to_dict()["version"] == store.BOOT_RECORD_VERSION


def test_the_history_keeps_the_last_boots_and_forgets_a_reflashed_slot() -> None:
    record = BootRecord(active="a")
    for i in range(store.HISTORY_LEN + 3):
        record = record.with_boot(BootEntry("a" if i % 2 else "b", "v", float(i)))
    assert (
        len(record.history) == store.HISTORY_LEN and record.history[-1].started_unix == store.HISTORY_LEN + 2
    )
    assert {e.slot for e in record.without_slot_history("b").history} == {"a"}


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"version": 3}, "version"),
        ({"history": {}}, "history"),
        (
            {"history": [{"slot": "a", "version": "v", "started_unix": 1.0, "end": "exploded"}]},
            "history[0].end",
        ),
        (
            {"history": [{"slot": "a", "version": "v", "started_unix": "now", "end": "failed"}]},
            "history[0].started_unix",
        ),
        (
            {"history": [{"slot": "a", "version": "v", "started_unix": 1, "end": "failed", "code": "x"}]},
            "history[0].code",
        ),
        ({"active": "c"}, "active"),
        ({"previous": "a"}, "previous"),  # equal to active
        ({"state": "maybe"}, "state"),
        ({"trial_boots": -1}, "trial_boots"),
        ({"trial_boots": True}, "trial_boots"),
        ({"rejected": {"z": "x"}}, "rejected"),
    ],
)
def test_boot_record_errors_name_the_field(change: dict[str, object], field: str) -> None:
    d = {**BootRecord(active="a", previous="b").to_dict(), **change}
    with pytest.raises(StoreError) as e:
        BootRecord.from_dict(d, "/s/boot.json")
    assert str(e.value).startswith(f"/s/boot.json: {field}:")


def test_read_boot_record_none_until_flashed_then_round_trip(tmp_path: Path) -> None:
    root = store.init_store(tmp_path / "s").root
    assert store.read_boot_record(root) is None
    with pytest.raises(StoreError, match="no firmware flashed"):
        store.active_image(root)
    record = BootRecord(active="b", previous="a", state="trial", trial_boots=2)
    store.write_boot_record(root, record)
    assert store.read_boot_record(root) == record


def test_torn_boot_record_is_named(tmp_path: Path) -> None:
    lay = store.init_store(tmp_path / "s")
    lay.boot_record.write_text('{"active": "a", "prev')
    with pytest.raises(StoreError, match=re.escape("boot.json: not valid JSON")):
        store.read_boot_record(lay.root)


def test_manifest_errors_name_the_field() -> None:
    good = ImageManifest("1", "0" * 64, 10, "t", "3.11", "m:f").to_dict()
    assert ImageManifest.from_dict(good, "m.json").sha256 == "0" * 64
    for change, field in (
        ({"sha256": "xyz"}, "sha256"),
        ({"size_bytes": 0}, "size_bytes"),
        ({"version": 3}, "version"),
    ):
        with pytest.raises(StoreError, match=re.escape(f"m.json: {field}:")):
            ImageManifest.from_dict({**good, **change}, "m.json")
    with pytest.raises(StoreError, match=re.escape("m.json: entry: missing")):
        ImageManifest.from_dict({k: v for k, v in good.items() if k != "entry"}, "m.json")


def test_verify_image_catches_a_flipped_byte_and_a_truncation(tmp_path: Path) -> None:
    root = store.init_store(tmp_path / "s").root
    content = bytes(range(256)) * 8
    fake_slot(root, "a", content)
    store.write_boot_record(root, BootRecord(active="a"))
    # No trust policy yet: nothing verifies, however intact.
    assert "no firmware trust policy" in (store.slot_usable(root, "a") or "")
    store.write_trust(root, store.TrustPolicy(allow_unsigned=True))
    slot, path, manifest = store.active_image(root)
    assert slot == "a" and path.read_bytes() == content and manifest.size_bytes == len(content)

    flipped = bytearray(content)
    flipped[1000] ^= 0x01
    path.write_bytes(bytes(flipped))
    with pytest.raises(StoreError, match="sha256") as e:
        store.active_image(root)
    assert str(path) in str(e.value)
    path.write_bytes(content[:-1])
    assert "size" in (store.slot_usable(root, "a") or "")
    path.unlink()
    assert "missing" in (store.slot_usable(root, "a") or "")
    assert "manifest.json: missing" in (store.slot_usable(root, "b") or "")


# --- boot status --------------------------------------------------------------------------------


def test_report_boot_round_trip_with_own_pid(tmp_path: Path) -> None:
    root = store.init_store(tmp_path / "s").root
    assert store.read_boot_status(root) is None
    store.report_boot(str(root), "READY")
    status = store.read_boot_status(root)
    assert status is not None and status.pid == os.getpid() and status.state is EcuState.READY
    store.report_boot(root, EcuState.OFF)
    status = store.read_boot_status(root)
    assert status is not None and status.state is EcuState.OFF
    store.clear_boot_status(root)
    assert store.read_boot_status(root) is None


def test_report_boot_carries_health_and_a_sequence_number(tmp_path: Path) -> None:
    root = store.init_store(tmp_path / "s").root
    store.report_boot(
        root, "READY", healthy_s=12.3456, host_link_up=True, internal_faults=2, unsigned_store=True
    )
    first = store.read_boot_status(root)
    assert first is not None
    assert (first.healthy_s, first.host_link_up, first.internal_faults, first.unsigned_store) == (
        12.346,
        True,
        2,
        True,
    )
    store.report_boot(root, "READY")
    second = store.read_boot_status(root)
    assert second is not None and second.seq == first.seq + 1 and not second.host_link_up


def test_a_boot_status_from_before_health_reads_as_unhealthy(tmp_path: Path) -> None:
    lay = store.init_store(tmp_path / "s")
    lay.boot_status.write_text(json.dumps({"pid": 7, "state": "READY", "t_unix": 1.0}))
    status = store.read_boot_status(lay.root)
    assert status == store.BootStatus(pid=7, state=EcuState.READY, t_unix=1.0)
    assert status.healthy_s == 0.0 and not status.host_link_up
    lay.boot_status.write_text(json.dumps({"pid": 7, "state": "READY", "t_unix": 1.0, "healthy_s": -1}))
    with pytest.raises(StoreError, match="healthy_s"):
        store.read_boot_status(lay.root)


def test_report_boot_refuses_unknown_state(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="'ARMED' is not an EcuState"):
        store.report_boot(tmp_path, "ARMED")


# --- calibration choice -------------------------------------------------------------------------


def test_usable_calibration_prefers_current_then_previous_then_none(tmp_path: Path) -> None:
    lay = store.init_store(tmp_path / "s")
    choice = store.usable_calibration(lay.root)
    assert choice.path is None and choice.calibration is None and choice.problems == ()

    store.write_atomic(lay.current_calibration, calibration_bytes(3))
    store.write_atomic(lay.previous_calibration, calibration_bytes(2))
    choice = store.usable_calibration(lay.root)
    assert choice.path == lay.current_calibration and choice.calibration is not None
    assert choice.calibration.version == 3

    # One flipped digit in a map: the CRC catches it and the previous calibration is used.
    text = lay.current_calibration.read_text().replace("105.333", "105.334")
    lay.current_calibration.write_text(text)
    choice = store.usable_calibration(lay.root)
    assert choice.path == lay.previous_calibration and choice.calibration is not None
    assert choice.calibration.version == 2
    assert len(choice.problems) == 1 and "current.json: crc32: mismatch" in choice.problems[0]

    lay.previous_calibration.write_bytes(b"")
    choice = store.usable_calibration(lay.root)
    assert choice.path is None and len(choice.problems) == 2


def test_store_status_summarises(tmp_path: Path) -> None:
    root = store.init_store(tmp_path / "s").root
    fake_slot(root, "a", b"image-a", version="v-a")
    store.write_boot_record(root, BootRecord(active="a"))
    store.write_atomic(store.current_calibration_path(root), calibration_bytes(4))
    store.write_trust(root, store.TrustPolicy(allow_unsigned=True))
    status = store.store_status(root)
    assert status["trust"] == {"allow_unsigned": True, "keys": []}
    assert status["boot"]["active"] == "a"
    assert status["slots"]["a"] == {"usable": True, "version": "v-a"}
    assert status["slots"]["b"] == {"empty": True}
    assert status["calibration"]["current"] == {"version": 4, "valid": True}
    assert status["calibration"]["previous"] is None
    json.dumps(status)


def test_calibration_helpers_match_the_module(tmp_path: Path) -> None:
    path = tmp_path / "c.json"
    path.write_bytes(calibration_bytes(5))
    cal = store.read_calibration_file(path)
    assert cal.version == 5 and calibration_to_dict(cal)["version"] == 5
    with pytest.raises(StoreError, match="missing"):
        store.read_calibration_file(tmp_path / "none.json")
