"""The generated vehicle-CAN packers against the general codec they stand in for.

`VehicleCodec` packs and unpacks through straight-line code generated per message from the DBC
(`vehicle_can._generate_packers`) and falls back to the general, signal-by-signal code
(`pack_general`, `unpack_general`) for anything else. The fallback is what raises the precise
errors, so the generated code must (a) give the same bits and frames wherever it answers, and
(b) answer for every plain frame, or the speed-up is gone without anyone noticing.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from bywire.protocol.vehicle_can import (
    COUNTER_START_BIT,
    FrameError,
    MessageInfo,
    SignalInfo,
    VehicleCodec,
    pack_general,
    unpack_general,
)

CODEC = VehicleCodec()
MESSAGES = CODEC.messages
PACKERS = CODEC._packers
SETTINGS = settings(max_examples=400, deadline=None)


def plain_value(sig: SignalInfo) -> st.SearchStrategy[Any]:
    """A value a sender normally passes: a float in the DBC range, a bool, an enum member."""
    if sig.kind == "float":
        return st.floats(sig.minimum, sig.maximum, allow_nan=False)
    if sig.kind == "bool":
        return st.booleans()
    assert sig.enum is not None
    return st.sampled_from(list(sig.enum))


def any_value(sig: SignalInfo) -> st.SearchStrategy[Any]:
    """Plain values and everything else a caller might pass: out of range, NaN, infinities, ints,
    numpy floats, 0/1 for flags, raw ints or foreign members for enums, wrong types."""
    span = sig.maximum - sig.minimum
    odd = st.one_of(
        st.floats(sig.minimum - span, sig.maximum + span),
        st.sampled_from([math.nan, math.inf, -math.inf, -0.0, 0, 1, 2, -1, True, False, None, "1", 1e300]),
        st.integers(-(2**40), 2**40),
        st.floats(sig.minimum, sig.maximum, allow_nan=False).map(np.float64),
        st.integers(0, 300),
    )
    return st.one_of(plain_value(sig), odd)


def build(info: MessageInfo, values: dict[str, Any]) -> Any:
    return info.frame_type(**values)


@st.composite
def message_and_values(draw: st.DrawFn, plain: bool) -> tuple[MessageInfo, dict[str, Any]]:
    info = draw(st.sampled_from(MESSAGES))
    pick = plain_value if plain else any_value
    return info, {sig.field: draw(pick(sig)) for sig in info.signals}


def generated(info: MessageInfo, frame: Any, saturate: bool) -> int | None:
    """The generated packer's payload, or None where it leaves the frame to the general path."""
    packers = PACKERS[info.frame_id]
    return (packers.pack_saturating if saturate else packers.pack)(frame, 5 << COUNTER_START_BIT)


def general(info: MessageInfo, frame: Any, saturate: bool) -> int | str:
    """The general path's payload, or its error's type and message."""
    try:
        return pack_general(info, frame, 5 << COUNTER_START_BIT, saturate)
    except (ValueError, TypeError) as exc:
        return f"{type(exc).__name__}: {exc}"


@SETTINGS
@given(message_and_values(plain=True), st.booleans())
def test_plain_frames_take_the_generated_path_with_the_general_bits(
    mv: tuple[MessageInfo, dict[str, Any]], saturate: bool
) -> None:
    info, values = mv
    frame = build(info, values)
    fast = generated(info, frame, saturate)
    assert fast is not None, f"{info.name}: the generated packer declined a plain frame {frame}"
    assert fast == general(info, frame, saturate)


@SETTINGS
@given(message_and_values(plain=False), st.booleans())
def test_any_value_gives_the_general_bits_or_is_left_to_the_general_path(
    mv: tuple[MessageInfo, dict[str, Any]], saturate: bool
) -> None:
    info, values = mv
    frame = build(info, values)
    fast = generated(info, frame, saturate)
    reference = general(info, frame, saturate)
    if fast is not None:
        assert fast == reference
    # Whatever the path, encode answers exactly as the general code does: same bits or same error.
    try:
        msg = CODEC.encode(frame, 5, saturate=saturate)
    except (ValueError, TypeError) as exc:
        assert f"{type(exc).__name__}: {exc}" == reference
    else:
        assert isinstance(reference, int)
        payload = int.from_bytes(msg.data, "little")
        assert payload >> 8 == reference >> 8  # byte 0 is the CRC, computed after the packing


@SETTINGS
@given(st.sampled_from(MESSAGES), st.data())
def test_unpack_gives_the_general_frame_or_leaves_the_error_to_it(
    info: MessageInfo, data: st.DataObject
) -> None:
    payload = data.draw(st.integers(0, (1 << (8 * info.length)) - 1))
    fast = PACKERS[info.frame_id].unpack(payload)
    try:
        reference = unpack_general(info, payload)
    except FrameError:
        assert fast is None
    else:
        assert fast is not None, f"{info.name}: the generated unpacker declined a valid payload"
        assert fast == reference
        assert [type(getattr(fast, s.field)) for s in info.signals] == [
            type(getattr(reference, s.field)) for s in info.signals
        ]


def test_every_message_has_generated_packers() -> None:
    assert set(PACKERS) == {m.frame_id for m in MESSAGES}
