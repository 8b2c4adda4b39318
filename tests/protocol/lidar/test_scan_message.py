"""The LIDAR scan message (protocol/lidar/scan_message.py): round trips, each refusal naming its field, a fuzz
test (random and mutated messages give a scan or `LidarScanError`, never another exception)."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bywire.protocol.lidar.scan_message import (
    HEADER_BYTES,
    MAGIC,
    MAX_POINTS,
    POINT_BYTES,
    LidarScanError,
    ScanPayload,
    decode,
    encode,
)

FUZZ = settings(max_examples=300, deadline=None)


def _arrays(n: int = 100, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return (
        rng.uniform(-120.0, 120.0, (n, 3)).astype(np.float32),
        rng.uniform(0.0, 1.0, n).astype(np.float32),
        rng.integers(0, 64, n).astype(np.int16),
    )


def test_round_trip_keeps_points_exactly_and_reflectance_to_a_255th() -> None:
    xyz, refl, beam = _arrays()
    buf = encode(xyz, refl, beam, stamp_s=12.3, sensor_height_m=1.73)
    assert len(buf) == HEADER_BYTES + 100 * POINT_BYTES and buf[:4] == MAGIC
    out = decode(buf)
    assert isinstance(out, ScanPayload) and len(out) == 100
    np.testing.assert_array_equal(out.xyz_m, xyz)
    np.testing.assert_allclose(out.reflectance, refl, atol=0.5 / 255.0 + 1e-7)
    np.testing.assert_array_equal(out.beam, beam)
    assert (out.stamp_s, out.sensor_height_m, out.beams) == (12.3, pytest.approx(1.73), 64)
    assert (
        out.xyz_m.dtype == np.float32 and out.reflectance.dtype == np.float32 and out.beam.dtype == np.uint8
    )


def test_an_empty_revolution_is_a_revolution() -> None:
    out = decode(encode(np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int16), 1.0, 1.73, beams=32))
    assert len(out) == 0 and out.beams == 32


def _header(**kw: object) -> bytes:
    fields = {
        "magic": MAGIC,
        "version": 1,
        "beams": 64,
        "flags": 0,
        "n": 0,
        "stamp": 0.0,
        "height": 1.73,
        **kw,
    }
    return struct.pack("<4sBBHIdf", *fields.values())


@pytest.mark.parametrize(
    ("buf", "words"),
    [
        (b"", "length: 0 bytes"),
        (_header()[:-1], "shorter than the 24-byte header"),
        (_header(magic=b"BWOL"), "magic"),
        (_header(version=2), "version: 2"),
        (_header(flags=1), "flags"),
        (_header(beams=0), "beams: 0"),
        (_header(n=MAX_POINTS + 1), "count"),
        (_header(n=1), "length: 24 bytes, but 1 points take 38"),
        (_header() + b"\0", "length: 25 bytes"),
        (_header(stamp=float("nan")), "not finite"),
        (_header(height=float("inf")), "not finite"),
        (_header(n=1) + struct.pack("<3f", 1.0, float("nan"), 0.0) + b"\x10\x00", "xyz_m: point 0"),
        (
            _header(n=1, beams=8) + struct.pack("<3f", 1.0, 2.0, 0.0) + b"\x10\x08",
            "beam: point 0 is on beam 8",
        ),
    ],
)
def test_bad_messages_are_refused_naming_the_field(buf: bytes, words: str) -> None:
    with pytest.raises(LidarScanError, match=words):
        decode(buf)


@pytest.mark.parametrize(
    ("kw", "words"),
    [
        ({"xyz_m": np.zeros((3, 2))}, "xyz_m: expected"),
        ({"reflectance": np.zeros(2)}, "3 points"),
        ({"beams": 0}, "beams"),
        ({"beams": 256}, "beams"),
        ({"stamp_s": float("nan")}, "finite"),
        ({"xyz_m": np.full((3, 3), np.inf)}, "xyz_m: point 0"),
        ({"reflectance": np.array([0.0, 1.5, 0.0])}, "reflectance"),
        ({"reflectance": np.array([0.0, np.nan, 0.0])}, "reflectance"),
        ({"beam": np.array([0, 64, 1])}, "beam"),
        ({"beam": np.array([0, -1, 1])}, "beam"),
        ({"beam": np.array([0.0, 1.0, 2.0])}, "beam"),
    ],
)
def test_arrays_that_make_no_message_are_refused(kw: dict[str, object], words: str) -> None:
    args: dict[str, object] = {
        "xyz_m": np.zeros((3, 3)),
        "reflectance": np.zeros(3),
        "beam": np.zeros(3, np.int16),
        "stamp_s": 0.0,
        "sensor_height_m": 1.73,
        **kw,
    }
    with pytest.raises(LidarScanError, match=words):
        encode(**args)  # type: ignore[arg-type]


def _check(buf: bytes) -> None:
    try:
        out = decode(buf)
    except LidarScanError:
        return
    assert len(buf) == HEADER_BYTES + len(out) * POINT_BYTES
    assert np.isfinite(out.xyz_m).all() and np.all(out.beam < out.beams)
    assert np.all((out.reflectance >= 0.0) & (out.reflectance <= 1.0))


@FUZZ
@given(st.binary(max_size=200))
def test_random_bytes_decode_or_are_refused(buf: bytes) -> None:
    _check(buf)


@FUZZ
@given(st.data())
def test_random_bodies_behind_a_valid_header_decode_or_are_refused(data: st.DataObject) -> None:
    n = data.draw(st.integers(0, 6))
    beams = data.draw(st.integers(1, 255))
    extra = data.draw(st.sampled_from([0, 0, 0, -1, 1]))
    body = data.draw(
        st.binary(min_size=max(0, n * POINT_BYTES + extra), max_size=max(0, n * POINT_BYTES + extra))
    )
    _check(_header(n=n, beams=beams) + body)


@FUZZ
@given(st.data())
def test_mutated_messages_decode_or_are_refused(data: st.DataObject) -> None:
    xyz, refl, beam = _arrays(n=data.draw(st.integers(0, 5)), seed=data.draw(st.integers(0, 1000)))
    buf = bytearray(encode(xyz, refl, beam, 0.5, 1.73))
    how = data.draw(st.sampled_from(["flip", "byte", "truncate", "extend"]))
    if how == "flip":
        i = data.draw(st.integers(0, len(buf) - 1))
        buf[i] ^= 1 << data.draw(st.integers(0, 7))
    elif how == "byte":
        buf[data.draw(st.integers(0, len(buf) - 1))] = data.draw(st.integers(0, 255))
    elif how == "truncate":
        del buf[data.draw(st.integers(0, len(buf) - 1)) :]
    else:
        buf += data.draw(st.binary(min_size=1, max_size=20))
    _check(bytes(buf))
    _check(memoryview(buf))  # type: ignore[arg-type]
