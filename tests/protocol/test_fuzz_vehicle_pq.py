"""Fuzzing the vehicle-CAN receiver on profile pq: the car's VW PQ messages beside our own.

Random and mutated frames never raise and always count exactly one outcome; a message with a
checksum (ours: the E2E CRC; the car's: the XOR) is accepted only with a valid one; whatever is
accepted decodes to values inside its DBC range, and a car selector outside D and R is never a gear.
"""

from __future__ import annotations

import random
from collections import Counter
from typing import Any

import can
from hypothesis import given, settings
from hypothesis import strategies as st

from bywire.protocol.e2e import crc_ok
from bywire.protocol.ecu_types import Gear
from bywire.protocol.vehicle_can import (
    CHECKSUM_E2E,
    CHECKSUM_XOR,
    GearReport,
    MessageInfo,
    RejectReason,
    VehicleCodec,
    VehicleFrame,
    VehicleTx,
    xor_checksum,
)
from bywire.protocol.vehicle_rx import VehicleRx

CODEC = VehicleCodec(profile="pq")
INFOS = CODEC.messages
KNOWN_IDS = [m.frame_id for m in INFOS]
OUTCOMES = ("accepted", "ignored", *(r.value for r in RejectReason))


def outcome_counts(rx: VehicleRx) -> Counter[str]:
    counts = rx.counts()
    return Counter({k: counts[k] for k in OUTCOMES})


def checksum_ok(info: MessageInfo, data: bytes | bytearray) -> bool:
    if info.checksum == CHECKSUM_E2E:
        return crc_ok(info.frame_id, data)
    if info.checksum == CHECKSUM_XOR:
        return data[info.checksum_byte] == xor_checksum(data, info.checksum_byte)
    return True


def in_range(info: MessageInfo, frame: VehicleFrame) -> bool:
    for sig in info.signals:
        value = getattr(frame, sig.field)
        if sig.kind in ("float", "magnitude") and not sig.minimum - 1e-9 <= abs(value) <= sig.maximum + 1e-9:
            return False
        if sig.kind == "mapped" and value not in (member for _, member in sig.mapping):
            return False
    return True


def feed_checked(rx: VehicleRx, msg: can.Message, now_s: float) -> VehicleFrame | None:
    before = outcome_counts(rx)
    frame = rx.feed(msg, now_s)
    step = outcome_counts(rx) - before
    assert sum(step.values()) == 1, step
    assert rx.unexpected_exceptions == 0
    if frame is not None:
        info = CODEC.info(msg.arbitration_id)
        assert isinstance(frame, info.frame_type)
        assert checksum_ok(info, msg.data)  # nothing reaches the ECU without its checksum
        assert in_range(info, frame)
        if isinstance(frame, GearReport):
            assert frame.gear_engaged in (Gear.DRIVE, Gear.REVERSE)
    return frame


@st.composite
def any_message(draw: st.DrawFn) -> can.Message:
    frame_id = draw(st.one_of(st.sampled_from(KNOWN_IDS), st.integers(0, 0x7FF)))
    data = draw(st.binary(min_size=0, max_size=8))
    return can.Message(
        timestamp=0.0,
        arbitration_id=frame_id,
        is_extended_id=draw(st.booleans()),
        is_remote_frame=draw(st.booleans()),
        is_error_frame=draw(st.booleans()),
        dlc=draw(st.one_of(st.just(len(data)), st.integers(0, 15))),
        data=data,
    )


@settings(max_examples=200)
@given(st.lists(any_message(), min_size=1, max_size=12))
def test_random_frames_never_raise_and_count_exactly_one_outcome(msgs: list[can.Message]) -> None:
    rx = VehicleRx(CODEC, max_age_cycles=None)
    for msg in msgs:
        feed_checked(rx, msg, 0.0)
    assert sum(outcome_counts(rx).values()) == len(msgs)


@settings(max_examples=300)
@given(st.sampled_from(INFOS), st.lists(st.binary(min_size=8, max_size=8), min_size=1, max_size=20))
def test_random_payloads_are_accepted_only_with_a_valid_checksum_and_in_range(
    info: MessageInfo, payloads: list[bytes]
) -> None:
    rx = VehicleRx(CODEC, max_age_cycles=None)
    for i, raw in enumerate(payloads):
        data = raw[: info.length]
        msg = can.Message(arbitration_id=info.frame_id, is_extended_id=False, data=data)
        frame = feed_checked(rx, msg, i * info.cycle_time_s)
        if not checksum_ok(info, data):
            assert frame is None


def random_frame(rng: random.Random, info: MessageInfo) -> VehicleFrame:
    values: dict[str, Any] = {}
    for sig in info.signals:
        if sig.kind == "float":
            values[sig.field] = rng.uniform(sig.minimum, sig.maximum)
        elif sig.kind == "magnitude":
            values[sig.field] = rng.uniform(-sig.maximum, sig.maximum)
        elif sig.kind == "bool":
            values[sig.field] = rng.random() < 0.5
        elif sig.kind == "mapped":
            values[sig.field] = rng.choice([member for _, member in sig.mapping])
        else:
            assert sig.enum is not None
            values[sig.field] = rng.choice(list(sig.enum))
    return info.frame_type(**values)  # type: ignore[no-any-return]


@settings(max_examples=200)
@given(
    st.sampled_from([i for i in INFOS if i.checksum != "none"]),
    st.lists(st.tuples(st.booleans(), st.integers(0, 2**32)), max_size=30),
    st.integers(0, 2**32),
)
def test_bit_flips_in_checksummed_messages_never_pass(
    info: MessageInfo, ops: list[tuple[bool, int]], seed: int
) -> None:
    """One flipped bit always spoils an XOR checksum (and our CRC): a flipped frame is never accepted,
    and the valid frames between them still are."""
    rng = random.Random(seed)
    tx, rx = VehicleTx(CODEC), VehicleRx(CODEC, max_age_cycles=None)
    now = 0.0
    flipped_in_a_row = 0
    resyncing = False  # more frames lost in a row than the counter's window: until the timeout re-syncs
    for flip, op_seed in ops:
        msg = tx.encode(random_frame(rng, info))  # a flipped frame still uses up a counter value
        now += info.cycle_time_s
        if not flip:
            resyncing = resyncing or flipped_in_a_row > 2
            frame = feed_checked(rx, msg, now)
            # within the window of lost frames (2 in a row) the stream goes on undisturbed
            assert frame is not None or resyncing
            resyncing = resyncing and frame is None
            flipped_in_a_row = 0
            continue
        data = bytearray(msg.data)
        bit = random.Random(op_seed).randrange(8 * info.length)
        data[bit // 8] ^= 1 << (bit % 8)
        bad = can.Message(arbitration_id=info.frame_id, is_extended_id=False, data=data)
        assert feed_checked(rx, bad, now) is None
        flipped_in_a_row += 1
