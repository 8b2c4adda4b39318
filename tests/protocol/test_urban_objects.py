"""The object-list datagram (protocol/objects.py): round trips, every refusal naming its field, a fuzz test
(random and mutated datagrams give a result or `ObjectListError`, never another exception), and both
transports (in process; loopback UDP)."""

from __future__ import annotations

import contextlib
import math
import struct
import time

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bywire.protocol.objects import (
    EgoPoseRecord,
    ObjectList,
    ObjectListError,
    ObjectRecord,
    decode,
    encode,
    open_object_link,
)


def _sample(n: int = 3, with_objects: bool = True) -> ObjectList:
    objs = (
        tuple(ObjectRecord(i + 1, 10.0 * i, -2.0, 0.5, 3.0, 4.5, 1.8) for i in range(n))
        if with_objects
        else ()
    )
    return ObjectList(12.5, 7, EgoPoseRecord(1.0, 2.0, 0.25, -0.5, 0.01), objs, with_objects)


def test_round_trip_keeps_every_field() -> None:
    msg = _sample()
    out = decode(encode(msg))
    assert out.t_s == 12.5 and out.seq == 7 and out.has_objects
    assert out.pose == msg.pose
    assert [o.object_id for o in out.objects] == [1, 2, 3]
    assert out.objects[1].x_m == 10.0 and out.objects[1].length_m == pytest.approx(4.5)
    pose_only = decode(encode(_sample(0, with_objects=False)))
    assert not pose_only.has_objects and pose_only.objects == ()


@pytest.mark.parametrize(
    ("mutate", "field"),
    [
        (lambda b: b"XXXX" + b[4:], "magic"),
        (lambda b: b[:4] + bytes([9]) + b[5:], "version"),
        (lambda b: b[:5] + bytes([0x80]) + b[6:], "flags"),
        (lambda b: b[:-1], "length"),
        (lambda b: b[:10], "header"),
        (lambda b: b[:8] + struct.pack("<d", math.nan) + b[16:], "t_s"),
    ],
)
def test_bad_datagrams_name_the_field(mutate, field: str) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(ObjectListError, match=field):
        decode(mutate(encode(_sample())))


def test_bad_object_values_name_the_object() -> None:
    bad = ObjectList(1.0, 1, None, (ObjectRecord(5, 0.0, 0.0, 0.0, -1.0, 4.5, 1.8),))
    with pytest.raises(ObjectListError, match=r"objects\[0\].speed_mps"):
        decode(encode(bad))
    huge = ObjectList(1.0, 1, None, (ObjectRecord(5, 0.0, 0.0, 0.0, 1.0, 400.0, 1.8),))
    with pytest.raises(ObjectListError, match=r"objects\[0\].length_m"):
        decode(encode(huge))
    with pytest.raises(ObjectListError, match="pose-only"):
        encode(ObjectList(1.0, 1, None, (ObjectRecord(5, 0, 0, 0, 1, 4, 2),), has_objects=False))


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=400))
def test_fuzz_random_bytes(data: bytes) -> None:
    with contextlib.suppress(ObjectListError):
        decode(data)


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 10), st.lists(st.tuples(st.integers(0, 200), st.integers(0, 255)), max_size=6))
def test_fuzz_mutated_datagrams(n: int, flips: list[tuple[int, int]]) -> None:
    data = bytearray(encode(_sample(n)))
    for pos, value in flips:
        if pos < len(data):
            data[pos] = value
    try:
        out = decode(bytes(data))
    except ObjectListError:
        return
    assert len(out.objects) <= 256 and math.isfinite(out.t_s)


def test_in_process_link_keeps_order() -> None:
    tx = open_object_link("mem://test-objects-order", receiver=False)
    rx = open_object_link("mem://test-objects-order", receiver=True)
    for k in range(3):
        tx.send(encode(ObjectList(float(k), k, None, ())))
    assert [decode(d).seq for d in rx.receive()] == [0, 1, 2]
    assert rx.receive() == []
    tx.close()


def test_udp_loopback_link() -> None:
    from bywire.hil.runner import free_udp_port

    url = f"udp://127.0.0.1:{free_udp_port()}"
    rx = open_object_link(url, receiver=True)
    tx = open_object_link(url, receiver=False)
    try:
        tx.send(encode(_sample(2)))
        got: list[bytes] = []
        deadline = time.monotonic() + 2.0
        while not got and time.monotonic() < deadline:
            got = rx.receive()
            time.sleep(0.01)
        assert len(got) == 1 and len(decode(got[0]).objects) == 2
    finally:
        rx.close()
        tx.close()


def test_link_urls_are_checked() -> None:
    with pytest.raises(ValueError, match="mem://NAME or udp://"):
        open_object_link("tcp://127.0.0.1:1", receiver=True)
    with pytest.raises(ValueError, match="loopback only"):
        open_object_link("udp://10.0.0.1:47000", receiver=False)
