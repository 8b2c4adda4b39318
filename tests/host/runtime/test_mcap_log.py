"""MCAP recording of the store's topics and the CAN buses (the host runtime's record and replay): exact round
trips, files that the standard `mcap` reader opens, survival of a SIGKILLed recorder, `bywire log info|plot`,
and the live Foxglove WebSocket view speaking the same schema."""

from __future__ import annotations

import argparse
import base64
import json
import math
import os
import signal
import socket
import struct
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can
import jsonschema
import numpy as np
import pytest
from mcap.exceptions import EndOfFile
from mcap.reader import make_reader
from mcap.records import Channel, Message
from mcap.stream_reader import StreamReader
from mcap.writer import Writer
from runtime_log_types import Faults, Mode, Point, Pose, Source, Status, Tick

from bywire.host import log_cli
from bywire.host.runtime.can_frame import CAN_FRAME_SCHEMA
from bywire.host.runtime.live_view import LiveView
from bywire.host.runtime.log_schema import LogError, decode_object, encode_object, json_schema, register_type
from bywire.host.runtime.mcap_reader import McapLogReader, read_frames, read_objects
from bywire.host.runtime.mcap_recorder import McapRecorder
from bywire.host.runtime.store import ObjectStore

TESTS_DIR = Path(__file__).resolve().parents[2]  # tests/, where the shared helpers are


def _status(t_s: float, **changes: Any) -> Status:
    fields: dict[str, Any] = dict(
        t_s=t_s,
        mode=Mode.ACTIVE,
        faults=Faults.CRC | Faults.STALE,
        speed_mps=math.nan,
        gap_m=None,
        counter=2**70,
        engaged=True,
        note='héllo \u2603 "quoted" NaN',
        blob=bytes(range(256)),
        path=(Point(1.0, -math.inf), Point(-0.0, 5e-324)),
        corner=(math.inf, 0.1 + 0.2),
        modes=[Mode.OFF, Mode.ARMED],
        samples=np.array([[1.0, np.nan], [np.inf, -0.0]]),
        lead=Point(0.1, math.nan),
    )
    fields.update(changes)
    return Status(**fields)


def _same_float(a: float, b: float) -> bool:
    return struct.pack("<d", a) == struct.pack("<d", b)  # bit-exact: NaN == NaN, -0.0 != 0.0


def _assert_same_status(got: Status, want: Status) -> None:
    for name in ("t_s", "speed_mps"):
        assert _same_float(getattr(got, name), getattr(want, name)), name
    assert (got.mode, got.faults, got.gap_m, got.counter, got.engaged, got.note, got.blob) == (
        want.mode,
        want.faults,
        want.gap_m,
        want.counter,
        want.engaged,
        want.note,
        want.blob,
    )
    assert type(got.mode) is Mode and type(got.faults) is Faults
    assert [(p.x_m, p.y_m) for p in got.path] == [(p.x_m, p.y_m) for p in want.path]
    assert all(
        _same_float(a, b)
        for pg, pw in zip(got.path, want.path, strict=True)
        for a, b in ((pg.x_m, pw.x_m), (pg.y_m, pw.y_m))
    )
    assert isinstance(got.path, tuple) and isinstance(got.modes, list) and got.modes == want.modes
    assert all(_same_float(a, b) for a, b in zip(got.corner, want.corner, strict=True))
    assert got.samples.dtype == want.samples.dtype and got.samples.shape == want.samples.shape
    assert got.samples.tobytes() == np.ascontiguousarray(want.samples).tobytes()
    if want.lead is None:
        assert got.lead is None
    else:
        assert got.lead is not None and _same_float(got.lead.x_m, want.lead.x_m)
        assert _same_float(got.lead.y_m, want.lead.y_m)


ARRAYS = [
    np.array([[1.0, np.nan], [np.inf, -0.0]]),
    np.arange(12, dtype=np.int16).reshape(3, 4).T,  # not C-contiguous
    np.array([True, False]),
    np.zeros((0, 3), dtype=np.float32),
    np.array(7, dtype=np.uint64),  # 0-d
    np.array([1 + 2j, np.nan * 1j], dtype=np.complex64),
    np.frombuffer(struct.pack("<d", float.fromhex("0x1.8p+1")) + b"\x01\x00\x00\x00\x00\x00\xf8\x7f", "<f8"),
]


def test_round_trip_of_every_field_kind(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    sent = [
        _status(0.001 * k, samples=arr, gap_m=None if k % 2 else -1.5, lead=None if k == 3 else Point(k, -k))
        for k, arr in enumerate(ARRAYS)
    ]
    poses = [
        Pose(0.5, 1.0),
        Pose(1.0, math.inf, -0.0, Source.ODOMETRY),
        Pose(np.float64(2.0), np.float64(np.nan)),
    ]
    with McapRecorder(path) as rec:
        for status in sent:
            rec.record("/status", status)
        for pose in poses:
            rec.record("/ego/pose", pose)
    entries = list(read_objects(path))
    statuses = [e for e in entries if e.topic == "/status"]
    assert len(statuses) == len(sent)
    for entry, want in zip(statuses, sent, strict=True):
        assert entry.schema_name == "test.Status" and isinstance(entry.obj, Status)
        assert entry.log_time_ns == round(want.t_s * 1e9)
        _assert_same_status(entry.obj, want)
        assert not entry.obj.samples.flags.writeable  # decoded objects are immutable all the way down
    got_poses = [e.obj for e in entries if e.topic == "/ego/pose"]
    assert got_poses[0] == poses[0] and got_poses[1].source is Source.ODOMETRY
    assert math.isinf(got_poses[1].x_m) and _same_float(got_poses[1].v_mps, -0.0)
    assert type(got_poses[2].t_s) is float and got_poses[2].t_s == 2.0 and math.isnan(got_poses[2].x_m)
    # The JSON as stored: a NaN field left out, infinities as the numbers +-1e999, enums as values.
    raw = statuses[0].raw
    assert "speed_mps" not in raw and "lead" not in statuses[3].raw
    assert raw["path"][0]["y_m"] == -math.inf and raw["corner"][0] == math.inf
    assert raw["mode"] == 2 and raw["faults"] == 6 and raw["gap_m"] == -1.5 and "gap_m" not in statuses[1].raw
    assert [e.obj for e in read_objects(path, topics=["/ego/pose"])] == got_poses


def test_unregistered_types_decode_as_dicts_with_non_finite_floats_restored(tmp_path: Path) -> None:
    @dataclass(frozen=True)
    class Local:  # never registered: a reader must not import or guess it
        t_s: float
        value: float
        label: str
        items: tuple[float, ...]

    path = tmp_path / "run.mcap"
    with McapRecorder(path) as rec:
        rec.record("/local", Local(1.0, math.nan, "NaN", (math.inf, 2.0)))
    [entry] = read_objects(path)
    assert isinstance(entry.obj, dict) and entry.schema_name.endswith("Local")
    assert math.isnan(entry.obj["value"]) and entry.obj["label"] == "NaN"  # a string field stays a string
    assert entry.obj["items"] == [math.inf, 2.0]
    assert "value" not in entry.raw  # left out in the file, NaN again in the dict


def _no_constants(name: str) -> None:
    raise AssertionError(f"{name} is not JSON (RFC 8259)")


def test_every_message_is_json_that_validates_against_its_own_schema(tmp_path: Path) -> None:
    """What tools other than ours do with a recording: parse strict JSON, validate it by its schema."""
    path = tmp_path / "run.mcap"
    with McapRecorder(path) as rec:
        for k, lead in enumerate((None, Point(math.nan, -math.inf), Point(1.0, 2.0))):
            # NaN and None where a field can be left out; the documented null cases (NaN in an
            # array or in a float | None) are kept out, as the types we record keep them out.
            rec.record("/status", _status(0.1 * k, lead=lead, gap_m=None if k else math.inf))
            rec.record("/ego/pose", Pose(0.1 * k, math.nan, -math.inf))
    with open(path, "rb") as f:
        seen = 0
        for schema, _, message in make_reader(f).iter_messages():
            doc = json.loads(message.data, parse_constant=_no_constants)
            jsonschema.Draft202012Validator(json.loads(schema.data)).validate(doc)
            seen += 1
    assert seen == 6
    statuses = [e.obj for e in read_objects(path, topics=["/status"])]
    assert statuses[0].gap_m == math.inf and statuses[1].gap_m is None and statuses[0].lead is None
    assert (
        statuses[1].lead is not None
        and math.isnan(statuses[1].lead.x_m)
        and statuses[1].lead.y_m == -math.inf
    )
    poses = [e.obj for e in read_objects(path, topics=["/ego/pose"])]
    assert all(math.isnan(p.x_m) and p.v_mps == -math.inf for p in poses)


def test_nan_where_no_field_can_be_left_out_is_null_and_reads_back() -> None:
    status = _status(0.0, gap_m=math.nan, corner=(math.nan, 1.0))
    raw = json.loads(encode_object(status))
    assert raw["gap_m"] is None and raw["corner"] == [None, 1.0]
    got = decode_object(Status, raw)
    assert math.isnan(got.gap_m) and math.isnan(got.corner[0])  # type: ignore[arg-type]
    assert decode_object(Status, {k: v for k, v in raw.items() if k != "gap_m"}).gap_m is None


def _legacy_file(path: Path, schema: dict[str, Any], messages: list[dict[str, Any]]) -> None:
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start()
        schema_id = writer.register_schema(str(schema["title"]), "jsonschema", json.dumps(schema).encode())
        channel = writer.register_channel("/status", "json", schema_id)
        for k, msg in enumerate(messages):
            writer.add_message(channel, k, json.dumps(msg).encode(), k)
        writer.finish()


def _older_schema(schema: dict[str, Any]) -> dict[str, Any]:
    """A schema as the older convention wrote it: no default annotations, every field without a
    class default required."""
    props = {k: {kk: vv for kk, vv in v.items() if kk != "default"} for k, v in schema["properties"].items()}
    return {**schema, "properties": props}


def test_recordings_of_the_older_convention_still_decode(tmp_path: Path) -> None:
    """Before: NaN, Infinity, -Infinity as strings, None as null, every field written."""
    old = dict(json.loads(encode_object(_status(1.0, speed_mps=1.0, lead=Point(0.0, 0.0)))))
    old.update(speed_mps="NaN", gap_m=None, lead={"x_m": "Infinity", "y_m": "-Infinity"}, corner=["NaN", 2.0])
    path = tmp_path / "old.mcap"
    _legacy_file(path, _older_schema(json_schema(Status)), [old])
    [entry] = read_objects(path)
    got = entry.obj
    assert isinstance(got, Status) and math.isnan(got.speed_mps) and got.gap_m is None  # null was None then
    assert got.lead == Point(math.inf, -math.inf) and math.isnan(got.corner[0])
    unregistered = tmp_path / "old_dict.mcap"
    _legacy_file(unregistered, {**_older_schema(json_schema(Status)), "title": "elsewhere.Status"}, [old])
    [entry] = read_objects(unregistered)
    assert isinstance(entry.obj, dict) and math.isnan(entry.obj["speed_mps"]) and entry.obj["gap_m"] is None
    assert entry.obj["lead"] == {"x_m": math.inf, "y_m": -math.inf}


def test_a_field_its_writer_did_not_know_takes_the_class_default(tmp_path: Path) -> None:
    schema = json_schema(Pose)
    older = {**schema, "properties": {k: v for k, v in schema["properties"].items() if k != "v_mps"}}
    path = tmp_path / "older.mcap"
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start()
        older_id = writer.register_schema("test.Pose", "jsonschema", json.dumps(older).encode())
        today_id = writer.register_schema("test.Pose", "jsonschema", json.dumps(schema).encode())
        for topic, schema_id in (("/older", older_id), ("/today", today_id)):
            channel = writer.register_channel(topic, "json", schema_id)
            writer.add_message(channel, 1, b'{"t_s":0.0,"x_m":1.0}', 1)
        writer.finish()
    got = {e.topic: e.obj for e in read_objects(path)}
    assert got["/older"] == Pose(0.0, 1.0)  # v_mps did not exist yet: its default
    assert math.isnan(got["/today"].v_mps)  # v_mps was NaN: left out


def test_schema_is_one_type_per_field_as_foxglove_parses_it() -> None:
    schema = json_schema(Status)
    assert schema["type"] == "object" and schema["title"] == "test.Status"
    props = schema["properties"]
    for name, prop in props.items():
        assert isinstance(prop["type"], str), name
        if prop["type"] == "array":
            assert isinstance(prop["items"]["type"], str) and "contentEncoding" not in prop["items"], name
            assert "oneOf" not in prop["items"], name
    assert props["mode"]["oneOf"] == [
        {"title": "OFF", "const": 0},
        {"title": "ARMED", "const": 1},
        {"title": "ACTIVE", "const": 2},
    ]
    assert props["blob"] == {"type": "string", "contentEncoding": "base64"}
    assert props["lead"]["properties"]["x_m"] == {"type": "number"}
    # A float field may be left out (NaN), an optional one too (None, its default): neither is required.
    assert set(schema["required"]) == {
        "mode",
        "faults",
        "counter",
        "engaged",
        "note",
        "blob",
        "path",
        "corner",
        "modes",
        "samples",
    }
    assert props["gap_m"] == {"type": "number", "default": None} and props["lead"]["default"] is None
    assert props["corner"]["minItems"] == props["corner"]["maxItems"] == 2


def test_unsupported_fields_are_refused_naming_the_field() -> None:
    @dataclass(frozen=True)
    class Nested:
        t_s: float
        grid: tuple[tuple[float, ...], ...]

    @dataclass(frozen=True)
    class Mapping:
        t_s: float
        gains: dict[str, float]

    @dataclass(frozen=True)
    class Mixed:
        t_s: float
        pair: tuple[float, str]

    with pytest.raises(LogError, match=r"Nested\.grid: .*arrays of arrays"):
        register_type(Nested)
    with pytest.raises(LogError, match=r"Mapping\.gains: type dict\[str, float\] is not supported"):
        encode_object(Mapping(0.0, {}))
    with pytest.raises(LogError, match=r"Mixed\.pair: .*tuples must hold one type"):
        json_schema(Mixed)
    with pytest.raises(LogError, match=r"Pose\.x_m: expected a number, got str"):
        encode_object(Pose(0.0, "fast"))  # type: ignore[arg-type]
    with pytest.raises(LogError, match=r"Status\.path\[1\]\.y_m: expected a number, got a string"):
        raw = json.loads(encode_object(_status(0.0)))
        raw["path"][1]["y_m"] = "fast"
        decode_object(Status, raw)
    with pytest.raises(LogError, match=r"fields \['extra'\] are not in Pose"):
        decode_object(Pose, {"t_s": 0.0, "x_m": 1.0, "extra": 1})
    with pytest.raises(LogError, match=r"field 'mode' of Status is missing"):
        raw = json.loads(encode_object(_status(0.0)))
        del raw["mode"]
        decode_object(Status, raw)

    @dataclass(frozen=True)
    class Maybe:
        t_s: float
        gaps_m: tuple[float | None, ...]

    with pytest.raises(LogError, match=r"Maybe\.gaps_m: .*may be None would be null"):
        json_schema(Maybe)


def test_recorder_as_store_tap_refuses_a_second_type_and_use_after_close(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    store = ObjectStore()
    rec = McapRecorder(path)
    store.add_tap(rec.record)
    for k in range(5):
        store.publish("/ego/pose", Pose(0.1 * k, float(k)))
    with pytest.raises(LogError, match=r"run\.mcap: topic '/ego/pose' carries Pose, not Tick"):
        rec.record("/ego/pose", Tick(1.0, 1, 0.0))
    rec.close()
    rec.close()  # idempotent
    with pytest.raises(LogError, match="the recording is closed"):
        rec.record("/ego/pose", Pose(1.0, 1.0))
    assert [e.obj.x_m for e in read_objects(path)] == [0.0, 1.0, 2.0, 3.0, 4.0]


def _frames() -> list[tuple[str, can.Message]]:
    return [
        ("vehicle", can.Message(timestamp=1.0, arbitration_id=0x123, data=b"\x01\x02", is_extended_id=False)),
        ("vehicle", can.Message(timestamp=1.001, arbitration_id=0x1ABCDEF0, data=bytes(8), is_rx=False)),
        (
            "host_link",
            can.Message(
                timestamp=1.002, arbitration_id=0x701, is_extended_id=False, dlc=1, is_remote_frame=True
            ),
        ),
        (
            "host_link",
            can.Message(
                timestamp=1.003,
                arbitration_id=0x18FF0001,
                data=bytes(range(64)),
                is_fd=True,
                bitrate_switch=True,
                error_state_indicator=True,
            ),
        ),
        ("vehicle", can.Message(timestamp=1.004, is_error_frame=True, dlc=0)),
    ]


def test_frames_round_trip(tmp_path: Path) -> None:
    path = tmp_path / "frames.mcap"
    with McapRecorder(path) as rec:
        for bus, msg in _frames():
            rec.record_frame(bus, msg)
        rec.record_frame("vehicle", can.Message(timestamp=1.6e9, arbitration_id=5), t_s=2.0)  # epoch stamp
    frames = list(read_frames(path))
    want = [msg for _, msg in _frames()]
    assert len(frames) == len(want) + 1
    for got, (bus, msg) in zip(frames, _frames(), strict=False):
        assert got.channel == bus
        assert got.equals(msg, timestamp_delta=0.0, check_channel=False, check_direction=True), (got, msg)
    assert frames[-1].timestamp == 2.0  # put on the run's clock by t_s
    assert [m.arbitration_id for m in read_frames(path, bus="host_link")] == [0x701, 0x18FF0001]
    entries = list(read_objects(path, topics=["/can/vehicle"]))
    assert [e.log_time_ns for e in entries] == [1_000_000_000, 1_001_000_000, 1_004_000_000, 2_000_000_000]
    assert entries[0].schema_name == CAN_FRAME_SCHEMA and entries[0].raw["data"] == [1, 2]


def test_standard_mcap_reader_opens_our_closed_files(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    with McapRecorder(path, chunk_size=1024) as rec:
        for k in range(200):
            rec.record("/ego/pose", Pose(0.01 * k, float(k)))
            if k % 10 == 0:
                rec.record("/status", _status(0.01 * k))
        for bus, msg in _frames():
            rec.record_frame(bus, msg)
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert {s.name: s.encoding for s in summary.schemas.values()} == {
            "test.Pose": "jsonschema",
            "test.Status": "jsonschema",
            CAN_FRAME_SCHEMA: "jsonschema",
        }
        assert {c.topic: c.message_encoding for c in summary.channels.values()} == {
            "/ego/pose": "json",
            "/status": "json",
            "/can/vehicle": "json",
            "/can/host_link": "json",
        }
        assert summary.statistics.message_count == 200 + 20 + 5 and len(summary.chunk_indexes) > 5
        messages = list(reader.iter_messages(topics=["/ego/pose"]))
    assert [json.loads(m.data)["x_m"] for _, _, m in messages] == [float(k) for k in range(200)]
    assert McapLogReader(path).complete is False  # not read yet
    reader2 = McapLogReader(path)
    assert sum(1 for _ in reader2.messages()) == 225 and reader2.complete


CHILD = """
import sys, time
from runtime_log_types import Tick
from bywire.host.runtime.mcap_recorder import McapRecorder
from bywire.host.runtime.store import ObjectStore

rec = McapRecorder(sys.argv[1], flush_interval_s=float(sys.argv[2]))
store = ObjectStore()
store.add_tap(rec.record)
start = time.monotonic()
seq = 0
while True:
    now = time.monotonic()
    store.publish("/tick", Tick(t_s=now - start, seq=seq, wall_s=now))
    seq += 1
    if seq == 300:
        print("recording", flush=True)
    time.sleep(0.001)
"""


@pytest.mark.parametrize("compression", ["lz4", "none"])
def test_other_chunk_compressions_read_back(tmp_path: Path, compression: str) -> None:
    path = tmp_path / f"{compression}.mcap"
    with McapRecorder(path, chunk_size=512, compression=compression) as rec:
        for k in range(100):
            rec.record("/ego/pose", Pose(0.01 * k, float(k)))
    assert [e.obj.x_m for e in read_objects(path)] == [float(k) for k in range(100)]
    with open(path, "rb") as f:
        assert sum(1 for _ in make_reader(f, validate_crcs=True).iter_messages()) == 100


def _library_prefix(path: Path) -> list[tuple[str, int, bytes]]:
    """What the mcap library's StreamReader alone yields from a cut file before it stops."""
    topics: dict[int, str] = {}
    out = []
    try:
        for record in StreamReader(str(path), validate_crcs=True).records:
            if isinstance(record, Channel):
                topics[record.id] = record.topic
            elif isinstance(record, Message):
                out.append((topics[record.channel_id], record.log_time, bytes(record.data)))
    except (EndOfFile, struct.error):  # how it ends a file cut inside a record
        pass
    return out


def test_a_file_cut_at_60_percent_reads_as_far_as_the_mcap_stream_reader_gets(tmp_path: Path) -> None:
    path = tmp_path / "known.mcap"
    _known_recording(path)
    full = [(m.topic, m.log_time_ns, m.data) for m in McapLogReader(path).messages()]
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 6 // 10])
    reader = McapLogReader(cut)
    ours = [(m.topic, m.log_time_ns, m.data) for m in reader.messages()]
    assert ours == _library_prefix(cut) == full[: len(ours)]
    assert len(full) // 3 < len(ours) < len(full) and not reader.complete and "cut short" in reader.end_note


def _readable(path: Path) -> int:
    """How many messages a reader gets from the file now (0 while it holds none yet)."""
    try:
        return sum(1 for _ in read_objects(path))
    except Exception:  # not even a header yet
        return 0


def test_recording_survives_sigkill_and_loses_nothing_already_flushed(tmp_path: Path) -> None:
    """A recorder killed mid-run leaves a gap-free prefix readable, holding at least everything that
    was readable before the kill: the recorder writes as it runs, not at close. (How much a kill
    loses on a given machine is a speed: `bywire bench runtime` measures the flush interval.)"""
    path = tmp_path / "killed.mcap"
    flush_interval_s = 0.1
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(TESTS_DIR), os.environ.get("PYTHONPATH", "")]))
    child = subprocess.Popen(
        [sys.executable, "-c", CHILD, str(path), str(flush_interval_s)],
        stdout=subprocess.PIPE,
        env=env,
        text=True,
    )
    try:
        assert child.stdout is not None and child.stdout.readline().strip() == "recording"
        hang_limit = time.monotonic() + 30.0  # a recorder that never writes, not a slow machine
        while (before_kill := _readable(path)) < 300:
            assert time.monotonic() < hang_limit, f"only {before_kill} messages readable while recording"
            time.sleep(0.02)
        child.send_signal(signal.SIGKILL)
        child.wait(timeout=10)
    finally:
        child.kill()
    ticks = list(read_objects(path))
    assert not _complete(path)
    seqs = [e.obj.seq for e in ticks]
    assert seqs == list(range(len(seqs))) and len(seqs) >= before_kill  # a gap-free prefix, nothing lost
    info = log_cli.log_info(path)
    assert info["complete"] is False and info["topics"]["/tick"]["count"] == len(seqs)
    assert "not closed" in info["ending"] or "cut short" in info["ending"]


def test_a_quiet_recorder_still_writes_within_the_flush_interval(tmp_path: Path) -> None:
    path = tmp_path / "quiet.mcap"
    rec = McapRecorder(path, flush_interval_s=0.05)
    try:
        rec.record("/ego/pose", Pose(1.0, 1.0))
        # Nothing else is recorded: the background thread must write the chunk by itself (judged
        # with a hang bound, not a speed bound: a stalled machine may take longer than the interval).
        hang_limit = time.monotonic() + 10.0
        while _readable(path) == 0:
            assert time.monotonic() < hang_limit, "the quiet recorder never wrote its message"
            time.sleep(0.01)
        assert [e.obj for e in read_objects(path)] == [Pose(1.0, 1.0)] and not _complete(path)
    finally:
        rec.close()
    assert _complete(path)


def _complete(path: Path) -> bool:
    reader = McapLogReader(path)
    for _ in reader.messages():
        pass
    return reader.complete


def _known_recording(path: Path) -> None:
    """/ego/pose at 100 Hz for 3 s with 0.3 s missing at 1.5 s, /status at 10 Hz, CAN at 50 Hz."""
    with McapRecorder(path, chunk_size=4096) as rec:
        for k in range(301):
            t_s = 10.0 + 0.01 * k
            if not 1.5 < t_s - 10.0 < 1.8:
                rec.record("/ego/pose", Pose(t_s, float(k), v_mps=math.sin(k / 20)))
            if k % 10 == 0:
                rec.record("/status", _status(t_s, counter=k, lead=Point(k, 0.0) if k % 20 else None))
            if k % 2 == 0:
                rec.record_frame(
                    "vehicle", can.Message(timestamp=t_s, arbitration_id=0x100 + k % 3, data=b"\x00")
                )


def _run_log(*argv: str) -> int:
    parser = argparse.ArgumentParser()
    log_cli.add_arguments(parser.add_subparsers(dest="log_command", required=True))
    return log_cli.main(parser.parse_args(list(argv)))


def test_log_info_counts_rates_and_gaps(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "known.mcap"
    _known_recording(path)
    out = tmp_path / "info.json"
    assert _run_log("info", str(path), "--json", str(out)) == 0
    printed = capsys.readouterr().out
    assert "complete" in printed and "/ego/pose" in printed and "test.Status" in printed
    info = json.loads(out.read_text())
    assert info["file"] == str(path) and info["complete"] is True
    assert info["duration_s"] == pytest.approx(3.0)
    pose = info["topics"]["/ego/pose"]
    assert pose["schema"] == "test.Pose" and pose["count"] == 301 - 29
    assert pose["first_s"] == pytest.approx(10.0) and pose["last_s"] == pytest.approx(13.0)
    assert pose["gaps"] == 1 and pose["max_gap_s"] == pytest.approx(0.30, abs=1e-6)
    assert pose["rate_hz"] == pytest.approx((301 - 29 - 1) / 3.0)
    status = info["topics"]["/status"]
    assert status["count"] == 31 and status["rate_hz"] == pytest.approx(10.0) and status["gaps"] == 0
    can_topic = info["topics"]["/can/vehicle"]
    assert can_topic["schema"] == CAN_FRAME_SCHEMA and can_topic["count"] == 151 and can_topic["gaps"] == 0
    assert can_topic["rate_hz"] == pytest.approx(50.0)


def test_log_info_on_a_truncated_and_on_a_damaged_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "known.mcap"
    _known_recording(path)
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    assert _run_log("info", str(cut), "--json", "-") == 0
    printed = capsys.readouterr().out
    assert "NOT CLOSED" in printed
    info = json.loads(printed[printed.index("{") :])
    assert info["complete"] is False and 0 < info["topics"]["/ego/pose"]["count"] < 272
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(data[:300] + bytes([data[300] ^ 0x40]) + data[301:])
    assert _run_log("info", str(damaged)) == 2
    assert "damaged.mcap: byte" in capsys.readouterr().err
    summary_damaged = tmp_path / "summary.mcap"  # the summary has its own CRC; all messages are intact
    summary_damaged.write_bytes(data[:-100] + bytes([data[-100] ^ 0x01]) + data[-99:])
    assert _run_log("info", str(summary_damaged), "--json", str(tmp_path / "s.json")) == 0
    info = json.loads((tmp_path / "s.json").read_text())
    assert info["complete"] is False and "summary's CRC" in info["damage"]
    assert info["topics"]["/ego/pose"]["count"] == 272
    capsys.readouterr()
    assert _run_log("info", str(tmp_path / "missing.mcap")) == 2
    assert "missing.mcap: cannot open" in capsys.readouterr().err


def test_log_plot_writes_a_png_and_names_what_exists(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "known.mcap"
    _known_recording(path)
    png = tmp_path / "plots" / "signals.png"
    signals = [
        "/ego/pose.v_mps",
        "/status.mode",
        "/status.lead.x_m",
        "/status.path.1.y_m",
        "/can/vehicle.arbitration_id",
    ]
    argv = ["plot", str(path), "--output", str(png)]
    for s in signals:
        argv += ["--signal", s]
    assert _run_log(*argv) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
    capsys.readouterr()
    assert _run_log("plot", str(path), "--signal", "/nope.x") == 2
    err = capsys.readouterr().err
    assert "no such topic" in err and "/ego/pose" in err and "/can/vehicle" in err
    assert _run_log("plot", str(path), "--signal", "/status.lead.z_m") == 2
    assert "no field 'z_m' in lead (fields: x_m, y_m)" in capsys.readouterr().err
    assert _run_log("plot", str(path), "--signal", "/status.note") == 2
    assert "is a str, not a number" in capsys.readouterr().err
    assert _run_log("plot", str(path), "--signal", "/status.path") == 2
    assert "its fields: 0, 1" in capsys.readouterr().err
    assert _run_log("plot", str(path), "--signal", "/can/vehicle.dlc") == 0
    assert path.with_suffix(".png").exists()


# -- the live view: a minimal Foxglove WebSocket client on the standard library ----------------------------


class _WsClient:
    """Just enough of RFC 6455 to speak the Foxglove WebSocket protocol with the SDK's server."""

    def __init__(self, port: int) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=5)
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall(
            (
                f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
                "Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n"
            ).encode()
        )
        self.buf = b""
        while b"\r\n\r\n" not in self.buf:
            self.buf += self._recv()
        head, self.buf = self.buf.split(b"\r\n\r\n", 1)
        assert head.startswith(b"HTTP/1.1 101"), head

    def _recv(self) -> bytes:
        data = self.sock.recv(65536)
        if not data:
            raise EOFError("the server closed the connection")
        return data

    def _take(self, n: int) -> bytes:
        while len(self.buf) < n:
            self.buf += self._recv()
        out, self.buf = self.buf[:n], self.buf[n:]
        return out

    def read(self) -> tuple[int, bytes]:
        b0, b1 = self._take(2)
        n = b1 & 0x7F
        if n == 126:
            n = struct.unpack(">H", self._take(2))[0]
        elif n == 127:
            n = struct.unpack(">Q", self._take(8))[0]
        return b0 & 0x0F, self._take(n)

    def read_json(self, op: str) -> dict[str, Any]:
        while True:
            kind, payload = self.read()
            if kind == 1 and json.loads(payload)["op"] == op:
                return dict(json.loads(payload))

    def send_json(self, msg: dict[str, Any]) -> None:
        data, mask = json.dumps(msg).encode(), os.urandom(4)
        assert len(data) < 126
        masked = bytes(b ^ mask[i % 4] for i, b in enumerate(data))
        self.sock.sendall(bytes([0x81, 0x80 | len(data)]) + mask + masked)

    def close(self) -> None:
        self.sock.close()


def test_live_view_publishes_the_recorder_schema_and_messages() -> None:
    with LiveView(0) as view:
        assert view.port > 0 and view.url == f"ws://127.0.0.1:{view.port}"
        store = ObjectStore()
        store.add_tap(view.publish)
        store.publish("/ego/pose", Pose(1.0, 2.0))
        view.publish_frame("vehicle", can.Message(timestamp=1.0, arbitration_id=0x10, data=b"\x07"))
        assert set(view.topics()) == {"/ego/pose", "/can/vehicle"}
        client = _WsClient(view.port)
        try:
            assert client.read_json("serverInfo")["name"] == "bywire"
            channels: dict[str, dict[str, Any]] = {}
            while len(channels) < 2:
                for ch in client.read_json("advertise")["channels"]:
                    channels[ch["topic"]] = ch
            pose_channel = channels["/ego/pose"]
            assert pose_channel["encoding"] == "json" and pose_channel["schemaEncoding"] == "jsonschema"
            assert pose_channel["schemaName"] == "test.Pose"
            assert json.loads(pose_channel["schema"]) == json_schema(Pose)  # the recorder's schema
            assert channels["/can/vehicle"]["schemaName"] == CAN_FRAME_SCHEMA
            client.send_json(
                {"op": "subscribe", "subscriptions": [{"id": 7, "channelId": pose_channel["id"]}]}
            )
            deadline = time.monotonic() + 5.0
            while True:  # the subscription takes effect asynchronously: publish until a message arrives
                store.publish("/ego/pose", Pose(2.0, math.nan))
                client.sock.settimeout(0.2)
                try:
                    kind, payload = client.read()
                except TimeoutError:
                    assert time.monotonic() < deadline, "no message data from the live view"
                    continue
                if kind == 2 and payload[0] == 0x01:
                    break
            sub_id, log_time_ns = struct.unpack("<IQ", payload[1:13])
            assert sub_id == 7 and log_time_ns == 2_000_000_000
            assert payload[13:] == encode_object(Pose(2.0, math.nan))  # one encoder: NaN left out
        finally:
            client.close()
    view.publish("/ego/pose", Pose(3.0, 0.0))  # after close: ignored, not an error
