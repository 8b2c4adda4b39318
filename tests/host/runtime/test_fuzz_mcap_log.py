"""Fuzzing the recording reader: a log is untrusted input.

Whatever bytes a file holds (cut anywhere by a crash, bits flipped, garbage, nothing at all), reading
it either yields messages of the original recording, in order, or raises LogError naming the file,
never another exception, never a hang, never an invented message. A cut file yields exactly a
prefix of the original messages.
"""

from __future__ import annotations

import functools
import json
import math
import struct
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import can
import jsonschema
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.writer import Writer
from runtime_log_types import Faults, Mode, Point, Pose, Status

from bywire.host import log_cli
from bywire.host.runtime.log_schema import LogError, decode_object, encode_object, schema_bytes
from bywire.host.runtime.mcap_reader import McapLogReader, read_frames, read_objects
from bywire.host.runtime.mcap_recorder import McapRecorder

FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@functools.cache
def good_recording() -> bytes:
    """A small closed recording with several chunks: store objects of every field kind and frames."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "good.mcap"
        with McapRecorder(path, chunk_size=700) as rec:
            for k in range(40):
                t_s = 0.01 * k
                rec.record("/ego/pose", Pose(t_s, float(k), v_mps=math.nan if k % 7 == 0 else 1.0))
                if k % 5 == 0:
                    rec.record(
                        "/status",
                        Status(
                            t_s=t_s,
                            mode=Mode(k % 3),
                            faults=Faults(k % 8),
                            speed_mps=math.inf,
                            gap_m=None,
                            counter=k,
                            engaged=bool(k % 2),
                            note=f"n{k}",
                            blob=bytes([k]),
                            path=(Point(1.0, 2.0),),
                            corner=(0.0, -0.0),
                            modes=[Mode.ARMED],
                            samples=np.arange(k % 4, dtype=np.float32),
                        ),
                    )
                rec.record_frame(
                    "vehicle", can.Message(timestamp=t_s, arbitration_id=k, data=bytes([k] * (k % 9)))
                )
        return path.read_bytes()


def _key(entry: Any) -> tuple[str, int, str]:
    return entry.topic, entry.log_time_ns, json.dumps(entry.raw, sort_keys=True)


@functools.cache
def good_entries() -> list[tuple[str, int, str]]:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "good.mcap"
        path.write_bytes(good_recording())
        return [_key(e) for e in read_objects(path)]


def _read_all(path: Path) -> Iterator[tuple[str, int, str]]:
    for entry in read_objects(path):
        yield _key(entry)


def _is_subsequence(part: list[Any], whole: list[Any]) -> bool:
    it = iter(whole)
    return all(any(x == y for y in it) for x in part)


def _check(path: Path, data: bytes) -> list[tuple[str, int, str]]:
    """Read `data` every way the tools do; only LogError may come out. Returns the messages read."""
    path.write_bytes(data)
    got: list[tuple[str, int, str]] = []
    try:
        for key in _read_all(path):
            got.append(key)
    except LogError as exc:
        assert exc.path == str(path) and str(exc).startswith(str(path))
    for reader in (lambda: list(read_frames(path)), lambda: log_cli.log_info(path)):
        try:
            reader()
        except LogError as exc:
            assert exc.path == str(path)
    return got


def test_the_good_recording_reads_back_whole() -> None:
    assert len(good_entries()) == 40 + 8 + 40


def _record_boundaries(data: bytes) -> list[tuple[int, int]]:
    """(offset, length) of the file's top-level records, walked independently of the reader."""
    out, pos = [], 8
    while pos + 9 <= len(data):
        opcode, length = struct.unpack_from("<BQ", data, pos)
        out.append((pos, length))
        pos += 9 + length
        if opcode == 0x02:  # footer, then the closing magic
            break
    return out


def test_cut_anywhere_yields_a_prefix_and_says_incomplete(tmp_path: Path) -> None:
    """Cut at every interesting place: each record's start, inside its opcode/length, its body, its end."""
    data = good_recording()
    path = tmp_path / "whole.mcap"
    path.write_bytes(data)
    full = [(m.topic, m.log_time_ns, m.data) for m in McapLogReader(path).messages()]
    cuts = set(range(0, 12))
    for offset, length in _record_boundaries(data):
        cuts |= {
            offset - 1,
            offset,
            offset + 1,
            offset + 8,
            offset + 9,
            offset + 10,
            offset + 9 + length // 2,
        }
    cuts |= {len(data) - k for k in range(0, 9)}
    assert len(cuts) > 500
    path = tmp_path / "cut.mcap"
    for n in sorted(c for c in cuts if 0 <= c <= len(data)):
        path.write_bytes(data[:n])
        reader = McapLogReader(path)
        try:
            got = [(m.topic, m.log_time_ns, m.data) for m in reader.messages()]
        except LogError as exc:
            assert n < 8, (n, exc)  # only a file without even the magic is refused outright
            continue
        assert got == full[: len(got)], n
        assert reader.complete == (n == len(data)), n
    assert got == full


@FUZZ
@given(st.data())
def test_flipped_bytes_give_a_log_error_or_only_original_messages(data: st.DataObject) -> None:
    raw = bytearray(good_recording())
    for _ in range(data.draw(st.integers(1, 4))):
        i = data.draw(st.integers(0, len(raw) - 1))
        raw[i] ^= data.draw(st.integers(1, 255))
    with tempfile.TemporaryDirectory() as tmp:
        got = _check(Path(tmp) / "flipped.mcap", bytes(raw))
    assert _is_subsequence(got, good_entries())


@FUZZ
@given(st.binary(max_size=2048), st.booleans())
def test_garbage_is_refused_or_yields_nothing(garbage: bytes, with_magic: bool) -> None:
    payload = (b"\x89MCAP0\r\n" + garbage) if with_magic else garbage
    with tempfile.TemporaryDirectory() as tmp:
        assert _check(Path(tmp) / "garbage.mcap", payload) == []


@FUZZ
@given(st.data())
def test_spliced_recordings_never_invent_messages(data: st.DataObject) -> None:
    raw = good_recording()
    a, b = sorted(data.draw(st.tuples(st.integers(8, len(raw)), st.integers(8, len(raw)))))
    insert = data.draw(st.binary(max_size=64))
    spliced = raw[:a] + insert + raw[b:]
    with tempfile.TemporaryDirectory() as tmp:
        _check(Path(tmp) / "spliced.mcap", spliced)


JSON_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=8),
    lambda children: (
        st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=6), children, max_size=4)
    ),
    max_leaves=12,
)


def _pose_like() -> st.SearchStrategy[dict[str, Any]]:
    keys = st.sampled_from(["t_s", "x_m", "v_mps", "source", "other"])
    values = JSON_VALUES | st.sampled_from(["NaN", "Infinity", "-Infinity", "gps", "odometry"])
    return st.dictionaries(keys, values, max_size=5)


@FUZZ
@given(st.lists(_pose_like() | JSON_VALUES, min_size=1, max_size=5))
def test_well_framed_files_with_hostile_json_decode_or_refuse(messages: list[Any]) -> None:
    """A valid MCAP file claiming the registered schema `test.Pose`, with arbitrary JSON payloads."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "hostile.mcap"
        with open(path, "wb") as f:
            writer = Writer(f)
            writer.start()
            schema_id = writer.register_schema("test.Pose", "jsonschema", schema_bytes(Pose))
            channel_id = writer.register_channel("/ego/pose", "json", schema_id)
            for k, msg in enumerate(messages):
                writer.add_message(channel_id, k, json.dumps(msg).encode(), k)
            writer.finish()
        try:
            entries = list(read_objects(path))
        except LogError as exc:
            assert exc.path == str(path) and "topic '/ego/pose'" in str(exc)
            return
        for entry, msg in zip(entries, messages, strict=True):
            assert isinstance(entry.obj, Pose) and entry.raw == msg
            assert (
                entry.obj == decode_object(Pose, msg)
                or math.isnan(entry.obj.v_mps)
                or math.isnan(entry.obj.x_m)
            )


SCHEMA_LIKE = st.recursive(
    JSON_VALUES,
    lambda children: st.dictionaries(
        st.sampled_from(
            ["type", "properties", "items", "default", "t_s", "x_m", "v_mps", "source", "number"]
        ),
        children | st.sampled_from(["number", "object", "array", "string"]),
        max_size=5,
    ),
    max_leaves=16,
)


@FUZZ
@given(
    st.sampled_from(["test.Pose", "elsewhere.Thing"]),
    SCHEMA_LIKE,
    st.lists(_pose_like() | JSON_VALUES, min_size=1, max_size=4),
)
def test_hostile_file_schemas_decode_or_refuse(name: str, file_schema: Any, messages: list[Any]) -> None:
    """The schema a file holds steers how its messages decode (the writer's convention, the fields it
    knew): whatever it says, reading yields objects or refuses with LogError."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "hostile_schema.mcap"
        with open(path, "wb") as f:
            writer = Writer(f)
            writer.start()
            schema_id = writer.register_schema(name, "jsonschema", json.dumps(file_schema).encode())
            channel_id = writer.register_channel("/x", "json", schema_id)
            for k, msg in enumerate(messages):
                writer.add_message(channel_id, k, json.dumps(msg).encode(), k)
            writer.finish()
        try:
            entries = list(read_objects(path))
        except LogError as exc:
            assert exc.path == str(path) and "topic '/x'" in str(exc)
            return
        assert len(entries) == len(messages)
        if name == "test.Pose":
            assert all(isinstance(e.obj, Pose) for e in entries)


FLOATS = st.floats(allow_nan=True, allow_infinity=True) | st.sampled_from([math.nan, -0.0, 5e-324])


@FUZZ
@given(FLOATS, FLOATS, FLOATS, st.lists(FLOATS.filter(lambda x: x == x), min_size=2, max_size=2))
def test_any_float_round_trips_bit_exact_as_valid_json(
    t_s: float, x_m: float, v_mps: float, corner: list[float]
) -> None:
    pose = Pose(t_s, x_m, v_mps)
    status = Status(
        t_s=t_s,
        mode=Mode.OFF,
        faults=Faults.NONE,
        speed_mps=x_m,
        gap_m=v_mps if v_mps == v_mps else None,
        counter=0,
        engaged=False,
        note="",
        blob=b"",
        path=(Point(x_m, v_mps),),
        corner=(corner[0], corner[1]),
        modes=[],
        samples=np.zeros(0),
    )
    for obj in (pose, status):
        data = encode_object(obj)
        doc = json.loads(data, parse_constant=lambda name: pytest.fail(f"{name} is not JSON"))
        jsonschema.Draft202012Validator(json.loads(schema_bytes(type(obj)))).validate(doc)
        got = decode_object(type(obj), data)
        assert encode_object(got) == data
    got_pose = decode_object(Pose, encode_object(pose))
    for got, want in zip((got_pose.t_s, got_pose.x_m, got_pose.v_mps), (t_s, x_m, v_mps), strict=True):
        # Bit-exact (-0.0 stays -0.0); every NaN reads back as NaN (JSON keeps no NaN payload).
        assert math.isnan(got) if want != want else struct.pack("<d", got) == struct.pack("<d", want)
