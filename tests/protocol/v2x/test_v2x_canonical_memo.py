"""The canonical check's shortcut (codec._RecentEncodings) never changes a verdict: every datagram,
ours or altered, decodes to the same message or is refused for the same reason with the shortcut as
with every datagram re-encoded (the reference path)."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bywire.protocol.v2x import codec
from bywire.protocol.v2x.codec import V2xDecodeError, _exact, _RecentEncodings
from bywire.protocol.v2x.iclcm import ControllerType, CooperativeState, iclcm_value
from bywire.protocol.v2x.schemas import SchemaSet, compiled
from bywire.protocol.v2x.wire import decode, encode
from tests.protocol.v2x.test_v2x_codec import T0_S, vehicle_states

ICLCM = "IGAMECooperativeLaneChangeMessage"


@pytest.fixture(autouse=True)
def _remembered() -> object:
    """The shortcut is on where a process receives what it sent (SIL), off otherwise."""
    codec.remember_own_encodings(True)
    yield
    codec.remember_own_encodings(False)


def _outcome(data: bytes, reference_s: float) -> object:
    try:
        return decode(data, reference_s)
    except V2xDecodeError as e:
        return (e.reason, str(e))


def _altered(data: bytes, draw: st.DrawFn) -> bytes:
    """The datagram as sent, or with a byte appended, one bit flipped, or its last byte cut."""
    kind = draw(st.sampled_from(["same", "append", "flip", "cut"]))
    if kind == "append":
        return data + bytes([draw(st.integers(0, 255))])
    if kind == "flip":
        i = draw(st.integers(0, 8 * len(data) - 1))
        b = bytearray(data)
        b[i // 8] ^= 0x80 >> (i % 8)
        return bytes(b)
    if kind == "cut":
        return data[:-1]
    return data


cooperative_states = st.builds(
    CooperativeState,
    station_id=st.integers(0, 2**32 - 1),
    generation_time_s=st.floats(T0_S - 30.0, T0_S + 30.0),
    controller_type=st.sampled_from(list(ControllerType)),
    target_accel_mps2=st.one_of(st.none(), st.floats(-10.0, 10.0)),
    time_headway_s=st.one_of(st.none(), st.floats(0.0, 2.0)),
    cruise_speed_mps=st.one_of(st.none(), st.floats(0.0, 49.0)),
    lane=st.one_of(st.none(), st.integers(1, 3)),
    participants_ready=st.booleans(),
)


@given(st.data(), st.one_of(vehicle_states(), cooperative_states))
@settings(max_examples=200, deadline=None)
def test_every_datagram_gets_the_verdict_of_the_reference_path(data: st.DataObject, msg: object) -> None:
    sent = encode(msg)  # type: ignore[arg-type]
    received = _altered(sent, data.draw)
    reference_s = msg.generation_time_s + 0.1  # type: ignore[attr-defined]
    with_shortcut = _outcome(received, reference_s)
    codec._ENCODED.clear()
    assert _outcome(received, reference_s) == with_shortcut


def test_nothing_is_remembered_unless_the_process_asks() -> None:
    """Off (HIL, a car: sender and receiver in separate processes) an encode costs no `repr`."""
    codec.remember_own_encodings(False)
    spec = compiled(SchemaSet.ICLCM)
    data = encode(CooperativeState(9, T0_S, ControllerType.CACC, -2.34, lane=2))
    assert len(codec._ENCODED) == 0
    assert not codec._ENCODED.known(data, spec, ICLCM, spec.decode(ICLCM, data))


def test_our_own_datagram_is_known_only_with_its_spec_type_and_value() -> None:
    """Remembered are asn1tools' encodings (the fast encoder's are checked by encoding them again)."""
    spec = compiled(SchemaSet.ICLCM)
    msg = CooperativeState(9, T0_S, ControllerType.CACC, -2.34, lane=2)
    data = codec.asn1_encode(spec, ICLCM, iclcm_value(msg), "iCLCM")
    value = spec.decode(ICLCM, data)
    assert codec._ENCODED.known(data, spec, ICLCM, value)
    assert not codec._ENCODED.known(data + b"\x00", spec, ICLCM, value)
    assert not codec._ENCODED.known(data, compiled(SchemaSet.CAM_V2), ICLCM, value)
    assert not codec._ENCODED.known(data, spec, "CAM", value)
    value["itsHeader"]["stationID"] = 10
    assert not codec._ENCODED.known(data, spec, ICLCM, value)


@pytest.mark.parametrize(
    ("a", "b"),
    [(True, 1), (0.0, -0.0), (1, 1.0), ([1], (1,)), ({"a": 1}, {"a": 1, "b": None}), (b"\x00", "\x00")],
)
def test_values_that_may_encode_differently_are_not_the_same(a: object, b: object) -> None:
    assert _exact(a) != _exact(b)
    assert _exact({"x": [a]}) == _exact({"x": [a]})


def test_the_memory_is_bounded_and_keeps_the_newest() -> None:
    memo = _RecentEncodings()
    memo.enabled = True
    spec = object()
    for k in range(_RecentEncodings.SIZE + 10):
        memo.remember(k.to_bytes(4, "big"), spec, "T", {"k": k})
    assert len(memo) == _RecentEncodings.SIZE
    assert not memo.known((0).to_bytes(4, "big"), spec, "T", {"k": 0})
    last = _RecentEncodings.SIZE + 9
    assert memo.known(last.to_bytes(4, "big"), spec, "T", {"k": last})
