"""End-to-end protection of vehicle-CAN frames: CRC-8 SAE J1850 and a 4-bit alive counter.

DESIGN section 3: every vehicle-CAN frame carries a checksum and an alive counter, and receivers reject
stale, repeated, out-of-order or corrupt frames and count each kind. The scheme is modelled on AUTOSAR
E2E profile 1 (SWS E2ELibrary):

- As in profile 1 variant 1A: byte 0 is the CRC, the low nibble of byte 1 the alive counter, and the
  CRC covers the two data-id bytes (data id mode "both") and then bytes 1..7, so it protects the
  counter and every signal. CRC-8 SAE J1850: polynomial 0x1D, initial value 0xFF, final xor 0xFF (the
  AUTOSAR Crc_CalculateCRC8 parameters), table driven. Hamming distance 3 over the 80-bit codeword:
  every 1- or 2-bit error is caught, longer bursts with probability 255/256.
- Deviation: the data id is the CAN frame id (little-endian) instead of a separately configured id, so
  a frame replayed under another id fails its CRC (always if the ids differ in 1 or 2 bits).
- Deviation: the counter uses all 16 values, 15 wraps to 0 (profile 1 counts 0..14, 15 is invalid).
- Deviation: no SyncCounter phase. `check_counter`: delta 0 is a repeat, 1 is in order, 2..max_delta is
  in order with frames lost, anything else is out of order (a jump back, or too many frames lost to
  tell); the reference counter moves only with accepted frames. After a receive timeout the receiver
  accepts the next CRC-valid frame as a re-sync whatever its counter (`CounterStatus.RESYNC`) except
  the last accepted counter itself: a repeat is never fresh (DESIGN section 4), so a sender frozen on
  its last frame stays timed out for as long as it repeats it. The timeout itself is the receiver's
  (vehicle_rx).
"""

from __future__ import annotations

from collections.abc import Iterable
from enum import StrEnum

CRC8_J1850_POLY = 0x1D
CRC8_J1850_INIT = 0xFF
CRC8_J1850_XOR_OUT = 0xFF
CRC_BYTE = 0  # payload byte holding the CRC
COUNTER_BYTE = 1  # payload byte whose low nibble holds the alive counter
COUNTER_MASK = 0x0F
COUNTER_MODULO = 16
DEFAULT_MAX_DELTA_COUNTER = 3  # tolerate 2 lost frames in a row (20 ms at 100 Hz) before out-of-order


def _make_table(poly: int) -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ poly) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return tuple(table)


_TABLE = _make_table(CRC8_J1850_POLY)


def _crc8_update(crc: int, data: Iterable[int]) -> int:
    table = _TABLE
    for byte in data:
        crc = table[crc ^ byte]
    return crc


def crc8_j1850(data: bytes | bytearray | memoryview) -> int:
    """CRC-8 SAE J1850 (poly 0x1D, init 0xFF, xor-out 0xFF) of `data`; b"123456789" gives 0x4B."""
    return _crc8_update(CRC8_J1850_INIT, data) ^ CRC8_J1850_XOR_OUT


def _check_frame_id(frame_id: int) -> None:
    if not 0 <= frame_id <= 0xFFFF:
        raise ValueError(f"E2E data id: frame id {frame_id:#x} does not fit the 2-byte data id")


# The CRC register after the two data-id bytes, per frame id: every frame of an id starts from the
# same value, and a bus has a handful of ids (bounded anyway: at most 2**16 entries).
_ID_SEEDS: dict[int, int] = {}


def e2e_crc(frame_id: int, data: bytes | bytearray | memoryview) -> int:
    """The frame's E2E CRC: CRC-8 J1850 over the frame id (2 bytes little-endian) then data[1:]."""
    crc = _ID_SEEDS.get(frame_id) if type(frame_id) is int else None  # 1.0 == 1, but is no frame id
    if crc is None:
        _check_frame_id(frame_id)
        crc = _ID_SEEDS[frame_id] = _crc8_update(CRC8_J1850_INIT, (frame_id & 0xFF, frame_id >> 8))
    table = _TABLE
    for byte in data[1:]:  # every frame, every receiver: the loop inline, not through _crc8_update
        crc = table[crc ^ byte]
    return crc ^ CRC8_J1850_XOR_OUT


def crc_ok(frame_id: int, data: bytes | bytearray | memoryview) -> bool:
    """True if byte 0 of a non-empty `data` holds the E2E CRC of the rest under `frame_id`."""
    return len(data) > CRC_BYTE and data[CRC_BYTE] == e2e_crc(frame_id, data)


def read_counter(data: bytes | bytearray | memoryview) -> int:
    """The alive counter: low nibble of byte 1 (the caller has checked the length)."""
    return data[COUNTER_BYTE] & COUNTER_MASK


def protect(frame_id: int, data: bytearray, counter: int) -> None:
    """Write `counter` into byte 1's low nibble of `data` in place, then the CRC into byte 0."""
    if not 0 <= counter < COUNTER_MODULO:
        raise ValueError(f"E2E frame {frame_id:#x}: alive counter {counter} outside 0..{COUNTER_MODULO - 1}")
    if len(data) <= COUNTER_BYTE:
        raise ValueError(f"E2E frame {frame_id:#x}: {len(data)} byte(s) cannot hold CRC and counter")
    data[COUNTER_BYTE] = (data[COUNTER_BYTE] & ~COUNTER_MASK & 0xFF) | counter
    data[CRC_BYTE] = e2e_crc(frame_id, data)


class RejectReason(StrEnum):
    """Why a receiver dropped a frame; each is counted per frame id and in total."""

    MALFORMED = "malformed"  # wrong DLC, remote/error/extended/FD frame, unknown id, value outside the DBC
    CORRUPT = "corrupt"  # CRC mismatch
    REPEATED = "repeated"  # same alive counter as the last accepted frame
    OUT_OF_ORDER = "out_of_order"  # counter went back, or jumped by more than the allowed gap
    STALE = "stale"  # receive timestamp older than the maximum age when processed (or in the future)


class CounterStatus(StrEnum):
    """Outcome of the alive-counter check of one CRC-valid frame."""

    INITIAL = "initial"  # first frame of this id: accepted, nothing to compare with
    OK = "ok"  # next counter: accepted
    LOST = "lost"  # counter advanced by 2..max_delta: accepted, delta - 1 frames lost
    RESYNC = "resync"  # after a timeout: accepted whatever the counter
    REPEATED = "repeated"
    OUT_OF_ORDER = "out_of_order"

    @property
    def accepted(self) -> bool:
        return self not in COUNTER_REJECTS


COUNTER_REJECTS = frozenset({CounterStatus.REPEATED, CounterStatus.OUT_OF_ORDER})


def counter_delta(last: int, new: int) -> int:
    """How far the counter advanced from `last` to `new`, modulo 16 (15 -> 0 is 1)."""
    return (new - last) % COUNTER_MODULO


def check_counter(
    last: int | None, new: int, *, timed_out: bool = False, max_delta: int = DEFAULT_MAX_DELTA_COUNTER
) -> tuple[CounterStatus, int]:
    """Classify a received counter against the last accepted one; returns (status, frames lost).

    `last` is None before the first accepted frame. `timed_out` means the receiver has had no
    accepted frame of this id for longer than its timeout: the frame re-synchronises the sequence.
    """
    if not 1 <= max_delta < COUNTER_MODULO - 1:
        raise ValueError(f"E2E max_delta {max_delta} outside 1..{COUNTER_MODULO - 2}")
    if last is None:
        return CounterStatus.INITIAL, 0
    delta = counter_delta(last, new)
    # A repeated counter is never fresh data, not even after a timeout: a frozen sender that repeats
    # its last frame must stay timed out, or it would be re-accepted once per timeout.
    if delta == 0:
        return CounterStatus.REPEATED, 0
    if timed_out:
        return CounterStatus.RESYNC, 0
    if delta == 1:
        return CounterStatus.OK, 0
    if delta <= max_delta:
        return CounterStatus.LOST, delta - 1
    return CounterStatus.OUT_OF_ORDER, 0


class TxCounter:
    """Hands out the alive counter per frame id: 0, 1, ..., 15, 0, ... independently for each id."""

    __slots__ = ("_next",)

    def __init__(self) -> None:
        self._next: dict[int, int] = {}

    def peek(self, frame_id: int) -> int:
        """The counter the next frame of `frame_id` will carry, without using it up."""
        return self._next.get(frame_id, 0)

    def next(self, frame_id: int) -> int:
        """The counter for the frame of `frame_id` being sent now; advances that id's sequence."""
        counter = self._next.get(frame_id, 0)
        self._next[frame_id] = (counter + 1) % COUNTER_MODULO
        return counter
