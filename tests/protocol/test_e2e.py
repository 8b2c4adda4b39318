"""E2E protection primitives: CRC-8 SAE J1850, the alive-counter check, the sender's counters."""

from __future__ import annotations

import itertools

import pytest
from hypothesis import given
from hypothesis import strategies as st

from bywire.protocol.e2e import (
    COUNTER_MODULO,
    CounterStatus,
    TxCounter,
    check_counter,
    counter_delta,
    crc8_j1850,
    crc_ok,
    e2e_crc,
    protect,
    read_counter,
)

# AUTOSAR SWS CRC Library, CRC8 SAE J1850 check values, and the CRC catalogue's check string.
J1850_VECTORS = [
    (b"123456789", 0x4B),
    (bytes.fromhex("00000000"), 0x59),
    (bytes.fromhex("F20183"), 0x37),
    (bytes.fromhex("0FAA0055"), 0x79),
    (bytes.fromhex("00FF5511"), 0xB8),
    (bytes.fromhex("332255AABBCCDDEEFF"), 0xCB),
    (bytes.fromhex("926B55"), 0x8C),
    (bytes.fromhex("FFFFFFFF"), 0x74),
]


def crc8_bitwise(data: bytes) -> int:
    """Reference: the polynomial division bit by bit, independent of the table."""
    crc = 0xFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1D) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc ^ 0xFF


@pytest.mark.parametrize(("data", "crc"), J1850_VECTORS)
def test_crc8_j1850_known_vectors(data: bytes, crc: int) -> None:
    assert crc8_j1850(data) == crc


def test_crc8_j1850_empty_is_init_xor_out() -> None:
    assert crc8_j1850(b"") == 0x00


@given(st.binary(max_size=64))
def test_table_matches_bitwise_reference(data: bytes) -> None:
    assert crc8_j1850(data) == crc8_bitwise(data)


@given(st.integers(0, 0x7FF), st.binary(min_size=1, max_size=8))
def test_e2e_crc_covers_data_id_little_endian_then_bytes_1_to_7(frame_id: int, data: bytes) -> None:
    assert e2e_crc(frame_id, data) == crc8_j1850(bytes([frame_id & 0xFF, frame_id >> 8]) + data[1:])


def test_e2e_crc_ignores_byte_0() -> None:
    data = bytearray(range(8))
    before = e2e_crc(0x120, data)
    data[0] ^= 0xFF
    assert e2e_crc(0x120, data) == before


def test_e2e_crc_rejects_ids_outside_two_bytes() -> None:
    with pytest.raises(ValueError, match="0x10000"):
        e2e_crc(0x10000, bytes(8))


@given(st.integers(0, 0x7FF), st.binary(min_size=8, max_size=8), st.integers(0, 15))
def test_protect_writes_counter_and_crc_and_keeps_upper_nibble(
    frame_id: int, data: bytes, counter: int
) -> None:
    buf = bytearray(data)
    protect(frame_id, buf, counter)
    assert read_counter(buf) == counter
    assert buf[1] >> 4 == data[1] >> 4
    assert buf[2:] == data[2:]
    assert crc_ok(frame_id, buf)


@pytest.mark.parametrize("counter", [-1, 16, 255])
def test_protect_rejects_counter_out_of_range(counter: int) -> None:
    with pytest.raises(ValueError, match=f"alive counter {counter}"):
        protect(0x100, bytearray(8), counter)


def test_protect_rejects_short_payload() -> None:
    with pytest.raises(ValueError, match="1 byte"):
        protect(0x100, bytearray(1), 0)


def test_crc_ok_false_on_empty() -> None:
    assert not crc_ok(0x100, b"")


def test_every_one_and_two_bit_error_in_a_frame_or_its_id_is_detected() -> None:
    # CRC-8 0x1D has Hamming distance 3 on an 80-bit codeword (16-bit id + 56 data bits + 8 CRC
    # bits): every error of one or two bits is caught, whatever the data. Checked exhaustively here.
    frame_id = 0x121
    data = bytearray(b"\x00\x35\x10\x27\xfe\x80\x01\x99")
    protect(frame_id, data, 5)
    positions = [("id", i) for i in range(16)] + [("data", i) for i in range(64)]
    for n in (1, 2):
        for flips in itertools.combinations(positions, n):
            fid, buf = frame_id, bytearray(data)
            for where, bit in flips:
                if where == "id":
                    fid ^= 1 << bit
                else:
                    buf[bit // 8] ^= 1 << (bit % 8)
            assert not crc_ok(fid, buf), flips


# -- alive counter ----------------------------------------------------------------------------------


def test_counter_wrap_15_to_0_is_in_order() -> None:
    assert counter_delta(15, 0) == 1
    assert check_counter(15, 0) == (CounterStatus.OK, 0)


@pytest.mark.parametrize(
    ("last", "new", "expected"),
    [
        (None, 9, (CounterStatus.INITIAL, 0)),
        (4, 5, (CounterStatus.OK, 0)),
        (4, 4, (CounterStatus.REPEATED, 0)),
        (4, 6, (CounterStatus.LOST, 1)),
        (4, 7, (CounterStatus.LOST, 2)),
        (4, 8, (CounterStatus.OUT_OF_ORDER, 0)),  # 3 lost > the default window of max_delta 3
        (4, 3, (CounterStatus.OUT_OF_ORDER, 0)),  # one step back
        (14, 1, (CounterStatus.LOST, 2)),  # gap across the wrap
        (1, 14, (CounterStatus.OUT_OF_ORDER, 0)),  # back across the wrap
    ],
)
def test_check_counter_table(last: int | None, new: int, expected: tuple[CounterStatus, int]) -> None:
    assert check_counter(last, new) == expected


@given(st.integers(0, 15), st.integers(0, 15), st.integers(1, 14))
def test_check_counter_classifies_by_modular_delta(last: int, new: int, max_delta: int) -> None:
    status, lost = check_counter(last, new, max_delta=max_delta)
    delta = (new - last) % 16
    if delta == 0:
        assert status is CounterStatus.REPEATED
    elif delta == 1:
        assert (status, lost) == (CounterStatus.OK, 0)
    elif delta <= max_delta:
        assert (status, lost) == (CounterStatus.LOST, delta - 1)
    else:
        assert status is CounterStatus.OUT_OF_ORDER
    assert status.accepted == (status in (CounterStatus.OK, CounterStatus.LOST))


@given(st.integers(0, 15), st.integers(0, 15))
def test_timeout_resyncs_whatever_the_counter_but_a_repeat(last: int, new: int) -> None:
    status = check_counter(last, new, timed_out=True)
    if new == last:
        # A sender frozen on its last frame stays timed out: a repeat is never fresh data.
        assert status == (CounterStatus.REPEATED, 0) and not status[0].accepted
    else:
        assert status == (CounterStatus.RESYNC, 0) and status[0].accepted


@pytest.mark.parametrize("max_delta", [0, 15, -3])
def test_check_counter_rejects_bad_window(max_delta: int) -> None:
    with pytest.raises(ValueError, match="max_delta"):
        check_counter(1, 2, max_delta=max_delta)


def test_tx_counter_per_id_and_wrap() -> None:
    tx = TxCounter()
    first = [tx.next(0x120) for _ in range(COUNTER_MODULO + 2)]
    assert first == [*range(16), 0, 1]
    assert tx.peek(0x121) == 0
    assert tx.next(0x121) == 0
    assert tx.peek(0x120) == 2
    assert tx.peek(0x120) == 2  # peeking does not advance
